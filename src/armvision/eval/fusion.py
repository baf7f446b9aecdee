"""Fusion and tracking accuracy against the simulator: ``armvision eval fusion --seed S``.

**End effector.** An empty workspace (no objects for the arm to hit) from the seed's camera
placement. The arm runs a scripted motion through ``waypoints`` poses (seeded; each reachable,
the gripper tag in view and turned toward the camera, planned with the *estimated*
calibration), ``move_time`` seconds each, without stopping in between. Every 1/rate_hz
seconds the encoders are read (SimArm: true angle + per-seed zero offset up to
``sim.encoder_bias_deg`` + noise, rounded to counts); every camera frame (30 FPS, rendered
with the D435 depth model) goes through the real tag detector. Four estimators see the same
readings and answer at every tick "where is the end effector now?":

- ``fused``: the default :class:`~armvision.fusion.kalman.EEFilter`, run by the
  :class:`~armvision.fusion.loop.FusionLoop` exactly as the runtime will (encoders read in
  the cycle, tag poses pushed with their capture times and replayed into the filter);
- ``camera``: the same filter with only the camera, ``encoders``: with only the encoders
  (the single-source baselines, same motion model and noise models);
- ``paper``: :class:`~armvision.fusion.kalman.PaperKF`, the paper's 7-state filter, updated
  at each tick with the camera when a new tag pose came in, else with the encoders.

The arm is ``sim.arm``'s: SimArm (no measured velocities), or the Dynamixel driver over the
servo-bus emulator (``--arm dynamixel-emulated``), whose Present_Velocity the filters fuse while
``fusion.joint_velocities`` is on (the encoders-only filter too: it is the same filter with one
source). RMSE is over every tick of the motion against the simulator's ``T_base_ee``; the
velocity's RMSE (``velocity_rmse_mm_s``) against the true positions differenced a tick either
side. The raw errors of
each source (the camera's at its detection instants, the encoders' fk at every tick) are
reported too, and so is the Cartesian random-walk variant of the filter
(``encoder_bias = "cartesian"``, no camera states) for comparison.

**Calibration.** Unless ``T_base_cam_estimate`` is given, the camera pose every estimator and
the object detector use is the true one perturbed by a seeded error of ``calibration_error``
= (metres, degrees) in random directions, applied in the camera frame (so the camera's
position is off by exactly that translation and its orientation by that angle), the accuracy
the calibration aims for. The perturbation is reported in the result.

**Objects.** A scene from the seed's camera placement with three bottles and a cup standing
side by side as the camera sees them, the arm asleep, seen through the real perception path
(SimCamera frames, ``GeometricDetector``, the tracker in the fusion loop). Three stages:
everything still (``static_s``; this gives ``object_rmse_mm``), one bottle moved out toward
the camera on a loop and back (``moving_s``), then all four moved along straight paths that
cross pairwise, each pair passing its crossing point a second or so apart (``crossing_s``).
The fusion loop maps detections into the base frame with its newest camera pose, which after
the arm's motion is the calibration as refined by the end-effector filter; that is the
headline. The same detections are also tracked with the given (perturbed) calibration and
with the true camera pose, and reported, so the calibration's share of the error is visible.
Objects are moved with :meth:`~armvision.sim.world.SimWorld.set_object_pose` every tick. The
truth is each object's centre (on its axis, half-way up). Tracks are matched to objects per
frame by the Hungarian method within ``match_radius``; an identity switch is an object whose
matched track id changes (CLEAR MOT, Bernardin & Stiefelhagen 2008).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable
from typing import Any, Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.optimize import linear_sum_assignment
from scipy.spatial.transform import Rotation

from armvision.camera.frames import project
from armvision.config import Config
from armvision.errors import ConfigError
from armvision.fusion.kalman import EEFilter, PaperKF
from armvision.fusion.loop import FusionLoop
from armvision.geometry import inv_T, make_T, rot_z, rpy_to_R
from armvision.robot.kinematics import fk, ik

Array = NDArray[np.float64]


# --------------------------------------------------------------------------- helpers


def perturbed_calibration(
    T_base_cam: Array, seed: int, translation: float = 0.002, rotation_deg: float = 0.2
) -> tuple[Array, dict[str, Any]]:
    """``T_base_cam`` with a seeded error of ``translation`` m and ``rotation_deg`` degrees.

    T_est = T_base_cam exp(xi): the camera's position moves by ``translation`` along a random
    direction and its orientation turns ``rotation_deg`` about a random axis (camera frame).
    """
    rng = np.random.default_rng([seed, 0xCA1B])
    axis = rng.normal(size=3)
    axis /= np.linalg.norm(axis)
    direction = rng.normal(size=3)
    direction /= np.linalg.norm(direction)
    rotvec = math.radians(rotation_deg) * axis
    dT = make_T(Rotation.from_rotvec(rotvec).as_matrix(), translation * direction)
    info = {
        "source": "true camera pose perturbed (seeded)",
        "translation_mm": 1000.0 * translation,
        "rotation_deg": rotation_deg,
        "translation_direction_cam": direction.tolist(),
        "rotation_axis_cam": axis.tolist(),
    }
    return T_base_cam @ dT, info


def _rmse_mm(errors: ArrayLike) -> float:
    e = np.asarray(errors, dtype=float).reshape(-1, 3)
    if len(e) == 0:
        return math.nan
    return 1000.0 * math.sqrt(float(np.mean(np.sum(e**2, axis=1))))


def scripted_waypoints(
    rng: np.random.Generator,
    T_base_cam: Array,
    T_ee_tag: Array,
    intrinsics: Any,
    n: int,
    margin_px: float = 60.0,
    max_tilt_deg: float = 35.0,
) -> list[Array]:
    """``n`` reachable ee poses with the tag in view and facing the camera (within tilt).

    Positions in front of the robot (x 0.25-0.45 m, y +-0.2 m, z 0.08-0.25 m), the gripper
    pitched down 40-80 degrees and yawed toward the target; the tag's centre must project at
    least ``margin_px`` inside the image of a camera at ``T_base_cam``.
    """
    T_cam_base = inv_T(T_base_cam)
    poses: list[Array] = []
    for _ in range(2000 * n):
        if len(poses) == n:
            break
        x, y = rng.uniform(0.25, 0.45), rng.uniform(-0.2, 0.2)
        z, pitch = rng.uniform(0.08, 0.25), math.radians(rng.uniform(40.0, 80.0))
        T_base_ee = make_T(rpy_to_R(0.0, pitch, math.atan2(y, x)), [x, y, z])
        T_cam_tag = T_cam_base @ T_base_ee @ T_ee_tag
        p = T_cam_tag[:3, 3]
        if p[2] < 0.3:
            continue
        u, v = project(intrinsics, p[None])[0]
        if not (margin_px < u < intrinsics.width - margin_px):
            continue
        if not (margin_px < v < intrinsics.height - margin_px):
            continue
        # The tag's z points into the tag: along the viewing ray when it faces the camera.
        facing = float(T_cam_tag[:3, 2] @ (p / np.linalg.norm(p)))
        if math.degrees(math.acos(np.clip(facing, -1.0, 1.0))) > max_tilt_deg:
            continue
        if ik(T_base_ee, np.zeros(6))[1]:
            poses.append(T_base_ee)
    if len(poses) < n:
        raise RuntimeError(f"found only {len(poses)} of {n} waypoints with the tag in view")
    return poses


class _FrameSchedule:
    """When SimCamera's next frame falls: on its grid first + n x period (read on time)."""

    def __init__(self, camera: Any) -> None:
        self.camera = camera
        self.first: float | None = None
        self.count = 0

    def due(self, now: float) -> float:
        return now if self.first is None else self.first + self.count * self.camera.period

    def read(self) -> Any:
        frame = self.camera.read()
        if self.first is None:
            self.first = frame.timestamp
        self.count += 1
        return frame


