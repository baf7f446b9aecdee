"""ROS 2 messages of a recording: topics, frame names, and pure converters to and from them.

The messages are the standard ROS 2 humble definitions (rosbags' type store, which also
encodes them as CDR and writes their definitions into the file's schemas), with the names the
ROS drivers of the same hardware use, so a recording plays into ROS 2 (``ros2 bag play``) and
opens in Foxglove as if the drivers had been running:

- frames: the arm's ``vx300s/base_link`` and ``vx300s/ee_gripper_link`` (interbotix_xsarm
  with ``robot_name:=vx300s``), the colour camera's ``camera_color_optical_frame``
  (realsense2_camera with ``camera_name:=camera``), and ``armvision/track_<id>`` per track;
- topics: :data:`TOPICS`.

Times are ``builtin_interfaces/Time`` on the system's clock (simulation seconds for a
simulation, seconds since the epoch on the real bench), and the same nanoseconds are each
message's MCAP log time.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Sequence
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from armvision.camera.frames import Intrinsics
from armvision.errors import ArmvisionError

BASE_FRAME = "vx300s/base_link"
EE_FRAME = "vx300s/ee_gripper_link"
CAMERA_FRAME = "camera_color_optical_frame"
TRACK_FRAME = "armvision/track_{id}"

#: topic -> message type (ROS 2 ``pkg/msg/Name``, or ``json`` for armvision's own channels).
TOPICS: dict[str, str] = {
    "/camera/color/image_raw/compressed": "sensor_msgs/msg/CompressedImage",
    "/camera/aligned_depth_to_color/image_raw": "sensor_msgs/msg/Image",
    "/camera/color/camera_info": "sensor_msgs/msg/CameraInfo",
    "/vx300s/joint_states": "sensor_msgs/msg/JointState",
    "/armvision/frame_joint_states": "sensor_msgs/msg/JointState",
    "/armvision/joint_commands": "sensor_msgs/msg/JointState",
    "/tf_static": "tf2_msgs/msg/TFMessage",
    "/tf": "tf2_msgs/msg/TFMessage",
    "/armvision/markers": "visualization_msgs/msg/MarkerArray",
    "/armvision/planning_scene": "visualization_msgs/msg/MarkerArray",
    "/armvision/config": "json",
    "/armvision/camera": "json",
    "/armvision/calibration": "json",
    "/armvision/detectors": "json",
    "/armvision/task": "json",
    "/armvision/health": "json",
    "/armvision/liquid": "json",
    "/armvision/tracks": "json",
    "/armvision/detections": "json",
    "/armvision/tags": "json",
    "/armvision/clock": "json",
    "/armvision/frame_clock": "json",
}
COLOR_TOPIC = "/camera/color/image_raw/compressed"
DEPTH_TOPIC = "/camera/aligned_depth_to_color/image_raw"
INFO_TOPIC = "/camera/color/camera_info"
JOINTS_TOPIC = "/vx300s/joint_states"
FRAME_JOINTS_TOPIC = "/armvision/frame_joint_states"
COMMANDS_TOPIC = "/armvision/joint_commands"
#: The clock's exact seconds (a float) of each fusion cycle and of each frame, written just
#: before it: stamps and log times are whole nanoseconds, and a replay must see the very same
#: times (a track dropped after exactly ``drop_after_s`` would otherwise be kept one frame
#: longer). Two topics: each has one producer, so each one's times only go forward.
CLOCK_TOPIC = "/armvision/clock"
FRAME_CLOCK_TOPIC = "/armvision/frame_clock"

#: Marker colours (RGBA 0..1) of the track cylinders by label; liquid has its own colour.
LABEL_COLOURS = {
    "bottle": (0.2, 0.6, 1.0, 0.35),
    "cup": (1.0, 0.7, 0.2, 0.35),
    "other": (0.6, 0.6, 0.6, 0.35),
}


@functools.cache
def typestore() -> Any:
    """rosbags' store of the ROS 2 humble message types (built once)."""
    from rosbags.typesys import Stores, get_typestore

    return get_typestore(Stores.ROS2_HUMBLE)


