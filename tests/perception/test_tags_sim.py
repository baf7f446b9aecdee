"""The gripper tag seen by the simulated D435i: pose accuracy against the simulator's truth.

Acceptance (issue 4): tags at 0.5-1.2 m, median position error <= 5 mm and rotation <= 2 deg.
"""

from __future__ import annotations

from armvision.config import Config
from armvision.eval import parse_seeds
from armvision.eval.tags import evaluate_tags


def test_tag_pose_accuracy_in_simulation_meets_the_target():
    result = evaluate_tags(Config(), parse_seeds("0-4"), poses_per_seed=4)
    summary = result["summary"]
    assert summary["tag_views"] == 20
    assert summary["tag_detection_rate"] == 1.0
    assert all(0.5 <= v["distance_m"] <= 1.2 for v in result["views"])
    assert summary["tag_position_error_mm_median"] <= 5.0
    assert summary["tag_rotation_error_deg_median"] <= 2.0
    # Depth refinement must not make the pose worse than PnP alone.
    assert (
        summary["tag_position_error_mm_median"] <= summary["tag_position_error_mm_median_no_depth"]
    )


def test_parse_seeds_forms():
    assert parse_seeds("3") == [3]
    assert parse_seeds("0-3") == [0, 1, 2, 3]
    assert parse_seeds("1,4-5") == [1, 4, 5]
