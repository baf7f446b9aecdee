"""The calibration file: versioned JSON, written so that a good calibration is never lost.

Saving first checks that what it writes will load back (every number finite, every field of
its type); then it writes the new file next to the old one under a temporary name (with the
old file's mode, or 0666 less the umask for a new file, as ``open`` would), flushes it to
disk, keeps the current calibration as ``<name>.bak`` and renames the new file into place,
so at every moment the path holds a complete calibration: an interrupted save (a crash,
Ctrl-C, a full disk) leaves the previous one, and a failed calibration never reaches
:func:`save`. The backup is best effort: it is written under a temporary name and renamed
over ``.bak`` (a link there is replaced, never followed), and if it cannot be made the new
calibration is saved anyway and :attr:`Saved.backup_error` says why. A path that is a
symbolic link keeps being one: the file it points to is the one replaced.

Loading checks everything before anything uses it: that the file is UTF-8 JSON, that it is
ours (``"schema": "armvision.calibration"``), a version we read, and every field of its
type (transforms rigid, numbers finite); any problem is a one-line
:class:`CalibrationError` that names the file and says what to do.
"""

from __future__ import annotations

import contextlib
import datetime as _dt
import json
import logging
import math
import os
import secrets
import stat
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from armvision.calibration.sampling import Sample
from armvision.errors import CalibrationError

Array = NDArray[np.float64]
log = logging.getLogger(__name__)

SCHEMA = "armvision.calibration"
VERSION = 1
#: How far from a rotation the stored R may be (rounding in the JSON is ~1e-16).
_ORTHONORMAL_TOLERANCE = 1e-6
#: The largest file taken for a calibration (a run of 200 poses is about 300 kB).
_MAX_BYTES = 16 * 1024 * 1024


@dataclass(frozen=True, eq=False)
class StoredCalibration:
    """A calibration as kept on disk (see :func:`record` for the fields' meaning)."""

    T_base_cam: Array
    method: str
    created: str
    residual_rms_mm: float
    residual_max_mm: float
    residuals_mm: tuple[float, ...]
    tag: dict[str, Any]
    camera: dict[str, Any]
    source: str
    joint_offsets: tuple[float, ...] | None = None
    samples: tuple[Sample, ...] = field(default=())
    methods: dict[str, Any] = field(default_factory=dict)
    truth: dict[str, Any] | None = None
    path: Path | None = None

    def to_dict(self) -> dict[str, Any]:
        data: dict[str, Any] = {
            "schema": SCHEMA,
            "version": VERSION,
            "created": self.created,
            "source": self.source,
            "method": self.method,
            "T_base_cam": np.asarray(self.T_base_cam).tolist(),
            "residual_rms_mm": self.residual_rms_mm,
            "residual_max_mm": self.residual_max_mm,
            "residuals_mm": list(self.residuals_mm),
            "tag": self.tag,
            "camera": self.camera,
            "joint_offsets_rad": None if self.joint_offsets is None else list(self.joint_offsets),
            "methods": self.methods,
            "samples": [s.to_dict() for s in self.samples],
        }
        if self.truth is not None:
            data["truth"] = self.truth
        return data


