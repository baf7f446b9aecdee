"""Property-based: whatever is in a calibration file, loading it gives a calibration or a
one-line CalibrationError that names the file, never another exception; and no series of
failing saves and bad files next to it loses the last good calibration."""

from __future__ import annotations

import copy
import dataclasses
import json
import math
import os
import shutil
import tempfile
from pathlib import Path
from unittest import mock

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from tests.calibration.helpers import T_BASE_CAM, make_result

from armvision.calibration import store
from armvision.calibration.procedure import pose_errors
from armvision.errors import CalibrationError

SETTINGS = settings(deadline=None, max_examples=150, suppress_health_check=[HealthCheck.too_slow])


def _base() -> dict:
    """A valid calibration, with a simulation's truth section so that it is mutated too."""
    result = make_result()
    moved = T_BASE_CAM.copy()
    moved[0, 3] += 0.001
    truth = {
        "T_base_cam": moved.tolist(),
        "tag_offset_ee": [-0.1, 0.0, 0.03],
        "encoder_bias_deg": [0.0] * 6,
        "methods": {n: pose_errors(f.T_base_cam, moved) for n, f in result.fits.items()},
        **pose_errors(result.T_base_cam, moved),
    }
    return store.record(dataclasses.replace(result, truth=truth), source="base").to_dict()


BASE = _base()


def _paths(value, prefix=()):
    """Every place in a JSON value: tuples of keys and indices."""
    yield prefix
    if isinstance(value, dict):
        for key, item in value.items():
            yield from _paths(item, (*prefix, key))
    elif isinstance(value, list):
        for i, item in enumerate(value):
            yield from _paths(item, (*prefix, i))


PLACES = [p for p in _paths(BASE) if p]  # every field, element and matrix entry
#: Mostly matrix entries; the fields and sections themselves drawn as often as those.
places = st.sampled_from([p for p in PLACES if len(p) <= 2]) | st.sampled_from(PLACES)

scalars = (
    st.none()
    | st.booleans()
    | st.integers()
    | st.integers(min_value=-(10**400), max_value=10**400)
    | st.floats(allow_nan=True, allow_infinity=True)
    | st.text(max_size=20)
)
json_values = st.recursive(
    scalars,
    lambda children: (
        st.lists(children, max_size=5) | st.dictionaries(st.text(max_size=8), children, max_size=5)
    ),
    max_leaves=25,
)


@pytest.fixture(scope="module")
def workdir():
    directory = Path(tempfile.mkdtemp(prefix="calibration-properties-"))
    yield directory
    shutil.rmtree(directory, ignore_errors=True)


def loads_or_one_line_error(path: Path) -> store.StoredCalibration | None:
    """The property: a StoredCalibration (that is usable and saves again) or a one-line
    CalibrationError naming the file. Any other exception fails the test."""
    try:
        calibration = store.load(path)
    except CalibrationError as exc:
        message = str(exc)
        assert "\n" not in message and "\r" not in message, message
        assert str(path) in message, message
        return None
    assert isinstance(calibration, store.StoredCalibration)
    T = calibration.T_base_cam
    assert T.shape == (4, 4) and np.all(np.isfinite(T))
    json.dumps(calibration.to_dict(), allow_nan=False)  # everything in it is plain JSON
    store.save(calibration, path.with_name("resaved.json"))  # and it saves again
    return calibration


def put(document, place, value):
    target = document
    for key in place[:-1]:
        target = target[key]
    target[place[-1]] = value


def write_json(path: Path, document) -> None:
    path.write_text(json.dumps(document))  # NaN and Infinity as Python writes them


@SETTINGS
@given(document=json_values)
def test_any_json_document_loads_or_is_a_one_line_error(workdir, document):
    path = workdir / "any.json"
    write_json(path, document)
    loads_or_one_line_error(path)
    if isinstance(document, dict):  # the same with our schema and version, to go further
        write_json(path, {**document, "schema": store.SCHEMA, "version": 1})
        loads_or_one_line_error(path)


@SETTINGS
@given(places=st.lists(places, min_size=1, max_size=3), data=st.data())
def test_any_field_replaced_by_any_value_loads_or_is_a_one_line_error(workdir, places, data):
    document = copy.deepcopy(BASE)
    for place in places:
        try:
            value = data.draw(json_values)
            if data.draw(st.booleans()) and isinstance(place[-1], str):
                parent = document
                for key in place[:-1]:
                    parent = parent[key]
                parent.pop(place[-1])  # a missing field
            else:
                put(document, place, value)
        except (KeyError, IndexError, TypeError, AttributeError):
            pass  # an earlier replacement removed this place (or made its parent a scalar)
    path = workdir / "mutated.json"
    write_json(path, document)
    loads_or_one_line_error(path)


@SETTINGS
@given(
    place=places,
    depth=st.integers(min_value=1, max_value=200_000),
    opener=st.sampled_from(["[", '{"a": ']),
)
def test_deep_nesting_anywhere_loads_or_is_a_one_line_error(workdir, place, depth, opener):
    closer = "]" if opener == "[" else "}"
    marker = "__DEEP__"
    document = copy.deepcopy(BASE)
    put(document, place, marker)
    deep = opener * depth + "1" + closer * depth
    path = workdir / "deep.json"
    path.write_text(json.dumps(document).replace(json.dumps(marker), deep))
    loads_or_one_line_error(path)


