"""`armvision demo` end to end: every step checked against the simulator, exit status 0."""

from __future__ import annotations

import json

from armvision.cli import main


def test_demo_passes_every_check_and_writes_the_image(tmp_path, capsys) -> None:
    status = main(["demo", "--seed", "0", "--out", str(tmp_path), "--json"])
    report = json.loads(capsys.readouterr().out)
    failed = [row for row in report["rows"] if not row["ok"]]
    assert status == 0 and report["ok"], failed
    steps = [row["step"] for row in report["rows"]]
    assert steps.count("detect") == 3 and steps.count("analyze") == 2
    assert {"calibrate", "grab", "runtime"} <= set(steps)
    assert (tmp_path / "demo.png").stat().st_size > 10_000