def msgdef(msgtype: str) -> str:
    """The ``ros2msg`` schema text of ``msgtype`` with its dependencies (as rosbag2 writes)."""
    text, _ = typestore().generate_msgdef(msgtype, ros_version=2)
    return str(text)


def serialize(message: Any, msgtype: str) -> bytes:
    return bytes(typestore().serialize_cdr(message, msgtype))


def deserialize(data: bytes | memoryview, msgtype: str) -> Any:
    return typestore().deserialize_cdr(bytes(data), msgtype)


# ---------------------------------------------------------------------------- time


def to_ns(t: float) -> int:
    """Clock seconds as integer nanoseconds (a recording's log times)."""
    return round(t * 1e9)


def stamp(t: float) -> Any:
    """``builtin_interfaces/Time`` of clock seconds ``t`` (nanoseconds rounded)."""
    ns = to_ns(t)
    sec, nanosec = divmod(ns, 1_000_000_000)
    return typestore().types["builtin_interfaces/msg/Time"](sec=int(sec), nanosec=int(nanosec))


def seconds(time_msg: Any) -> float:
    """Clock seconds of a ``builtin_interfaces/Time``."""
    return (int(time_msg.sec) * 1_000_000_000 + int(time_msg.nanosec)) / 1e9


def header(t: float, frame_id: str) -> Any:
    return typestore().types["std_msgs/msg/Header"](stamp=stamp(t), frame_id=frame_id)


# ---------------------------------------------------------------------------- images


def compressed_color(
    rgb: NDArray[np.uint8], t: float, quality: int = 90, image_format: str = "jpeg"
) -> Any:
    """``sensor_msgs/CompressedImage`` of an RGB image: JPEG (``quality``) or lossless PNG.

    ``format`` is image_transport's ``"rgb8; jpeg compressed bgr8"`` (what its compressed
    plugin writes, and what Foxglove and ``ros2 bag play`` consumers read).
    """
    bgr = cv2.cvtColor(np.ascontiguousarray(rgb), cv2.COLOR_RGB2BGR)
    if image_format == "png":
        ok, buf = cv2.imencode(".png", bgr, [cv2.IMWRITE_PNG_COMPRESSION, 1])
    else:
        ok, buf = cv2.imencode(".jpg", bgr, [cv2.IMWRITE_JPEG_QUALITY, int(quality)])
    if not ok:
        raise ArmvisionError(f"{image_format} encoding of a colour frame failed")
    fmt = f"rgb8; {image_format} compressed bgr8"
    msg_type = typestore().types["sensor_msgs/msg/CompressedImage"]
    return msg_type(header=header(t, CAMERA_FRAME), format=fmt, data=buf.reshape(-1))


def decode_color(message: Any) -> NDArray[np.uint8]:
    """The RGB image (H, W, 3) of a ``CompressedImage`` (JPEG or PNG)."""
    data = np.asarray(message.data, dtype=np.uint8)
    bgr = cv2.imdecode(data, cv2.IMREAD_COLOR)
    if bgr is None:
        raise ArmvisionError(f"a recorded colour frame ({message.format!r}) does not decode")
    return np.ascontiguousarray(cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB))


def depth_image(depth_m: NDArray[np.floating], t: float) -> Any:
    """``sensor_msgs/Image`` 16UC1 of a depth image in metres: millimetres, rounded, as the
    RealSense driver publishes (0 = no depth; beyond 65.535 m is no depth too)."""
    d = np.asarray(depth_m, dtype=np.float64)
    mm = np.rint(np.where(np.isfinite(d), d, 0.0) * 1000.0)
    mm[(mm < 0) | (mm > 65535)] = 0
    data = mm.astype("<u2")
    h, w = data.shape
    msg_type = typestore().types["sensor_msgs/msg/Image"]
    return msg_type(
        header=header(t, CAMERA_FRAME),
        height=h,
        width=w,
        encoding="16UC1",
        is_bigendian=0,
        step=2 * w,
        data=data.view(np.uint8).reshape(-1),
    )


