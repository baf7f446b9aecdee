"""``armvision demo``: the whole system on the simulated workspace, checked against the truth.

Headless and deterministic for a seed (lockstep simulation):

1. **Scene**: two bottles and a cup of random sizes, fills and liquids on the table
   (:func:`demo_scene`), the camera at the configured placement.
2. **Calibrate** with the gripper tag (the paper's two phases, ``calibration.method``) on an
   empty table with the same camera and the same arm, as a user does before putting things
   down; or load a saved calibration (``calibration_path``).
3. **Detect**: the runtime's stages (camera, tags, objects, liquid, fusion at 100 Hz) run
   for :data:`DETECT_S` seconds with the arm asleep; every container must be tracked with the
   right label within :data:`POSITION_TOL_MM` of its true centre.
4. **Analyse** each bottle in place (:func:`~armvision.tasks.analyze.analyze`): fill within
   :data:`FILL_TOL` of the true fill.
5. **Grab** one bottle and lift it (:func:`~armvision.tasks.grab.grab`); the simulator must
   see it held at least 5 cm up after 2 s.

The report table gives every measured value beside the simulator's; the annotated image shows
the last frame with tags, boxes, fills and tracks. Success means every step passed.
"""

from __future__ import annotations

import dataclasses
import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from armvision.config import Config
from armvision.runtime.recorder import Recorder, RecordingError
from armvision.runtime.state import CalibrationStatus

#: Calibration passes within these of the simulator's camera pose. The simulated servos have
#: zero offsets of up to ``sim.encoder_bias_deg`` (0.3 deg); the waist's turns the whole arm
#: about the base axis, which no camera calibration can tell from a turn of the camera, so the
#: rotation can be off by about that much whatever the solver (README, Calibration).
CALIBRATION_TOL_MM = 6.0
CALIBRATION_TOL_DEG = 0.5
#: Seconds the stages run before the tracks are read.
DETECT_S = 3.0
#: A track is the object's if its centre is within this of the true centre, millimetres.
POSITION_TOL_MM = 15.0
#: A fill measurement passes within this of the truth (0..1 scale; 0.1 = 10 points).
FILL_TOL = 0.10
#: The grabbed bottle must be this high above its start, and still held, after HOLD_S.
LIFT_TOL_M = 0.05
HOLD_S = 2.0


@dataclass
class Row:
    """One line of the report: a step, what was measured, the truth, and the verdict."""

    step: str
    item: str
    measured: str
    truth: str
    error: str
    ok: bool


@dataclass
class DemoReport:
    rows: list[Row] = field(default_factory=list)
    image_path: Path | None = None
    seconds: float = 0.0
    sim_seconds: float = 0.0
    seed: int = 0

    @property
    def ok(self) -> bool:
        return bool(self.rows) and all(r.ok for r in self.rows)

    def add(self, step: str, item: str, measured: str, truth: str, error: str, ok: bool) -> None:
        self.rows.append(Row(step, item, measured, truth, error, bool(ok)))

    def table(self) -> str:
        """The report as a fixed-width text table."""
        head = ("step", "item", "measured", "truth", "error", "ok")
        cells = [head] + [
            (r.step, r.item, r.measured, r.truth, r.error, "yes" if r.ok else "NO")
            for r in self.rows
        ]
        widths = [max(len(c[i]) for c in cells) for i in range(len(head))]
        lines = ["  ".join(c[i].ljust(widths[i]) for i in range(len(head))).rstrip() for c in cells]
        lines.insert(1, "  ".join("-" * w for w in widths))
        passed = sum(r.ok for r in self.rows)
        lines.append("")
        lines.append(
            f"{passed}/{len(self.rows)} checks passed"
            f" in {self.seconds:.0f} s ({self.sim_seconds:.0f} s simulated), seed {self.seed}: "
            + ("DEMO OK" if self.ok else "DEMO FAILED")
        )
        return "\n".join(lines)

    def to_dict(self) -> dict[str, Any]:
        return {
            "ok": self.ok,
            "seed": self.seed,
            "seconds": round(self.seconds, 1),
            "sim_seconds": round(self.sim_seconds, 1),
            "image": None if self.image_path is None else str(self.image_path),
            "rows": [dataclasses.asdict(r) for r in self.rows],
        }