class _RecordingArm:
    """The arm as the fusion loop sees it, keeping each reading for the other estimators."""

    def __init__(self, arm: Any) -> None:
        self.arm = arm
        self.last: Array | None = None
        self.last_velocities: Array | None = None

    def get_joint_positions(self) -> Array:
        self.last = self.arm.get_joint_positions()
        return self.last

    def get_joint_velocities(self) -> Array | None:
        self.last_velocities = self.arm.get_joint_velocities()
        return self.last_velocities


# --------------------------------------------------------------------------- end effector


def _camera_pose_error(T_base_cam: Array, T_base_cam_true: Array) -> tuple[float, float]:
    """How far a camera pose is from the true one: (millimetres, degrees)."""
    dp = np.linalg.norm(T_base_cam[:3, 3] - T_base_cam_true[:3, 3])
    dr = Rotation.from_matrix(T_base_cam[:3, :3].T @ T_base_cam_true[:3, :3]).magnitude()
    return 1000.0 * float(dp), math.degrees(float(dr))


def _ee_calibration(
    T_base_cam_true: Array,
    seed: int,
    T_base_cam_estimate: Array | None,
    calibration_error: tuple[float, float],
) -> tuple[Array, dict[str, Any]]:
    """The camera pose the estimators use (given, or the truth perturbed) and its report."""
    if T_base_cam_estimate is None:
        T_est, calibration = perturbed_calibration(T_base_cam_true, seed, *calibration_error)
    else:
        T_est = np.asarray(T_base_cam_estimate, dtype=float)
        calibration = {"source": "given"}
    mm, deg = _camera_pose_error(T_est, T_base_cam_true)
    calibration["camera_position_error_mm"] = mm
    calibration["camera_rotation_error_deg"] = deg
    return T_est, calibration


