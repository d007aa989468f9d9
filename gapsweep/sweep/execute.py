"""Running one task: the method plug-in's ``run`` inside the guarantees every store row needs.

:func:`run_task` never raises: an exception becomes a ``failed`` row with its message, a solver warning goes into
the row's message, a non-finite mean gap of a ``done`` row turns it into ``failed`` (never a NaN stored as
success), an error that a signal caused (inside JIT compilation, say) is marked ``interrupted:`` (the runner leaves
the row pending), and every row gets its wall time and rank. A device fault (gapsweep.sweep.farm.device_fault: out
of GPU memory, a lost context, the driver's or the MPS server's refusal) is not the task's failure: it raises
:class:`~gapsweep.sweep.farm.DeviceFault` and the farm runs the task elsewhere. The test hook
``GAPSWEEP_TEST_DELAY`` and the fault-injection seam ``_fail`` live in :class:`gapsweep.sweep.context.Context`.
"""

from __future__ import annotations

import time
import warnings
from typing import Any

from gapsweep.core import deadline
from gapsweep.sweep import limits
from gapsweep.sweep import methods as registry
from gapsweep.sweep.context import Context
from gapsweep.sweep.farm import DeviceFault, device_fault
from gapsweep.sweep.methods.base import non_finite
from gapsweep.sweep.schema import MISSING_EXTRA_PREFIX, StoreWriteError, Task, TaskResult

__all__ = ["run_task"]


def test_delay(seconds: float) -> None:
    """The test hook GAPSWEEP_TEST_DELAY: a task that takes ``seconds``, as a solver would (it keeps the time
    limit between its "iterations", gapsweep.core.deadline)."""
    end = time.monotonic() + seconds
    while (left := end - time.monotonic()) > 0:
        deadline.check()
        time.sleep(min(0.02, left))


def run_task(t: Task, ctx: Context, prev: Any = None) -> tuple[TaskResult, Any]:
    """Run one task; an exception becomes status ``failed`` with the message -- except a device fault, which
    raises :class:`DeviceFault` (and a store write error, which stops the run).
    Returns the result and the warm-start state for the next task of a chain (or None)."""
    t0 = time.perf_counter()
    signals = limits.signal_count()
    try:
        if ctx._delay:
            test_delay(ctx._delay)
        if t.sigma0 in ctx._fail:
            raise RuntimeError(f"injected failure at sigma0={t.sigma0!r}")
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            res, state = registry.get(t.method).run(t, ctx, prev)
        if caught and not res.message:  # solver warnings (e.g. under-resolved rho) go into the row's message
            w = caught[0]
            res.message = f"warning: {w.category.__name__}: {w.message}"
        bad = non_finite(res) if res.status == "done" else []
        if bad:  # never store a NaN as success
            res.status, res.message = "failed", f"non-finite result: {', '.join(bad)}"
            state = None
    except StoreWriteError:  # the store's failure (kept fields not writable), not the task's: the run stops
        raise
    except DeviceFault:
        raise
    except Exception as e:  # the sweep goes on; the row records what happened
        why = device_fault(e)
        if why:  # the device's fault, not the task's: the farm runs it on another worker
            raise DeviceFault(why) from e
        # an error caused by a signal (issue 31: one inside JIT compilation) is an interruption, not the task's
        # result: the runner leaves such a row pending (or --resume runs it again)
        if limits.cut_by_signal(e, signals):
            msg = limits.interrupted_message(e)
        elif _missing_extra(e):  # the installation's gap, not the task's: --resume runs it again
            msg = f"{MISSING_EXTRA_PREFIX} {e} (run again by --resume once it is installed)"
        else:
            msg = f"{type(e).__name__}: {e}"
        res, state = TaskResult("failed", msg), None
    res.values["wall_time"] = time.perf_counter() - t0
    res.values["rank"] = ctx.rank
    return res, state


def _missing_extra(e: BaseException) -> bool:
    """Whether ``e`` (or an exception in its chain) is gapsweep.core.extras.MissingExtraError."""
    from gapsweep.core.extras import MissingExtraError

    seen: set[int] = set()
    x: BaseException | None = e
    while x is not None and id(x) not in seen:
        seen.add(id(x))
        if isinstance(x, MissingExtraError):
            return True
        x = x.__cause__ or x.__context__
    return False
