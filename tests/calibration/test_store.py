"""The calibration file: round trip, backups, interrupted saves, bad files named."""

from __future__ import annotations

import dataclasses
import json
import logging
import math
import os
import re
import stat

import numpy as np
import pytest
from tests.calibration.helpers import OFFSET, T_BASE_CAM, make_result

from armvision.calibration import store
from armvision.config import TagConfig
from armvision.errors import CalibrationError


def test_round_trip_keeps_everything(tmp_path):
    path = tmp_path / "calibration.json"
    written = store.record(make_result(), source="test")
    store.save(written, path)
    loaded = store.load(path)
    np.testing.assert_array_equal(loaded.T_base_cam, written.T_base_cam)
    assert loaded.method == "joint"
    assert loaded.camera["serial"] == "123456789012"
    assert loaded.camera["intrinsics"]["fx"] == 615.0
    assert loaded.tag["id"] == 96
    assert loaded.tag["offset_ee_configured"] == list(TagConfig().offset_ee)
    np.testing.assert_allclose(loaded.tag["offset_ee_estimated"], OFFSET, atol=1e-9)
    assert len(loaded.samples) == 10
    np.testing.assert_array_equal(loaded.samples[3].T_cam_tag, written.samples[3].T_cam_tag)
    assert set(loaded.methods) >= {"svd", "joint", "tsai", "shah"}
    assert loaded.residuals_mm == written.residuals_mm
    data = json.loads(path.read_text())
    assert data["schema"] == "armvision.calibration" and data["version"] == store.VERSION
    assert data["created"].endswith("+00:00")


def test_saving_again_keeps_the_previous_file_as_backup(tmp_path):
    path = tmp_path / "calibration.json"
    first = store.record(make_result(), source="first")
    moved = T_BASE_CAM.copy()
    moved[0, 3] += 0.1
    second = store.record(make_result(moved), source="second")
    store.save(first, path)
    assert not store.backup_path(path).exists()
    store.save(second, path)
    assert store.load(path).source == "second"
    assert store.load(store.backup_path(path)).source == "first"
    assert sorted(p.name for p in tmp_path.iterdir()) == [
        "calibration.json",
        "calibration.json.bak",
    ]


@pytest.mark.parametrize("fail_at", ["fsync", "replace", "open"])
@pytest.mark.parametrize("exception", [OSError("disk full"), KeyboardInterrupt()])
def test_an_interrupted_save_leaves_the_previous_calibration(
    tmp_path, monkeypatch, fail_at, exception
):
    """``open`` fails in the backup only (the new file is written by os.open): an OSError
    there still saves (see the backup tests), Ctrl-C leaves everything as it was."""
    path = tmp_path / "calibration.json"
    store.save(store.record(make_result(), source="good"), path)
    before = path.read_bytes()

    def boom(*args, **kwargs):
        raise exception

    target = {"fsync": (os, "fsync"), "replace": (os, "replace"), "open": ("builtins.open",)}[
        fail_at
    ]
    monkeypatch.setattr(*target, boom)
    moved = T_BASE_CAM.copy()
    moved[1, 3] += 0.2
    if fail_at == "open" and isinstance(exception, OSError):
        saved = store.save(store.record(make_result(moved), source="new"), path)
        monkeypatch.undo()
        assert "disk full" in saved.backup_error and store.load(path).source == "new"
    else:
        expected = CalibrationError if isinstance(exception, OSError) else KeyboardInterrupt
        with pytest.raises(expected):
            store.save(store.record(make_result(moved), source="new"), path)
        monkeypatch.undo()
        assert path.read_bytes() == before
        assert store.load(path).source == "good"
    leftovers = [p.name for p in tmp_path.iterdir() if p.name.endswith(".tmp")]
    assert leftovers == []


def write(tmp_path, text, name="calibration.json"):
    path = tmp_path / name
    path.write_text(text)
    return path


def valid_dict():
    return store.record(make_result(), source="test").to_dict()


