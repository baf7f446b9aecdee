"""The UI's one-step tasks (Home, Sleep, gripper) and Calibrate while running, in lockstep
simulations checked against the simulator's truth."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from armvision.bench.system import calibrate_empty_table, sim_system
from armvision.config import Config
from armvision.errors import CalibrationError
from armvision.eval.fusion import perturbed_calibration
from armvision.geometry import pose_error
from armvision.robot.kinematics import VX300S
from armvision.runtime.build import load_calibration
from armvision.runtime.state import CalibrationStatus
from armvision.sim.scene import ObjectSpec, SceneSpec, random_camera_pose
from armvision.tasks import basic
from armvision.tasks.calibrate import calibrate

BOTTLE = ObjectSpec(
    "bottle", "bottle", radius=0.03, height=0.2, fill=0.5, liquid="juice", x=0.42, y=0.0
)


def test_home_sleep_and_gripper_tasks_reach_their_poses() -> None:
    config = Config()
    scene = SceneSpec(random_camera_pose(config.sim, None))
    with sim_system(config, 1, scene=scene) as system:
        world = system.world
        for name, q_goal in (("home", VX300S.home), ("sleep", VX300S.sleep)):
            status = system.run_task(name, getattr(basic, name))
            assert status.phase == "succeeded", status.error
            assert np.allclose(world.joint_positions(), q_goal, atol=np.radians(0.5)), name
            assert status.result["pose"] == name
            assert np.allclose(status.result["joints_deg"], np.degrees(q_goal), atol=0.6)
        lo, hi = VX300S.finger_limits
        status = system.run_task("gripper_close", basic.gripper_close)
        assert status.phase == "succeeded"
        assert system.arm.gripper.get_finger_position() == pytest.approx(lo, abs=0.003)
        assert status.result["finger_mm"] == pytest.approx(1000 * lo, abs=3)
        system.run_task("gripper_open", basic.gripper_open)
        assert system.arm.gripper.get_finger_position() == pytest.approx(hi, abs=0.003)


def test_calibrate_while_running_switches_the_system_to_the_new_pose(tmp_path) -> None:
    """Start 3 cm / 2 deg off, calibrate as a task: the running system (fusion, object
    detector, tracks) takes the new pose, which is within the demo's tolerance of the truth,
    and the file saved beside the old one (kept as .bak) loads back the same."""
    base = Config()
    # The detection stages off: the task reads frames itself, and the test runs 5x faster.
    config = dataclasses.replace(
        base,
        runtime=dataclasses.replace(
            base.runtime, tag_detection=False, object_detection=False, liquid_detection=False
        ),
    )
    scene = SceneSpec(random_camera_pose(config.sim, None))
    T_true = scene.T_base_cam
    T_wrong, _ = perturbed_calibration(T_true, 0, 0.03, 2.0)
    wrong = CalibrationStatus("a wrong one", "none", None, T_wrong)
    path = tmp_path / "calibration.json"
    path.write_text("{}")  # a previous file: must survive as .bak
    with sim_system(config, 2, scene=scene, calibration=wrong) as system:
        status = system.run_task("calibrate", calibrate, save_path=path)
        assert status.phase == "succeeded", status.error
        result = status.result
        dp, dr = pose_error(system.calibration.T_base_cam, T_true)
        assert dp < 0.006 and np.degrees(dr) < 0.5
        assert result["error_vs_simulator_mm"] == pytest.approx(1000 * dp, abs=1e-3)
        assert result["used"] >= config.calibration.min_samples
        assert np.array_equal(system.T_base_cam, system.calibration.T_base_cam)
        assert np.array_equal(system.fusion.T_base_cam, system.calibration.T_base_cam)
        assert np.array_equal(system.snapshot().T_base_cam, system.calibration.T_base_cam)
        assert system.calibration.joint_offsets_rad is not None
        assert str(path) in system.calibration.source
        # The encoder offsets now corrected: the fused ee sits on the true one.
        system.pump(system.clock() + 1.0)
        p_fused = system.snapshot().fusion.T_base_ee[:3, 3]
        assert np.linalg.norm(p_fused - system.world.T_base_ee()[:3, 3]) < 0.004
        assert np.allclose(system.world.joint_positions(), VX300S.home, atol=0.01)  # ends home
    saved = load_calibration(path)
    assert np.allclose(saved.T_base_cam, system.calibration.T_base_cam)
    assert (tmp_path / "calibration.json.bak").read_text() == "{}"


def test_tracks_follow_a_recalibration() -> None:
    """With the wrong pose a bottle is tracked centimetres off; after set_calibration with
    the true one its track is found again at the true place."""
    config = Config()
    scene = SceneSpec(random_camera_pose(config.sim, None), (BOTTLE,))
    T_true = scene.T_base_cam
    T_wrong, _ = perturbed_calibration(T_true, 1, 0.08, 3.0)
    wrong = CalibrationStatus("a wrong one", "none", None, T_wrong)
    with sim_system(config, 3, scene=scene, calibration=wrong) as system:
        centre = system.world.T_base_object("bottle")[:3, 3] + [0, 0, BOTTLE.height / 2]

        def bottle_error() -> float:
            system.pump(system.clock() + 2.0)
            (track,) = system.snapshot().bottles()
            return float(np.linalg.norm(track.p_base[:2] - centre[:2]))

        assert bottle_error() > 0.02
        system.set_calibration(CalibrationStatus("truth", "none", None, T_true))
        assert bottle_error() < 0.01


def fast_calibration_config(**calibration) -> Config:
    """No detection stages (the task reads frames itself), fewer poses: a quick Calibrate."""
    base = Config()
    return dataclasses.replace(
        base,
        runtime=dataclasses.replace(
            base.runtime, tag_detection=False, object_detection=False, liquid_detection=False
        ),
        calibration=dataclasses.replace(base.calibration, extra_poses=0, **calibration),
    )


def test_an_implausible_calibration_is_refused_and_the_previous_one_kept(tmp_path) -> None:
    """Before: any solve was applied and saved. Here the limit is below the simulation's
    ~0.5 mm residual, so the same (real) run is refused with the check's reason."""
    config = fast_calibration_config(max_residual_rms_mm=0.05)
    scene = SceneSpec(random_camera_pose(config.sim, None))
    T_wrong, _ = perturbed_calibration(scene.T_base_cam, 0, 0.03, 2.0)
    wrong = CalibrationStatus("a wrong one", "none", None, T_wrong)
    path = tmp_path / "calibration.json"
    with sim_system(config, 2, scene=scene, calibration=wrong) as system:
        status = system.run_task("calibrate", calibrate, save_path=path)
        assert status.phase == "failed"
        assert status.error.startswith("calibration refused: residual ")
        assert "exceeds calibration.max_residual_rms_mm = 0.05" in status.error
        assert "keeps its previous calibration" in status.error
        assert system.calibration is wrong
        assert np.array_equal(system.fusion.T_base_cam, T_wrong)
        assert np.allclose(system.world.joint_positions(), VX300S.home, atol=0.01)
    assert not path.exists()


