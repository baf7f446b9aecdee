"""Liquid-level accuracy against the simulator: ``armvision eval liquid --n N --seed S``.

Scenes of 3-4 bottles each, built for this evaluation (not the default scene generator, whose
fills stay within 10-90 %): fill uniform 0-100 % with one bottle in ten exactly empty and one
in ten exactly full, every liquid colour of the simulator, radius 26-37 mm, height 16-24 cm,
random camera placement and random lighting (``sim.scene.random_lighting``). One frame per
scene. The container box is the projection of the true bottle geometry, so the liquid level
is measured independently of any detector. Bottles less than ``min_visible`` visible (another
object or the arm in front, or partly outside the image), judged from MuJoCo's segmentation
rendering, are skipped and counted.

``boxes="detector"`` measures the system end to end instead: the geometric detector runs on
the frame (told the true camera pose, as after a calibration), and each bottle gets the box
and geometry (:meth:`~armvision.perception.liquid.ContainerGeometry.of`) of the detection
labelled bottle within ``DETECTOR_GATE_M`` of its true centre, as the runtime gives them; a
bottle without one is skipped and counted (``detector_missed``).

The meter may answer ``unknown`` (``LiquidLevel.fill`` None). The MAE is over the bottles that
got a number, and the unknown answers are counted apart: on a see-through bottle an unknown is
a failure (``clear_unknown_rate``, so that answering unknown cannot buy a lower MAE), on an
opaque one it is the right answer (``opaque_unknown_rate``); per family both show
(``by_family``).
"""

from __future__ import annotations

import dataclasses
import math
import time
from typing import Any, Literal

import numpy as np
from numpy.typing import NDArray

from armvision.camera.frames import Intrinsics, pixel_box, project
from armvision.config import Config
from armvision.geometry import inv_T
from armvision.perception.detection import FrameContext
from armvision.perception.geometric import GeometricDetector
from armvision.perception.liquid import ContainerGeometry, LiquidLevel, LiquidLevelMeter
from armvision.sim._mujoco import mujoco
from armvision.sim.camera import SimCamera
from armvision.sim.scene import (
    BOTTLE_CAP_WIDENING,
    BOTTLE_FAMILIES,
    BOTTLE_NECK_RADIUS,
    DISTRACTOR_KINDS,
    LIQUID_COLOURS,
    ObjectSpec,
    SceneSpec,
    place_cluttered,
    place_without_overlap,
    random_camera_pose,
    random_cluttered_object,
    random_lighting,
)
from armvision.sim.world import SimWorld

CAP_RADIUS = BOTTLE_NECK_RADIUS * BOTTLE_CAP_WIDENING  # of the radius, as the simulator builds
#: How far a detection's centre may be from a bottle's true centre to be its detection, m.
DETECTOR_GATE_M = 0.03
Boxes = Literal["truth", "detector"]


def random_bottle(rng: np.random.Generator, name: str) -> ObjectSpec:
    """A bottle with fill 0-100 % (:func:`random_fill`), not yet placed."""
    fill = random_fill(rng)
    return ObjectSpec(
        name,
        "bottle",
        radius=float(rng.uniform(0.026, 0.037)),
        height=float(rng.uniform(0.16, 0.24)),
        fill=fill,
        liquid=str(rng.choice(list(LIQUID_COLOURS))),
        x=0.0,
        y=0.0,
    )


#: Distractors standing among the bottles of a cluttered liquid scene.
CLUTTERED_DISTRACTORS = 2


def random_fill(rng: np.random.Generator) -> float:
    """Fill 0-100 %: 10 % exactly empty, 10 % exactly full, the rest uniform."""
    u = rng.uniform()
    return 0.0 if u < 0.1 else 1.0 if u < 0.2 else float(rng.uniform(0.0, 1.0))


