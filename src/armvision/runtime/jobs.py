"""The motion worker's queue: tasks run one at a time, each to a final :class:`TaskStatus`.

:class:`Jobs` keeps the queued and the running task, runs one (:meth:`Jobs.run`) with a fresh
:class:`~armvision.runtime.context.TaskContext`, turns whatever it returns or raises into a
status (succeeded, failed with a readable reason, stopped), and makes Stop end the running
task and drop the queued ones. It does not decide *where* a task runs: the realtime
scheduler's motion thread takes them from :meth:`Jobs.next`, a lockstep system runs each on
the caller's thread at submission.
"""

from __future__ import annotations

import itertools
import logging
import queue
import threading
import time
from collections.abc import Mapping
from typing import TYPE_CHECKING, Any

from armvision.errors import ArmvisionError
from armvision.runtime.context import Task, TaskContext, TaskReport, TaskStopped
from armvision.runtime.state import TaskPhase, TaskStatus

if TYPE_CHECKING:
    from armvision.runtime.system import System

log = logging.getLogger("armvision.runtime")


class Job:
    """One submitted task: what to call, its stop flag, and its final status once done."""

    def __init__(self, task_id: int, name: str, fn: Task, kwargs: dict[str, Any]) -> None:
        self.task_id, self.name, self.fn, self.kwargs = task_id, name, fn, kwargs
        self.stop = threading.Event()
        self.done = threading.Event()
        self.status: TaskStatus | None = None


class Jobs:
    """The queue of tasks of one :class:`~armvision.runtime.system.System`."""

    def __init__(self, system: System) -> None:
        self.system = system
        self._queue: queue.Queue[Job | None] = queue.Queue()
        self._current: Job | None = None
        self._pending: list[Job] = []
        self._submitted: dict[int, Job] = {}
        self._lock = threading.Lock()
        self._ids = itertools.count(1)
        #: The newest final status of each task name (a later task may build on it: place
        #: sets down the bottle the newest successful grab holds).
        self.last: dict[str, TaskStatus] = {}

    @property
    def busy(self) -> bool:
        return self._current is not None

    def new(self, name: str, fn: Task, kwargs: dict[str, Any]) -> Job:
        job = Job(next(self._ids), name, fn, kwargs)
        with self._lock:
            self._submitted[job.task_id] = job
        return job

    def enqueue(self, job: Job) -> None:
        """Queue ``job`` for the motion thread (shown as queued if nothing runs now)."""
        with self._lock:
            self._pending.append(job)
        if self._current is None:
            self.system.store.set_task(
                TaskStatus(name=job.name, phase="queued", task_id=job.task_id)
            )
        self._queue.put(job)

    def next(self) -> Job | None:
        """The next queued job (blocks); None once :meth:`close` was called."""
        return self._queue.get()

    def close(self) -> None:
        """Wake the motion thread so it ends."""
        self._queue.put(None)

    def wait(self, task_id: int, timeout_s: float | None = None) -> TaskStatus:
        """Wait for task ``task_id`` to end; its final status."""
        job = self._submitted.get(task_id)
        if job is None:
            raise ArmvisionError(f"no task {task_id}")
        deadline = None if timeout_s is None else time.monotonic() + timeout_s
        # Short waits, so Ctrl-C reaches the caller at once.
        while not job.done.wait(0.2):
            if deadline is not None and time.monotonic() > deadline:
                raise ArmvisionError(
                    f"task {task_id} ({job.name}) did not end within {timeout_s} s"
                )
        assert job.status is not None
        return job.status

    def stop(self) -> None:
        """Set the stop flag of the running task and of every queued one (dropping them)."""
        with self._lock:
            current = self._current
            pending, self._pending = self._pending, []
        for job in pending:
            job.stop.set()
        if current is not None:
            current.stop.set()

    def run(self, job: Job) -> None:
        """Run ``job`` to its end on this thread and publish its final status."""
        if not self._begin(job):
            return
        system = self.system
        started = system.clock()
        system.store.set_task(
            TaskStatus(name=job.name, phase="running", started=started, task_id=job.task_id)
        )
        phase, error, result, halt_error = self._call(job)
        current = system.store.task()
        status = TaskStatus(
            name=job.name,
            phase=phase,
            progress=1.0 if phase == "succeeded" else current.progress,
            message=current.message if current.task_id == job.task_id else "",
            started=started,
            finished=system.clock(),
            result=result if isinstance(result, Mapping) else None,
            error=error,
            task_id=job.task_id,
        )
        self.finish(job, status)
        system.meters["motion"].tick()
        if halt_error is not None:  # kept in the motion stage's health until the next task
            system.meters["motion"].error(halt_error)

    def _begin(self, job: Job) -> bool:
        """Make ``job`` the current one; False (and it is finished) if stopped while queued."""
        with self._lock:
            if job in self._pending:
                self._pending.remove(job)
            if job.stop.is_set():
                status = TaskStatus(
                    name=job.name,
                    phase="stopped",
                    error="stopped before it started",
                    task_id=job.task_id,
                    finished=self.system.clock(),
                )
                self.finish(job, status)
                return False
            self._current = job
        return True

    def _call(self, job: Job) -> tuple[TaskPhase, str | None, Any, str | None]:
        """(phase, error, result, halt error) of calling the task."""
        phase: TaskPhase = "succeeded"
        error: str | None = None
        result: Any = None
        halt_error = None
        try:
            value = job.fn(TaskContext(self.system, job.task_id, job.stop), **job.kwargs)
            result = value.to_dict() if isinstance(value, TaskReport) else value
            if isinstance(value, TaskReport) and not value.ok:
                phase = "failed"
                error = str(result.get("reason") or "the task did not succeed")
        except TaskStopped:
            phase, error = "stopped", "stopped by the operator"
            halt_error = self.system.halt_arm()
            if halt_error is not None:
                error += f"; {halt_error}"
        except ArmvisionError as exc:
            phase, error = "failed", str(exc)
            log.warning("task %s failed: %s", job.name, exc)
        except Exception as exc:  # a bug: say so readably, keep the traceback in the log
            phase, error = "failed", f"internal error ({type(exc).__name__}: {exc})"
            log.exception("task %s crashed", job.name)
        finally:
            with self._lock:
                self._current = None
        return phase, error, result, halt_error

    def fail(self, job: Job, exc: Exception) -> None:
        """The worker itself failed on ``job`` (not the task): finish it as failed."""
        log.exception("the motion worker failed on task %s", job.name)
        with self._lock:
            self._current = None
        message = f"internal error ({type(exc).__name__}: {exc})"
        self.system.meters["motion"].error(message)
        if not job.done.is_set():
            self.finish(
                job,
                TaskStatus(
                    name=job.name,
                    phase="failed",
                    error=message,
                    task_id=job.task_id,
                    finished=self.system.clock(),
                ),
            )

    def finish(self, job: Job, status: TaskStatus) -> None:
        self.last[job.name] = status
        self.system.store.set_task(status)
        job.status = status
        job.done.set()
