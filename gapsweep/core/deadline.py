"""Cooperative time limits for the solvers' iteration loops.

A caller (the sweep's ``--task-timeout``) opens :func:`limit`; every solver loop calls :func:`check` once per
iteration, which raises :class:`DeadlineExceeded` there -- at a point where nothing is half-done -- once the
limit has passed. Unlike an asynchronous exception (a signal handler raising wherever Python happens to run), it
can never land inside an import, numba's compiler or an HDF5 call, so a timed-out task leaves the process as it
was. Costs one clock read per iteration. Outside :func:`limit` :func:`check` does nothing.
"""

from __future__ import annotations

import contextlib
import threading
import time
from collections.abc import Iterator

__all__ = ["DeadlineExceeded", "check", "limit"]

_local = threading.local()


class DeadlineExceeded(Exception):
    """A solver loop passed the time limit of the enclosing :func:`limit`."""


@contextlib.contextmanager
def limit(seconds: float | None) -> Iterator[None]:
    """Within the block, :func:`check` raises :class:`DeadlineExceeded` after ``seconds`` [s] (None or 0: no
    limit). Nests: the earlier deadline wins."""
    if not seconds:
        yield
        return
    old = getattr(_local, "at", None)
    at = time.monotonic() + float(seconds)
    _local.at = at if old is None else min(old, at)
    _local.seconds = float(seconds)
    try:
        yield
    finally:
        _local.at = old


def check() -> None:
    """Raise :class:`DeadlineExceeded` if the enclosing :func:`limit` has passed (call once per iteration)."""
    at = getattr(_local, "at", None)
    if at is not None and time.monotonic() > at:
        raise DeadlineExceeded(f"time limit of {getattr(_local, 'seconds', 0.0):g} s exceeded")