class _EERun:
    """The estimators of the end-effector evaluation fed the same readings tick by tick, and
    what each said beside the truth (``rows``) and the raw error of each source."""

    def __init__(
        self,
        fusion: Any,
        world: Any,
        camera: Any,
        arm: Any,
        detector: Any,
        T_est: Array,
        T_ee_tag: Array,
    ) -> None:
        self.world = world
        self.detector = detector
        self.T_est = T_est
        self.T_tag_ee = inv_T(T_ee_tag)
        self.recorder = _RecordingArm(arm)
        self.schedule = _FrameSchedule(camera)
        fx = camera.intrinsics.fx
        self.loop = FusionLoop(
            fusion, self.recorder, T_est, T_ee_tag, clock=lambda: world.time, focal_px=fx
        )
        self.camera_only = EEFilter(fusion, T_est, T_ee_tag, focal_px=fx, use_encoders=False)
        self.encoders_only = EEFilter(fusion, T_est, T_ee_tag, focal_px=fx, use_camera=False)
        self.cartesian = EEFilter(
            dataclasses.replace(fusion, encoder_bias="cartesian", estimate_camera_pose=False),
            T_est,
            T_ee_tag,
            focal_px=fx,
        )
        self.dt = 1.0 / fusion.rate_hz
        self.paper = PaperKF(T_est, dt=self.dt)
        self.rows: dict[str, list[Array]] = {
            k: [] for k in ("truth", "fused", "camera", "encoders", "paper", "cartesian")
        }
        self.velocities: dict[str, list[Array]] = {"fused": [], "encoders": []}
        self.measured_velocities = False  # the arm gave joint velocities
        self.raw_camera: list[Array] = []
        self.raw_encoders: list[Array] = []
        self.frames = 0
        self.detected = 0

    def _read_frames(self, tick: float) -> list[tuple[float, Array]]:
        """Frames due by ``tick``: render and detect (the read advances the world to the frame
        time); the (capture time, T_cam_tag) of each tag seen."""
        new_tags: list[tuple[float, Array]] = []
        while self.schedule.due(self.world.time) <= tick + 1e-9:
            frame = self.schedule.read()
            self.frames += 1
            tags = self.detector.detect(frame)
            if tags:
                self.detected += 1
                new_tags.append((frame.timestamp, tags[0].T_cam_tag))
                p_est = (self.T_est @ tags[0].T_cam_tag @ self.T_tag_ee)[:3, 3]
                self.raw_camera.append(p_est - self.world.T_base_ee()[:3, 3])
        return new_tags

    def step(self, tick: float) -> None:
        """One tick: the frames due, the world run to ``tick``, every estimator updated."""
        new_tags = self._read_frames(tick)
        self.world.run_until(tick)
        for t_tag, T_cam_tag in new_tags:
            self.loop.push_tag(t_tag, T_cam_tag)
        snapshot = self.loop.step()
        q = self.recorder.last
        # The step read the encoders (through the recorder) and fused them.
        assert q is not None and snapshot.ee is not None
        t_now = snapshot.time
        truth = self.world.T_base_ee()[:3, 3]
        qd = self.recorder.last_velocities
        self.encoders_only.update_encoders(t_now, q, qd)
        self.cartesian.update_encoders(t_now, q, qd)
        for t_tag, T_cam_tag in new_tags:
            self.camera_only.update_camera(t_tag, T_cam_tag)
            self.cartesian.update_camera(t_tag, T_cam_tag)
        p_fk = fk(q)[:3, 3]
        self.raw_encoders.append(p_fk - truth)
        self._step_paper(p_fk, new_tags)
        self._record(t_now, truth, np.asarray(snapshot.ee.p_base))
        self.velocities["fused"].append(np.asarray(snapshot.ee.v_base))
        self.velocities["encoders"].append(np.asarray(self.encoders_only.estimate(t_now).v_base))
        self.measured_velocities = self.measured_velocities or qd is not None

    def _step_paper(self, p_fk: Array, new_tags: list[tuple[float, Array]]) -> None:
        paper = self.paper
        if paper.P[0, 0] == 1.0 and paper.x[0] == 0.0:  # first tick: start at the encoders
            paper.x[:3] = p_fk
            paper.P[:3, :3] = np.eye(3) * 1e-4
        if new_tags:  # the paper alternates: the camera when it has a new pose
            paper.step(p_cam=(new_tags[-1][1] @ self.T_tag_ee)[:3, 3])
        else:
            paper.step(p_base=p_fk)

    def _record(self, t_now: float, truth: Array, fused: Array) -> None:
        rows = self.rows
        rows["truth"].append(truth)
        rows["fused"].append(fused)
        rows["encoders"].append(np.asarray(self.encoders_only.estimate(t_now).p_base))
        rows["cartesian"].append(np.asarray(self.cartesian.estimate(t_now).p_base))
        rows["paper"].append(self.paper.position)
        rows["camera"].append(
            np.asarray(self.camera_only.estimate(t_now).p_base)
            if self.camera_only.time is not None
            else np.full(3, np.nan)
        )


