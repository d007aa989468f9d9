"""Batched GFMD in a sweep: pressure chains run side by side, one batched solve per chain step (docs/running.md,
"Batched GFMD").

Which units batch (``mode``, ``gapsweep run --batch``):

* ``"off"`` (default): none; every chain runs one solve at a time. In the sweep this was measured faster than
  ``"auto"`` on an H200 (figure jobs 2 and 3, 16 ranks, 8 on the GPU with MPS: 13.1 s and 7.2 s against 32.7 s
  and 33.5 s, equal stores; docs/benchmarks.md): one batch unit holds up to 32 chains on one rank while the
  other GPU ranks idle, although the batched solver alone beats one-by-one solves at N = 1024 (1.27x).
* ``"auto"``: GFMD chains (and single GFMD tasks) with ``backend = "cupy"`` -- GPU units, so they run on GPU
  ranks -- where the batched solver alone was measured to pay: ``n <= BATCH_MAX_N``, the exponential law, method
  "cg"/"auto", no ``extra`` solver options.
* ``"all"``: the same chains with any backend (a CPU backend runs the batch with numpy: CI tests this path).

Chains with the same grid size and common solver options (tol, max_iter, backend, e_star, length) are grouped in
expansion order, at most ``BATCH_CHAINS`` per batch unit. The grouping is made before sharding and does not
depend on the rank count. A batch unit runs step ``k`` of all its chains as one :func:`gapsweep.gfmd.solve_batch`
call, each problem warm-started from step ``k - 1`` of its own chain exactly as the one-by-one chain does
(converged solutions only); a chain stops after its last wanted task (resume). The batched solver does the
one-by-one CG step for step, so rows agree with the unbatched sweep to round-off (tests/test_batching.py).
Only what the store needs leaves the GPU: statistics and the histogram of the gap are computed there
(gapsweep.sweep.tasks.gfmd_row), and each result is dropped once its row is made.

Per-task behaviour is that of :func:`gapsweep.sweep.tasks.run_task`: an injected failure, an exception or a
non-finite result gives a failed row; a solver warning goes into its own row's message; a step that raises as a
whole is re-run one task at a time (so one bad input fails only its own row). ``wall_time`` of a batched row is
its share of the step's wall time; a ``--task-timeout`` bounds each step.
"""

from __future__ import annotations

import logging
import re
import time
import warnings
from collections.abc import Iterator
from typing import Any

from gapsweep.core.deadline import DeadlineExceeded
from gapsweep.sweep import methods as registry
from gapsweep.sweep.context import Context, use_gpu
from gapsweep.sweep.execute import run_task
from gapsweep.sweep.farm import DeviceFault, device_fault
from gapsweep.sweep.methods.base import non_finite as _non_finite
from gapsweep.sweep.methods.gfmd import gfmd_host_fields, gfmd_row
from gapsweep.sweep.schema import StoreWriteError, Task, TaskResult, Unit

__all__ = ["BATCH_CHAINS", "BATCH_MAX_N", "MODES", "batch_units", "run_batch"]


def _cost(t: Task) -> float:
    return registry.get(t.method).cost(t)

log = logging.getLogger("gapsweep.batching")

MODES = ("auto", "off", "all")
BATCH_MAX_N = 1024  # largest grid where a batch beat one-by-one solves on the GPU (issue 14 benchmark)
BATCH_CHAINS = 32  # chains per batch unit (32 problems of N = 1024 need ~3.7 GB on the GPU)
_BATCH_GAIN = 1.27  # measured batch speed-up at N = 1024 (cost model only)


def _batchable(t: Task, mode: str) -> bool:
    if mode == "off" or t.method != "gfmd" or t.n > BATCH_MAX_N:
        return False
    if t.opt("method") not in ("auto", "cg") or t.opt("interaction", "exponential") != "exponential":
        return False
    if t.opt("surface.periodic") is False:  # free boundaries: solve_batch is periodic only
        return False
    if any(k.startswith("extra.") for k, _ in t.options):
        return False
    if t.opt("thickness") is not None or t.opt("hardness") is not None:  # a layer / a cap: not in solve_batch
        return False
    return mode == "all" or t.opt("backend") == "cupy"


