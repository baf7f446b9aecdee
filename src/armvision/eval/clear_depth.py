"""Depth on clear plastic: a real D435 (ClearGrasp's real-val frames) against SimCamera.

:func:`measure_real` reads the raw D435 depth of clear bottles and cups, their true depth
(the same scene with spray-painted twins) and the objects' mask from a folder of ClearGrasp's
``real-val/d435`` files (read in place, never copied: their licence is evaluation-only), and
sorts every masked pixel with a true depth into

- **missing**: no depth (0);
- **behind**: raw - true > +2 cm, the surface behind seen through the plastic;
- **wrong**: otherwise |raw - true| > 1 cm;
- **good**: the rest.

It adds the error sizes, the same shares by true distance and by viewing angle (the angle
between the surface normal and the pixel's ray, from ``*-normals.exr``), and two habits of the
camera off the clear objects measured on the painted-twin frames: speckle holes (small
islands of no depth) and flying pixels (depth between the near and the far side of an edge).
:func:`measure_sim` measures SimCamera's frames of clear bottles the same way, the true depth
being the render with the clear walls opaque.
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENCV_IO_ENABLE_OPENEXR", "1")  # before cv2 is imported

import dataclasses
import itertools
import math
from collections.abc import Iterable
from pathlib import Path
from typing import Any, Literal

import cv2
import numpy as np
from numpy.typing import NDArray

from armvision.config import Config
from armvision.errors import ConfigError

BEHIND_M = 0.02  # raw - true above this: the surface behind
WRONG_M = 0.01  # |raw - true| above this (and not behind): wrong
FX = FY = 921.0  # camera_intrinsics.yaml of the ClearGrasp d435 sample (1280x720)
CX, CY = 642.0, 359.0
DISTANCE_BINS_M = (0.0, 0.5, 0.6, 0.7, 10.0)
ANGLE_BINS_DEG = (0.0, 30.0, 50.0, 70.0, 90.01)
CATEGORIES = ("missing", "behind", "wrong", "good")
SPECKLE_MAX_AREA = 16  # px at 1280x720: a hole this small is speckle, not a shadow or a surface


def _read_exr(path: Path) -> NDArray[np.float32]:
    img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if img is None:
        raise ConfigError(f"cannot read {path} (needs OpenCV with OpenEXR)")
    return np.asarray(img, dtype=np.float32)


def frame_ids(folder: str | os.PathLike[str]) -> list[str]:
    """The frames in ``folder``: every ``<id>-transparent-depth-img.exr`` with its files."""
    root = Path(folder)
    if not root.is_dir():
        raise ConfigError(f"{root} is not a folder")
    ids = sorted(p.name.split("-")[0] for p in root.glob("*-transparent-depth-img.exr"))
    if not ids:
        raise ConfigError(f"{root} holds no *-transparent-depth-img.exr")
    return ids


def classify(raw: NDArray[np.floating], true: NDArray[np.floating]) -> dict[str, NDArray[np.bool_]]:
    """The four categories for pixels with a true depth (raw 0 or not finite = missing)."""
    missing = ~np.isfinite(raw) | (raw <= 0)
    d = np.where(missing, 0.0, raw - true)
    behind = ~missing & (d > BEHIND_M)
    wrong = ~missing & ~behind & (np.abs(d) > WRONG_M)
    good = ~missing & ~behind & ~wrong
    return {"missing": missing, "behind": behind, "wrong": wrong, "good": good}


def _stats(raw: NDArray[np.floating], true: NDArray[np.floating]) -> dict[str, Any]:
    """Shares and error sizes of pixels (1-D arrays, all with a true depth)."""
    n = int(raw.size)
    out: dict[str, Any] = {"pixels": n}
    if n == 0:
        return out
    cats = classify(raw, true)
    for name in CATEGORIES:
        out[name] = float(cats[name].mean())
    err = np.abs(raw - true)[~cats["missing"]]
    out["median_error_m"] = float(np.median(err)) if err.size else None
    out["p90_error_m"] = float(np.percentile(err, 90)) if err.size else None
    behind = (raw - true)[cats["behind"]]
    out["behind_median_m"] = float(np.median(behind)) if behind.size else None
    out["behind_p90_m"] = float(np.percentile(behind, 90)) if behind.size else None
    wrong = (raw - true)[cats["wrong"]]
    out["wrong_quantiles_m"] = (
        [float(q) for q in np.percentile(wrong, np.linspace(0, 100, 11))] if wrong.size else None
    )
    return out


def _binned(
    raw: NDArray[np.floating],
    true: NDArray[np.floating],
    key: NDArray[np.floating],
    edges: tuple[float, ...],
) -> list[dict[str, Any]]:
    rows = []
    for lo, hi in itertools.pairwise(edges):
        sel = (key >= lo) & (key < hi)
        row = {"lo": lo, "hi": hi, **_stats(raw[sel], true[sel])}
        rows.append(row)
    return rows


def _view_angle_deg(normals: NDArray[np.float32]) -> NDArray[np.float64]:
    """Angle between the surface normal and the ray of each pixel (0 = facing the camera).

    The file's channels (OpenCV reads B, G, R) hold the normal's z, y, x; the y convention is
    taken as the one under which the normals face the camera most consistently.
    """
    h, w = normals.shape[:2]
    n = normals[..., ::-1].astype(np.float64)  # x, y, z
    u, v = np.meshgrid(np.arange(w), np.arange(h))
    ray = np.stack([(u - CX) / FX, (v - CY) / FY, np.ones((h, w))], axis=-1)
    ray /= np.linalg.norm(ray, axis=-1, keepdims=True)
    best: NDArray[np.float64] | None = None
    best_consistency = -1.0
    for sy, sz in ((1, 1), (-1, -1), (1, -1), (-1, 1)):
        dots = n[..., 0] * ray[..., 0] + sy * n[..., 1] * ray[..., 1] + sz * n[..., 2] * ray[..., 2]
        consistency = float(np.mean(dots < 0))  # a visible surface faces against the ray
        if consistency > best_consistency:
            best_consistency, best = consistency, dots
    assert best is not None
    return np.degrees(np.arccos(np.clip(np.abs(best), 0.0, 1.0)))


def speckle_and_flying(depth: NDArray[np.floating], exclude: NDArray[np.bool_]) -> dict[str, float]:
    """Habits off the clear objects (``exclude``), from a raw depth image.

    ``speckle``: share of pixels in holes of at most SPECKLE_MAX_AREA px (8-connected);
    ``flying``: share of the pixels at a depth edge (a jump above 3 % of the depth within
    7x7 px) whose depth lies in the middle half between the edge's near and far side;
    ``edge_missing``: share of those edge pixels with no depth.
    """
    z = np.nan_to_num(np.asarray(depth, dtype=np.float32), nan=0.0)
    hole = (z <= 0).astype(np.uint8)
    _, labels, cc_stats, _ = cv2.connectedComponentsWithStats(hole, connectivity=8)
    small = cc_stats[:, cv2.CC_STAT_AREA] <= SPECKLE_MAX_AREA
    small[0] = False  # label 0 is the valid depth
    speckle = small[labels] & ~exclude
    kernel = np.ones((7, 7), np.uint8)
    near = cv2.erode(np.where(z > 0, z, 1e3).astype(np.float32), kernel)
    far = cv2.dilate(z, kernel)
    edge = (far - near > 0.03 * near) & (near < 1e3) & ~exclude
    valid = edge & (z > 0)
    gap = far - near
    mid = valid & (z > near + 0.25 * gap) & (z < far - 0.25 * gap)
    n_edge = max(int(edge.sum()), 1)
    return {
        "speckle": float(speckle.sum() / max(int((~exclude).sum()), 1)),
        "flying": float(mid.sum() / n_edge),
        "edge_missing": float((edge & (z <= 0)).sum() / n_edge),
    }


def measure_real(folder: str | os.PathLike[str]) -> dict[str, Any]:
    """The statistics of the ClearGrasp real D435 frames in ``folder``, per frame and pooled."""
    root = Path(folder)
    frames: dict[str, Any] = {}
    pooled: dict[str, list[NDArray[np.floating]]] = {"raw": [], "true": [], "z": [], "ang": []}
    habits = []
    for fid in frame_ids(root):
        raw = _read_exr(root / f"{fid}-transparent-depth-img.exr")[..., 0]
        true = _read_exr(root / f"{fid}-opaque-depth-img.exr")[..., 0]
        mask_img = cv2.imread(str(root / f"{fid}-mask.png"), cv2.IMREAD_GRAYSCALE)
        if mask_img is None:
            raise ConfigError(f"cannot read {root / f'{fid}-mask.png'}")
        mask = mask_img > 127
        normals_path = root / f"{fid}-normals.exr"
        angle = _view_angle_deg(_read_exr(normals_path)) if normals_path.exists() else None
        has_truth = mask & np.isfinite(true) & (true > 0)
        r, t = raw[has_truth], true[has_truth]
        row = _stats(r, t)
        row["mask_pixels"] = int(mask.sum())
        row["no_truth"] = float(1.0 - has_truth.sum() / max(int(mask.sum()), 1))
        row["by_distance"] = _binned(r, t, t, DISTANCE_BINS_M)
        if angle is not None:
            a = angle[has_truth]
            row["by_angle"] = _binned(r, t, a, ANGLE_BINS_DEG)
            pooled["ang"].append(a)
        # The painted-twin frame is raw D435 depth too: its habits off the objects.
        near_mask = cv2.dilate(mask.view(np.uint8), np.ones((9, 9), np.uint8)).view(bool)
        row["habits"] = speckle_and_flying(true, near_mask)
        habits.append(row["habits"])
        frames[fid] = row
        pooled["raw"].append(r)
        pooled["true"].append(t)
    r, t = np.concatenate(pooled["raw"]), np.concatenate(pooled["true"])
    all_rows = _stats(r, t)
    all_rows["by_distance"] = _binned(r, t, t, DISTANCE_BINS_M)
    if len(pooled["ang"]) == len(frames):
        all_rows["by_angle"] = _binned(r, t, np.concatenate(pooled["ang"]), ANGLE_BINS_DEG)
    all_rows["habits"] = {k: float(np.mean([h[k] for h in habits])) for k in habits[0]}
    frame_shares = {c: [frames[f][c] for f in frames] for c in CATEGORIES}
    all_rows["frame_range"] = {c: (min(v), max(v)) for c, v in frame_shares.items()}
    return {"folder": str(root), "frames": frames, "pooled": all_rows}


# ------------------------------------------------------------------------- the simulated side


def clear_bottle_scene(config: Config, seed: int) -> Any:
    """Several empty clear bottles (and a clear cup) 0.5-1.2 m from the camera, for ``seed``."""
    from armvision.sim.scene import ObjectSpec, SceneSpec, random_camera_pose

    rng = np.random.default_rng([seed, 0xC1EA])
    T_base_cam = random_camera_pose(config.sim, None)
    cam_xy = T_base_cam[:2, 3]
    objects: list[ObjectSpec] = []
    placed: list[tuple[float, float]] = []
    while len(objects) < 5:
        distance = rng.uniform(0.5, 1.15)  # horizontal, from the camera toward the base
        bearing = rng.uniform(-0.35, 0.35)
        heading = math.atan2(-cam_xy[1], -cam_xy[0]) + bearing
        x, y = cam_xy[0] + distance * math.cos(heading), cam_xy[1] + distance * math.sin(heading)
        if math.hypot(x, y) < 0.2 or any(math.hypot(x - px, y - py) < 0.09 for px, py in placed):
            continue
        placed.append((x, y))
        kind: Literal["bottle", "cup"] = "cup" if len(objects) == 4 else "bottle"
        objects.append(
            ObjectSpec(
                f"clear{len(objects)}",
                kind,
                radius=float(rng.uniform(0.028, 0.036)),
                height=float(rng.uniform(0.16, 0.24)) if kind == "bottle" else 0.1,
                fill=0.0,
                liquid="water",
                x=float(x),
                y=float(y),
                colour=(0.85, 0.92, 1.0, 0.25),
            )
        )
    return SceneSpec(T_base_cam, tuple(objects))


def measure_sim(config: Config | None = None, seeds: Iterable[int] = (0, 1, 2)) -> dict[str, Any]:
    """SimCamera's frames of clear bottles measured like :func:`measure_real`.

    The camera effects are switched on (``sim.camera_effects = true``) whatever ``config``
    says; the true depth is the render with the clear geoms opaque, before any noise.
    """
    from armvision.sim.camera import SimCamera
    from armvision.sim.world import SimWorld

    base = config if config is not None else Config()
    sim = dataclasses.replace(base.sim, camera_effects=True)
    cfg = dataclasses.replace(base, sim=sim)
    frames: dict[str, Any] = {}
    raws, trues = [], []
    for seed in seeds:
        world = SimWorld(cfg, seed, scene=clear_bottle_scene(cfg, seed))
        with world, SimCamera(world) as camera:
            frame = camera.read()
            truth = camera.last_clear_truth
        assert truth is not None
        sel = truth.clear & np.isfinite(truth.z_true) & (truth.z_true > 0)
        r, t = frame.depth[sel].astype(np.float64), truth.z_true[sel]
        row = _stats(r, t)
        row["by_distance"] = _binned(r, t, t, DISTANCE_BINS_M)
        frames[str(seed)] = row
        raws.append(r)
        trues.append(t)
    r, t = np.concatenate(raws), np.concatenate(trues)
    pooled = _stats(r, t)
    pooled["by_distance"] = _binned(r, t, t, DISTANCE_BINS_M)
    return {"frames": frames, "pooled": pooled}