def record(result, source: str) -> StoredCalibration:
    """What to keep of a :class:`~armvision.calibration.procedure.CalibrationResult`.

    The tag section holds the configured offset and the one the method used or estimated;
    ``methods`` every method's transform and residual (or its failure: a method whose answer
    is not finite is kept as one); ``truth`` the simulator's camera pose and the errors, when
    there is one.
    """
    fit = result.fit
    intrinsics = None if result.intrinsics is None else result.intrinsics.to_dict()
    methods: dict[str, Any] = {}
    for name, other in result.fits.items():
        if isinstance(other, str):
            methods[name] = {"error": other}
            continue
        entry = {
            "T_base_cam": other.T_base_cam.tolist(),
            "residual_rms_mm": 1000 * other.rms_m,
            "offset_ee": other.offset_ee.tolist(),
            "dropped_samples": other.dropped,
            "joint_offsets_rad": None
            if other.joint_offsets is None
            else other.joint_offsets.tolist(),
        }
        bad = _non_finite(entry)
        methods[name] = entry if bad is None else {"error": f"its {bad[0]} is not finite"}
    truth = result.truth
    if truth is not None and isinstance(truth.get("methods"), dict):
        kept = {k: v for k, v in truth["methods"].items() if _non_finite(v) is None}
        truth = {**truth, "methods": kept}
    return StoredCalibration(
        T_base_cam=fit.T_base_cam,
        method=result.method,
        created=_dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds"),
        residual_rms_mm=1000 * fit.rms_m,
        residual_max_mm=1000 * fit.max_m,
        residuals_mm=tuple(float(1000 * r) for r in fit.residuals),
        tag={
            "family": result.tag.family,
            "id": result.tag.id,
            "size": result.tag.size,
            "offset_ee_configured": list(result.tag.offset_ee),
            "offset_ee_estimated": fit.offset_ee.tolist(),
            "dropped_samples": fit.dropped,
        },
        joint_offsets=None if fit.joint_offsets is None else tuple(fit.joint_offsets.tolist()),
        camera={
            "serial": result.camera_serial,
            "intrinsics": intrinsics,
        },
        source=source,
        samples=tuple(result.samples),
        methods=methods,
        truth=truth,
    )


# --------------------------------------------------------------------------- saving


@dataclass(frozen=True)
class Saved:
    """What :func:`save` did.

    ``path`` as given; ``file`` the file written (the target when ``path`` is a symbolic
    link); ``backup`` where the calibration it replaced was kept, None when there was none or
    it could not be kept, and then ``backup_error`` says why (one line).
    """

    path: Path
    file: Path
    backup: Path | None = None
    backup_error: str | None = None


def _resolve(path: Path) -> Path:
    """The file ``path`` names: a symbolic link's final target, else ``path`` itself."""
    try:
        if not path.is_symlink():
            return path
    except (OSError, ValueError):
        return path
    return Path(os.path.realpath(path))


def backup_path(path: str | os.PathLike) -> Path:
    """Where :func:`save` keeps the calibration it replaces (beside a symbolic link's target)."""
    target = _resolve(Path(path))
    return target.with_name(target.name + ".bak")


def _name(path: Path) -> str:
    """The path for a one-line message (control characters escaped)."""
    text = str(path)
    return text if text.isprintable() else text.encode("unicode_escape").decode("ascii")


def _reason(exc: BaseException) -> str:
    return " ".join(str(exc).split()) or type(exc).__name__


def _non_finite(value: Any, name: str = "") -> tuple[str, Any] | None:
    """The first number in ``value`` (nested dicts and lists) that is not finite, with its
    field name (``samples[2].T_cam_tag[1][3]``), or None."""
    if isinstance(value, np.ndarray):
        value = value.tolist()
    if isinstance(value, dict):
        for key, item in value.items():
            found = _non_finite(item, f"{name}.{key}" if name else str(key))
            if found is not None:
                return found
    elif isinstance(value, (list, tuple)):
        for i, item in enumerate(value):
            found = _non_finite(item, f"{name}[{i}]")
            if found is not None:
                return found
    elif isinstance(value, (float, np.floating)) and not math.isfinite(value):
        return name, value
    return None


def _write_new(directory: Path, name: str, payload: bytes, mode: int | None) -> Path:
    """A new file in ``directory`` holding ``payload``, flushed to disk: a temporary name
    (``.<name>.<random>.tmp``), created as ``open`` would (0666 less the umask) or with
    ``mode``. Nothing is left behind when it fails."""
    flags = os.O_WRONLY | os.O_CREAT | os.O_EXCL | getattr(os, "O_NOFOLLOW", 0)
    for _ in range(100):
        tmp = directory / f".{name[:200]}.{secrets.token_hex(4)}.tmp"
        try:
            fd = os.open(tmp, flags, 0o666)
        except FileExistsError:
            continue
        break
    else:
        raise FileExistsError(f"no free temporary name for {name} in {directory}")
    try:
        with os.fdopen(fd, "wb") as f:
            if mode is not None and hasattr(os, "fchmod"):
                os.fchmod(f.fileno(), mode)
            f.write(payload)
            f.flush()
            os.fsync(f.fileno())
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        raise
    return tmp


