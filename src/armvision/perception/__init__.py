"""Perception: AprilTag poses, bottle and cup detection, liquid level.

Each detector is a small object with named settings and a ``detect`` method returning plain
frozen records, in the camera frame. The object detectors share one protocol,
:class:`~armvision.perception.detection.ObjectDetector`:
``detect(frame, FrameContext(T_base_cam=..., joint_positions=...))``.
"""