@pytest.mark.parametrize(
    ("content", "message"),
    [
        ('{"schema": "armvision.calibration", "version": 1, "T_base', "not valid JSON"),
        ("", "not valid JSON"),
        ('{"camera_to_base": [[1, 0, 0, 0]]}', "not an armvision calibration"),
        ("[1, 2, 3]", "not an armvision calibration"),
        ("transformation:\n  x: 1.0\n", "not valid JSON"),  # e.g. an easy_handeye YAML
    ],
)
def test_a_corrupt_or_foreign_file_is_refused_with_its_name(tmp_path, content, message):
    path = write(tmp_path, content, "my_cal.json")
    with pytest.raises(CalibrationError, match=message) as info:
        store.load(path)
    assert str(path) in str(info.value)


@pytest.mark.parametrize(
    ("change", "message"),
    [
        (lambda d: d.update(version=99), "newer than this armvision reads"),
        (lambda d: d.update(version="one"), "positive integer"),
        (lambda d: d.pop("T_base_cam"), "lacks the field 'T_base_cam'"),
        (lambda d: d.update(T_base_cam=[[1, 0, 0], [0, 1, 0]]), "4x4"),
        (lambda d: d.update(T_base_cam=(2 * np.eye(4)).tolist()), "not a rigid transform"),
        (lambda d: d.update(T_base_cam="identity"), "4x4"),
        (lambda d: d["samples"][0].pop("T_cam_tag"), r"lacks the field 'samples\[0\].T_cam_tag'"),
        (lambda d: d.update(residual_rms_mm="small"), "residual_rms_mm must be a number"),
    ],
)
def test_an_inconsistent_file_is_refused_with_its_name(tmp_path, change, message):
    data = valid_dict()
    change(data)
    path = write(tmp_path, json.dumps(data))
    with pytest.raises(CalibrationError, match=message) as info:
        store.load(path)
    assert str(path) in str(info.value)


def test_a_damaged_file_points_at_the_backup(tmp_path):
    path = tmp_path / "calibration.json"
    store.save(store.record(make_result(), source="one"), path)
    store.save(store.record(make_result(), source="two"), path)
    path.write_text(path.read_text()[:100])  # damaged after the fact
    with pytest.raises(CalibrationError, match=r"previous calibration is in .*\.bak"):
        store.load(path)


def test_a_missing_file_says_how_to_make_one(tmp_path):
    with pytest.raises(CalibrationError, match="armvision calibrate"):
        store.load(tmp_path / "nope.json")


def test_an_unwritable_place_is_a_clear_error(tmp_path):
    blocker = tmp_path / "file"
    blocker.write_text("x")
    with pytest.raises(CalibrationError, match="cannot write the calibration"):
        store.save(store.record(make_result(), source="x"), blocker / "calibration.json")


# ---------------------------------------------------------------- regressions: malformed files


def load_error(path) -> str:
    """The message of the CalibrationError loading ``path`` gives (any other exception fails)."""
    with pytest.raises(CalibrationError) as info:
        store.load(path)
    message = str(info.value)
    assert str(path) in message and "\n" not in message
    return message


BAD_VALUES = [5, 2.5, "text", True, None, [], [1, 2], {}, {"a": 1}]
FIELDS = ["methods", "samples", "tag", "camera", "truth", "created", "source", "method"]
FIELDS += ["residuals_mm", "joint_offsets_rad", "residual_rms_mm", "T_base_cam"]
#: The values of BAD_VALUES that are valid for a field (a camera of unknown serial and
#: intrinsics, no samples, no other methods, no truth).
VALID = {
    "methods": [{}],
    "samples": [[]],
    "camera": [{}, {"a": 1}],
    "truth": [None],
    "created": ["text"],
    "source": ["text"],
    "method": ["text"],
    "joint_offsets_rad": [None],
    "residual_rms_mm": [5, 2.5],
}
WRONG_TYPES = [
    (key, value)
    for key in FIELDS
    for value in BAD_VALUES
    if not any(value == v and type(value) is type(v) for v in VALID.get(key, []))
]


@pytest.mark.parametrize(("key", "value"), WRONG_TYPES, ids=[f"{k}={v!r}" for k, v in WRONG_TYPES])
def test_a_field_of_the_wrong_type_is_a_calibration_error(tmp_path, key, value):
    """Before: ``"methods": 5`` raised TypeError, ``"methods": "text"`` ValueError, and a
    number or an object for created, source or tag was taken as it was."""
    data = valid_dict()
    data[key] = value
    message = load_error(write(tmp_path, json.dumps(data)))
    assert key in message


