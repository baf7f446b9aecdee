"""Recordings of runs in MCAP with ROS 2 messages: writing them, reading them back, and the
camera and arm that play one back (see docs/architecture.md, "Recording and replay")."""
