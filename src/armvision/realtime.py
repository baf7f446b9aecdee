"""How a process that runs fixed-rate threads shares the Python interpreter among them.

A thread that calls into C code which lets go of the interpreter (every MuJoCo step, most
NumPy and OpenCV calls) must take it back afterwards. While another thread runs Python code,
CPython hands it over only after its switch interval, 5 ms by default: the simulated physics,
which takes it back after each 2 ms step, then falls behind real time whenever the detector
threads are busy, and the fusion thread, waiting behind it, misses its 10 ms cycles. Measured on
2 cores, a grab in the realtime simulation held the physics lock up to 184 ms for 10 steps with
the default interval, at most 16 ms with 0.5 ms; with four busy loops beside it, the realtime
system test's fusion rate went from 92.6-96.9 Hz to 98.9-99.3 Hz (README, "realtime").
"""

from __future__ import annotations

import sys

#: The switch interval the realtime threads need (seconds): a tenth of the default.
REALTIME_SWITCH_INTERVAL_S = 0.0005


def share_interpreter_finely() -> None:
    """Shorten the interpreter's switch interval to :data:`REALTIME_SWITCH_INTERVAL_S` (process
    wide; a shorter one a user set is kept)."""
    if sys.getswitchinterval() > REALTIME_SWITCH_INTERVAL_S:
        sys.setswitchinterval(REALTIME_SWITCH_INTERVAL_S)
