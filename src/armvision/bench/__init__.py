"""The simulated bench wired into the runtime: simulated systems, calibration in simulation,
snapshots and the demo. Everything here may use the simulation; nothing below this package does.
"""
