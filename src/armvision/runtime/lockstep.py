"""The lockstep schedule: no threads; the stages run in time order as the simulation advances.

:meth:`Lockstep.pump` moves a simulated world's clock forward and, on the way, runs a fusion
cycle every 1/``fusion.rate_hz`` and reads (renders) a frame only when an enabled detector is
due, at most at its configured rate. Tasks run on the caller's thread and their waits pump.
Repeatable for a seed and as fast as the machine allows: the demo and the evaluations run so.
"""

from __future__ import annotations

import functools
import math
from typing import TYPE_CHECKING, Protocol, runtime_checkable

import numpy as np
from numpy.typing import NDArray

from armvision.errors import ArmvisionError

if TYPE_CHECKING:
    from armvision.runtime.system import System

#: The detection stages, in the order a lockstep frame serves them.
DETECTORS = ("tags", "objects", "liquid")


@runtime_checkable
class SimulatedWorld(Protocol):
    """A simulation under a system: its clock, which lockstep advances, and the one truth a
    task reports against (the calibrate task compares its result with the true camera pose).
    The simulated bench's ``SimWorld`` is one."""

    @property
    def time(self) -> float: ...
    @property
    def timestep(self) -> float: ...
    def run_until(self, t: float) -> None: ...
    def T_base_cam(self) -> NDArray[np.float64]: ...


class Lockstep:
    """The lockstep schedule of one system on ``world``."""

    def __init__(self, system: System, world: SimulatedWorld) -> None:
        self.system = system
        self.world = world
        self._next_fusion = 0.0
        self._due = dict.fromkeys(DETECTORS, 0.0)

    def start(self) -> None:
        system = self.system
        system.camera.start()
        now = system.clock()
        self._next_fusion = now
        self._due = dict.fromkeys(DETECTORS, now)
        system.fusion_step()
        system.meters["fusion"].tick()

    def pump(self, until: float) -> None:
        """Run every stage in time order while the world advances to ``until``."""
        system = self.system
        fusion_period = 1.0 / system.config.fusion.rate_hz
        if self._next_fusion < system.clock() - fusion_period:
            # The clock moved outside pump() (a blocking arm call): the cycles that time held
            # are gone, as on a stalled thread; replaying them all at one instant would only
            # stack identical encoder readings into the filter.
            system.fusion_stalls += 1
            self._next_fusion = system.clock()
        while True:
            due = [self._due[n] for n in DETECTORS if system.enabled[n]]
            frame_due = min(due) if due else math.inf
            if min(self._next_fusion, frame_due) > until:
                break
            if frame_due < self._next_fusion:
                self._frame(frame_due)
            else:
                self.world.run_until(self._next_fusion)
                system.guard("fusion", system.fusion_step)
                self._next_fusion += fusion_period
        if until > system.clock():
            self.world.run_until(until)

    def _frame(self, due: float) -> None:
        """Advance to a detector's due time, read the frame and run every detector due."""
        system = self.system
        half_frame = 0.5 / float(system.config.camera.fps)
        self.world.run_until(max(due, system.clock()))
        frame = system.read_frame()
        now = frame.timestamp
        for name, work in (("tags", system.tags_once), ("objects", system.objects_once)):
            if system.enabled[name] and self._due[name] <= now + half_frame:
                system.guard(name, functools.partial(work, frame))
                self._due[name] = now + 1.0 / system.rates[name] - half_frame
        if system.enabled["liquid"] and self._due["liquid"] <= now + half_frame:
            system.guard("liquid", system.liquid_once)
            self._due["liquid"] = now + 1.0 / system.rates["liquid"] - half_frame
        for name in DETECTORS:  # a disabled detector is due when switched back on
            if not system.enabled[name]:
                self._due[name] = now


def require_world(world: SimulatedWorld | None) -> SimulatedWorld:
    """``world``, or an error that says what lockstep mode needs."""
    if world is None:
        raise ArmvisionError(
            "lockstep mode needs the simulated world whose clock it advances (time, timestep, "
            "run_until); pass world=..., or run with threads (lockstep=False)"
        )
    return world