@pytest.mark.parametrize(
    ("section", "key", "value"),
    [
        ("tag", "size", "text"),
        ("tag", "size", -0.04),
        ("tag", "id", 1.5),
        ("tag", "offset_ee_configured", [0.1, 0.2]),
        ("camera", "serial", 5),
        ("camera", "intrinsics", "text"),
    ],
)
def test_a_subfield_of_the_wrong_type_is_a_calibration_error(tmp_path, section, key, value):
    """Before: the tag and camera sections were taken as they were, whatever they held."""
    data = valid_dict()
    data[section][key] = value
    assert f"{section}.{key}" in load_error(write(tmp_path, json.dumps(data)))


def test_a_broken_sample_or_method_is_a_calibration_error(tmp_path):
    data = valid_dict()
    data["samples"][2]["joint_positions"] = {"q": 1}
    assert "samples[2].joint_positions" in load_error(write(tmp_path, json.dumps(data)))
    data = valid_dict()
    data["methods"]["svd"]["T_base_cam"] = [["1", "0", "0", "0"]] * 4
    assert "methods.svd.T_base_cam" in load_error(write(tmp_path, json.dumps(data)))


def test_a_key_with_a_newline_is_named_on_one_line(tmp_path):
    """Before: the raw key split the one-line error in two (found by Hypothesis)."""
    data = valid_dict()
    data["methods"]["svd\nx"] = {"T_base_cam": "not a matrix"}
    message = load_error(write(tmp_path, json.dumps(data)))
    assert "\n" not in message
    assert "methods.svd\\nx" in message


def test_deeply_nested_json_is_a_calibration_error(tmp_path):
    """Before: RecursionError from the JSON parser."""
    deep = '{"schema": "armvision.calibration", "version": 1, "x": ' + "[" * 100_000
    deep += "]" * 100_000 + "}"
    assert "nested" in load_error(write(tmp_path, deep))


@pytest.mark.parametrize(
    ("raw", "message"),
    [
        (b'{"schema": "armvision.calibration", "version": 1, "T_base_cam": NaN}', "NaN"),
        (b'{"schema": "armvision.calibration", "version": 1e400}', "version"),
        (b'{"schema": "armvision.calibration", "version": ' + b"9" * 5000 + b"}", "not valid"),
        (b"\xff\xfe\x00{", "UTF-8"),
    ],
)
def test_nan_huge_numbers_and_bytes_are_calibration_errors(tmp_path, raw, message):
    path = tmp_path / "calibration.json"
    path.write_bytes(raw)
    assert message in load_error(path)


def test_a_directory_in_place_of_the_file_is_a_calibration_error(tmp_path):
    (tmp_path / "calibration.json").mkdir()
    assert "not a regular file" in load_error(tmp_path / "calibration.json")


# ---------------------------------------------------------------- regressions: saving


def test_saving_a_nan_says_which_field_and_writes_nothing(tmp_path):
    """Before: a bare ValueError from json.dumps."""
    path = tmp_path / "calibration.json"
    store.save(store.record(make_result(), source="good"), path)
    before = path.read_bytes()
    good = store.record(make_result(), source="bad")
    samples = list(good.samples)
    T = samples[2].T_cam_tag.copy()
    T[1, 3] = np.nan
    samples[2] = dataclasses.replace(samples[2], T_cam_tag=T)
    for bad, field in [
        (dataclasses.replace(good, samples=tuple(samples)), "samples[2].T_cam_tag[1][3]"),
        (dataclasses.replace(good, residual_rms_mm=math.inf), "residual_rms_mm"),
        (dataclasses.replace(good, residuals_mm=(1.0, math.nan)), "residuals_mm[1]"),
    ]:
        with pytest.raises(CalibrationError, match=re.escape(field)) as info:
            store.save(bad, path)
        assert "not finite" in str(info.value) and str(path) in str(info.value)
        assert path.read_bytes() == before
        assert not store.backup_path(path).exists()
        assert sorted(p.name for p in tmp_path.iterdir()) == ["calibration.json"]


