"""Textures and procedural geometry for the simulated workspace.

Everything here is a pure function returning arrays or bytes, so the scene builder in
:mod:`armvision.sim.model` stays a description of the scene and these stay testable.

AprilTag textures come from OpenCV's ``DICT_APRILTAG_36h11`` (the same codes as the AprilTag
library, so pupil-apriltags decodes the same id). OpenCV draws the 8x8-cell black-bordered
code; the detector also needs the white quiet zone around it, which we add here.
"""

from __future__ import annotations

import itertools
import math

import cv2
import numpy as np
from numpy.typing import NDArray

from armvision.errors import SimulationError

#: Cells across a tag36h11 code including its black border (6 data cells + 2 border cells).
TAG36H11_BLACK_CELLS = 8
_ARUCO_FAMILIES = {"tag36h11": cv2.aruco.DICT_APRILTAG_36h11}


def tag_outer_size(black_size: float, white_border_cells: int = 1) -> float:
    """Edge (m) of the printed tag including its white border, given the black square's edge.

    ``black_size`` is what pupil-apriltags calls ``tag_size``; the quiet zone adds
    ``white_border_cells`` cells of ``black_size / 8`` on every side.
    """
    cell = black_size / TAG36H11_BLACK_CELLS
    return black_size + 2 * white_border_cells * cell


def tag_image(
    tag_id: int,
    family: str = "tag36h11",
    pixels_per_cell: int = 16,
    white_border_cells: int = 1,
) -> NDArray[np.uint8]:
    """Greyscale image (H, W) uint8 of one AprilTag, upright, with a white quiet zone.

    Cells are ``pixels_per_cell`` square with hard edges (nearest-neighbour scaling), so the
    black square spans exactly ``8 * pixels_per_cell`` pixels.
    """
    if family not in _ARUCO_FAMILIES:
        raise SimulationError(
            f"the simulator can draw only {sorted(_ARUCO_FAMILIES)} tags, not {family!r};"
            ' set tag.family = "tag36h11"'
        )
    dictionary = cv2.aruco.getPredefinedDictionary(_ARUCO_FAMILIES[family])
    n_codes = dictionary.bytesList.shape[0]
    if not 0 <= tag_id < n_codes:
        raise SimulationError(f"{family} has ids 0..{n_codes - 1}; tag id {tag_id} does not exist")
    code = cv2.aruco.generateImageMarker(dictionary, tag_id, TAG36H11_BLACK_CELLS)
    # OpenCV stores the AprilTag codes turned by 180 degrees relative to the AprilTag
    # library's canonical images; turned back, the detector's tag frame is x right, y down
    # in the upright image (checked against pupil-apriltags' pose in the tests).
    code = np.ascontiguousarray(np.rot90(code, 2))
    code = np.pad(code, white_border_cells, constant_values=255)
    side = code.shape[0] * pixels_per_cell
    scaled = cv2.resize(code, (side, side), interpolation=cv2.INTER_NEAREST)
    return np.asarray(scaled, dtype=np.uint8)


def png_bytes(image: NDArray[np.uint8]) -> bytes:
    """PNG encoding of a greyscale or RGB image (RGB channel order)."""
    bgr = cv2.cvtColor(image, cv2.COLOR_RGB2BGR) if image.ndim == 3 else image
    ok, buf = cv2.imencode(".png", bgr)
    if not ok:  # pragma: no cover - OpenCV always encodes uint8 images
        raise SimulationError("OpenCV could not encode a texture as PNG")
    return buf.tobytes()


def textured_plate_mesh(
    size: float, thickness: float
) -> tuple[NDArray[np.float64], NDArray[np.int64], NDArray[np.float64]]:
    """A square plate (vertices, faces, texcoords) whose +z face shows a whole 2-D texture.

    The plate spans x, y in [-size/2, size/2] and z in [-thickness, 0], so its front face lies
    in z = 0. Texture u runs along +x and v along -y: the top row of the image is at +y,
    which is how the image looks to a viewer on the +z side with +y up.
    The back vertices reuse the edge texels (the white border), so the sides are white too.
    """
    h = size / 2.0
    corners = np.array([[-h, -h], [h, -h], [h, h], [-h, h]])
    uv = np.array([[0.0, 1.0], [1.0, 1.0], [1.0, 0.0], [0.0, 0.0]])
    front = np.column_stack([corners, np.zeros(4)])
    back = np.column_stack([corners, np.full(4, -thickness)])
    vertices = np.vstack([front, back])
    texcoords = np.vstack([uv, uv])
    faces = np.array(
        [
            [0, 1, 2],
            [0, 2, 3],  # front, +z, counter-clockwise seen from +z
            [4, 6, 5],
            [4, 7, 6],  # back
            [0, 4, 5],
            [0, 5, 1],  # sides
            [1, 5, 6],
            [1, 6, 2],
            [2, 6, 7],
            [2, 7, 3],
            [3, 7, 4],
            [3, 4, 0],
        ]
    )
    return vertices, faces, texcoords


