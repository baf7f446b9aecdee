"""ViSP's real eye-to-hand set (Franka Panda + RealSense): every solver against ViSP's answer.

ViSP names a pose ``aMb`` (the pose of frame b in frame a, so armvision's ``T_a_b``) and saves
it as a ``vpPoseVector`` ``aPb`` = [tx, ty, tz, tux, tuy, tuz]: metres, and the theta-u
rotation vector (axis times angle, radians) -- what ``cv2.Rodrigues`` takes. In the set:
``franka_pose_rPe_N.yaml`` is ``rMe``, the end effector in the robot base (armvision's
``T_base_ee``); the published ``rMc`` is ``T_base_cam`` and ``eMo`` the tag ("object") in the
end effector. ViSP's AprilTag frame is armvision's (the AprilTag library's: z into the tag)
turned half a turn about x (z out of the tag, towards the camera), so
``T_ee_tag = eMo @ Rx(pi)``; the tag's centre, all that the point solvers use, is the same in
both.

The tag on the Franka is not armvision's gripper mount, so every solver is given the
published tag centre (``eMo``'s translation) as its tag-offset prior: ``svd`` and
``robust_svd`` keep it fixed, ``joint`` estimates the offset starting from it (and once more
from zero, to show it needs no prior), the OpenCV solvers estimate their own.
``joint_kinematic`` needs ViperX-300s joint readings, which a Franka set has not.
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any
from xml.etree import ElementTree

import cv2
import numpy as np
from numpy.typing import ArrayLike, NDArray

from armvision.calibration.procedure import pose_errors
from armvision.calibration.solve import METHODS, Fit, solve
from armvision.camera.frames import Intrinsics
from armvision.config import Config
from armvision.errors import ArmvisionError, CalibrationError
from armvision.geometry import make_T
from armvision.perception.tags import TagDetector

Array = NDArray[np.float64]

SUBDIR = "visp_franka_handeye/eye-to-hand"
TAG_ID = 10
TAG_SIZE_M = 0.048
#: ViSP's published answer (tutorial-calibration-extrinsic-eye-to-hand.dox, calibrated
#: intrinsics): rMc and eMo as 4x4 matrices.
PUBLISHED_rMc = make_T(
    [
        [-0.0161049, -0.139226, -0.99013],
        [0.999844, -0.00939845, -0.0149414],
        [-0.00722546, -0.990216, 0.139356],
    ],
    [0.954036, -0.0512357, 0.47622],
)
PUBLISHED_eMo = make_T(
    [
        [0.00622146, 0.0219727, 0.999739],
        [0.999978, 0.00193654, -0.00626551],
        [-0.0020737, 0.999757, -0.0219602],
    ],
    [0.0220351, -0.0051383, -0.0556314],
)
#: ViSP's tag frame in armvision's: half a turn about x.
R_VISP_TAG = np.diag([1.0, -1.0, -1.0])


def pose_vector_to_T(vector: ArrayLike) -> Array:
    """``T_a_b`` of a ViSP ``aPb`` pose vector [tx, ty, tz, tux, tuy, tuz] (m, theta-u rad)."""
    v = np.asarray(vector, dtype=float).reshape(-1)
    if v.shape != (6,) or not np.all(np.isfinite(v)):
        raise ArmvisionError(f"a ViSP pose vector has 6 finite numbers, got {v.tolist()}")
    return make_T(cv2.Rodrigues(v[3:].reshape(3, 1))[0], v[:3])


def visp_tag_to_armvision(T_x_visptag: ArrayLike) -> Array:
    """A pose of ViSP's AprilTag frame as a pose of armvision's (z into the tag)."""
    T = np.array(T_x_visptag, dtype=float)
    T[:3, :3] = T[:3, :3] @ R_VISP_TAG
    return T


def read_pose_vector(path: Path) -> Array:
    """The 4x4 pose in a ViSP ``vpPoseVector::saveYAML`` file (rows: 6, cols: 1, data: ...)."""
    text = path.read_text()
    values = re.findall(r"\[\s*([-+0-9.eE]+)\s*\]", text.partition("data:")[2])
    if len(values) != 6:
        raise ArmvisionError(f"{path}: expected 6 pose values under 'data:', found {len(values)}")
    return pose_vector_to_T([float(v) for v in values])


def read_visp_camera(path: Path) -> Intrinsics:
    """Intrinsics from a ViSP camera XML (``perspectiveProjWithDistortion``; kud must be 0)."""
    root = ElementTree.parse(path).getroot()
    camera = root.find("camera")
    model = None if camera is None else camera.find("model")
    if camera is None or model is None:
        raise ArmvisionError(f"{path}: no <camera><model> in the ViSP camera file")

    def number(node: ElementTree.Element, tag: str) -> float:
        text = node.findtext(tag)
        if text is None:
            raise ArmvisionError(f"{path}: <{tag}> missing")
        return float(text)

    if abs(number(model, "kud")) > 1e-12:
        raise ArmvisionError(f"{path}: radial distortion (kud) is not modelled here")
    return Intrinsics(
        width=int(number(camera, "image_width")),
        height=int(number(camera, "image_height")),
        fx=number(model, "px"),
        fy=number(model, "py"),
        ppx=number(model, "u0"),
        ppy=number(model, "v0"),
    )


def load_samples(folder: Path) -> tuple[Array, Array, list[int]]:
    """(T_base_ee, T_cam_tag, image numbers) for every image in which the tag was found."""
    intrinsics = read_visp_camera(folder / "franka_camera.xml")
    detector = TagDetector(ids=[TAG_ID], tag_size=TAG_SIZE_M, refine_with_depth=False)
    T_be, T_ct, used = [], [], []
    numbers = sorted(
        int(m.group(1))
        for p in folder.glob("franka_image-*.png")
        if (m := re.fullmatch(r"franka_image-(\d+)\.png", p.name))
    )
    for n in numbers:
        image = cv2.imread(str(folder / f"franka_image-{n}.png"), cv2.IMREAD_GRAYSCALE)
        if image is None:
            continue
        found = detector.detect_image(image, intrinsics)
        if len(found) != 1:
            continue
        T_be.append(read_pose_vector(folder / f"franka_pose_rPe_{n}.yaml"))
        T_ct.append(found[0].T_cam_tag)
        used.append(n)
    return np.array(T_be), np.array(T_ct), used


_PRIORS = {
    "svd": "published, fixed",
    "robust_svd": "published, fixed",
    "joint": "estimated from published",
    "joint_kinematic": "n/a",
}


def _row(name: str, prior: str, fit: Fit | str) -> dict[str, Any]:
    if isinstance(fit, str):
        return {"method": name, "prior": prior, "error": fit}
    errors = pose_errors(fit.T_base_cam, PUBLISHED_rMc)
    return {
        "method": name,
        "prior": prior,
        "camera_error_mm": errors["translation_error_mm"],
        "camera_error_deg": errors["rotation_error_deg"],
        "residual_rms_mm": 1000 * fit.rms_m,
        "residual_mean_mm": 1000 * float(np.mean(fit.residuals[fit.used])),
        "used": int(fit.used.sum()),
        "tag_offset_mm": np.round(1000 * fit.offset_ee, 1).tolist(),
        "camera_position_m": np.round(fit.T_base_cam[:3, 3], 4).tolist(),
    }


def evaluate_visp(root: Path, config: Config) -> dict[str, Any]:
    """Detect the tag in every image, run every solver, compare with ViSP's ``rMc``."""
    folder = root / SUBDIR
    if not folder.is_dir():
        raise FileNotFoundError(f"no {SUBDIR}/ in {root}")
    T_be, T_ct, used = load_samples(folder)
    if len(used) < 3:
        raise ArmvisionError(f"the tag was found in only {len(used)} images")
    cal = config.calibration
    prior = PUBLISHED_eMo[:3, 3]
    rows = []
    for name in METHODS:
        try:
            fit: Fit | str = solve(
                T_be, T_ct, name, prior, cal.outlier_mm / 1000, min(cal.min_samples, len(used))
            )
        except CalibrationError as exc:
            fit = str(exc)
        label = _PRIORS.get(name, "estimated")
        rows.append(_row(name, label, fit))
    zero = solve(T_be, T_ct, "joint", np.zeros(3), cal.outlier_mm / 1000, 3)
    rows.append(_row("joint", "estimated from zero", zero))
    good = [r for r in rows if "camera_error_mm" in r]
    best = min(good, key=lambda r: r["camera_error_mm"])
    return {
        "images": len(used),
        "tag_found_in": used,
        "tag_offset_prior_mm": np.round(1000 * prior, 1).tolist(),
        "tag_offset_handling": (
            "svd/robust_svd: published eMo centre, fixed; joint: estimated from the published"
            " centre and from zero; OpenCV solvers: estimated; joint_kinematic: needs ViperX"
            " joint readings"
        ),
        "intrinsics": "franka_camera.xml (factory, no distortion; ViSP used calibrated ones)",
        "methods": rows,
        "summary": {
            "images_with_tag": f"{len(used)}/8",
            "best_method": best["method"],
            "best_camera_error_mm": round(best["camera_error_mm"], 2),
            "best_camera_error_deg": round(best["camera_error_deg"], 2),
            "methods_within_10mm_2deg": sum(
                r["camera_error_mm"] <= 10 and r["camera_error_deg"] <= 2 for r in good
            ),
            "methods_run": len(good),
            "published_residual": "2.35 mm / 0.51 deg (ViSP's mean)",
            "max_camera_error_mm": round(max(r["camera_error_mm"] for r in good), 1),
        },
    }