def _run_motion(world: Any, arm: Any, poses: list[Array], move_time: float, run: _EERun) -> None:
    """From ``poses[0]`` through the others, ``move_time`` each without stopping in between,
    a tick of ``run`` every fusion period until 0.5 s after the last move ends."""
    next_pose = 1
    move_end = world.time
    tick = world.time
    end = math.inf
    while tick < end:
        if world.time >= move_end - 1e-9 and next_pose < len(poses):
            if arm.set_ee_pose_matrix(poses[next_pose], moving_time=move_time, blocking=False):
                move_end = world.time + move_time
            next_pose += 1
            if next_pose == len(poses):
                end = move_end + 0.5
        tick += run.dt
        run.step(tick)


def _ee_result(run: _EERun, waypoints: int, encoder_bias: Array) -> dict[str, Any]:
    """The end-effector figures of a finished run."""
    rows = run.rows
    truth = np.array(rows["truth"])
    rmse = {}
    for name in ("fused", "camera", "encoders", "paper", "cartesian"):
        est = np.array(rows[name])
        ok = np.all(np.isfinite(est), axis=1)
        rmse[name] = _rmse_mm(est[ok] - truth[ok])
    # The true velocity by central differences of the true positions (a tick apart).
    v_true = (truth[2:] - truth[:-2]) / (2.0 * run.dt)
    velocity_rmse = {
        name: _rmse_mm(np.array(v)[1:-1] - v_true) for name, v in run.velocities.items()
    }
    final = run.loop.snapshot()
    ee = final.ee
    stats = final.ee_stats
    frames = run.frames
    return {
        "ticks": len(truth),
        "seconds": len(truth) * run.dt,
        "waypoints": waypoints,
        "frames": frames,
        "tag_detection_rate": run.detected / frames if frames else 0.0,
        "rmse_mm": rmse,
        "velocity_rmse_mm_s": velocity_rmse,
        "joint_velocities_fused": run.measured_velocities and run.loop.config.joint_velocities,
        "raw_rmse_mm": {
            "camera": _rmse_mm(np.array(run.raw_camera)),
            "encoders": _rmse_mm(run.raw_encoders),
        },
        "encoder_bias_true_deg": np.degrees(encoder_bias).tolist(),
        "encoder_bias_estimated_deg": None
        if ee is None or ee.encoder_bias is None
        else np.degrees(ee.encoder_bias).tolist(),
        "camera_correction_estimated": None
        if ee is None or ee.camera_correction is None
        else {
            "rotation_deg": np.degrees(ee.camera_correction[:3]).tolist(),
            "translation_mm": (1000.0 * ee.camera_correction[3:]).tolist(),
        },
        "filter_stats": dataclasses.asdict(stats),
    }