def liquid_scene(config: Config, seed: int, bottles: int = 4) -> SceneSpec:
    """A scene of ``bottles`` random bottles, random camera placement and lighting; with
    ``sim.profile = "cluttered"`` the bottles come from every family (clear, tinted, opaque)
    with distractors among them (:func:`cluttered_liquid_scene`)."""
    if config.sim.profile == "cluttered":
        return cluttered_liquid_scene(config, seed, bottles)
    rng = np.random.default_rng([seed, 0x11F])
    sim = dataclasses.replace(config.sim, randomize_camera=True)
    T_base_cam = random_camera_pose(sim, rng)
    drafts = [random_bottle(rng, f"bottle{i}") for i in range(bottles)]
    xy = place_without_overlap(rng, [o.radius for o in drafts])
    objects = tuple(
        dataclasses.replace(o, x=x, y=y, yaw=float(rng.uniform(-math.pi, math.pi)))
        for o, (x, y) in zip(drafts, xy)
    )
    return SceneSpec(T_base_cam, objects, (), random_lighting(rng))


def cluttered_liquid_scene(config: Config, seed: int, bottles: int = 4) -> SceneSpec:
    """``bottles`` bottles of random families (fill as :func:`random_fill`) and
    :data:`CLUTTERED_DISTRACTORS` distractors, placed as the cluttered profile places them
    (1-5 cm apart, some behind others), random camera and lighting."""
    rng = np.random.default_rng([seed, 0x11F, 0xC1077E4])
    sim = dataclasses.replace(config.sim, randomize_camera=True)
    T_base_cam = random_camera_pose(sim, rng)
    kinds = [str(rng.choice(BOTTLE_FAMILIES)) for _ in range(bottles)]
    kinds += [str(rng.choice(DISTRACTOR_KINDS)) for _ in range(CLUTTERED_DISTRACTORS)]
    drafts = []
    for i, kind in enumerate(kinds):
        obj = random_cluttered_object(rng, f"object{i}", kind)
        if obj.label == "bottle":
            obj = dataclasses.replace(obj, fill=random_fill(rng))
        drafts.append(obj)
    cam_xy = (float(T_base_cam[0, 3]), float(T_base_cam[1, 3]))
    objects, _ = place_cluttered(rng, drafts, cam_xy)
    return SceneSpec(T_base_cam, tuple(objects), (), random_lighting(rng))


def bottle_outline_cam(spec: ObjectSpec, T_cam_obj: NDArray[np.float64]) -> list[NDArray]:
    """Camera-frame points of the body and of the neck + cap outlines (two point sets)."""
    ang = np.linspace(0.0, 2.0 * math.pi, 36, endpoint=False)
    ring = np.column_stack([np.cos(ang), np.sin(ang), np.zeros_like(ang)])

    def rings(radius: float, heights: tuple[float, ...]) -> NDArray:
        return np.concatenate([ring * [radius, radius, 0.0] + [0.0, 0.0, h] for h in heights])

    r, hb, H = spec.radius, spec.body_height, spec.height
    parts = [rings(r, (0.0, hb)), rings(CAP_RADIUS * r, (hb, H))]
    return [p @ T_cam_obj[:3, :3].T + T_cam_obj[:3, 3] for p in parts]


def true_box_and_mask(
    intr: Intrinsics, spec: ObjectSpec, T_cam_obj: NDArray[np.float64]
) -> tuple[tuple[float, float, float, float], NDArray[np.bool_]]:
    """Pixel box (x0, y0, x1, y1) of the projected true bottle and its silhouette mask."""
    import cv2

    mask = np.zeros((intr.height, intr.width), np.uint8)
    all_uv = []
    for pts in bottle_outline_cam(spec, T_cam_obj):
        uv = project(intr, pts)
        all_uv.append(uv)
        hull = cv2.convexHull(np.round(uv).astype(np.int32))
        cv2.fillConvexPoly(mask, hull, 1)
    x0, y0, x1, y1 = pixel_box(np.concatenate(all_uv))
    return (float(x0), float(y0), float(x1), float(y1)), mask.astype(bool)


