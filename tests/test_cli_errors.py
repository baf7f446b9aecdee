"""Every mistake on the command line is a one-line error that says what to do, exit status 2,
found before anything slow starts: bad files, empty paths, out-of-range numbers, unwritable
output directories. The CLI runs in-process (armvision.cli.main)."""

from __future__ import annotations

import os
import time

import pytest

from armvision.cli import main


@pytest.fixture(autouse=True)
def no_ambient_config(monkeypatch, tmp_path):
    monkeypatch.delenv("ARMVISION_CONFIG", raising=False)
    monkeypatch.chdir(tmp_path)  # no ./armvision.toml


def fails(capsys, *argv: str) -> str:
    """Run ``armvision argv``; check exit status 2 and a one-line error; return that line."""
    code = main(list(argv))
    captured = capsys.readouterr()
    lines = captured.err.splitlines()
    assert code == 2, (code, captured.err)
    assert len(lines) == 1, captured.err
    assert "Traceback" not in captured.err
    assert ": error: " in lines[0]
    return lines[0]


def test_config_file_that_is_not_utf8(capsys, tmp_path):
    bad = tmp_path / "bad.toml"
    bad.write_bytes(b"[tag]\nid = 96 # \xff\xfe\n")
    line = fails(capsys, "--config", str(bad), "info")
    assert "bad.toml is not valid UTF-8" in line


@pytest.mark.parametrize("value", ["", '""', "' '"])
def test_empty_calibration_file(capsys, value):
    line = fails(capsys, "--set", f"calibration.file={value}", "config")
    assert "'calibration.file'" in line


SEEDED = [
    ["sim", "snapshot"],
    ["perceive"],
    ["calibrate"],
    ["demo"],
    ["grab"],
    ["analyze"],
    ["follow"],
    ["ui"],
    ["eval", "liquid"],
    ["eval", "fusion"],
    ["eval", "grab"],
    ["eval", "follow"],
]


@pytest.mark.parametrize("seed", ["-1", "4294967296", "x"])
@pytest.mark.parametrize("command", SEEDED, ids=" ".join)
def test_seeds_out_of_range(capsys, command, seed):
    line = fails(capsys, *command, "--seed", seed)
    assert "argument --seed" in line
    if seed != "x":  # (calibrate's --seed is a plain int: argparse says 'invalid int value')
        assert "from 0 to 4294967295" in line


@pytest.mark.parametrize(
    ("argv", "argument"),
    [
        (["eval", "liquid", "--n", "0"], "--n"),
        (["eval", "liquid", "--n", "-5"], "--n"),
        (["eval", "liquid", "--boxes", "network"], "--boxes"),
        (["eval", "grab", "--trials", "0"], "--trials"),
        (["eval", "fusion", "--waypoints", "1"], "--waypoints"),
        (["eval", "perception", "--seeds", "5-2"], "--seeds"),
        (["eval", "perception", "--seeds", "0-99999999999"], "--seeds"),  # no huge list
        (["eval", "perception", "--seeds", "4294967296"], "--seeds"),
        (["eval", "calibration", "--seeds", "1,,2"], "--seeds"),
        (["eval", "calibration", "--offset-error-mm", "-1"], "--offset-error-mm"),
        (["eval", "calibration", "--offset-error-mm", "nan"], "--offset-error-mm"),
        (["follow", "--duration", "-1"], "--duration"),
        (["follow", "--duration", "inf"], "--duration"),
        (["follow", "--duration", "0"], "--duration"),
        (["follow", "--tag-id", "-1"], "--tag-id"),
        (["follow", "--track", "-2"], "--track"),
        (["grab", "--track", "-1"], "--track"),
        (["analyze", "--track", "1.5"], "--track"),
        (["eval", "follow", "--duration", "nan"], "--duration"),
        (["eval", "follow", "--duration", "-3"], "--duration"),
        (["ui", "--port", "70000"], "--port"),  # used to wrap to 4464
        (["ui", "--port", "-1"], "--port"),
        (["perceive", "--out", ""], "--out"),
    ],
)
def test_numbers_out_of_range(capsys, argv, argument):
    line = fails(capsys, *argv)
    assert f"argument {argument}" in line


def test_argparse_errors_are_one_line_too(capsys):
    line = fails(capsys, "eval", "liquid", "--n", "many")
    assert "argument --n" in line and "--help" in line
    fails(capsys, "nosuchcommand")
    assert main(["--version"]) == 0  # --version and --help still exit 0
    assert main(["--help"]) == 0


@pytest.fixture(params=["under-a-file", "proc"])
def unwritable(request, tmp_path):
    """A directory nobody can write to, even as root: one whose parent is a regular file, or
    /proc (it exists, so only writing a file into it finds the problem)."""
    if request.param == "proc":
        if not os.path.isdir("/proc"):
            pytest.skip("no /proc here")
        return "/proc"
    blocker = tmp_path / "a-file"
    blocker.write_text("not a directory")
    return str(blocker / "out")


@pytest.mark.parametrize(
    "command",
    [["perceive"], ["demo"], ["sim", "snapshot"]],
    ids=" ".join,
)
def test_unwritable_out_fails_before_any_work(capsys, unwritable, command):
    start = time.monotonic()
    line = fails(capsys, *command, "--out", unwritable)
    assert time.monotonic() - start < 5.0  # no scene built, no calibration run
    assert "--out" in line and unwritable in line and "choose" in line


def test_out_that_is_a_file(capsys, tmp_path):
    existing = tmp_path / "taken"
    existing.write_text("")
    line = fails(capsys, "perceive", "--out", str(existing))
    assert "--out" in line and str(existing) in line


def test_calibrate_checks_its_output_folder_before_moving_the_arm(capsys, tmp_path):
    start = time.monotonic()
    blocker = tmp_path / "a-file"
    blocker.write_text("not a folder")
    line = fails(capsys, "calibrate", "--sim", "--out", str(blocker / "calibration.json"))
    assert "the calibration's folder" in line and "cannot write there" in line
    assert time.monotonic() - start < 5.0  # refused before the (30 s) sampling started


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["place", "--sim", "--zone", "nope"], "no zone 'nope' in place.zones"),
        (["place", "--sim", "--zone", "full", "--x", "0.2"], "not both"),
        (["place", "--sim", "--x", "0.2"], "say where"),
        (["sort", "--sim", "--by", "colour"], "sorting by colour needs a rule"),
        (["sort", "--sim", "--colours", "teal=full"], "unknown colour name 'teal'"),
        (["sort", "--sim", "--threshold", "2"], "between 0 and 1"),
    ],
)
def test_place_and_sort_refuse_bad_input_before_building_a_system(argv, message, capsys):
    assert message in fails(capsys, *argv)
