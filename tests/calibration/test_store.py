"""The calibration file: round trip, backups, interrupted saves, bad files named."""

from __future__ import annotations

import json
import os

import numpy as np
import pytest
from tests.calibration.helpers import OFFSET, T_BASE_CAM, samples

from armvision.calibration import store
from armvision.calibration.procedure import CalibrationResult, solve_all
from armvision.calibration.sampling import Sample, SamplingResult
from armvision.camera.frames import Intrinsics
from armvision.config import TagConfig
from armvision.errors import CalibrationError


def make_result(T_base_cam=T_BASE_CAM, seed=0) -> CalibrationResult:
    T_be, T_ct = samples(n=10, seed=seed, T_base_cam=T_base_cam)
    sample_list = tuple(
        Sample(2, 0.1 * i, 0.2, np.zeros(6), T_be[i], T_ct[i], 5, 5, 0.0003, 80.0)
        for i in range(len(T_be))
    )
    fits = solve_all(sample_list, OFFSET, 0.005, 6)
    sampling = SamplingResult(sample_list, 0.0, np.array([1.0, 0.0, 0.45]), ("a skipped pose",))
    return CalibrationResult(
        "joint",
        fits["joint"],
        fits,
        sampling,
        TagConfig(),
        Intrinsics(640, 480, 615.0, 615.0, 319.5, 239.5),
        "123456789012",
    )


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


@pytest.mark.parametrize("fail_at", ["fsync", "copy2", "replace"])
@pytest.mark.parametrize("exception", [OSError("disk full"), KeyboardInterrupt()])
def test_an_interrupted_save_leaves_the_previous_calibration(
    tmp_path, monkeypatch, fail_at, exception
):
    path = tmp_path / "calibration.json"
    store.save(store.record(make_result(), source="good"), path)
    before = path.read_bytes()

    def boom(*args, **kwargs):
        raise exception

    target = {"fsync": (os, "fsync"), "copy2": (store.shutil, "copy2"), "replace": (os, "replace")}[
        fail_at
    ]
    monkeypatch.setattr(*target, boom)
    moved = T_BASE_CAM.copy()
    moved[1, 3] += 0.2
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
        (lambda d: d.update(T_base_cam=[[1, 0, 0], [0, 1, 0]]), "finite 4x4"),
        (lambda d: d.update(T_base_cam=(2 * np.eye(4)).tolist()), "not a rigid transform"),
        (lambda d: d.update(T_base_cam="identity"), "4x4"),
        (lambda d: d["samples"][0].pop("T_cam_tag"), "lacks the field 'T_cam_tag'"),
        (lambda d: d.update(residual_rms_mm="small"), "malformed"),
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