def demo_scene(config: Config, seed: int):
    """Two bottles and a cup (random sizes, fills, liquids, yaw), placed without overlap."""
    from armvision.sim.scene import (
        ObjectSpec,
        SceneSpec,
        place_without_overlap,
        random_camera_pose,
        random_object,
    )

    rng = np.random.default_rng([seed, 0xDE30])
    want = {"bottle": 2, "cup": 1}
    drafts: list[ObjectSpec] = []
    while any(want.values()):
        obj = random_object(rng, f"object{len(drafts)}")
        if want[obj.label] > 0:
            want[obj.label] -= 1
            drafts.append(obj)
    xy = place_without_overlap(rng, [o.radius for o in drafts])
    objects = tuple(
        dataclasses.replace(o, x=x, y=y, yaw=float(rng.uniform(-math.pi, math.pi)))
        for o, (x, y) in zip(drafts, xy)
    )
    return SceneSpec(random_camera_pose(config.sim, rng), objects)


def _calibrate(
    config: Config, seed: int, T_base_cam: np.ndarray, report: DemoReport, say: Callable
) -> CalibrationStatus:
    """Calibrate on an empty table with the demo's camera placement and arm."""
    from armvision.bench.system import calibrate_empty_table

    say("calibrating with the gripper tag (empty table)")
    status, result = calibrate_empty_table(config, seed, T_base_cam)
    truth = result.truth or {}
    dt, dr = truth.get("translation_error_mm", math.nan), truth.get("rotation_error_deg", math.nan)
    report.add(
        "calibrate",
        f"{result.method}, {len(result.samples)} poses",
        f"residual {status.residual_mm:.2f} mm",
        "camera pose",
        f"{dt:.2f} mm {dr:.3f} deg",
        dt <= CALIBRATION_TOL_MM and dr <= CALIBRATION_TOL_DEG,
    )
    return status


def run_demo(
    config: Config,
    seed: int = 0,
    out_dir: str | Path = "out/demo",
    calibration_path: str | Path | None = None,
    say: Callable[[str], None] = lambda message: None,
    record_to: str | Path | None = None,
) -> DemoReport:
    """Run the demo (see the module docstring); the report says what passed. ``record_to``:
    record the run (after the calibration) to this MCAP file; if it cannot be written, ``say``
    says so and the demo goes on."""
    from armvision.bench.snapshot import _write_png
    from armvision.bench.system import sim_system, sim_world
    from armvision.runtime.build import load_calibration
    from armvision.runtime.view import annotated

    started = time.monotonic()
    report = DemoReport(seed=seed)
    scene = demo_scene(config, seed)
    if calibration_path is not None:
        calibration = load_calibration(calibration_path)
        report.add("calibrate", f"loaded {calibration_path}", calibration.method, "-", "-", True)
    else:
        calibration = _calibrate(config, seed, scene.T_base_cam, report, say)

    system = sim_system(config, seed, scene=scene, calibration=calibration)
    recorder = None
    if record_to is not None:
        try:
            recorder = Recorder(record_to, config, wait=True, notify=say).open()
            system.attach_recorder(recorder)
            say(f"recording to {record_to}")
        except RecordingError as exc:
            say(f"{exc}; the demo goes on without recording")
    with system:
        world = sim_world(system)
        truth = {o.spec.name: o for o in world.objects()}
        say(f"detecting for {DETECT_S:.0f} s")
        system.pump(system.clock() + DETECT_S)
        state = system.snapshot()
        matched = _report_detection(report, state, truth)
        _analyse_bottles(system, report, truth, matched, say)

        frame_state = system.snapshot()
        image = annotated(frame_state, config.tag.size, newest=False)

        _grab_bottle(system, world, report, truth, say)
        report.sim_seconds = system.clock()
        _report_runtime(config, system, report)

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    if image is not None:
        report.image_path = out / "demo.png"
        _write_png(report.image_path, image)
    report.seconds = time.monotonic() - started
    return report