def _segmentation(world: SimWorld, width: int, height: int) -> NDArray[np.int32]:
    """Geom id per pixel (-1 = none) from MuJoCo's segmentation rendering of the camera."""
    renderer = mujoco.Renderer(world.model, height, width)
    try:
        renderer.enable_segmentation_rendering()
        with world.lock:
            renderer.update_scene(world.data, camera=world.camera_id)
        seg = renderer.render()
    finally:
        renderer.close()
    return seg[..., 0].copy()


def _visible_fraction(
    world: SimWorld, seg: NDArray[np.int32], spec: ObjectSpec, mask: NDArray[np.bool_]
) -> float:
    """Fraction of the bottle's true silhouette ``mask`` where the segmentation shows the
    bottle itself (not another object or the arm in front)."""
    body = mujoco.mj_name2id(world.model, mujoco.mjtObj.mjOBJ_BODY, spec.name)
    geoms = np.flatnonzero(world.model.geom_bodyid == body)  # every part of this bottle
    return float(np.isin(seg[mask], geoms).mean())


def _bottle_record(
    scene_seed: int,
    spec: ObjectSpec,
    T_cam_obj: NDArray[np.float64],
    visible: float,
    box: tuple[float, float, float, float],
    prof: LiquidLevel,
    hough: LiquidLevel,
    base: float,
) -> dict[str, Any]:
    """One measured bottle of ``per_bottle``: both methods' readings beside the truth, and
    what each cue of the default method alone would have said (same body top). ``fill`` and
    ``error_pct`` are None when the default method answered unknown (``unknown`` says why);
    so are the cues' fills when it found no body top (a detector's box reaching the image
    border, which the meter refuses before looking for one)."""
    body = prof.body_height_m
    cue_fill = {
        cue: None
        if level is None or body is None
        else float(np.clip((level - base) / (body - base), 0.0, 1.0))
        for cue, level in (
            ("colour", prof.level_colour_m),
            ("depth", prof.level_depth_m),
        )
    }
    assert hough.fill is not None  # the Hough method always answers
    return {
        "scene": scene_seed,
        "name": spec.name,
        "kind": spec.kind,
        "fill_visible": spec.fill_visible,
        "liquid": spec.liquid,
        "radius": spec.radius,
        "height": spec.height,
        "distance_m": float(np.linalg.norm(T_cam_obj[:3, 3])),
        "visible": visible,
        "box": list(box),
        "fill_true": spec.fill,
        "fill": prof.fill,
        "unknown": prof.unknown,
        "fill_hough": hough.fill,
        "error_pct": None if prof.fill is None else 100.0 * (prof.fill - spec.fill),
        "error_pct_hough": 100.0 * (hough.fill - spec.fill),
        "confidence": prof.confidence,
        "level_m_true": spec.liquid_top,
        "level_m": prof.level_m,
        "body_height_m_true": spec.body_height,
        "body_height_m": prof.body_height_m,
        "fill_colour_cue": cue_fill["colour"],
        "fill_depth_cue": cue_fill["depth"],
        "level_colour_m": prof.level_colour_m,
        "level_depth_m": prof.level_depth_m,
    }


class _Tally:
    """What the scenes of an evaluation gave so far."""

    def __init__(self) -> None:
        self.profile_meter = LiquidLevelMeter("profile")
        self.hough_meter = LiquidLevelMeter("hough")
        self.per_bottle: list[dict[str, Any]] = []
        self.skipped: list[dict[str, Any]] = []
        self.ms_profile: list[float] = []
        self.ms_hough: list[float] = []
        self.detector_missed = 0