@SETTINGS
@given(
    place=places,
    number=st.sampled_from(["NaN", "Infinity", "-Infinity", "1e400", "-1e999", "9" * 5000]),
)
def test_nan_infinity_and_huge_numbers_anywhere_are_refused(workdir, place, number):
    marker = "__NUMBER__"
    document = copy.deepcopy(BASE)
    put(document, place, marker)
    path = workdir / "number.json"
    path.write_text(json.dumps(document).replace(json.dumps(marker), number))
    assert loads_or_one_line_error(path) is None  # none of these is a JSON number we take


VALID_TEXT = json.dumps(BASE, indent=1).encode()


@SETTINGS
@given(raw=st.binary(max_size=300))
def test_random_bytes_are_a_one_line_error(workdir, raw):
    path = workdir / "bytes.json"
    path.write_bytes(raw)
    loads_or_one_line_error(path)


@SETTINGS
@given(
    edits=st.lists(
        st.tuples(
            st.integers(min_value=0, max_value=len(VALID_TEXT)),
            st.integers(min_value=0, max_value=8),
            st.binary(max_size=6) | st.sampled_from([b"\xff", b"\xc3", b"\xed\xa0\x80", b"\x00"]),
        ),
        min_size=1,
        max_size=4,
    ),
    truncate=st.none() | st.integers(min_value=0, max_value=len(VALID_TEXT)),
)
def test_a_damaged_valid_file_loads_or_is_a_one_line_error(workdir, edits, truncate):
    """Bytes of a real calibration file replaced, inserted (invalid UTF-8 among them), cut."""
    raw = VALID_TEXT
    for at, remove, insert in edits:
        raw = raw[:at] + insert + raw[at + remove :]
    if truncate is not None:
        raw = raw[:truncate]
    path = workdir / "damaged.json"
    path.write_bytes(raw)
    loads_or_one_line_error(path)


# ------------------------------------------------------------ hostile saves and bad files

GOOD = [store.record(make_result(seed=seed), source=f"good {seed}") for seed in range(3)]
NAN = dataclasses.replace(GOOD[0], residual_max_mm=math.nan, source="nan")

OPERATIONS = [
    "save_good",
    "save_nan",
    "save_disk_full",
    "save_fsync_fails",
    "save_interrupted",
    "save_backup_unreadable",
    "junk_backup",
    "backup_is_directory",
    "backup_links_to_victim",
    "backup_links_to_path",
    "junk_temporary_file",
    "remove_backup",
]


def _clear(path: Path) -> None:
    if path.is_symlink() or path.is_file():
        path.unlink()
    elif path.is_dir():
        shutil.rmtree(path)


def _fail(exception):
    def boom(*args, **kwargs):
        raise exception

    return boom


_real_open = open


def _no_reading(file, mode="r", *args, **kwargs):
    """``open`` that refuses to read (the backup's copy of the old file)."""
    if "r" in mode:
        raise PermissionError(13, "Permission denied", str(file))
    return _real_open(file, mode, *args, **kwargs)


@settings(deadline=None, max_examples=60, suppress_health_check=[HealthCheck.too_slow])
@given(
    steps=st.lists(
        st.tuples(st.sampled_from(OPERATIONS), st.integers(0, 2), st.binary(max_size=40)),
        min_size=1,
        max_size=14,
    )
)
def test_the_last_good_calibration_is_never_lost(workdir, steps):
    directory = Path(tempfile.mkdtemp(dir=workdir))
    path = directory / "calibration.json"
    backup = store.backup_path(path)
    victim = directory / "victim.txt"
    victim.write_text("not a calibration")
    store.save(GOOD[0], path)
    last_good = GOOD[0].source
    for operation, which, junk in steps:
        if operation == "save_good":
            saved = store.save(GOOD[which], path)
            assert saved.file == path
            last_good = GOOD[which].source
        elif operation == "save_nan":
            with pytest.raises(CalibrationError, match="residual_max_mm is not finite"):
                store.save(NAN, path)
        elif operation in ("save_disk_full", "save_fsync_fails", "save_interrupted"):
            name, exception = {
                "save_disk_full": ("replace", OSError(28, "No space left on device")),
                "save_fsync_fails": ("fsync", OSError(5, "Input/output error")),
                "save_interrupted": ("replace", KeyboardInterrupt()),
            }[operation]
            expected = KeyboardInterrupt if operation == "save_interrupted" else CalibrationError
            with mock.patch.object(os, name, _fail(exception)), pytest.raises(expected):
                store.save(GOOD[which], path)
        elif operation == "save_backup_unreadable":
            with mock.patch("builtins.open", _no_reading):
                saved = store.save(GOOD[which], path)
            assert saved.backup is None and "could not be kept" in saved.backup_error
            last_good = GOOD[which].source
        elif operation == "junk_backup":
            _clear(backup)
            backup.write_bytes(junk)
        elif operation == "backup_is_directory":
            _clear(backup)
            backup.mkdir()
            (backup / "x").write_bytes(junk)
        elif operation == "backup_links_to_victim":
            _clear(backup)
            backup.symlink_to(victim)
        elif operation == "backup_links_to_path":
            _clear(backup)
            backup.symlink_to(path)
        elif operation == "junk_temporary_file":
            (directory / f".calibration.json.{junk.hex()[:8] or 'x'}.tmp").write_bytes(junk)
        elif operation == "remove_backup":
            _clear(backup)
        assert store.load(path).source == last_good, operation
        assert victim.read_text() == "not a calibration"
        assert path.is_file() and not path.is_symlink()
    shutil.rmtree(directory)
