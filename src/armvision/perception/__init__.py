"""Perception: AprilTag poses, bottle and cup detection, liquid level.

Each detector is a small object with named settings and a ``detect(frame)`` method returning
plain frozen records, in the camera frame.
"""