def _analyse_bottles(
    system: Any, report: DemoReport, truth: dict, matched: dict[str, int], say: Callable
) -> None:
    """Analyse each tracked bottle in place; a row each, its fill against the truth."""
    from armvision.tasks.analyze import analyze

    for name, obj in truth.items():
        if obj.spec.label != "bottle" or name not in matched:
            continue
        track_id = matched[name]
        say(f"analysing the bottle of track {track_id}")
        status = system.run_task("analyze", analyze, track_id=track_id)
        result = status.result or {}
        fill = result.get("fill") if status.phase == "succeeded" else None
        err = math.nan if fill is None else abs(fill - obj.spec.fill)
        colour = result.get("colour_name") or result.get("colour") or "-"
        report.add(
            "analyze",
            f"{name} (track {track_id})",
            f"fill {100 * fill:.1f} % {colour}" if fill is not None else (status.error or "failed"),
            f"fill {100 * obj.spec.fill:.1f} % {obj.spec.liquid}",
            f"{100 * err:.1f} points" if fill is not None else "-",
            fill is not None and err <= FILL_TOL,
        )


def _grab_bottle(system: Any, world: Any, report: DemoReport, truth: dict, say: Callable) -> None:
    """Grab a bottle and hold it HOLD_S; a row: held, a bottle, lifted LIFT_TOL_M or more."""
    from armvision.tasks.grab import grab

    say("grabbing a bottle")
    start_z = {n: float(o.T_base_obj[2, 3]) for n, o in truth.items()}
    status = system.run_task("grab", grab)
    system.pump(system.clock() + HOLD_S)
    held = world.held_object()
    lift = None if held is None else float(world.T_base_object(held)[2, 3]) - start_z[held]
    result = status.result or {}
    report.add(
        "grab",
        f"{held or 'nothing'} held" if held else "bottle",
        (
            f"{status.phase} in {result.get('duration_s', math.nan):.1f} s"
            + (f", lifted {100 * lift:.1f} cm" if lift is not None else "")
        )
        if status.phase == "succeeded"
        else f"{status.phase}: {status.error}",
        f"held >= {100 * LIFT_TOL_M:.0f} cm up after {HOLD_S:.0f} s",
        "-",
        status.phase == "succeeded"
        and held is not None
        and truth[held].spec.label == "bottle"
        and lift is not None
        and lift >= LIFT_TOL_M,
    )


def _report_runtime(config: Config, system: Any, report: DemoReport) -> None:
    """A row for the stages: the fusion rate achieved, and none stopped by an error."""
    health = system.snapshot().health
    dead = [h.name for h in health.values() if h.last_error is not None]
    report.add(
        "runtime",
        "stages",
        f"fusion {health['fusion'].rate_hz:.0f} Hz, errors: {', '.join(dead) or 'none'}",
        f"{config.fusion.rate_hz:.0f} Hz",
        "-",
        not dead,
    )


def _report_detection(report: DemoReport, state, truth: dict) -> dict[str, int]:
    """Match tracks to the true objects; a row per object; object name -> track id."""
    from scipy.optimize import linear_sum_assignment

    names = list(truth)
    tracks = list(state.tracks)
    centres = {
        n: o.T_base_obj[:3, 3] + o.T_base_obj[:3, 2] * o.spec.height / 2 for n, o in truth.items()
    }
    matched: dict[str, int] = {}
    if tracks:
        cost = np.array([[np.linalg.norm(t.p_base - centres[n]) for t in tracks] for n in names])
        for i, j in zip(*linear_sum_assignment(cost)):
            if cost[i, j] <= POSITION_TOL_MM / 1000.0 * 3:
                matched[names[i]] = j
    result: dict[str, int] = {}
    for n in names:
        o = truth[n]
        if n not in matched:
            report.add("detect", n, "not tracked", o.spec.kind, "-", False)
            continue
        t = tracks[matched[n]]
        err_mm = 1000.0 * float(np.linalg.norm(t.p_base - centres[n]))
        height = f", h {100 * t.height:.1f} cm" if t.height is not None else ""
        report.add(
            "detect",
            f"{n} (track {t.id})",
            f"{t.label}{height}",
            f"{o.spec.kind}, h {100 * o.spec.height:.1f} cm",
            f"{err_mm:.1f} mm",
            t.label == o.spec.label and err_mm <= POSITION_TOL_MM,
        )
        result[n] = t.id
    extra = len(tracks) - len(matched)
    if extra:
        report.add("detect", "false tracks", str(extra), "0", "-", False)
    return result
