"""Is a calibration plausible enough to adopt? One check for ``armvision calibrate`` and the
UI's Calibrate.

A solve always returns a transform; these say whether the samples behind it support it:

* the RMS residual over the samples used (``calibration.max_residual_rms_mm``): the tag seen
  where the kinematics put it to within millimetres, or something moved or is mis-measured
  (a loose tag, a wrong ``tag.size`` scales every detected distance);
* the spread of the tag positions, the RMS distance of the used samples' tags from their
  centroid (``calibration.min_sample_spread_m``): samples bunched in one place fix the
  rotation poorly whatever their residual;
* how far the tag mount the method estimated lies from ``tag.offset_ee``
  (``calibration.max_tag_offset_error_mm``): a mount centimetres away means the tag is not
  where the configuration says, or the fit absorbed an error elsewhere.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from armvision.config import CalibrationConfig
from armvision.errors import CalibrationError


@dataclass(frozen=True)
class Quality:
    """The three measures and, one sentence each, what is wrong (empty when plausible)."""

    residual_rms_mm: float
    sample_spread_m: float
    tag_offset_error_mm: float
    problems: tuple[str, ...]

    @property
    def ok(self) -> bool:
        return not self.problems

    def refusal(self, remedy: str) -> str:
        """The one-line message refusing the calibration, ending with ``remedy``."""
        return f"calibration refused: {'; '.join(self.problems)}; {remedy}"


def assess(result, cfg: CalibrationConfig) -> Quality:
    """Measure a :class:`~armvision.calibration.procedure.CalibrationResult` against the
    limits in ``cfg`` (see the module doc)."""
    fit = result.fit
    used = np.asarray(fit.used, dtype=bool)
    rms_mm = 1000.0 * float(fit.rms_m)
    tags = np.array([s.T_cam_tag[:3, 3] for s, u in zip(result.samples, used) if u])
    if len(tags):
        spread = float(np.sqrt(np.mean(np.sum((tags - tags.mean(axis=0)) ** 2, axis=1))))
    else:
        spread = 0.0
    configured = np.asarray(result.tag.offset_ee, dtype=float)
    offset_mm = 1000.0 * float(np.linalg.norm(np.asarray(fit.offset_ee) - configured))
    problems = []
    if not math.isfinite(rms_mm) or rms_mm > cfg.max_residual_rms_mm:
        problems.append(
            f"residual {rms_mm:.1f} mm RMS exceeds calibration.max_residual_rms_mm ="
            f" {cfg.max_residual_rms_mm:g} (is the tag loose, or tag.size wrong?)"
        )
    if not math.isfinite(spread) or spread < cfg.min_sample_spread_m:
        problems.append(
            f"the tag positions spread only {spread:.3f} m RMS about their centre, under"
            f" calibration.min_sample_spread_m = {cfg.min_sample_spread_m:g} (did the arm"
            " reach its poses, and does the camera see the whole workspace?)"
        )
    if not math.isfinite(offset_mm) or offset_mm > cfg.max_tag_offset_error_mm:
        problems.append(
            f"the tag mount came out {offset_mm:.1f} mm from tag.offset_ee, more than"
            f" calibration.max_tag_offset_error_mm = {cfg.max_tag_offset_error_mm:g}"
            " (is tag.offset_ee measured right, or has the tag moved?)"
        )
    return Quality(rms_mm, spread, offset_mm, tuple(problems))


def check_quality(result, cfg: CalibrationConfig, remedy: str, force: bool = False) -> Quality:
    """:func:`assess`, and a CalibrationError saying why (then ``remedy``) if the result is
    implausible, unless ``force`` (then the caller warns with ``quality.problems``)."""
    quality = assess(result, cfg)
    if quality.problems and not force:
        raise CalibrationError(quality.refusal(remedy))
    return quality
