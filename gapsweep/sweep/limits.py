"""Stopping a run cleanly: SIGINT/SIGTERM, a stop file, and the optional per-task time limit
(``docs/reliability.md``).

* :class:`Stop` installs handlers for SIGINT and SIGTERM (main thread only). In *raise* mode (serial runs) a
  signal raises :class:`Interrupted` at once -- the current task is abandoned -- unless a store write is in
  progress (:meth:`Stop.critical`), in which case it is raised when the write is complete. In *flag* mode (MPI
  ranks, where a rank leaving the task farm abruptly would hang the others) it only records the request; the
  farm drains (no new work, the tasks in flight finish) and every rank ends cleanly. A file ``<store>.stop``
  is a stop request too (what the Slurm scripts create when Slurm signals the time limit).
* :func:`install_early` (the CLI, first thing) closes the start-up window (issue 19): before it, SIGTERM killed
  the process outright and SIGINT raised anywhere, so a signal in the first half-second left a stale lease and a
  run not recorded as interrupted. For ``run`` the early handler only *records* the signal; the run's
  :class:`Stop` adopts it when installed, opens the store, records the run as interrupted and exits 130/143.
  For the other commands (merge, report, export) it raises :class:`Interrupted` at once -- their ``finally``
  blocks remove temporary files and release the lease -- except inside :func:`deferred` (a lease being
  created or released). Only the *first* signal acts: a second one in a row (an impatient user, a launcher
  that forwards to the process group and to each rank) must not cut the clean-up of the first.
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

__all__ = ["Interrupted", "Stop", "TaskTimeout", "deadline", "deferred", "install_early", "restore_early",
           "take_pending"]

SIGNAL_NAMES = {signal.SIGINT: "SIGINT", signal.SIGTERM: "SIGTERM"}

_received: int | None = None  # the first SIGINT/SIGTERM this process got through one of our handlers
_pending: int | None = None  # ... not yet acted on (deferred, or recorded for the run's Stop to adopt)
_defer = 0  # depth of deferred() blocks
_defer_all = False  # the run command: record only, the run's Stop acts on it
_raised: int | None = None  # raised by the early handler; cleared by whoever reports the Interrupted (the CLI)
_count = 0  # SIGINT/SIGTERM received by this process's handlers, ever (signal_count)


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
        self.on_request: Any = None  # called once with the signal number when a farm starts stopping
        self._critical = 0
        self._old: dict[int, Any] = {}

    def _handler(self, signum: int, frame: Any) -> None:
        global _received, _count
        _count += 1
        first = self.signum is None
        if first:
            self.signum = signum
        if _received is None:
            _received = signum
        if self.mode == "raise" and not self._critical and first:
            raise Interrupted(signum)

    def install(self) -> Stop:
        """Take over SIGINT/SIGTERM; a signal recorded by the early handler is adopted (acted on at the next
        check: the end of the first store write in raise mode, the farm's next round in flag mode)."""
        global _pending
        if threading.current_thread() is threading.main_thread():
            for s in SIGNAL_NAMES:
                self._old[s] = signal.signal(s, self._handler)
        if _pending is not None and self.signum is None:
            self.signum, _pending = _pending, None
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
    from gapsweep.sweep.schema import TIMEOUT_PREFIX  # here, not at the top: this module loads before numpy

    return f"{TIMEOUT_PREFIX} task exceeded its time limit of {seconds:g} s (run again by --resume)"


def signal_count() -> int:
    """How many SIGINT/SIGTERM this process's handlers have received: a task compares it before and after, so
    that an error caused by a signal (one raised inside C code and swallowed there, e.g. in an llvmlite callback
    during JIT compilation) is known for an interruption, not recorded as the task's failure."""
    return _count


# Errors that say a computation was cut rather than that it failed: numba's dispatcher after a compilation whose
# llvmlite callback swallowed the exception a signal handler raised.
_CUT_MESSAGES = ("no compiled object yet",)


def cut_by_signal(e: BaseException, count_before: int) -> bool:
    """Whether the exception ``e`` of a task comes from an interruption: a signal arrived since
    ``count_before`` (:func:`signal_count`), an Interrupted / KeyboardInterrupt in its chain, or a message that
    only a cut computation gives (``_CUT_MESSAGES``)."""
    if _count != count_before:
        return True
    seen: set[int] = set()
    x: BaseException | None = e
    while x is not None and id(x) not in seen:
        seen.add(id(x))
        if isinstance(x, (Interrupted, KeyboardInterrupt)) or any(m in str(x) for m in _CUT_MESSAGES):
            return True
        x = x.__cause__ or x.__context__
    return False


def interrupted_message(e: BaseException) -> str:
    """The message of a row cut by an interruption; ``--resume`` runs rows with this prefix again."""
    from gapsweep.sweep.schema import INTERRUPTED_PREFIX

    return f"{INTERRUPTED_PREFIX} {type(e).__name__}: {e} (cut by a signal; run again by --resume)"


def is_interrupted(message: str) -> bool:
    from gapsweep.sweep.schema import INTERRUPTED_PREFIX

    return message.startswith(INTERRUPTED_PREFIX)


def is_timeout(message: str) -> bool:
    from gapsweep.sweep.schema import TIMEOUT_PREFIX

    return message.startswith((TIMEOUT_PREFIX, "TaskTimeout", "DeadlineExceeded"))


def _early(signum: int, frame: Any) -> None:
    global _received, _pending, _count
    _count += 1
    if _received is not None:  # a second signal: the first one's clean-up is under way
        return
    _received = signum
    if _defer_all or _defer:
        _pending = signum
        return
    _raise(signum)


def _raise(signum: int) -> None:
    """Raise Interrupted, remembering it: C code (HDF5 inside h5py) may swallow an exception raised in a signal
    handler, and then the command must still not pass for uninterrupted (:func:`take_pending`)."""
    global _raised
    _raised = signum
    raise Interrupted(signum)


def install_early(*, defer_all: bool) -> dict[int, Any]:
    """Handle SIGINT/SIGTERM from the start of the process (module docstring). ``defer_all``: only record
    (the run command, whose :class:`Stop` adopts the signal); else raise :class:`Interrupted` outside
    :func:`deferred` blocks -- at once if a signal was recorded before this call."""
    global _defer_all, _pending
    _defer_all = defer_all
    old: dict[int, Any] = {}
    if threading.current_thread() is threading.main_thread():
        for s in SIGNAL_NAMES:
            old[s] = signal.signal(s, _early)
    if not defer_all and not _defer and _pending is not None:
        s, _pending = _pending, None
        _raise(s)
    return old


def restore_early(old: dict[int, Any]) -> None:
    """Put back the handlers :func:`install_early` replaced and forget its state (``cli.main`` called in a
    process that goes on, e.g. a test). Where those were our own (``python -m gapsweep``: the process is about
    to exit, its clean-up done) further signals are ignored, so a late one cannot turn exit 143 into a kill."""
    global _received, _pending, _defer_all, _raised
    for s, h in old.items():
        signal.signal(s, signal.SIG_IGN if h is _early else h)
    _received = _pending = _raised = None
    _defer_all = False


def take_pending() -> int | None:
    """A signal the early handler recorded and no run adopted, or raised and nobody reported (swallowed in C
    code): the command exits 128 + it. Clears both."""
    global _pending, _raised
    s = _pending if _pending is not None else _raised
    _pending = _raised = None
    return s


@contextlib.contextmanager
def deferred() -> Iterator[None]:
    """A few statements that a signal must not cut (a lease file created but not yet owned, or being
    removed): the early handler's Interrupted is raised at the end of the block instead."""
    global _defer, _pending
    _defer += 1
    try:
        yield
    finally:
        _defer -= 1
    if not _defer and not _defer_all and _pending is not None:
        s, _pending = _pending, None
        _raise(s)


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