def _keep_backup(target: Path) -> tuple[Path | None, str | None]:
    """Copy ``target`` to ``<target>.bak`` (best effort): ``(backup, None)``, ``(None, None)``
    when there is nothing to keep, ``(None, why)`` when it could not be kept.

    The copy goes to a temporary file renamed over ``.bak``, so whatever is there (a link,
    a read-only file) is replaced itself and nothing is written through it.
    """
    backup = target.with_name(target.name + ".bak")
    try:
        st = os.stat(target)
    except FileNotFoundError:
        return None, None
    except OSError as exc:
        return None, f"the previous calibration could not be kept as {backup} ({_reason(exc)})"
    if not stat.S_ISREG(st.st_mode):
        return None, None  # replacing it fails, and says so
    tmp = None
    try:
        with open(target, "rb") as f:
            payload = f.read()
        tmp = _write_new(backup.parent, backup.name, payload, stat.S_IMODE(st.st_mode))
        with contextlib.suppress(OSError):
            os.utime(tmp, ns=(st.st_atime_ns, st.st_mtime_ns))
        os.replace(tmp, backup)
        tmp = None
        return backup, None
    except OSError as exc:
        why = (
            f"the previous calibration could not be kept as {_name(backup)} ({_reason(exc)}):"
            f" remove or fix {_name(backup)} to have a backup next time"
        )
        log.warning("%s", why)
        return None, why
    finally:
        if tmp is not None:
            with contextlib.suppress(OSError):
                os.unlink(tmp)


def save(calibration: StoredCalibration, path: str | os.PathLike) -> Saved:
    """Write atomically, keeping the previous file as ``<path>.bak`` (best effort).

    CalibrationError, with nothing written, if the calibration has a number that is not
    finite (it names the field) or would not load back, or if the file cannot be written.
    """
    path = Path(path)
    name = _name(path)
    unchanged = "nothing was written and the previous calibration is unchanged"
    data = calibration.to_dict()
    bad = _non_finite(data)
    if bad is not None:
        raise CalibrationError(
            f"cannot save the calibration to {name}: {bad[0]} is not finite ({bad[1]}),"
            f" so {unchanged}: calibrate again"
        )
    try:
        text = json.dumps(data, indent=1, allow_nan=False)
        _parse(json.loads(text))
    except (TypeError, ValueError, _FieldError) as exc:
        problem = f"{exc.name} {exc.problem}" if isinstance(exc, _FieldError) else _reason(exc)
        raise CalibrationError(
            f"cannot save the calibration to {name}: {problem}, so {unchanged}: calibrate again"
        ) from exc
    target = _resolve(path)
    if target.is_symlink():
        raise CalibrationError(
            f"cannot write the calibration to {name}: it is a symbolic link that leads to no"
            f" file (a loop): point it at a file or remove it; {unchanged}"
        )
    try:
        target.parent.mkdir(parents=True, exist_ok=True)
        st = os.stat(target)
    except FileNotFoundError:
        mode = None
    except OSError as exc:
        raise CalibrationError(f"cannot write the calibration to {name}: {_reason(exc)}") from exc
    else:
        mode = stat.S_IMODE(st.st_mode) if stat.S_ISREG(st.st_mode) else None
    tmp = None
    try:
        tmp = _write_new(target.parent, target.name, text.encode("utf-8"), mode)
        backup, backup_error = _keep_backup(target)
        os.replace(tmp, target)
        tmp = None
    except OSError as exc:
        raise CalibrationError(
            f"cannot write the calibration to {name}: {_reason(exc)}; the previous one is"
            " unchanged: check the place is writable and has space, or choose another path"
        ) from exc
    finally:
        if tmp is not None:
            with contextlib.suppress(OSError):
                os.unlink(tmp)
    _fsync_dir(target.parent)
    return Saved(path, target, backup, backup_error)