def lathe_mesh(
    profile_rz: NDArray[np.float64] | list[tuple[float, float]], segments: int = 32
) -> tuple[NDArray[np.float64], NDArray[np.int64]]:
    """Closed solid of revolution about z from a 2-D outline, as (vertices, faces).

    ``profile_rz`` lists (r, z) points from the axis at the bottom, out and round, back to the
    axis at the top, counter-clockwise in the (r, z) half plane, so the faces point outward.
    Points with r = 0 become a single vertex (a fan), keeping the mesh watertight.
    Example: a cup of radius R, height H and wall t is
    ``[(0, 0), (R, 0), (R, H), (R - t, H), (R - t, t), (0, t)]``.
    """
    profile = np.asarray(profile_rz, dtype=float)
    angles = np.linspace(0.0, 2.0 * math.pi, segments, endpoint=False)
    cos, sin = np.cos(angles), np.sin(angles)
    vertices: list[NDArray[np.float64]] = []
    rings: list[list[int]] = []  # vertex indices of each profile point around the circle
    for r, z in profile:
        start = len(vertices)
        if r <= 1e-12:
            vertices.append(np.array([0.0, 0.0, z]))
            rings.append([start] * segments)
        else:
            vertices.extend(np.column_stack([r * cos, r * sin, np.full(segments, z)]))
            rings.append(list(range(start, start + segments)))
    faces: list[tuple[int, int, int]] = []
    for lower, upper in itertools.pairwise(rings):
        for k in range(segments):
            a, b = lower[k], lower[(k + 1) % segments]
            c, d = upper[(k + 1) % segments], upper[k]
            # Skip the degenerate half of a quad that touches the axis.
            if a != b:
                faces.append((a, b, c))
            if c != d:
                faces.append((a, c, d))
    return np.array(vertices), np.array(faces, dtype=np.int64)


def cup_profile(radius: float, height: float, wall: float) -> list[tuple[float, float]]:
    """Outline (r, z) of an open cup with a flat bottom ``wall`` thick, for :func:`lathe_mesh`."""
    return [
        (0.0, 0.0),
        (radius, 0.0),
        (radius, height),
        (radius - wall, height),
        (radius - wall, wall),
        (0.0, wall),
    ]


def tapered_cup_profile(
    radius: float, bottom_radius: float, height: float, wall: float, base: float
) -> list[tuple[float, float]]:
    """Outline (r, z) of an open cup ``radius`` wide at the rim and ``bottom_radius`` at the
    bottom (a tumbler, a plastic cup), side wall ``wall`` and bottom ``base`` thick."""
    return [
        (0.0, 0.0),
        (bottom_radius, 0.0),
        (radius, height),
        (radius - wall, height),
        (bottom_radius - wall, base),
        (0.0, base),
    ]


def frustum_profile(r_bottom: float, r_top: float, height: float) -> list[tuple[float, float]]:
    """Outline (r, z) of a solid truncated cone (a bottle's shoulder), z from 0 to ``height``."""
    return [(0.0, 0.0), (r_bottom, 0.0), (r_top, height), (0.0, height)]


def bowl_profile(
    radius: float, foot_radius: float, height: float, wall: float, n: int = 8
) -> list[tuple[float, float]]:
    """Outline (r, z) of a bowl: a flat foot of ``foot_radius``, the side curving out (a
    quarter ellipse) to the rim at ``radius``, ``height``; wall ``wall`` thick."""
    t = np.linspace(0.0, math.pi / 2, n)
    out_r = foot_radius + (radius - foot_radius) * np.sin(t)
    out_z = height * (1.0 - np.cos(t))
    outer = [(0.0, 0.0)] + [(float(r), float(z)) for r, z in zip(out_r, out_z)]
    inner = [(float(r - wall), float(max(z, 0.0) + wall)) for r, z in zip(out_r, out_z)]
    inner[-1] = (radius - wall, height)
    return outer + inner[::-1] + [(0.0, wall)]