def _evaluate_ee(
    config: Config,
    seed: int,
    T_base_cam_estimate: Array | None,
    calibration_error: tuple[float, float],
    waypoints: int,
    move_time: float,
) -> tuple[dict[str, Any], Array, Array, Array, dict[str, Any]]:
    from armvision.bench.system import sim_arm
    from armvision.perception.tags import TagDetector
    from armvision.sim.arm import SimArm
    from armvision.sim.camera import SimCamera
    from armvision.sim.world import SimWorld

    empty = dataclasses.replace(
        config, sim=dataclasses.replace(config.sim, min_objects=0, max_objects=0)
    )
    with SimWorld(empty, seed) as world, SimCamera(world) as camera:
        arm, owned = sim_arm(world, None)  # sim.arm: SimArm or the emulated Dynamixel bus
        try:
            encoder_bias = arm.encoder_bias if isinstance(arm, SimArm) else np.zeros(6)
            T_base_cam_true = world.T_base_cam()
            T_est, calibration = _ee_calibration(
                T_base_cam_true, seed, T_base_cam_estimate, calibration_error
            )
            T_ee_tag = world.T_ee_tag
            rng = np.random.default_rng([seed, 0xF05])
            poses = scripted_waypoints(rng, T_est, T_ee_tag, camera.intrinsics, waypoints)
            detector = TagDetector.from_config(config.tag, ids=[config.tag.id])
            if not arm.set_ee_pose_matrix(poses[0], moving_time=2.0):
                raise RuntimeError(f"cannot reach the first waypoint: {arm.last_error}")
            run = _EERun(config.fusion, world, camera, arm, detector, T_est, T_ee_tag)
            _run_motion(world, arm, poses, move_time, run)
        finally:
            arm.close()
            for thing in owned:
                thing.close()

    result = _ee_result(run, len(poses), encoder_bias)
    result["arm"] = config.sim.arm
    refined = run.loop.ee_filter.T_base_cam_refined()
    mm, deg = _camera_pose_error(refined, T_base_cam_true)
    calibration["refined_camera_position_error_mm"] = mm
    calibration["refined_camera_rotation_error_deg"] = deg
    return result, T_est, refined, T_base_cam_true, calibration


# --------------------------------------------------------------------------- objects


def _object_paths(
    starts: Array, static_s: float, moving_s: float, crossing_s: float
) -> tuple[Callable[[float], Array], Array, dict[str, tuple[float, float]]]:
    """Positions (4, 2) of the four objects at time t from the start of the object run."""
    # Crossing: the objects of each pair swap sides along perpendicular diagonals that cross
    # half-way; the second of a pair starts ``lag`` later, so they pass the crossing apart.
    lag = 0.45 * crossing_s
    travel = crossing_s - lag
    goals = np.array([starts[1], starts[0], starts[3], starts[2]]) + np.array([0.16, 0.0])
    stages = {
        "static": (0.0, static_s),
        "moving": (static_s, static_s + moving_s),
        "crossing": (static_s + moving_s, static_s + moving_s + crossing_s),
    }

    def at(t: float) -> Array:
        xy = starts.copy()
        t_move = t - static_s
        if 0.0 < t_move <= moving_s:  # object 0 out toward the camera on a loop, and back
            phase = 2.0 * math.pi * t_move / moving_s
            xy[0] += [0.12 * 0.5 * (1.0 - math.cos(phase)), -0.04 * math.sin(phase)]
        t_cross = t - static_s - moving_s
        if t_cross > 0.0:
            for k in range(4):
                start_k = lag if k % 2 else 0.0
                f = float(np.clip((t_cross - start_k) / travel, 0.0, 1.0))
                xy[k] = starts[k] + f * (goals[k] - starts[k])
        return xy

    return at, goals, stages


