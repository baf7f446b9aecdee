"""`armvision perceive` and `armvision eval perception|liquid` as a user runs them."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np

ARMVISION = [sys.executable, "-m", "armvision.cli"]


def run(*args: str, cwd) -> subprocess.CompletedProcess:
    return subprocess.run([*ARMVISION, *args], capture_output=True, text=True, cwd=cwd, timeout=300)


def test_perceive_sim_writes_annotated_image_and_matching_detections(tmp_path):
    result = run("perceive", "--sim", "--seed", "3", "--out", "out", cwd=tmp_path)
    assert result.returncode == 0, result.stderr
    assert (tmp_path / "out" / "annotated.png").stat().st_size > 10_000
    record = json.loads((tmp_path / "out" / "detections.json").read_text())
    assert [t["id"] for t in record["tags"]] == [96]
    T_est, T_true = (
        np.array(record["tags"][0]["T_cam_tag"]),
        np.array(record["ground_truth"]["T_cam_tag"]),
    )
    assert np.linalg.norm(T_est[:3, 3] - T_true[:3, 3]) < 0.005
    truth = record["ground_truth"]["objects"]
    assert len(record["detections"]) == len(truth)
    for det in record["detections"]:
        nearest = min(
            truth, key=lambda o: np.linalg.norm(np.subtract(o["center_cam"], det["center_cam"]))
        )
        assert np.linalg.norm(np.subtract(nearest["center_cam"], det["center_cam"])) < 0.02
        assert det["label"] == nearest["label"]
        if det["label"] == "bottle":
            assert abs(det["fill"] - nearest["fill"]) < 0.1


def test_eval_commands_print_one_json_object_with_the_summary(tmp_path):
    result = run("eval", "perception", "--seeds", "0-1", "--json", cwd=tmp_path)
    assert result.returncode == 0, result.stderr
    summary = json.loads(result.stdout)["summary"]
    for key in (
        "tag_position_error_mm_median",
        "tag_rotation_error_deg_median",
        "object_recall",
        "object_false_positives",
        "object_label_accuracy",
        "object_center_error_mm_median",
    ):
        assert key in summary, key
    assert summary["object_recall"] == 1.0 and summary["object_false_positives"] == 0
    liquid = run("eval", "liquid", "--n", "4", "--seed", "1", "--json", cwd=tmp_path)
    assert liquid.returncode == 0, liquid.stderr
    summary = json.loads(liquid.stdout)["summary"]
    assert summary["mae_pct"] <= 10.0 and "mae_pct_hough" in summary