def _key(t: Task) -> tuple:
    """Options common to every problem of one solve_batch call."""
    sp = t.surface_params()
    return (t.n, t.opt("backend"), t.opt("tol"), t.opt("max_iter"), t.opt("e_star"), sp["length"])


def batch_units(tasks: list[Task], units: list[Unit], mode: str = "off", chains: int = BATCH_CHAINS) -> list[Unit]:
    """``units`` with the batchable GFMD chains (and single GFMD tasks) grouped into batch units of at most
    ``chains`` chains; sorted largest cost first as :func:`gapsweep.sweep.tasks.make_units` does."""
    if mode not in MODES:
        raise ValueError(f"batch mode must be one of {', '.join(MODES)}, got {mode!r}")
    groups: dict[tuple, list[Unit]] = {}
    out: list[Unit] = []
    for u in units:
        t = tasks[u.tasks[0]]
        if u.kind in ("chain", "single") and _batchable(t, mode):
            groups.setdefault(_key(t), []).append(u)
        else:
            out.append(u)
    for members in groups.values():
        members.sort(key=lambda u: u.tasks[0])  # expansion order: deterministic, independent of the costs
        for s in range(0, len(members), chains):
            part = members[s:s + chains]
            if len(part) == 1:
                out.append(part[0])
                continue
            cost = sum(_cost(tasks[i]) for u in part for i in u.tasks) / _BATCH_GAIN
            out.append(Unit(tuple(i for u in part for i in u.tasks), cost, any(u.gpu for u in part), "batch",
                            tuple(u.tasks for u in part)))
    out.sort(key=lambda u: (-u.cost, tasks[u.tasks[0]].task_id))
    return out


_PROBLEM = re.compile(r"^problems\[(\d+)\]: ")


def run_batch(tasks: list[Task], unit: Unit, ctx: Context, todo: set[int], limit: float | None = None,
              stop: Any = None) -> Iterator[tuple[int, TaskResult]]:
    """Run a batch unit: yields ``(task index, result)`` for the tasks in ``todo``, step by step."""
    from gapsweep import gfmd
    from gapsweep.sweep import limits

    # each chain runs from its start to its last wanted task (the warm starts of a full run)
    runs = []
    for c in unit.chains:
        want = [k for k, i in enumerate(c) if i in todo]
        if want:
            runs.append(c[: want[-1] + 1])
    if not runs:
        return
    first = tasks[runs[0][0]]
    use_gpu(first, ctx)
    backend = "cupy" if first.opt("backend") == "cupy" else "numpy"
    heights: dict[int, Any] = {}  # chain -> its surface (on the GPU for cupy, moved there once per chain)
    state: dict[int, Any] = {}
    for step in range(max(len(c) for c in runs)):
        live = [(j, c[step]) for j, c in enumerate(runs) if step < len(c)]
        rows: dict[int, TaskResult] = {}
        probs, who = [], []
        for j, i in live:
            t = tasks[i]
            if t.sigma0 in ctx._fail:  # fault-injection seam, as in run_task
                rows[i] = TaskResult("failed", f"RuntimeError: injected failure at sigma0={t.sigma0!r}",
                                     {"wall_time": 0.0, "rank": ctx.rank})
                state[j] = None
                continue
            if j not in heights:
                h = ctx.surface(t, t.n)
                if backend == "cupy":
                    import cupy

                    h = cupy.asarray(h)
                heights[j] = h
            probs.append(gfmd.BatchProblem(heights=heights[j], sigma0=t.sigma0, gamma0=t.opt("gamma0"), rho=t.rho,
                                           initial=state.get(j) if t.opt("warm_start") else None))
            who.append((j, i))
        if probs:
            rows.update(_solve_step(tasks, probs, who, ctx, backend, limit, state, limits))
        if stop is not None and any(limits.is_interrupted(r.message) for r in rows.values() if r.status == "failed") \
                and stop.requested():  # cut by a signal (issue 31): those rows stay pending
            if stop.mode == "raise":
                raise limits.Interrupted(stop.signum)
            return
        for _, i in live:
            if i in todo:
                yield i, rows[i]
        if stop is not None and stop.mode == "flag" and stop.requested():
            return


