"""``armvision calibrate`` and ``armvision eval calibration`` end to end in simulation."""

from __future__ import annotations

import json

from armvision.calibration import store
from armvision.calibration.solve import METHODS
from armvision.cli import main

FAST = ["--set", "sim.encoder_bias_deg=0", "--set", "calibration.extra_poses=0"]


def test_calibrate_saves_a_file_with_the_truth_and_a_failed_run_keeps_it(tmp_path, capsys):
    path = tmp_path / "cal.json"
    assert main([*FAST, "calibrate", "--sim", "--seed", "1", "--out", str(path), "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["path"] == str(path)
    assert out["truth"]["translation_error_mm"] < 3.0
    assert out["truth"]["rotation_error_deg"] < 0.3
    saved = store.load(path)
    assert saved.source == "simulation, seed 1" and saved.camera["serial"] == "sim"
    assert len(saved.samples) == len(saved.residuals_mm) >= 6
    before = path.read_bytes()

    # A camera that looks at the floor never sees the tag: the run fails and saves nothing.
    away = ["--set", "sim.camera_pitch_deg=89"]
    code = main([*FAST, *away, "calibrate", "--sim", "--seed", "1", "--out", str(path)])
    captured = capsys.readouterr()
    assert code == 2
    assert "was not seen" in captured.err and "Traceback" not in captured.err
    assert path.read_bytes() == before
    assert not store.backup_path(path).exists()


def test_calibrate_prints_the_residual_table(tmp_path, capsys):
    path = tmp_path / "cal.json"
    args = [*FAST, "--set", "calibration.phase2_heights=[0.15, 0.3]"]
    assert main([*args, "calibrate", "--sim", "--seed", "2", "--out", str(path)]) == 0
    out = capsys.readouterr().out
    assert "residual" in out and "method joint_kinematic" in out and "<- chosen" in out
    assert f"saved {path}" in out
    # A second run keeps the first as the backup and says so.
    assert main([*args, "calibrate", "--sim", "--seed", "2", "--out", str(path)]) == 0
    assert "previous kept as" in capsys.readouterr().out
    assert store.load(store.backup_path(path)).T_base_cam.shape == (4, 4)


def test_eval_calibration_prints_one_json_object(capsys):
    args = [*FAST, "--set", "calibration.phase2_heights=[0.15, 0.3]"]
    assert main([*args, "eval", "calibration", "--seeds", "4", "--json"]) == 0
    result = json.loads(capsys.readouterr().out)
    summary = result["summary"]
    for key in (
        "translation_error_mm_median",
        "translation_error_mm_max",
        "rotation_error_deg_median",
    ):
        assert summary[key] is not None
    assert summary["translation_error_mm_max"] < 3.0
    assert set(result["methods"]) == set(METHODS)
    assert {"svd", "robust_svd", "joint", "tsai", "park", "horaud", "andreff"} < set(METHODS)
    assert {"daniilidis", "shah", "li"} < set(METHODS)
    assert result["runs"][0]["placement"]["distance_m"] >= 0.8


def test_an_implausible_calibration_is_refused_unless_forced(tmp_path, capsys):
    """Before: any solve was saved without a word. A limit below the simulation's ~0.5 mm
    residual makes the (real) run implausible: refused, nothing written; with --force saved,
    with a warning, also when the previous calibration cannot be kept as the backup."""
    path = tmp_path / "cal.json"
    strict = [*FAST, "--set", "calibration.max_residual_rms_mm=0.05"]
    assert main([*strict, "calibrate", "--sim", "--seed", "1", "--out", str(path)]) == 2
    (err,) = [line for line in capsys.readouterr().err.splitlines() if "error" in line]
    assert err.startswith("armvision: error: calibration refused: residual ")
    assert "exceeds calibration.max_residual_rms_mm = 0.05 (is the tag loose, or tag.size" in err
    assert err.endswith("rerun, or pass --force to keep it")
    assert not path.exists()

    path.write_text("{}")  # a previous file, whose backup cannot be written: a directory
    store.backup_path(path).mkdir()
    (store.backup_path(path) / "x").write_text("x")
    args = [*strict, "calibrate", "--sim", "--seed", "1", "--out", str(path), "--force"]
    assert main(args) == 0
    captured = capsys.readouterr()
    assert "warning: calibration kept with --force although residual" in captured.err
    assert f"saved {path}, but the previous calibration could not be kept as" in captured.out
    assert store.load(path).residual_rms_mm > 0.05
