"""Camera-to-robot calibration with the AprilTag on the gripper.

``sampling`` moves the arm through the paper's two-phase plan and collects samples,
``solve`` turns samples into ``T_base_cam`` by several methods, ``store`` keeps the result as a
versioned JSON file, ``procedure`` ties them together for the CLI and the runtime.
"""