def _measure_scene(
    config: Config,
    scene_seed: int,
    bottles_per_scene: int,
    min_visible: float,
    tally: _Tally,
    boxes: Boxes = "truth",
) -> None:
    """One frame of a liquid scene: each bottle measured by both methods, or skipped."""
    scene = liquid_scene(config, scene_seed, bottles_per_scene)
    with SimWorld(config, scene_seed, scene=scene) as world:
        with SimCamera(world) as camera:
            frame = camera.read()
        intr = frame.intrinsics
        found = []
        if boxes == "detector":
            context = FrameContext(T_base_cam=world.T_base_cam())
            found = [
                d
                for d in GeometricDetector(seed=scene_seed).detect(frame, context)
                if d.label == "bottle"
            ]
        seg = _segmentation(world, intr.width, intr.height)
        T_cam_base = inv_T(world.T_base_cam())
        for state in world.objects():
            spec = state.spec
            if spec.label != "bottle":
                continue  # a distractor of a cluttered scene
            T_cam_obj = T_cam_base @ state.T_base_obj
            box, mask = true_box_and_mask(intr, spec, T_cam_obj)
            inside = (
                box[0] >= 2
                and box[1] >= 2
                and box[2] <= intr.width - 2
                and box[3] <= intr.height - 2
            )
            visible = _visible_fraction(world, seg, spec, mask)
            if not inside or visible < min_visible:
                tally.skipped.append({"scene": scene_seed, "name": spec.name, "visible": visible})
                continue
            geometry = None
            if boxes == "detector":
                centre = T_cam_obj[:3, 3] + 0.5 * spec.height * T_cam_obj[:3, 2]
                gaps = [float(np.linalg.norm(d.center_cam - centre)) for d in found]
                if not gaps or min(gaps) > DETECTOR_GATE_M:
                    tally.detector_missed += 1
                    continue
                det = found[int(np.argmin(gaps))]
                box, geometry = det.box, ContainerGeometry.of(det)
            t0 = time.perf_counter()
            prof = tally.profile_meter.measure(frame, box, geometry)
            t1 = time.perf_counter()
            hough = tally.hough_meter.measure(frame, box)
            t2 = time.perf_counter()
            tally.ms_profile.append(1e3 * (t1 - t0))
            tally.ms_hough.append(1e3 * (t2 - t1))
            tally.per_bottle.append(
                _bottle_record(
                    scene_seed,
                    spec,
                    T_cam_obj,
                    visible,
                    box,
                    prof,
                    hough,
                    tally.profile_meter.base,
                )
            )


def _errors(records: list[dict[str, Any]]) -> NDArray[np.float64]:
    """Absolute errors (points) of the records that got a number."""
    return np.abs([b["error_pct"] for b in records if b["error_pct"] is not None])


def _summary(tally: _Tally, scenes: int) -> dict[str, Any]:
    per_bottle, ms_profile, ms_hough = tally.per_bottle, tally.ms_profile, tally.ms_hough
    clear = [b for b in per_bottle if b["fill_visible"]]
    err = _errors(clear)
    err_h = np.abs([b["error_pct_hough"] for b in clear])

    def cue_mae(key: str) -> float:
        errs = [abs(b[key] - b["fill_true"]) for b in clear if b[key] is not None]
        return 100.0 * float(np.mean(errs)) if errs else math.nan

    return {
        # Over the bottles that got a number, opaque ones included (they should not get one).
        "mae_pct": float(_errors(per_bottle).mean()) if len(_errors(per_bottle)) else math.nan,
        "mae_pct_hough": float(err_h.mean()) if len(err_h) else math.nan,
        "bottles": len(per_bottle),
        "skipped": len(tally.skipped),
        "detector_missed": tally.detector_missed,
        "scenes": scenes,
        "p90_error_pct": float(np.percentile(err, 90)) if len(err) else math.nan,
        "max_error_pct": float(err.max()) if len(err) else math.nan,
        "p90_error_pct_hough": float(np.percentile(err_h, 90)) if len(err_h) else math.nan,
        # Each cue of the default method alone (depth: over the bottles where it saw liquid).
        "mae_pct_colour_cue": cue_mae("fill_colour_cue"),
        "mae_pct_depth_cue": cue_mae("fill_depth_cue"),
        "ms_per_bottle": float(np.median(ms_profile)) if ms_profile else math.nan,
        "ms_per_bottle_hough": float(np.median(ms_hough)) if ms_hough else math.nan,
        **_unknown_summary(per_bottle),
        "by_family": _by_family(per_bottle),
    }


