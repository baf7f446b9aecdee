"""The simulated workspace in motion: :class:`SimWorld` compiles the scene (see
:mod:`armvision.sim.model`), owns the physics clock and answers every ground-truth question
(true camera pose, end-effector and tag poses, object poses and fill levels, which object the
gripper holds).

Frames: ``world`` has z up with the floor at z = 0; the robot's ``base`` sits on the table top
at ``TABLE_TOP_Z`` with the same orientation, so ``T_world_base`` is a pure translation. Public
methods answer in the base frame, like everything above the simulator.

Clock: in ``lockstep`` mode nothing moves until someone calls :meth:`SimWorld.run_until`
(blocking arm moves and camera reads do), so a seed gives the same run every time. In
``realtime`` mode a thread steps physics at wall-clock speed and :meth:`run_until` waits.
Controllers (the simulated servos) are called before every physics step, under the lock.
"""

from __future__ import annotations

import logging
import math
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray

from armvision.config import Config
from armvision.errors import SimulationError
from armvision.geometry import inv_T, make_T, rot_z
from armvision.realtime import share_interpreter_finely
from armvision.robot.kinematics import VX300S
from armvision.robot.tag_mount import tag_mount
from armvision.sim import names
from armvision.sim._mujoco import mujoco
from armvision.sim.model import (
    MARKER_PARKED,
    R_MJCAM_CAM,
    R_TAG_PLATE,
    T_WORLD_BASE,
    build_model,
    quat_wxyz,
)
from armvision.sim.scene import LIQUID_COLOURS, ObjectSpec, SceneSpec, generate_scene

Array = NDArray[np.float64]
log = logging.getLogger("armvision.sim")

Mode = Literal["lockstep", "realtime"]


def _rigid(T: ArrayLike, name: str) -> Array:
    """``T`` as a finite 4x4 with an orthonormal rotation, or SimulationError naming it."""
    T = np.asarray(T, dtype=float)
    if T.shape != (4, 4) or not np.all(np.isfinite(T)):
        raise SimulationError(f"{name} must be a finite 4x4 matrix, got shape {T.shape}")
    if not np.allclose(T[:3, :3].T @ T[:3, :3], np.eye(3), atol=1e-6):
        raise SimulationError(f"{name}'s rotation is not orthonormal: build it with make_T")
    return T


@dataclass(frozen=True)
class ObjectState:
    """Ground truth of one object: its spec plus where it is now (bottom centre, base frame)."""

    spec: ObjectSpec
    T_base_obj: Array
    held: bool

    @property
    def upright(self) -> bool:
        return bool(self.T_base_obj[2, 2] > math.cos(math.radians(10.0)))

    def to_dict(self) -> dict[str, Any]:
        s = self.spec
        return {
            "name": s.name,
            "kind": s.kind,
            "label": s.label,
            "fill_visible": s.fill_visible,
            "radius": s.radius,
            "height": s.height,
            "fill": s.fill,
            "liquid": s.liquid,
            "liquid_rgba": list(LIQUID_COLOURS[s.liquid]),
            "liquid_top_above_bottom": s.liquid_top,
            "T_base_obj": self.T_base_obj.tolist(),
            "position_base": self.T_base_obj[:3, 3].tolist(),
            "upright": self.upright,
            "held": self.held,
        }


@dataclass(frozen=True)
class GroundTruth:
    """Everything the simulator knows at one instant, in the base frame."""

    time: float
    T_base_cam: Array
    T_base_ee: Array
    T_base_tag: Array
    T_ee_tag: Array
    joint_positions: Array
    finger_position: float
    objects: tuple[ObjectState, ...]
    held_object: str | None
    loose_tags: dict[int, Array] = field(default_factory=dict)

    def to_dict(self) -> dict[str, Any]:
        return {
            "time": self.time,
            "frames": "T_a_b is the pose of frame b in frame a; cam is the OpenCV optical frame",
            "T_world_base": T_WORLD_BASE.tolist(),
            "T_base_cam": self.T_base_cam.tolist(),
            "T_base_ee": self.T_base_ee.tolist(),
            "T_base_tag": self.T_base_tag.tolist(),
            "T_ee_tag": self.T_ee_tag.tolist(),
            "joint_names": list(VX300S.joint_names),
            "joint_positions": self.joint_positions.tolist(),
            "finger_position": self.finger_position,
            "objects": [o.to_dict() for o in self.objects],
            "held_object": self.held_object,
            "loose_tags": {str(k): v.tolist() for k, v in self.loose_tags.items()},
        }