def decode_depth(message: Any) -> NDArray[np.float32]:
    """Depth in metres (float32, 0 = none) of a 16UC1 (mm) or 32FC1 (m) ``Image``."""
    h, w = int(message.height), int(message.width)
    raw = np.asarray(message.data, dtype=np.uint8)
    big = bool(message.is_bigendian)
    if message.encoding in ("16UC1", "mono16"):
        mm = raw.view(">u2" if big else "<u2").reshape(h, int(message.step) // 2)[:, :w]
        # In float64, then float32: what a camera that rounds to 1 mm units gives.
        return (mm.astype(np.float64) * 0.001).astype(np.float32)
    if message.encoding == "32FC1":
        m = raw.view(">f4" if big else "<f4").reshape(h, int(message.step) // 4)[:, :w]
        return np.nan_to_num(m.astype(np.float32), nan=0.0, posinf=0.0, neginf=0.0)
    raise ArmvisionError(f"a recorded depth image is {message.encoding!r}; expected 16UC1")


def camera_info(intr: Intrinsics, t: float) -> Any:
    """``sensor_msgs/CameraInfo`` of librealsense intrinsics, as realsense2_camera fills it:
    ``plumb_bob`` with the five coefficients (``equidistant`` for Kannala-Brandt), K, an
    identity R and P = [K | 0]."""
    K = [intr.fx, 0.0, intr.ppx, 0.0, intr.fy, intr.ppy, 0.0, 0.0, 1.0]
    P = [intr.fx, 0.0, intr.ppx, 0.0, 0.0, intr.fy, intr.ppy, 0.0, 0.0, 0.0, 1.0, 0.0]
    model = "equidistant" if intr.model == "kannala_brandt4" else "plumb_bob"
    msg_type = typestore().types["sensor_msgs/msg/CameraInfo"]
    roi = typestore().types["sensor_msgs/msg/RegionOfInterest"](
        x_offset=0, y_offset=0, height=0, width=0, do_rectify=False
    )
    return msg_type(
        header=header(t, CAMERA_FRAME),
        height=intr.height,
        width=intr.width,
        distortion_model=model,
        d=np.array(intr.coeffs, dtype=np.float64),
        k=np.array(K, dtype=np.float64),
        r=np.eye(3).reshape(-1),
        p=np.array(P, dtype=np.float64),
        binning_x=0,
        binning_y=0,
        roi=roi,
    )


def intrinsics_of(message: Any) -> Intrinsics:
    """Intrinsics of a ``CameraInfo`` (``plumb_bob`` read as librealsense's
    ``inverse_brown_conrady`` when it has coefficients, the D400 colour model)."""
    k = np.asarray(message.k, dtype=float)
    d = [float(v) for v in np.asarray(message.d, dtype=float)[:5]] + [0.0] * 5
    if message.distortion_model == "equidistant":
        model = "kannala_brandt4"
    else:
        model = "inverse_brown_conrady" if any(d[:5]) else "none"
    return Intrinsics(
        int(message.width), int(message.height), float(k[0]), float(k[4]), float(k[2]),
        float(k[5]), model, (d[0], d[1], d[2], d[3], d[4]),
    )  # fmt: skip


# ---------------------------------------------------------------------------- the arm


def joint_state(
    t: float,
    names: tuple[str, ...],
    positions: NDArray[np.float64],
    velocities: NDArray[np.float64] | None = None,
    efforts: NDArray[np.float64] | None = None,
) -> Any:
    """``sensor_msgs/JointState`` (velocities and efforts empty when not known)."""
    msg_type = typestore().types["sensor_msgs/msg/JointState"]
    empty = np.zeros(0, dtype=np.float64)
    return msg_type(
        header=header(t, ""),
        name=list(names),
        position=np.asarray(positions, dtype=np.float64),
        velocity=empty if velocities is None else np.asarray(velocities, dtype=np.float64),
        effort=empty if efforts is None else np.asarray(efforts, dtype=np.float64),
    )


# ---------------------------------------------------------------------------- transforms


def _quaternion_xyzw(R: NDArray[np.float64]) -> NDArray[np.float64]:
    from scipy.spatial.transform import Rotation

    return np.asarray(Rotation.from_matrix(np.asarray(R, dtype=float)).as_quat(), dtype=float)


def transform(t: float, parent: str, child: str, T_parent_child: NDArray[np.float64]) -> Any:
    """``geometry_msgs/TransformStamped``: the pose of ``child`` in ``parent``."""
    types = typestore().types
    T = np.asarray(T_parent_child, dtype=float)
    qx, qy, qz, qw = (float(v) for v in _quaternion_xyzw(T[:3, :3]))
    x, y, z = (float(v) for v in T[:3, 3])
    return types["geometry_msgs/msg/TransformStamped"](
        header=header(t, parent),
        child_frame_id=child,
        transform=types["geometry_msgs/msg/Transform"](
            translation=types["geometry_msgs/msg/Vector3"](x=x, y=y, z=z),
            rotation=types["geometry_msgs/msg/Quaternion"](x=qx, y=qy, z=qz, w=qw),
        ),
    )


def tf_message(transforms: list[Any]) -> Any:
    return typestore().types["tf2_msgs/msg/TFMessage"](transforms=transforms)


def matrix_of(transform_msg: Any) -> NDArray[np.float64]:
    """The 4x4 pose of a ``geometry_msgs/Transform``."""
    from scipy.spatial.transform import Rotation

    r, p = transform_msg.rotation, transform_msg.translation
    T = np.eye(4)
    T[:3, :3] = Rotation.from_quat([r.x, r.y, r.z, r.w]).as_matrix()
    T[:3, 3] = [p.x, p.y, p.z]
    return T


# ---------------------------------------------------------------------------- markers


def _marker(
    t: float,
    ns: str,
    marker_id: int,
    kind: int,
    position: tuple[float, float, float],
    scale: tuple[float, float, float],
    rgba: tuple[float, float, float, float],
    text: str = "",
    action: int = 0,
    points: Sequence[Sequence[float]] = (),
) -> Any:
    types = typestore().types
    x, y, z = position
    point = types["geometry_msgs/msg/Point"]
    return types["visualization_msgs/msg/Marker"](
        header=header(t, BASE_FRAME),
        ns=ns,
        id=marker_id,
        type=kind,
        action=action,
        pose=types["geometry_msgs/msg/Pose"](
            position=types["geometry_msgs/msg/Point"](x=float(x), y=float(y), z=float(z)),
            orientation=types["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0),
        ),
        scale=types["geometry_msgs/msg/Vector3"](
            x=float(scale[0]), y=float(scale[1]), z=float(scale[2])
        ),
        color=types["std_msgs/msg/ColorRGBA"](
            r=float(rgba[0]), g=float(rgba[1]), b=float(rgba[2]), a=float(rgba[3])
        ),
        lifetime=types["builtin_interfaces/msg/Duration"](sec=0, nanosec=0),
        frame_locked=False,
        points=[point(x=float(px), y=float(py), z=float(pz)) for px, py, pz in points],
        colors=[],
        texture_resource="",
        texture=types["sensor_msgs/msg/CompressedImage"](
            header=header(t, ""), format="", data=np.zeros(0, np.uint8)
        ),
        uv_coordinates=[],
        text=text,
        mesh_resource="",
        mesh_file=types["visualization_msgs/msg/MeshFile"](filename="", data=np.zeros(0, np.uint8)),
        mesh_use_embedded_materials=False,
    )


CUBE, CYLINDER, LINE_LIST, CUBE_LIST, TEXT = 1, 3, 5, 6, 9  # visualization_msgs/Marker types
DELETEALL = 3  # visualization_msgs/Marker action

#: Planning-scene marker colours (RGBA 0..1): the table, collision bodies, occupied cells, arm.
SCENE_COLOURS = {
    "table": (0.6, 0.6, 0.6, 0.25),
    "body": (1.0, 0.55, 0.1, 0.3),
    "occupied": (0.9, 0.2, 0.2, 0.6),
    "arm": (0.3, 0.9, 0.4, 0.35),
}
#: The table drawn as a square this wide (m) in front of the arm's base.
SCENE_TABLE_SIZE_M = 1.2


def scene_markers(t: float, scene: dict[str, Any]) -> Any:
    """``visualization_msgs/MarkerArray`` of a planning scene (``PlanningScene.to_dict()``):
    a DELETEALL first, then the table as a thin square at its height, every collision body
    (tracks with their uncertainty added) as a cylinder from its bottom to its top, the
    occupancy grid's cells outside every body as one cube list (a cube of the cell's size at
    each cell's top) and the arm's link capsules as lines as thick as the capsules."""
    markers = [_marker(t, "scene", 0, CUBE, (0, 0, 0), (1, 1, 1), (0, 0, 0, 0), "", DELETEALL)]
    z = float(scene["table_z"])
    size = SCENE_TABLE_SIZE_M
    markers.append(
        _marker(
            t,
            "scene_table",
            0,
            CUBE,
            (size / 2, 0.0, z - 0.0025),
            (size, size, 0.005),
            SCENE_COLOURS["table"],
        )
    )
    for k, body in enumerate(scene["bodies"]):
        (x, y), r = body["xy"], body["radius"]
        height = max(body["top"] - body["bottom"], 1e-3)
        centre = (x, y, body["bottom"] + height / 2)
        markers.append(
            _marker(
                t,
                "scene_bodies",
                k,
                CYLINDER,
                centre,
                (2 * r, 2 * r, height),
                SCENE_COLOURS["body"],
                body["label"],
            )
        )
    cells = scene["occupied_cells"]
    if cells:
        side = float(np.sqrt(2.0) * cells[0]["radius"])  # the cell: its body is the circumcircle
        tops = [(c["xy"][0], c["xy"][1], c["top"] - side / 2) for c in cells]
        markers.append(
            _marker(
                t,
                "scene_occupied",
                0,
                CUBE_LIST,
                (0, 0, 0),
                (side, side, side),
                SCENE_COLOURS["occupied"],
                points=tops,
            )
        )
    for k, link in enumerate(scene["arm"] or ()):
        width = 2 * float(link["radius"])
        markers.append(
            _marker(
                t,
                "scene_arm",
                k,
                LINE_LIST,
                (0, 0, 0),
                (width, 0.0, 0.0),
                SCENE_COLOURS["arm"],
                points=(link["a"], link["b"]),
            )
        )
    return typestore().types["visualization_msgs/msg/MarkerArray"](markers=markers)


def track_markers(t: float, tracks: list[dict[str, Any]]) -> Any:
    """``visualization_msgs/MarkerArray`` of tracks (dicts of :func:`track_record`): a DELETEALL
    first (tracks that ended disappear), then per track a translucent cylinder of its radius
    and height standing on the table, a cylinder of its liquid up to the measured fill (in
    the liquid's colour), and a text label ``bottle #3 62 %`` above it."""
    markers = [_marker(t, "tracks", 0, CYLINDER, (0, 0, 0), (1, 1, 1), (0, 0, 0, 0), "", DELETEALL)]
    for track in tracks:
        x, y, z = track["position_m"]
        radius = track["radius_m"] or 0.03
        height = track["height_m"] or 0.1
        bottom = z - height / 2.0
        rgba = LABEL_COLOURS.get(track["label"], LABEL_COLOURS["other"])
        base_id = 3 * int(track["id"])
        markers.append(
            _marker(
                t, "tracks", base_id, CYLINDER, (x, y, z), (2 * radius, 2 * radius, height), rgba
            )
        )
        fill = track.get("fill")
        label = f"{track['label']} #{track['id']}"
        if fill is not None and math.isfinite(fill) and fill > 0:
            colour = track.get("liquid_colour") or (80, 120, 200)
            level = height * min(max(fill, 0.0), 1.0)
            liquid_rgba = (colour[0] / 255, colour[1] / 255, colour[2] / 255, 0.8)
            markers.append(
                _marker(
                    t,
                    "liquid",
                    base_id + 1,
                    CYLINDER,
                    (x, y, bottom + level / 2),
                    (1.8 * radius, 1.8 * radius, level),
                    liquid_rgba,
                )
            )
            label += f" {100 * fill:.0f} %"
        markers.append(
            _marker(
                t,
                "labels",
                base_id + 2,
                TEXT,
                (x, y, bottom + height + 0.03),
                (0.0, 0.0, 0.025),
                (1.0, 1.0, 1.0, 1.0),
                label,
            )
        )
    return typestore().types["visualization_msgs/msg/MarkerArray"](markers=markers)
