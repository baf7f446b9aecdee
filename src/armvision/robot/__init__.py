"""The robot arm: kinematics, the Arm interface and its backends.

``robot.interbotix`` (the real arm) is not imported here: it needs ROS 2, so it loads on demand.
"""

from armvision.robot.kinematics import VX300S, ArmModel, fk, ik, jacobian_space

__all__ = ["VX300S", "ArmModel", "fk", "ik", "jacobian_space"]