def _object_scene(config: Config, seed: int):
    from armvision.sim.scene import ObjectSpec, generate_scene

    rng = np.random.default_rng([seed, 0x0B7])
    base = generate_scene(
        dataclasses.replace(
            config, sim=dataclasses.replace(config.sim, min_objects=0, max_objects=0)
        ),
        seed,
    )
    # Side by side as the camera (in front of the robot, on its x axis) sees them, so none
    # hides another while still; pair (0, 1) crosses at (0.38, -0.14), (2, 3) at (0.38, 0.14).
    starts = np.array([[0.30, -0.22], [0.30, -0.06], [0.30, 0.06], [0.30, 0.22]])
    kinds: list[Literal["bottle", "cup"]] = ["bottle", "bottle", "bottle", "cup"]
    objects = []
    for k, (kind, (x, y)) in enumerate(zip(kinds, starts)):
        radius = float(rng.uniform(0.026, 0.032))
        height = (
            float(rng.uniform(0.16, 0.22)) if kind == "bottle" else float(rng.uniform(0.08, 0.11))
        )
        objects.append(
            ObjectSpec(
                f"{kind}{k}",
                kind,
                radius=radius,
                height=height,
                fill=float(rng.uniform(0.2, 0.8)),
                liquid=str(rng.choice(["water", "juice", "cola", "wine", "milk"])),
                x=float(x),
                y=float(y),
                colour=(0.85, 0.92, 1.0, 0.25) if kind == "bottle" else (0.85, 0.2, 0.2, 1.0),
            )
        )
    return dataclasses.replace(base, objects=tuple(objects)), starts


def _track_metrics(
    records: list[dict[str, Any]],
    scene: Any,
    stages: dict[str, tuple[float, float]],
    match_radius: float,
) -> dict[str, Any]:
    """RMSE per stage, identity switches, misses and labels of one run of tracks."""
    names = [o.name for o in scene.objects]
    last_id: dict[int, int] = {}
    switches = 0
    errors: dict[str, list[list[Array]]] = {s: [[] for _ in names] for s in stages}
    labels_ok = labels_n = misses = false_tracks = 0
    for rec in records:
        truth, tracks = rec["truth"], rec["tracks"]
        stage = next(s for s, (a, b) in stages.items() if a <= rec["t"] <= b + 1e-9)
        matched: dict[int, int] = {}
        if tracks:
            dist = np.array([[np.linalg.norm(p - c) for _, p, _ in tracks] for c in truth])
            rows, cols = linear_sum_assignment(dist)
            matched = {int(r): int(c) for r, c in zip(rows, cols) if dist[r, c] <= match_radius}
        misses += len(names) - len(matched)
        false_tracks += len(tracks) - len(matched)
        for k, j in matched.items():
            track_id, p, label = tracks[j]
            if k in last_id and last_id[k] != track_id:
                switches += 1
            last_id[k] = track_id
            errors[stage][k].append(p - truth[k])
            labels_n += 1
            labels_ok += label == scene.objects[k].label

    def pooled(stage: str, which: list[int]) -> float:
        return _rmse_mm(np.concatenate([np.reshape(errors[stage][k], (-1, 3)) for k in which]))

    everything = list(range(len(names)))
    bottles = [k for k, o in enumerate(scene.objects) if o.label == "bottle"]
    return {
        "static_rmse_mm": pooled("static", everything),
        "static_rmse_mm_bottles": pooled("static", bottles),
        "static_rmse_mm_per_object": [pooled("static", [k]) for k in everything],
        "moving_rmse_mm": pooled("moving", [0]),
        "moving_frames_tracked": len(errors["moving"][0]),
        "crossing_rmse_mm": pooled("crossing", everything),
        "id_switches": switches,
        "missed_object_frames": misses,
        "false_track_frames": false_tracks,
        "label_accuracy": labels_ok / labels_n if labels_n else math.nan,
    }


def _min_gap(at: Callable[[float], Array], radii: Array, total: float) -> float:
    """The least clearance between two objects' sides along the paths, metres; RuntimeError
    under 1 cm (the design must never make two objects touch: they would knock each other
    over)."""
    min_gap = math.inf
    for t in np.linspace(0.0, total, 600):
        xy = at(float(t))
        for i in range(4):
            for j in range(i + 1, 4):
                min_gap = min(min_gap, float(np.linalg.norm(xy[i] - xy[j]) - radii[i] - radii[j]))
    if min_gap < 0.01:
        raise RuntimeError(f"object paths come within {1000 * min_gap:.0f} mm of touching")
    return min_gap


def _push_frames(
    schedule: _FrameSchedule,
    world: Any,
    tick: float,
    detector: Any,
    T_detector: Array,
    arm: Any,
    loops: dict[str, FusionLoop],
) -> float | None:
    """Detect in the frames due by ``tick`` and give every loop the detections; the newest
    frame's capture time (None: no frame was due)."""
    from armvision.perception.detection import FrameContext

    frame_time = None
    while schedule.due(world.time) <= tick + 1e-9:
        frame = schedule.read()
        context = FrameContext(T_detector, arm.get_joint_positions())
        detections = detector.detect(frame, context)
        for loop in loops.values():
            loop.push_detections(frame.timestamp, detections)
        frame_time = frame.timestamp
    return frame_time