# --------------------------------------------------------------------------- the world


Controller = Callable[[float], None]


class SimWorld:
    """The workspace in MuJoCo: build it from a config and a seed, step it, ask it the truth.

    ``mode="lockstep"``: time advances only in :meth:`run_until` (called by blocking arm moves,
    gripper actions and camera reads), so runs are repeatable. ``mode="realtime"``: a thread
    steps physics at wall-clock speed until :meth:`close`. Use as a context manager.
    """

    def __init__(
        self,
        config: Config | None = None,
        seed: int = 0,
        mode: Mode = "lockstep",
        scene: SceneSpec | None = None,
    ) -> None:
        if mode not in ("lockstep", "realtime"):
            raise SimulationError(f"mode must be 'lockstep' or 'realtime', not {mode!r}")
        self.config = config if config is not None else Config()
        self.seed = int(seed)
        self.mode: Mode = mode
        self.scene = scene if scene is not None else generate_scene(self.config, self.seed)
        self.model = build_model(self.config, self.scene)
        self.data = mujoco.MjData(self.model)
        self.lock = threading.RLock()
        self._controllers: list[Controller] = []
        self._ids()
        self._set_initial_state()
        self._thread: threading.Thread | None = None
        self._stop = threading.Event()
        self._thread_error: BaseException | None = None
        if mode == "realtime":
            share_interpreter_finely()
            self._thread = threading.Thread(
                target=self._realtime_loop, name="sim-physics", daemon=True
            )
            self._thread.start()

    # ---------------------------------------------------------------- construction helpers

    def _ids(self) -> None:
        m = self.model

        def idx(kind: mujoco.mjtObj, name: str) -> int:
            i = mujoco.mj_name2id(m, kind, name)
            if i < 0:  # pragma: no cover - only if sim.model and this disagree
                raise SimulationError(f"internal: the scene has no {name}")
            return i

        J, B, S, G = (
            mujoco.mjtObj.mjOBJ_JOINT,
            mujoco.mjtObj.mjOBJ_BODY,
            mujoco.mjtObj.mjOBJ_SITE,
            mujoco.mjtObj.mjOBJ_GEOM,
        )
        self._qadr = np.array([m.jnt_qposadr[idx(J, n)] for n in VX300S.joint_names])
        self._dofadr = np.array([m.jnt_dofadr[idx(J, n)] for n in VX300S.joint_names])
        self._finger_qadr = (
            m.jnt_qposadr[idx(J, VX300S.finger_names[0])],
            m.jnt_qposadr[idx(J, VX300S.finger_names[1])],
        )
        self.arm_actuators = np.array(
            [idx(mujoco.mjtObj.mjOBJ_ACTUATOR, n) for n in VX300S.joint_names]
        )
        self.gripper_actuator = idx(mujoco.mjtObj.mjOBJ_ACTUATOR, names.GRIPPER_ACTUATOR)
        self._ee_site = idx(S, names.EE_SITE)
        self._tag_site = idx(S, names.ARM_TAG_SITE)
        self._loose_sites = {
            t.tag_id: idx(S, names.loose_tag(k)) for k, t in enumerate(self.scene.loose_tags)
        }
        self.camera_id = idx(mujoco.mjtObj.mjOBJ_CAMERA, names.CAMERA_NAME)
        self._camera_mocap = m.body_mocapid[idx(B, names.CAMERA_BODY)]
        self._mount_mocap = m.body_mocapid[idx(B, names.CAMERA_MOUNT_BODY)]
        self._marker_mocap = m.body_mocapid[idx(B, names.MARKER_BODY)]
        self._object_bodies = {o.name: idx(B, o.name) for o in self.scene.objects}
        self._pads = (idx(G, names.LEFT_PAD), idx(G, names.RIGHT_PAD))

    def _set_initial_state(self) -> None:
        """Arm in its sleep pose (as the real arm powers up), gripper open, objects at rest."""
        d = self.data
        d.qpos[self._qadr] = VX300S.sleep
        d.qpos[self._finger_qadr[0]] = VX300S.finger_limits[1]
        d.qpos[self._finger_qadr[1]] = -VX300S.finger_limits[1]
        d.ctrl[self.arm_actuators] = VX300S.sleep
        d.ctrl[self.gripper_actuator] = VX300S.finger_limits[1]
        mujoco.mj_forward(self.model, d)

    # ---------------------------------------------------------------- clock

    @property
    def time(self) -> float:
        """Simulation time, seconds since the world was built."""
        return float(self.data.time)

    @property
    def timestep(self) -> float:
        return float(self.model.opt.timestep)

    def add_controller(self, controller: Controller) -> None:
        """Call ``controller(t)`` before every physics step (under the lock) to set ``ctrl``."""
        with self.lock:
            self._controllers.append(controller)

    def remove_controller(self, controller: Controller) -> None:
        with self.lock:
            self._controllers.remove(controller)

    def _step(self, n: int) -> None:
        """``n`` physics steps with the controllers run before each; caller holds the lock."""
        m, d = self.model, self.data
        if not self._controllers:
            mujoco.mj_step(m, d, n)
        else:
            for _ in range(n):
                for controller in self._controllers:
                    controller(d.time)
                mujoco.mj_step(m, d)
        if not np.all(np.isfinite(d.qpos)):
            raise SimulationError(
                f"the simulation became unstable at t={d.time:.3f} s; try a smaller sim.timestep"
            )

    def run_until(self, t: float, timeout_s: float | None = None) -> None:
        """Make simulation time reach ``t`` (to within a step): step to it (lockstep) or wait."""
        if self.mode == "lockstep":
            with self.lock:
                n = math.ceil((t - self.data.time) / self.timestep - 1e-6)
                if n > 0:
                    self._step(n)
            return
        limit = (t - self.time) * 2.0 + 5.0 if timeout_s is None else timeout_s
        deadline = time.monotonic() + limit
        while self.time < t - 0.5 * self.timestep:
            if self._thread_error is not None:
                raise SimulationError(f"the physics thread failed: {self._thread_error}")
            if self._stop.is_set():
                raise SimulationError("the simulation is closed; build a new SimWorld")
            if time.monotonic() > deadline:
                raise SimulationError(
                    f"simulation time did not reach {t:.3f} s within {limit:.1f} s: "
                    "the physics thread is too slow for real time on this machine"
                )
            time.sleep(min(0.002, max(t - self.time, 0.0)))

    def advance(self, seconds: float) -> None:
        """Run the simulation ``seconds`` further (see :meth:`run_until`)."""
        self.run_until(self.time + seconds)

    def _realtime_loop(self) -> None:
        """Keep simulation time equal to wall-clock time since start, in steps of ~2 ms."""
        start_wall, start_sim = time.monotonic(), self.time
        try:
            while not self._stop.is_set():
                target = start_sim + (time.monotonic() - start_wall)
                behind = target - self.time
                if behind > 0.25:  # cannot keep up: drop the backlog instead of spiralling
                    log.warning("simulation %.0f ms behind real time; skipping", behind * 1e3)
                    start_sim, start_wall = self.time, time.monotonic()
                    continue
                # At most 10 steps per lock hold, so readers and renderers get a turn.
                n = min(int(behind / self.timestep), 10)
                if n > 0:
                    with self.lock:
                        self._step(n)
                else:
                    time.sleep(self.timestep)
        except BaseException as exc:  # reported by run_until, not lost in the thread
            self._thread_error = exc
            log.exception("simulation physics thread failed")

    def close(self) -> None:
        """Stop the physics thread (realtime mode); the world keeps its last state."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=2.0)
            self._thread = None

    def __enter__(self) -> SimWorld:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # ---------------------------------------------------------------- scene edits

    def set_camera_pose(self, T_base_cam: ArrayLike) -> None:
        """Move the camera (and its stand) to ``T_base_cam``, OpenCV optical frame."""
        T_world_cam = T_WORLD_BASE @ np.asarray(T_base_cam, dtype=float)
        R_world_mjcam = T_world_cam[:3, :3] @ R_MJCAM_CAM
        with self.lock:
            self.data.mocap_pos[self._camera_mocap] = T_world_cam[:3, 3]
            self.data.mocap_quat[self._camera_mocap] = quat_wxyz(R_world_mjcam)
            yaw = math.atan2(T_world_cam[1, 2], T_world_cam[0, 2])
            self.data.mocap_pos[self._mount_mocap] = T_world_cam[:3, 3]
            self.data.mocap_quat[self._mount_mocap] = quat_wxyz(rot_z(yaw))
            mujoco.mj_forward(self.model, self.data)

    def set_marker(self, p_base: ArrayLike | None) -> None:
        """Show the red marker sphere (1 cm radius, no collisions) at ``p_base``; None hides it."""
        p_world = (
            np.array(MARKER_PARKED)
            if p_base is None
            else T_WORLD_BASE[:3, :3] @ np.asarray(p_base, dtype=float) + T_WORLD_BASE[:3, 3]
        )
        with self.lock:
            self.data.mocap_pos[self._marker_mocap] = p_world
            mujoco.mj_forward(self.model, self.data)

    def set_object_pose(self, name: str, T_base_obj: ArrayLike) -> None:
        """Put object ``name`` (bottom centre, z along its axis) at ``T_base_obj``, at rest.

        Sets the object's free joint and zeroes its velocity, as if a hand had placed it there;
        physics carries on from that state. Drive an object along a path by calling this every
        frame or so with small steps (large jumps into another body make contact forces fly).
        """
        if name not in self._object_bodies:
            raise SimulationError(
                f"no object {name!r}; the scene has {[o.name for o in self.scene.objects]}"
            )
        T = _rigid(T_base_obj, "T_base_obj")
        T_world_obj = T_WORLD_BASE @ T
        joint = self.model.body_jntadr[self._object_bodies[name]]
        qadr, dofadr = self.model.jnt_qposadr[joint], self.model.jnt_dofadr[joint]
        with self.lock:
            self.data.qpos[qadr : qadr + 3] = T_world_obj[:3, 3]
            self.data.qpos[qadr + 3 : qadr + 7] = quat_wxyz(T_world_obj[:3, :3])
            self.data.qvel[dofadr : dofadr + 6] = 0.0
            mujoco.mj_forward(self.model, self.data)

    def set_loose_tag_pose(self, tag_id: int, T_base_tag: ArrayLike) -> None:
        """Put loose tag ``tag_id`` at ``T_base_tag`` (AprilTag convention: z into the tag).

        Loose tags are mocap bodies: they go exactly where they are put and push nothing. To
        move one along a path, call this from a controller (:meth:`add_controller`) every step.
        """
        index = next((k for k, t in enumerate(self.scene.loose_tags) if t.tag_id == tag_id), None)
        if index is None:
            raise SimulationError(
                f"no loose tag {tag_id}; the scene has {[t.tag_id for t in self.scene.loose_tags]}"
            )
        T = _rigid(T_base_tag, "T_base_tag")
        # The body is the plate; its site (the tag frame) sits at the body origin turned by
        # R_TAG_PLATE^T, so the plate's rotation is R_base_tag R_TAG_PLATE.
        T_world_plate = T_WORLD_BASE @ make_T(T[:3, :3] @ R_TAG_PLATE, T[:3, 3])
        body = mujoco.mj_name2id(self.model, mujoco.mjtObj.mjOBJ_BODY, names.loose_tag(index))
        mocap = self.model.body_mocapid[body]
        with self.lock:
            self.data.mocap_pos[mocap] = T_world_plate[:3, 3]
            self.data.mocap_quat[mocap] = quat_wxyz(T_world_plate[:3, :3])
            mujoco.mj_forward(self.model, self.data)

    @property
    def marker_radius(self) -> float:
        return float(
            self.model.geom_size[
                self.model.body_geomadr[
                    mujoco.mj_name2id(self.model, mujoco.mjtObj.mjOBJ_BODY, names.MARKER_BODY)
                ]
            ][0]
        )

    # ---------------------------------------------------------------- ground truth

    @property
    def T_world_base(self) -> Array:
        return T_WORLD_BASE.copy()

    def _T_base(self, pos: ArrayLike, xmat: ArrayLike) -> Array:
        T_world_x = make_T(np.asarray(xmat, dtype=float).reshape(3, 3), pos)
        return inv_T(T_WORLD_BASE) @ T_world_x

    def T_base_cam(self) -> Array:
        """True camera pose, OpenCV optical frame (x right, y down, z forward)."""
        with self.lock:
            T_base_mjcam = self._T_base(
                self.data.cam_xpos[self.camera_id], self.data.cam_xmat[self.camera_id]
            )
        T_base_mjcam[:3, :3] = T_base_mjcam[:3, :3] @ R_MJCAM_CAM
        return T_base_mjcam

    def T_base_ee(self) -> Array:
        """True pose of ee_gripper_link (the point between the fingertips)."""
        with self.lock:
            return self._T_base(
                self.data.site_xpos[self._ee_site], self.data.site_xmat[self._ee_site]
            )

    def T_base_tag(self) -> Array:
        """True pose of the gripper's AprilTag, AprilTag convention (z into the tag)."""
        with self.lock:
            return self._T_base(
                self.data.site_xpos[self._tag_site], self.data.site_xmat[self._tag_site]
            )

    def T_base_loose_tags(self) -> dict[int, Array]:
        """True poses of the loose tags on the table, by tag id."""
        with self.lock:
            return {
                tag_id: self._T_base(self.data.site_xpos[s], self.data.site_xmat[s])
                for tag_id, s in self._loose_sites.items()
            }

    @property
    def T_ee_tag(self) -> Array:
        return tag_mount(self.config.tag.offset_ee)

    def joint_positions(self) -> Array:
        """True arm joint angles, rad, in VX300S.joint_names order."""
        with self.lock:
            return self.data.qpos[self._qadr].copy()

    def joint_velocities(self) -> Array:
        with self.lock:
            return self.data.qvel[self._dofadr].copy()

    def finger_position(self) -> float:
        """True travel of the left finger, metres (0.021 closed .. 0.057 open)."""
        with self.lock:
            return float(self.data.qpos[self._finger_qadr[0]])

    def T_base_object(self, name: str) -> Array:
        """True pose of an object's bottom centre (z along its axis)."""
        body = self._object_bodies[name]
        with self.lock:
            return self._T_base(self.data.xpos[body], self.data.xmat[body])

    def held_object(self) -> str | None:
        """The object touching both finger pads, or None."""
        left, right = self._pads
        touching: dict[int, set[int]] = {left: set(), right: set()}
        with self.lock:
            d, m = self.data, self.model
            for c in d.contact[: d.ncon]:
                for pad, other in ((c.geom1, c.geom2), (c.geom2, c.geom1)):
                    if pad in touching:
                        touching[pad].add(int(m.geom_bodyid[other]))
        both = touching[left] & touching[right]
        for name, body in self._object_bodies.items():
            if body in both:
                return name
        return None

    def objects(self) -> tuple[ObjectState, ...]:
        held = self.held_object()
        return tuple(
            ObjectState(o, self.T_base_object(o.name), o.name == held) for o in self.scene.objects
        )

    def object_spec(self, name: str) -> ObjectSpec:
        for o in self.scene.objects:
            if o.name == name:
                return o
        raise SimulationError(
            f"no object {name!r}; the scene has {[o.name for o in self.scene.objects]}"
        )

    def ground_truth(self) -> GroundTruth:
        """A consistent snapshot of every true quantity, read under the lock."""
        with self.lock:
            objects = self.objects()
            return GroundTruth(
                time=self.time,
                T_base_cam=self.T_base_cam(),
                T_base_ee=self.T_base_ee(),
                T_base_tag=self.T_base_tag(),
                T_ee_tag=self.T_ee_tag,
                joint_positions=self.joint_positions(),
                finger_position=self.finger_position(),
                objects=objects,
                held_object=next((o.spec.name for o in objects if o.held), None),
                loose_tags=self.T_base_loose_tags(),
            )