def test_a_backup_that_cannot_be_written_does_not_block_the_save(tmp_path, caplog):
    """Before: the failed copy to .bak was a CalibrationError and nothing was saved."""
    path = tmp_path / "calibration.json"
    store.save(store.record(make_result(), source="first"), path)
    store.backup_path(path).mkdir()
    (store.backup_path(path) / "something").write_text("x")  # a directory cannot be replaced
    with caplog.at_level(logging.WARNING, logger="armvision.calibration.store"):
        saved = store.save(store.record(make_result(), source="second"), path)
    assert store.load(path).source == "second"
    assert saved.backup is None
    assert saved.backup_error is not None and str(store.backup_path(path)) in saved.backup_error
    assert "could not be kept" in saved.backup_error and "\n" not in saved.backup_error
    assert any("could not be kept" in r.getMessage() for r in caplog.records)
    assert [p.name for p in tmp_path.iterdir() if p.name.endswith(".tmp")] == []


def test_a_read_only_backup_is_replaced(tmp_path):
    path = tmp_path / "calibration.json"
    store.save(store.record(make_result(), source="first"), path)
    store.save(store.record(make_result(), source="second"), path)
    store.backup_path(path).chmod(0o444)
    saved = store.save(store.record(make_result(), source="third"), path)
    assert saved.backup == store.backup_path(path) and saved.backup_error is None
    assert store.load(store.backup_path(path)).source == "second"


def test_a_symlinked_backup_is_replaced_not_followed(tmp_path):
    """Before: copy2 wrote the previous calibration through the link into its target."""
    path = tmp_path / "calibration.json"
    victim = tmp_path / "precious.txt"
    victim.write_text("do not touch")
    store.save(store.record(make_result(), source="first"), path)
    store.backup_path(path).symlink_to(victim)
    store.save(store.record(make_result(), source="second"), path)
    assert victim.read_text() == "do not touch"
    assert not store.backup_path(path).is_symlink()
    assert store.load(store.backup_path(path)).source == "first"


def test_a_symlinked_calibration_path_stays_a_link(tmp_path):
    """Before: the link was replaced by a regular file and its target kept the old one."""
    real_dir = tmp_path / "real"
    real_dir.mkdir()
    target = real_dir / "calibration.json"
    link = tmp_path / "calibration.json"
    store.save(store.record(make_result(), source="first"), target)
    link.symlink_to(target)
    saved = store.save(store.record(make_result(), source="second"), link)
    assert link.is_symlink() and link.resolve() == target.resolve()
    assert store.load(target).source == "second"
    assert store.load(real_dir / "calibration.json.bak").source == "first"
    assert saved.backup == real_dir / "calibration.json.bak"
    assert store.backup_path(link) == saved.backup
    assert sorted(p.name for p in tmp_path.iterdir()) == ["calibration.json", "real"]
    # A dangling link: the calibration is made where it points.
    (tmp_path / "later.json").symlink_to(real_dir / "later.json")
    store.save(store.record(make_result(), source="third"), tmp_path / "later.json")
    assert store.load(real_dir / "later.json").source == "third"
    assert (tmp_path / "later.json").is_symlink()


def test_saving_keeps_the_file_mode_and_a_new_file_follows_the_umask(tmp_path):
    """Before: every save left a 0600 file (mkstemp's mode)."""
    path = tmp_path / "calibration.json"
    old = os.umask(0o022)
    try:
        store.save(store.record(make_result(), source="first"), path)
        assert stat.S_IMODE(path.stat().st_mode) == 0o644
        path.chmod(0o640)
        store.save(store.record(make_result(), source="second"), path)
        assert stat.S_IMODE(path.stat().st_mode) == 0o640
        assert stat.S_IMODE(store.backup_path(path).stat().st_mode) == 0o640
        os.umask(0o077)
        store.save(store.record(make_result(), source="x"), tmp_path / "new.json")
        assert stat.S_IMODE((tmp_path / "new.json").stat().st_mode) == 0o600
    finally:
        os.umask(old)