def _failed(e: Exception) -> TaskResult:
    """The failed row of an exception -- unless it is a device fault, which raises DeviceFault (gapsweep.farm)."""
    why = device_fault(e)
    if why:
        raise DeviceFault(why) from e
    return TaskResult("failed", f"{type(e).__name__}: {e}")


def _notes(caught: list[warnings.WarningMessage], n: int) -> dict[int, str]:
    """The warnings a batched solve raised, as row messages: a warning that names its problem (``_PROBLEM``) goes
    to that row, any other to every row of the ``n``; the first warning of a row is kept."""
    notes: dict[int, str] = {}
    for w in caught:
        m = _PROBLEM.match(str(w.message))
        for k in ([int(m.group(1))] if m else range(n)):
            notes.setdefault(k, f"warning: {w.category.__name__}: {_PROBLEM.sub('', str(w.message))}")
    return notes


def _step_row(t: Task, ctx: Context, r: Any, note: str | None) -> tuple[TaskResult, Any]:
    """One task's row of a batched solve's result ``r`` and its next warm start: a row with non-finite values is
    failed (never a NaN stored as success), an error in making the row fails it (a device fault raises)."""
    try:
        res, nxt = gfmd_row(t, ctx, r)
        if note is not None and not res.message:
            res.message = note
        bad = _non_finite(res) if res.status == "done" else []
        if bad:  # never store a NaN as success
            res.status, res.message, nxt = "failed", f"non-finite result: {', '.join(bad)}", None
    except (StoreWriteError, DeviceFault):
        raise
    except Exception as e:
        res, nxt = _failed(e), None
    return res, nxt


def _solve_step(tasks: list[Task], probs: list, who: list[tuple[int, int]], ctx: Context, backend: str,
                limit: float | None, state: dict[int, Any], limits: Any) -> dict[int, TaskResult]:
    """One chain step of a batch: rows of its tasks, and the next warm starts in ``state``."""
    from gapsweep import gfmd

    t0 = tasks[who[0][1]]
    sp = t0.surface_params()
    start = time.perf_counter()
    if ctx._delay:
        from gapsweep.sweep.execute import test_delay

        test_delay(ctx._delay * len(probs))
    try:
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            kw = dict(e_star=t0.opt("e_star"), length=sp["length"], tol=t0.opt("tol"), backend=backend,
                      max_iter=t0.opt("max_iter"), host=False)
            if any(gfmd_host_fields(tasks[i], ctx) is True for _, i in who):
                kw["host"] = True
            if limit:
                with limits.task_limit(limit):
                    results = gfmd.solve_batch(probs, **kw)
            else:
                results = gfmd.solve_batch(probs, **kw)
    except (limits.TaskTimeout, DeadlineExceeded):
        msg = limits.timeout_message(limit)
        out = {}
        for j, i in who:
            out[i] = TaskResult("failed", msg, {"wall_time": limit, "rank": ctx.rank})
            state[j] = None
        return out
    except (StoreWriteError, DeviceFault):
        raise
    except Exception as e:  # e.g. one bad input: one task at a time, so that only its row fails (a device fault
        # raises DeviceFault from run_task there, and the farm runs the unit elsewhere)
        log.info("batch step failed as a whole (%s: %s): its tasks run one by one", type(e).__name__, e)
        out = {}
        for j, i in who:
            out[i], state[j] = run_task(tasks[i], ctx, state.get(j))
        return out
    share = (time.perf_counter() - start) / len(probs)
    notes = _notes(caught, len(probs))
    out = {}
    for k, ((j, i), r) in enumerate(zip(who, results)):
        t1 = time.perf_counter()
        res, nxt = _step_row(tasks[i], ctx, r, notes.get(k))
        res.values["wall_time"] = share + time.perf_counter() - t1
        res.values["rank"] = ctx.rank
        out[i] = res
        state[j] = nxt
    return out
