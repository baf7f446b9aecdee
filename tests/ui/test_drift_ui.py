"""A camera knocked while the UI runs: the page's state says so with its size, and the moves
that aim from the camera are disabled and refused with the reason until it is put back."""

from __future__ import annotations

import httpx
import numpy as np
from tests.ui.conftest import running_ui

from armvision.geometry import make_T

JSON = {"Content-Type": "application/json"}


def test_a_knocked_camera_is_shown_and_aimed_moves_are_refused() -> None:
    with running_ui() as ui, httpx.Client(timeout=10.0) as client:
        state = ui.wait_state(
            client, lambda s: s["calibration"]["drift"]["translation_mm"] is not None, 15.0
        )
        assert not state["calibration"]["drift"]["drifted"]
        assert state["actions"]["grab"]["enabled"]
        T_true = ui.system.world.T_base_cam()
        ui.system.world.set_camera_pose(T_true @ make_T(np.eye(3), [0.0, 0.02, 0.0]))
        state = ui.wait_state(client, lambda s: s["calibration"]["drift"]["drifted"], 10.0)
        drift = state["calibration"]["drift"]
        assert 15.0 < drift["translation_mm"] < 25.0  # 2 cm, as the simulator moved it
        for name in ("grab", "analyze", "follow_bottle", "follow_tag"):
            reason = state["actions"][name]["reason"] or ""
            assert not state["actions"][name]["enabled"] and "camera has moved" in reason
        for name in ("home", "sleep", "calibrate"):
            assert state["actions"][name]["enabled"], name
        r = client.post(f"{ui.url}/api/actions/grab", headers=JSON, content=b"{}")
        assert r.status_code == 409 and "camera has moved" in r.json()["error"]
        assert "recalibrate" in r.json()["error"]
        ui.system.world.set_camera_pose(T_true)  # put back: the mark clears the same way
        state = ui.wait_state(client, lambda s: not s["calibration"]["drift"]["drifted"], 10.0)
        assert state["actions"]["grab"]["enabled"]