def _fsync_dir(directory: Path) -> None:
    """Make the rename durable (POSIX); harmless where directories cannot be opened."""
    with contextlib.suppress(OSError):
        fd = os.open(directory, os.O_RDONLY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)


# --------------------------------------------------------------------------- loading


class _FieldError(Exception):
    """A field that is not what it should be (``name`` as in ``samples[2].T_cam_tag``)."""

    def __init__(self, name: str, problem: str) -> None:
        # A key may hold a newline or a control character: show it escaped, on one line.
        name = name if name.isprintable() else repr(name)[1:-1]
        super().__init__(f"{name} {problem}")
        self.name = name
        self.problem = problem


class _MissingFieldError(_FieldError):
    def __init__(self, name: str) -> None:
        super().__init__(name, "is missing")


class _NotJSONError(ValueError):
    """NaN or Infinity in the text: Python's parser takes them, JSON has no such numbers."""


def _refuse_constant(constant: str) -> Any:
    raise _NotJSONError(f"{constant} is not a number JSON allows")


def _show(value: Any) -> str:
    """A short description of a JSON value for a message."""
    if value is None or isinstance(value, bool):
        return json.dumps(value)
    if isinstance(value, int):
        return repr(value) if abs(value) < 10**30 else "a huge integer"
    if isinstance(value, float):
        return repr(value)
    if isinstance(value, str):
        return repr(value if len(value) <= 40 else value[:40] + "...")
    if isinstance(value, list):
        return f"a list of {len(value)}"
    if isinstance(value, dict):
        return "an object"
    return type(value).__name__


def _get(data: dict[str, Any], key: str, name: str) -> Any:
    if key not in data:
        raise _MissingFieldError(name)
    return data[key]


def _object(value: Any, name: str) -> dict[str, Any]:
    if not isinstance(value, dict):
        raise _FieldError(name, f"must be an object, got {_show(value)}")
    return value


def _list(value: Any, name: str, length: int | None = None) -> list[Any]:
    if not isinstance(value, list):
        raise _FieldError(name, f"must be a list, got {_show(value)}")
    if length is not None and len(value) != length:
        raise _FieldError(name, f"must have {length} entries, got {len(value)}")
    return value


def _text(value: Any, name: str, empty: bool = True) -> str:
    if not isinstance(value, str):
        raise _FieldError(name, f"must be a string, got {_show(value)}")
    try:
        value.encode("utf-8")
    except UnicodeEncodeError:
        raise _FieldError(name, "is not valid text (it holds an unpaired surrogate)") from None
    if not empty and not value:
        raise _FieldError(name, "must not be empty")
    return value


def _number(value: Any, name: str, minimum: float | None = None, positive: bool = False) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise _FieldError(name, f"must be a number, got {_show(value)}")
    try:
        x = float(value)
    except OverflowError:
        raise _FieldError(name, "is too large a number") from None
    if not math.isfinite(x):
        raise _FieldError(name, f"must be a finite number, got {x}")
    if positive and x <= 0:
        raise _FieldError(name, f"must be positive, got {x:g}")
    if minimum is not None and x < minimum:
        raise _FieldError(name, f"must be at least {minimum:g}, got {x:g}")
    return x


def _integer(value: Any, name: str, minimum: int = 0) -> int:
    if isinstance(value, bool) or not isinstance(value, int):
        raise _FieldError(name, f"must be an integer, got {_show(value)}")
    if not minimum <= value < 2**63:
        raise _FieldError(name, f"must be an integer from {minimum} up, got {_show(value)}")
    return value


def _numbers(value: Any, name: str, length: int | None = None, minimum=None) -> list[float]:
    items = _list(value, name, length)
    return [_number(v, f"{name}[{i}]", minimum) for i, v in enumerate(items)]


def _integers(value: Any, name: str) -> list[int]:
    return [_integer(v, f"{name}[{i}]") for i, v in enumerate(_list(value, name))]


def _optional(value: Any, read: Callable[[Any], Any]) -> Any:
    return None if value is None else read(value)