def _true_centres(world: Any, scene: Any) -> list[Array]:
    """Each object's centre now (on its axis, half-way up), base frame."""
    truth = []
    for o in scene.objects:
        T_base_obj = world.T_base_object(o.name)
        truth.append(T_base_obj[:3, 3] + T_base_obj[:3, 2] * o.height / 2.0)
    return truth


def _track_objects(
    config: Config,
    seed: int,
    scene: Any,
    at: Callable[[float], Array],
    calibrations: dict[str, Array],
    total: float,
) -> dict[str, list[dict[str, Any]]]:
    """Move the objects along ``at`` for ``total`` seconds, one fusion loop per calibration;
    per calibration, a record per tick with a new frame (time, truth, confirmed tracks)."""
    from armvision.perception.geometric import GeometricDetector
    from armvision.sim.arm import SimArm
    from armvision.sim.camera import SimCamera
    from armvision.sim.world import SimWorld

    fusion = config.fusion
    names = [o.name for o in scene.objects]
    yaws = [o.yaw for o in scene.objects]
    records: dict[str, list[dict[str, Any]]] = {name: [] for name in calibrations}
    with SimWorld(config, seed, scene=scene) as world, SimCamera(world) as camera:
        arm = SimArm(world)  # asleep, out of the way; its readings feed the self-filter
        detector = GeometricDetector(seed=seed)
        T_detector = next(iter(calibrations.values()))
        loops = {
            name: FusionLoop(
                fusion,
                arm,
                T,
                world.T_ee_tag,
                clock=lambda: world.time,
                focal_px=camera.intrinsics.fx,
            )
            for name, T in calibrations.items()
        }
        dt = 1.0 / fusion.rate_hz
        schedule = _FrameSchedule(camera)
        t0 = world.time
        tick = t0
        while tick - t0 < total - 1e-9:
            tick += dt
            xy = at(tick - t0)
            for k, name in enumerate(names):
                world.set_object_pose(name, make_T(rot_z(yaws[k]), [xy[k, 0], xy[k, 1], 0.0]))
            frame_time = _push_frames(schedule, world, tick, detector, T_detector, arm, loops)
            world.run_until(tick)
            snapshots = {name: loop.step() for name, loop in loops.items()}
            if frame_time is None:
                continue
            truth = _true_centres(world, scene)
            for name, snapshot in snapshots.items():
                records[name].append(
                    {
                        "t": frame_time - t0,
                        "truth": np.array(truth),
                        "tracks": [
                            (tr.id, np.asarray(tr.p_base), tr.label)
                            for tr in snapshot.tracks
                            if tr.confirmed
                        ],
                    }
                )
        arm.close()
    return records


def _evaluate_objects(
    config: Config,
    seed: int,
    calibrations: dict[str, Array],
    static_s: float,
    moving_s: float,
    crossing_s: float,
    match_radius: float,
) -> dict[str, Any]:
    """Track the four objects with one fusion loop per camera pose in ``calibrations``.

    The detector (which needs the camera pose only for the table prior and the self-filter)
    runs once per frame with the first calibration; every loop gets the same detections.
    """
    scene, starts = _object_scene(config, seed)
    at, _, stages = _object_paths(starts, static_s, moving_s, crossing_s)
    radii = np.array([o.radius for o in scene.objects])
    total = static_s + moving_s + crossing_s
    min_gap = _min_gap(at, radii, total)
    records = _track_objects(config, seed, scene, at, calibrations, total)
    return {
        "frames": len(next(iter(records.values()))),
        "objects": [
            {"name": o.name, "kind": o.kind, "radius": o.radius, "height": o.height}
            for o in scene.objects
        ],
        "min_gap_between_objects_mm": 1000.0 * min_gap,
        "by_calibration": {
            name: _track_metrics(recs, scene, stages, match_radius)
            for name, recs in records.items()
        },
    }


# --------------------------------------------------------------------------- entry point


