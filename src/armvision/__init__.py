"""armvision: vision-guided manipulation, Interbotix ViperX-300s arm + Intel RealSense D435i.

Hardware backends (pyrealsense2, Interbotix/ROS 2) are imported only when asked for, so
``import armvision`` works anywhere.
"""

__version__ = "0.1.0"