def test_a_good_calibration_is_used_even_when_it_cannot_be_saved(tmp_path) -> None:
    """Before: a failing save (here: the path lies under a regular file) failed the task, and
    the good result was thrown away; likewise a .bak that could not be written."""
    config = fast_calibration_config()
    scene = SceneSpec(random_camera_pose(config.sim, None))
    T_true = scene.T_base_cam
    T_wrong, _ = perturbed_calibration(T_true, 0, 0.03, 2.0)
    wrong = CalibrationStatus("a wrong one", "none", None, T_wrong)
    (tmp_path / "not-a-directory").write_text("x")
    unwritable = tmp_path / "not-a-directory" / "calibration.json"
    with sim_system(config, 2, scene=scene, calibration=wrong) as system:
        status = system.run_task("calibrate", calibrate, save_path=unwritable)
        assert status.phase == "succeeded", status.error
        dp, _ = pose_error(system.calibration.T_base_cam, T_true)
        assert dp < 0.006 and np.array_equal(
            system.fusion.T_base_cam, system.calibration.T_base_cam
        )
        assert status.result["saved"] is None
        assert "cannot write the calibration" in status.result["save_error"]
        assert "in use, but not saved: cannot write the calibration" in status.message
        assert "not saved" in system.calibration.source

        # A previous calibration whose backup cannot be written (a directory is in the way).
        path = tmp_path / "calibration.json"
        path.write_text("{}")
        (tmp_path / "calibration.json.bak").mkdir()
        (tmp_path / "calibration.json.bak" / "x").write_text("x")
        status = system.run_task("calibrate", calibrate, save_path=path)
        assert status.phase == "succeeded", status.error
        assert status.result["saved"] == str(path) and status.result["save_error"] is None
        (warning,) = status.result["warnings"]
        assert "could not be kept as" in warning and warning in status.message
    assert np.allclose(load_calibration(path).T_base_cam, system.calibration.T_base_cam)


def test_the_simulated_calibrate_as_a_user_would_refuses_an_implausible_result() -> None:
    """calibrate_empty_table (the demo's and `armvision grab --sim`'s calibration) uses the
    same plausibility check: before, any solve was adopted."""
    config = fast_calibration_config(min_sample_spread_m=2.0)
    with pytest.raises(CalibrationError, match=r"^calibration refused: the tag positions spread"):
        calibrate_empty_table(config, 1)
