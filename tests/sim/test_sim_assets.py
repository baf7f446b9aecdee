"""Tag textures and procedural meshes (sim/assets.py)."""

from __future__ import annotations

import numpy as np
import pytest

from armvision.errors import SimulationError
from armvision.perception.tags import pupil_detector
from armvision.sim import assets


@pytest.mark.parametrize("tag_id", [0, 96, 586])
def test_tag_image_decodes_to_its_id_upright(tag_id: int) -> None:
    image = np.pad(assets.tag_image(tag_id), 50, constant_values=255)
    detector = pupil_detector(families="tag36h11")
    f = 500.0
    (det,) = detector.detect(
        image,
        estimate_tag_pose=True,
        tag_size=0.04,
        camera_params=(f, f, image.shape[1] / 2, image.shape[0] / 2),
    )
    assert det.tag_id == tag_id
    # Seen head-on and upright, the AprilTag frame is x right, y down, z into the tag.
    assert det.pose_R == pytest.approx(np.eye(3), abs=0.02)


def test_tag_image_black_square_spans_eight_cells_inside_a_white_border() -> None:
    image = assets.tag_image(96, pixels_per_cell=10, white_border_cells=1)
    assert image.shape == (100, 100)
    assert np.all(image[:10] == 255) and np.all(image[:, -10:] == 255)
    assert np.all(image[10, 10:90] == 0) and np.all(image[89, 10:90] == 0)


def test_tag_outer_size_adds_one_cell_per_side() -> None:
    assert assets.tag_outer_size(0.04) == pytest.approx(0.05)


def test_unknown_family_or_id_is_a_clear_error() -> None:
    with pytest.raises(SimulationError, match="tag36h11"):
        assets.tag_image(1, family="tag25h9")
    with pytest.raises(SimulationError, match=r"ids 0\.\.586"):
        assets.tag_image(587)


def _edge_counts(faces: np.ndarray) -> dict[tuple[int, int], int]:
    counts: dict[tuple[int, int], int] = {}
    for tri in faces:
        for a, b in ((tri[0], tri[1]), (tri[1], tri[2]), (tri[2], tri[0])):
            key = (min(a, b), max(a, b))
            counts[key] = counts.get(key, 0) + 1
    return counts


def _signed_volume(vertices: np.ndarray, faces: np.ndarray) -> float:
    a, b, c = (vertices[faces[:, k]] for k in range(3))
    return float(np.sum(np.einsum("ij,ij->i", a, np.cross(b, c))) / 6.0)


def test_cup_mesh_is_watertight_outward_and_has_the_volume_of_its_walls() -> None:
    R, H, t = 0.035, 0.1, 0.004
    vertices, faces = assets.lathe_mesh(assets.cup_profile(R, H, t), segments=64)
    assert all(n == 2 for n in _edge_counts(faces).values())
    # Solid volume: outer cylinder minus the hollow (polygon area factor for 64 segments).
    polygon = 64 / (2 * np.pi) * np.sin(2 * np.pi / 64)
    expected = polygon * np.pi * (R**2 * H - (R - t) ** 2 * (H - t))
    assert _signed_volume(vertices, faces) == pytest.approx(expected, rel=1e-6)


def test_plate_mesh_front_face_maps_the_whole_texture() -> None:
    vertices, faces, uv = assets.textured_plate_mesh(0.05, 0.001)
    front = vertices[:, 2] == 0.0
    assert np.ptp(vertices[front, 0]) == pytest.approx(0.05)
    top_left = np.argmin(np.where(front, vertices[:, 0] - vertices[:, 1], np.inf))
    assert vertices[top_left, :2] == pytest.approx([-0.025, 0.025])
    assert uv[top_left] == pytest.approx([0.0, 0.0])  # image row 0 at +y
    assert _signed_volume(vertices, faces) == pytest.approx(0.05 * 0.05 * 0.001)
