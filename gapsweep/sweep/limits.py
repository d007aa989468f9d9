"""Stopping a run cleanly: SIGINT/SIGTERM, a stop file, and the optional per-task time limit
(``docs/reliability.md``).

* :class:`Stop` installs handlers for SIGINT and SIGTERM (main thread only). In *raise* mode (serial runs) a
  signal raises :class:`Interrupted` at once -- the current task is abandoned -- unless a store write is in
  progress (:meth:`Stop.critical`), in which case it is raised when the write is complete. In *flag* mode (MPI
  ranks, where a rank leaving the task farm abruptly would hang the others) it only records the request; the
  farm drains (no new work, the tasks in flight finish) and every rank ends cleanly. A file ``<store>.stop``
  is a stop request too (what the Slurm scripts create when Slurm signals the time limit).
* :func:`deadline` bounds one task's wall time: on the main thread with ``SIGALRM``, on another thread by
  raising :class:`TaskTimeout` asynchronously in it. Either is delivered when the task next runs Python code
  (a single long C call finishes first).
"""

from __future__ import annotations

import contextlib
import ctypes
import signal
import threading
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from gapsweep.sweep.schema import TIMEOUT_PREFIX

__all__ = ["Interrupted", "Stop", "TaskTimeout", "deadline"]

SIGNAL_NAMES = {signal.SIGINT: "SIGINT", signal.SIGTERM: "SIGTERM"}


class Interrupted(BaseException):
    """The run was asked to stop (a signal or a stop file); ``signum`` gives the exit status 128 + signum."""

    def __init__(self, signum: int, counts: dict[str, int] | None = None) -> None:
        super().__init__(f"interrupted by {SIGNAL_NAMES.get(signum, signum)}")
        self.signum = signum
        self.counts = counts or {}

    @property
    def name(self) -> str:
        return SIGNAL_NAMES.get(self.signum, f"signal {self.signum}")

    @property
    def exit_code(self) -> int:
        return 128 + int(self.signum)


class TaskTimeout(Exception):
    """A task ran past its time limit (recorded as a failed row; the sweep goes on)."""


class Stop:
    """Stop requests of a run: signals (while installed) and a stop file."""

    def __init__(self, mode: str = "raise", stop_file: Path | None = None) -> None:
        self.mode = mode
        self.signum: int | None = None
        self.stop_file = stop_file
        self._critical = 0
        self._old: dict[int, Any] = {}

    def _handler(self, signum: int, frame: Any) -> None:
        self.signum = signum
        if self.mode == "raise" and not self._critical:
            raise Interrupted(signum)

    def install(self) -> Stop:
        if threading.current_thread() is threading.main_thread():
            for s in SIGNAL_NAMES:
                self._old[s] = signal.signal(s, self._handler)
        return self

    def restore(self) -> None:
        for s, h in self._old.items():
            signal.signal(s, h)
        self._old.clear()

    def requested(self) -> bool:
        """A signal arrived or the stop file exists (then SIGTERM is what the run reports)."""
        if self.signum is None and self.stop_file is not None and self.stop_file.exists():
            self.signum = signal.SIGTERM
        return self.signum is not None

    @contextlib.contextmanager
    def critical(self) -> Iterator[None]:
        """A store write: a signal arriving inside is acted on when the write is complete."""
        self._critical += 1
        try:
            yield
        finally:
            self._critical -= 1
        if self.mode == "raise" and not self._critical and self.signum is not None:
            raise Interrupted(self.signum)


# A task's time limit is kept cooperatively (gapsweep.core.deadline: the solvers' loops stop between
# iterations); the asynchronous TaskTimeout below is only a late fallback for code without such a loop (one long
# kernel), at HARD_FACTOR times the limit plus HARD_GRACE seconds.
HARD_FACTOR = 2.0
HARD_GRACE = 5.0


@contextlib.contextmanager
def task_limit(seconds: float | None) -> Iterator[None]:
    """The time limit of one task: cooperative at ``seconds`` (gapsweep.core.deadline), asynchronous
    (:func:`deadline`) only at ``HARD_FACTOR * seconds + HARD_GRACE``."""
    from gapsweep.core import deadline as coop

    if not seconds:
        yield
        return
    with coop.limit(seconds), deadline(HARD_FACTOR * seconds + HARD_GRACE):
        yield


def timeout_message(seconds: float) -> str:
    """The message of a timed-out row; ``--resume`` runs rows with this prefix again."""
    return f"{TIMEOUT_PREFIX} task exceeded its time limit of {seconds:g} s (run again by --resume)"


def is_timeout(message: str) -> bool:
    return message.startswith(TIMEOUT_PREFIX) or message.startswith(("TaskTimeout", "DeadlineExceeded"))


@contextlib.contextmanager
def deadline(seconds: float | None) -> Iterator[None]:
    """Raise :class:`TaskTimeout` in the calling thread if the block runs longer than ``seconds``."""
    if not seconds:
        yield
        return
    armed = [True]
    msg = f"task exceeded its time limit of {seconds:g} s"
    if threading.current_thread() is threading.main_thread():
        def on_alarm(signum: int, frame: Any) -> None:
            if armed[0]:
                raise TaskTimeout(msg)

        old = signal.signal(signal.SIGALRM, on_alarm)
        signal.setitimer(signal.ITIMER_REAL, seconds)
        try:
            yield
        finally:
            armed[0] = False
            signal.setitimer(signal.ITIMER_REAL, 0)
            signal.signal(signal.SIGALRM, old)
        return
    tid = threading.get_ident()
    lock = threading.Lock()

    def fire() -> None:
        with lock:
            if armed[0]:
                ctypes.pythonapi.PyThreadState_SetAsyncExc(ctypes.c_ulong(tid), ctypes.py_object(TaskTimeout))

    timer = threading.Timer(seconds, fire)
    timer.daemon = True
    timer.start()
    try:
        yield
    finally:
        with lock:
            armed[0] = False
        timer.cancel()