def _by_family(per_bottle: list[dict[str, Any]]) -> dict[str, dict[str, Any]]:
    """Per bottle family: how many were measured, how many of those the default method
    answered unknown, and its MAE (points) over the ones it gave a number (NaN: none)."""
    out: dict[str, dict[str, Any]] = {}
    for kind in sorted({b["kind"] for b in per_bottle}):
        family = [b for b in per_bottle if b["kind"] == kind]
        errs = _errors(family)
        out[kind] = {
            "bottles": len(family),
            "fill_visible": bool(family[0]["fill_visible"]),
            "unknown": len(family) - len(errs),
            "mae_pct": float(errs.mean()) if len(errs) else math.nan,
        }
    return out


def _unknown_summary(per_bottle: list[dict[str, Any]]) -> dict[str, Any]:
    """Unknown answers. An opaque bottle's liquid cannot be seen, so it should be reported
    unknown (``opaque_unknown_rate``); a see-through bottle should get a number, and each
    unknown one counts against the meter (``clear_unknown_rate``), so that answering unknown
    does not buy a lower MAE. ``mae_pct_fill_visible`` is over the see-through bottles that
    got a number (``clear_measured`` of ``clear_bottles``); ``mae_pct_opaque`` over the
    opaque bottles that got one all the same (NaN: none did)."""
    opaque = [b for b in per_bottle if not b["fill_visible"]]
    clear = [b for b in per_bottle if b["fill_visible"]]
    clear_err, opaque_err = _errors(clear), _errors(opaque)
    return {
        "mae_pct_fill_visible": float(clear_err.mean()) if len(clear_err) else math.nan,
        "clear_bottles": len(clear),
        "clear_measured": len(clear_err),
        "clear_unknown_rate": 1.0 - len(clear_err) / len(clear) if clear else math.nan,
        "opaque_bottles": len(opaque),
        "opaque_unknown_rate": 1.0 - len(opaque_err) / len(opaque) if opaque else math.nan,
        "mae_pct_opaque": float(opaque_err.mean()) if len(opaque_err) else math.nan,
    }


def evaluate_liquid(
    config: Config,
    n: int,
    seed: int,
    bottles_per_scene: int = 4,
    min_visible: float = 0.9,
    max_scenes: int | None = None,
    boxes: Boxes = "truth",
) -> dict[str, Any]:
    """Both liquid methods on >= ``n`` visible bottles; ``{"summary": ..., "per_bottle": ...}``.

    Errors are in percentage points of fill against ``ObjectSpec.fill`` (liquid height over
    inner body height). ``summary``: ``mae_pct`` (default method, every bottle it gave a
    number), ``mae_pct_hough`` (see-through bottles), ``bottles`` measured, ``skipped`` (not
    visible enough), ``scenes``, p90 and max errors (see-through bottles with a number), the
    MAE of the default method's colour and depth cues alone, the median milliseconds per
    bottle of each method, the unknown answers (:func:`_unknown_summary`) and the figures
    per bottle family (:func:`_by_family`); ``boxes``: see the module docstring
    (``detector_missed``: bottles the detector did not find as bottles).
    """
    if boxes not in ("truth", "detector"):
        raise ValueError(f"boxes must be 'truth' or 'detector', not {boxes!r}")
    if n < 1:
        raise ValueError("n must be at least 1")
    tally = _Tally()
    scenes = 0
    limit = max_scenes if max_scenes is not None else 10 * n
    while len(tally.per_bottle) < n and scenes < limit:
        scene_seed = seed * 100_003 + scenes
        scenes += 1
        _measure_scene(config, scene_seed, bottles_per_scene, min_visible, tally, boxes)
    return {
        "summary": _summary(tally, scenes),
        "per_bottle": tally.per_bottle,
        "skipped": tally.skipped,
    }