def _matrix(value: Any, name: str) -> Array:
    """A rigid 4x4 transform (rotation + translation) from 4 lists of 4 finite numbers."""
    if not isinstance(value, list) or len(value) != 4:
        raise _FieldError(name, f"must be a 4x4 matrix (4 rows of 4 numbers), got {_show(value)}")
    T = np.array([_numbers(row, f"{name}[{i}]", 4) for i, row in enumerate(value)])
    R = T[:3, :3]
    if (
        np.abs(R.T @ R - np.eye(3)).max() > _ORTHONORMAL_TOLERANCE
        or abs(np.linalg.det(R) - 1.0) > _ORTHONORMAL_TOLERANCE
        or np.abs(T[3] - [0, 0, 0, 1]).max() > 0
    ):
        raise _FieldError(name, "is not a rigid transform (rotation + translation)")
    return T


def _tag(value: Any) -> dict[str, Any]:
    tag = _object(value, "tag")
    return {
        "family": _text(_get(tag, "family", "tag.family"), "tag.family", empty=False),
        "id": _integer(_get(tag, "id", "tag.id"), "tag.id"),
        "size": _number(_get(tag, "size", "tag.size"), "tag.size", positive=True),
        "offset_ee_configured": _numbers(
            _get(tag, "offset_ee_configured", "tag.offset_ee_configured"),
            "tag.offset_ee_configured",
            3,
        ),
        "offset_ee_estimated": _numbers(
            _get(tag, "offset_ee_estimated", "tag.offset_ee_estimated"),
            "tag.offset_ee_estimated",
            3,
        ),
        "dropped_samples": _integers(tag.get("dropped_samples", []), "tag.dropped_samples"),
    }


def _intrinsics(value: Any) -> dict[str, Any]:
    name = "camera.intrinsics"
    k = _object(value, name)

    def number(key: str, **limits: Any) -> float:
        return _number(_get(k, key, f"{name}.{key}"), f"{name}.{key}", **limits)

    return {
        "width": _integer(_get(k, "width", f"{name}.width"), f"{name}.width", 1),
        "height": _integer(_get(k, "height", f"{name}.height"), f"{name}.height", 1),
        "fx": number("fx", positive=True),
        "fy": number("fy", positive=True),
        "ppx": number("ppx"),
        "ppy": number("ppy"),
        "model": _text(k.get("model", "none"), f"{name}.model", empty=False),
        "coeffs": _numbers(k.get("coeffs", [0.0] * 5), f"{name}.coeffs", 5),
    }


def _camera(value: Any) -> dict[str, Any]:
    camera = _object(value, "camera")
    return {
        "serial": _optional(camera.get("serial"), lambda v: _text(v, "camera.serial")),
        "intrinsics": _optional(camera.get("intrinsics"), _intrinsics),
    }


def _methods(value: Any) -> dict[str, Any]:
    methods: dict[str, Any] = {}
    for method, entry in _object(value, "methods").items():
        name = f"methods.{_text(method, 'a method name', empty=False)}"
        entry = _object(entry, name)
        if "error" in entry:
            methods[method] = {"error": _text(entry["error"], f"{name}.error")}
            continue
        offsets = entry.get("joint_offsets_rad")
        methods[method] = {
            "T_base_cam": _matrix(
                _get(entry, "T_base_cam", f"{name}.T_base_cam"), f"{name}.T_base_cam"
            ).tolist(),
            "residual_rms_mm": _number(
                _get(entry, "residual_rms_mm", f"{name}.residual_rms_mm"),
                f"{name}.residual_rms_mm",
                0,
            ),
            "offset_ee": _numbers(
                _get(entry, "offset_ee", f"{name}.offset_ee"), f"{name}.offset_ee", 3
            ),
            "dropped_samples": _integers(
                entry.get("dropped_samples", []), f"{name}.dropped_samples"
            ),
            "joint_offsets_rad": None
            if offsets is None
            else _numbers(offsets, f"{name}.joint_offsets_rad", 6),
        }
    return methods