def evaluate_fusion(
    config: Config,
    seed: int = 0,
    T_base_cam_estimate: Array | None = None,
    calibration_error: tuple[float, float] = (0.002, 0.2),
    waypoints: int = 10,
    move_time: float = 1.5,
    static_s: float = 2.0,
    moving_s: float = 3.0,
    crossing_s: float = 4.0,
    match_radius: float = 0.05,
    objects: bool = True,
) -> dict[str, Any]:
    """End-effector fusion and object tracking vs the simulator (module docstring).

    ``objects=False`` evaluates the end effector only (the object fields are then absent).
    ``config.sim.arm`` chooses the arm of the end-effector run: SimArm (no measured joint
    velocities) or the Dynamixel driver over the servo-bus emulator (Present_Velocity fused
    while ``fusion.joint_velocities``; its encoders have no zero offset or noise beyond the
    counts).

    ``summary``: ``ee_rmse_mm_fused``, ``ee_rmse_mm_camera``, ``ee_rmse_mm_encoders``,
    ``ee_rmse_mm_paper`` (each the estimator's RMSE over every tick of the motion),
    ``ee_improvement_pct`` (fused vs the better single-source filter), the raw per-measurement
    RMSEs, ``object_rmse_mm`` (static stage, all objects), ``moving_object_rmse_mm``,
    ``crossing_object_rmse_mm`` and ``id_switches``. ``calibration`` says which camera pose the
    estimators used and how far it is from the truth.
    """
    if waypoints < 2:
        raise ConfigError(
            f"waypoints must be at least 2 (a motion needs two poses), not {waypoints}"
        )
    for name, value in (
        ("move_time", move_time),
        ("static_s", static_s),
        ("moving_s", moving_s),
        ("crossing_s", crossing_s),
        ("match_radius", match_radius),
    ):
        if not (math.isfinite(value) and value > 0.0):
            raise ConfigError(f"{name} must be a positive number, not {value}")
    if T_base_cam_estimate is not None:
        T_base_cam_estimate = np.asarray(T_base_cam_estimate, dtype=float)
        if T_base_cam_estimate.shape != (4, 4) or not np.all(np.isfinite(T_base_cam_estimate)):
            raise ConfigError("T_base_cam_estimate must be a finite 4x4 pose (T_base_cam)")
    ee, T_est, T_refined, T_true, calibration = _evaluate_ee(
        config, seed, T_base_cam_estimate, calibration_error, waypoints, move_time
    )
    rmse = ee["rmse_mm"]
    best_single = min(rmse["camera"], rmse["encoders"])
    summary: dict[str, Any] = {
        "ee_rmse_mm_fused": rmse["fused"],
        "ee_rmse_mm_camera": rmse["camera"],
        "ee_rmse_mm_encoders": rmse["encoders"],
        "ee_rmse_mm_paper": rmse["paper"],
        "ee_improvement_pct": 100.0 * (1.0 - rmse["fused"] / best_single),
        "ee_rmse_mm_fused_cartesian_bias": rmse["cartesian"],
        "ee_rmse_mm_camera_raw": ee["raw_rmse_mm"]["camera"],
        "ee_rmse_mm_encoders_raw": ee["raw_rmse_mm"]["encoders"],
        "ee_velocity_rmse_mm_s_fused": ee["velocity_rmse_mm_s"]["fused"],
        "ee_velocity_rmse_mm_s_encoders": ee["velocity_rmse_mm_s"]["encoders"],
        "tag_detection_rate": ee["tag_detection_rate"],
    }
    out: dict[str, Any] = {"seed": seed, "summary": summary, "calibration": calibration, "ee": ee}
    if not objects:
        return out
    # The fusion loop maps detections with its newest camera pose: after the arm's motion, the
    # calibration refined by the end-effector filter. The other two are for comparison.
    tracking = _evaluate_objects(
        config,
        seed,
        {"refined": T_refined, "given": T_est, "true": T_true},
        static_s,
        moving_s,
        crossing_s,
        match_radius,
    )
    tracked = tracking["by_calibration"]["refined"]
    summary.update(
        {
            "object_rmse_mm": tracked["static_rmse_mm"],
            "object_rmse_mm_bottles": tracked["static_rmse_mm_bottles"],
            "moving_object_rmse_mm": tracked["moving_rmse_mm"],
            "crossing_object_rmse_mm": tracked["crossing_rmse_mm"],
            "id_switches": tracked["id_switches"],
            "object_label_accuracy": tracked["label_accuracy"],
            "object_rmse_mm_given_calibration": tracking["by_calibration"]["given"][
                "static_rmse_mm"
            ],
            "object_rmse_mm_true_calibration": tracking["by_calibration"]["true"]["static_rmse_mm"],
        }
    )
    out["objects"] = tracking
    return out
