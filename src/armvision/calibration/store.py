"""The calibration file: versioned JSON, written so that a good calibration is never lost.

Saving writes the new file next to the old one under a temporary name, flushes it to disk, keeps
the current calibration as ``<name>.bak`` and then renames the new file into place, so at
every moment the path holds a complete calibration: an interrupted save (a crash, Ctrl-C, a
full disk) leaves the previous one, and a failed calibration never reaches :func:`save`.

Loading checks everything before anything uses it: that the file is JSON, that it is ours
(``"schema": "armvision.calibration"``), a version we read, and a proper rigid transform; any
problem is a :class:`CalibrationError` that names the file and says what to do.
"""

from __future__ import annotations

import contextlib
import datetime as _dt
import json
import math
import os
import shutil
import tempfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from armvision.calibration.sampling import Sample
from armvision.errors import CalibrationError

Array = NDArray[np.float64]

SCHEMA = "armvision.calibration"
VERSION = 1
#: How far from a rotation the stored R may be (rounding in the JSON is ~1e-16).
_ORTHONORMAL_TOLERANCE = 1e-6


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
    ``methods`` every method's transform and residual (or its failure); ``truth`` the
    simulator's camera pose and the errors, when there is one.
    """
    fit = result.fit
    intrinsics = None if result.intrinsics is None else result.intrinsics.to_dict()
    methods: dict[str, Any] = {}
    for name, other in result.fits.items():
        if isinstance(other, str):
            methods[name] = {"error": other}
        else:
            methods[name] = {
                "T_base_cam": other.T_base_cam.tolist(),
                "residual_rms_mm": 1000 * other.rms_m,
                "offset_ee": other.offset_ee.tolist(),
                "dropped_samples": other.dropped,
                "joint_offsets_rad": None
                if other.joint_offsets is None
                else other.joint_offsets.tolist(),
            }
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
        truth=result.truth,
    )


def backup_path(path: str | os.PathLike) -> Path:
    """Where :func:`save` keeps the calibration it replaces."""
    path = Path(path)
    return path.with_name(path.name + ".bak")


def save(calibration: StoredCalibration, path: str | os.PathLike) -> Path:
    """Write atomically, keeping the previous file as ``<path>.bak``; returns the path."""
    path = Path(path)
    text = json.dumps(calibration.to_dict(), indent=1, allow_nan=False)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    except OSError as exc:
        raise CalibrationError(f"cannot write the calibration to {path}: {exc}") from exc
    try:
        with os.fdopen(fd, "w", encoding="utf-8") as f:
            f.write(text)
            f.flush()
            os.fsync(f.fileno())
        if path.exists():
            # A copy, not a rename, so ``path`` holds a complete calibration throughout.
            shutil.copy2(path, backup_path(path))
        os.replace(tmp, path)
    except BaseException as exc:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        if isinstance(exc, OSError):
            raise CalibrationError(
                f"cannot write the calibration to {path}: {exc}; the previous one is unchanged"
            ) from exc
        raise
    _fsync_dir(path.parent)
    return path


def _fsync_dir(directory: Path) -> None:
    """Make the rename durable (POSIX); harmless where directories cannot be opened."""
    with contextlib.suppress(OSError):
        fd = os.open(directory, os.O_RDONLY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)


def _matrix(value: Any, what: str, where: str) -> Array:
    try:
        T = np.asarray(value, dtype=float)
    except (TypeError, ValueError) as exc:
        raise CalibrationError(f"{where}: {what} is not a 4x4 matrix of numbers") from exc
    if T.shape != (4, 4) or not np.all(np.isfinite(T)):
        raise CalibrationError(f"{where}: {what} must be a finite 4x4 matrix, got shape {T.shape}")
    R = T[:3, :3]
    if (
        np.abs(R.T @ R - np.eye(3)).max() > _ORTHONORMAL_TOLERANCE
        or abs(np.linalg.det(R) - 1.0) > _ORTHONORMAL_TOLERANCE
        or np.abs(T[3] - [0, 0, 0, 1]).max() > 0
    ):
        raise CalibrationError(f"{where}: {what} is not a rigid transform (rotation + translation)")
    return T


def load(path: str | os.PathLike) -> StoredCalibration:
    """Read and validate a calibration file; CalibrationError naming the file on any problem."""
    path = Path(path)
    redo = "run `armvision calibrate` to make a new one"
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise CalibrationError(f"no calibration at {path}: {redo}") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise CalibrationError(f"cannot read the calibration {path}: {exc}") from exc
    where = f"calibration file {path}"
    try:
        data = json.loads(text)
    except json.JSONDecodeError as exc:
        backup = backup_path(path)
        hint = f"; the previous calibration is in {backup}" if backup.exists() else ""
        raise CalibrationError(
            f"{where} is not valid JSON (line {exc.lineno}: {exc.msg}): it is damaged{hint},"
            f" or {redo}"
        ) from exc
    if not isinstance(data, dict) or data.get("schema") != SCHEMA:
        raise CalibrationError(
            f'{where} is not an armvision calibration (no "schema": "{SCHEMA}"): point'
            f" calibration.file at the file `armvision calibrate` wrote, or {redo}"
        )
    version = data.get("version")
    if not isinstance(version, int) or version < 1:
        raise CalibrationError(f'{where}: "version" must be a positive integer, got {version!r}')
    if version > VERSION:
        raise CalibrationError(
            f"{where} has version {version}, newer than this armvision reads ({VERSION}):"
            f" upgrade armvision, or {redo}"
        )
    try:
        T = _matrix(data["T_base_cam"], "T_base_cam", where)
        tag = data["tag"]
        camera = data["camera"]
        method = str(data["method"])
        rms = float(data["residual_rms_mm"])
        worst = float(data["residual_max_mm"])
        residuals = tuple(float(r) for r in data["residuals_mm"])
        samples = tuple(Sample.from_dict(s) for s in data.get("samples", []))
        offsets = data.get("joint_offsets_rad")
        joint_offsets = None if offsets is None else tuple(float(v) for v in offsets)
        if joint_offsets is not None and (
            len(joint_offsets) != 6 or not all(map(math.isfinite, joint_offsets))
        ):
            raise ValueError("joint_offsets_rad must be 6 finite angles")
        if not isinstance(tag, dict) or not isinstance(camera, dict):
            raise TypeError("tag and camera must be objects")
        for s in samples:
            _matrix(s.T_base_ee, "a sample's T_base_ee", where)
            _matrix(s.T_cam_tag, "a sample's T_cam_tag", where)
    except KeyError as exc:
        raise CalibrationError(f"{where} lacks the field {exc.args[0]!r}: {redo}") from exc
    except (TypeError, ValueError) as exc:
        raise CalibrationError(f"{where} has a malformed field ({exc}): {redo}") from exc
    if not (math.isfinite(rms) and math.isfinite(worst)):
        raise CalibrationError(f"{where}: the residuals are not finite numbers: {redo}")
    return StoredCalibration(
        T_base_cam=T,
        method=method,
        created=str(data.get("created", "")),
        residual_rms_mm=rms,
        residual_max_mm=worst,
        residuals_mm=residuals,
        tag=tag,
        camera=camera,
        source=str(data.get("source", "")),
        joint_offsets=joint_offsets,
        samples=samples,
        methods=dict(data.get("methods", {})),
        truth=data.get("truth"),
        path=path,
    )