def _errors(value: Any, name: str) -> dict[str, float]:
    errors = _object(value, name)
    return {
        key: _number(_get(errors, key, f"{name}.{key}"), f"{name}.{key}", 0)
        for key in ("translation_error_mm", "rotation_error_deg")
    }


def _truth(value: Any) -> dict[str, Any]:
    truth = _object(value, "truth")
    methods = _object(truth.get("methods", {}), "truth.methods")
    return {
        "T_base_cam": _matrix(
            _get(truth, "T_base_cam", "truth.T_base_cam"), "truth.T_base_cam"
        ).tolist(),
        "tag_offset_ee": _numbers(
            _get(truth, "tag_offset_ee", "truth.tag_offset_ee"), "truth.tag_offset_ee", 3
        ),
        "encoder_bias_deg": _numbers(
            truth.get("encoder_bias_deg", [0.0] * 6), "truth.encoder_bias_deg", 6
        ),
        "methods": {
            _text(k, "a truth.methods name"): _errors(v, f"truth.methods.{k}")
            for k, v in methods.items()
        },
        **_errors(truth, "truth"),
    }


def _sample(value: Any, name: str) -> Sample:
    s = _object(value, name)

    def get(key: str) -> Any:
        return _get(s, key, f"{name}.{key}")

    return Sample(
        phase=_integer(get("phase"), f"{name}.phase"),
        azimuth=_number(get("azimuth"), f"{name}.azimuth"),
        height=_number(get("height"), f"{name}.height"),
        joint_positions=np.array(_numbers(get("joint_positions"), f"{name}.joint_positions", 6)),
        T_base_ee=_matrix(get("T_base_ee"), f"{name}.T_base_ee"),
        T_cam_tag=_matrix(get("T_cam_tag"), f"{name}.T_cam_tag"),
        detections=_integer(get("detections"), f"{name}.detections"),
        frames=_integer(get("frames"), f"{name}.frames", 1),
        spread_m=_number(get("spread_m"), f"{name}.spread_m", 0),
        decision_margin=_number(get("decision_margin"), f"{name}.decision_margin"),
    )


def _parse(data: dict[str, Any]) -> dict[str, Any]:
    """The fields of :class:`StoredCalibration` from a file's JSON object (schema and
    version already checked); _FieldError naming the first field that is not as it should be."""
    samples = tuple(
        _sample(s, f"samples[{i}]") for i, s in enumerate(_list(data.get("samples", []), "samples"))
    )
    residuals = tuple(_numbers(_get(data, "residuals_mm", "residuals_mm"), "residuals_mm", None, 0))
    if samples and len(residuals) != len(samples):
        raise _FieldError("residuals_mm", f"has {len(residuals)} values for {len(samples)} samples")
    return {
        "T_base_cam": _matrix(_get(data, "T_base_cam", "T_base_cam"), "T_base_cam"),
        "method": _text(_get(data, "method", "method"), "method", empty=False),
        "created": _text(data.get("created", ""), "created"),
        "source": _text(data.get("source", ""), "source"),
        "residual_rms_mm": _number(
            _get(data, "residual_rms_mm", "residual_rms_mm"), "residual_rms_mm", 0
        ),
        "residual_max_mm": _number(
            _get(data, "residual_max_mm", "residual_max_mm"), "residual_max_mm", 0
        ),
        "residuals_mm": residuals,
        "tag": _tag(_get(data, "tag", "tag")),
        "camera": _camera(_get(data, "camera", "camera")),
        "joint_offsets": _optional(
            data.get("joint_offsets_rad"),
            lambda v: tuple(_numbers(v, "joint_offsets_rad", 6)),
        ),
        "samples": samples,
        "methods": _methods(data.get("methods", {})),
        "truth": _optional(data.get("truth"), _truth),
    }


def _read_raw(path: Path, name: str, redo: str) -> bytes:
    """The bytes of the calibration file at ``path`` (a regular file of at most
    :data:`_MAX_BYTES`); CalibrationError if it is missing, not a file, too big or unreadable."""
    try:
        st = os.stat(path)
    except FileNotFoundError:
        raise CalibrationError(f"no calibration at {name}: {redo}") from None
    except (OSError, ValueError) as exc:
        raise CalibrationError(
            f"cannot read the calibration {name} ({_reason(exc)}): check the path and its"
            f" permissions, or {redo}"
        ) from None
    where = f"calibration file {name}"
    if not stat.S_ISREG(st.st_mode):
        raise CalibrationError(
            f"{where} is not a regular file: point calibration.file at the file"
            f" `armvision calibrate` wrote, or {redo}"
        )
    if st.st_size > _MAX_BYTES:
        raise CalibrationError(
            f"{where} has {st.st_size} bytes, far more than a calibration: point"
            f" calibration.file at the file `armvision calibrate` wrote, or {redo}"
        )
    try:
        with open(path, "rb") as f:
            return f.read(_MAX_BYTES)
    except OSError as exc:
        raise CalibrationError(
            f"cannot read the calibration {name} ({_reason(exc)}): check its permissions, or {redo}"
        ) from None


def _decode(raw: bytes, path: Path, where: str, restore: str, redo: str) -> Any:
    """The JSON value of a calibration file's bytes; CalibrationError if they are no UTF-8
    JSON (pointing at the backup, named in ``restore``, when there is one)."""
    damaged = f"it is damaged: {restore}or {redo}"
    try:
        text = raw.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        raise CalibrationError(f"{where} is not UTF-8 text (byte {exc.start}): {damaged}") from None
    try:
        return json.loads(text, parse_constant=_refuse_constant)
    except RecursionError:
        raise CalibrationError(
            f"{where} is nested too deeply to be a calibration: {damaged}"
        ) from None
    except json.JSONDecodeError as exc:
        hint = f"; the previous calibration is in {_name(backup_path(path))}" if restore else ""
        raise CalibrationError(
            f"{where} is not valid JSON (line {exc.lineno}: {exc.msg}): it is damaged{hint},"
            f" or {redo}"
        ) from None
    except ValueError as exc:
        reason = _reason(exc) if isinstance(exc, _NotJSONError) else _reason(exc).split(":")[0]
        raise CalibrationError(f"{where} is not valid JSON ({reason}): {damaged}") from None


def _check_header(data: Any, where: str, restore: str, redo: str) -> dict[str, Any]:
    """``data`` if it is an armvision calibration of a version this armvision reads;
    CalibrationError if not."""
    damaged = f"it is damaged: {restore}or {redo}"
    if not isinstance(data, dict) or data.get("schema") != SCHEMA:
        raise CalibrationError(
            f'{where} is not an armvision calibration (no "schema": "{SCHEMA}"): point'
            f" calibration.file at the file `armvision calibrate` wrote, or {redo}"
        )
    version = data.get("version")
    if isinstance(version, bool) or not isinstance(version, int) or version < 1:
        raise CalibrationError(
            f'{where}: "version" must be a positive integer, got {_show(version)}: {damaged}'
        )
    if version > VERSION:
        raise CalibrationError(
            f"{where} has version {_show(version)}, newer than this armvision reads"
            f" ({VERSION}): upgrade armvision, or {redo}"
        )
    return data


def load(path: str | os.PathLike) -> StoredCalibration:
    """Read and validate a calibration file; a one-line CalibrationError naming the file and
    saying what to do on any problem."""
    path = Path(path)
    name = _name(path)
    redo = "run `armvision calibrate` to make a new one"
    raw = _read_raw(path, name, redo)
    where = f"calibration file {name}"
    restore = ""
    with contextlib.suppress(OSError, ValueError):
        if backup_path(path).is_file():
            restore = f"restore the previous calibration from {_name(backup_path(path))}, "
    data = _check_header(_decode(raw, path, where, restore, redo), where, restore, redo)
    try:
        fields = _parse(data)
    except _MissingFieldError as exc:
        raise CalibrationError(
            f"{where} lacks the field {exc.name!r}: add it, {restore}or {redo}"
        ) from None
    except _FieldError as exc:
        raise CalibrationError(
            f"{where}: {exc.name} {exc.problem}: correct it, {restore}or {redo}"
        ) from None
    return StoredCalibration(**fields, path=path)
