"""Tasks: expansion of a job spec into tasks with stable content ids, and the grouping into work units.

* A :class:`~gapsweep.sweep.schema.Task` is one (method, hurst, rho, sigma0, seed, n) point with the spec's fixed
  parameters; its id is the first 16 hex digits of the SHA-256 of its canonical JSON (parameters that change the
  result, never the position in the grid), so resume and merge are keyed by content.
* A :class:`~gapsweep.sweep.schema.Unit` is what a worker runs in one go: a single task, a pressure chain (same
  surface, sigma0 in decreasing or increasing order) where each solve warm-starts from the previous solution,
  a set of tasks sharing an expensive input (the discrete theory's spectrum of one surface), or a batch of GFMD
  chains (gapsweep.sweep.batching). A chain is always run from its start on one rank, so its results do not
  depend on the rank count or on resume.

How a method expands, what a task costs, which tasks chain or share a set and how one runs: the method's plug-in
(gapsweep.sweep.methods). This module names no method.
"""

from __future__ import annotations

from collections import OrderedDict
from collections.abc import Iterator

from gapsweep.sweep import batching
from gapsweep.sweep import methods as registry
from gapsweep.sweep.context import Context
from gapsweep.sweep.execute import run_task
from gapsweep.sweep.methods.base import non_finite as _non_finite  # noqa: F401 - name of version 0.1
from gapsweep.sweep.methods.gfmd import FLAG_DETACHED, FLAG_JUMP, JUMP_FACTOR  # noqa: F401 - names of 0.1
from gapsweep.sweep.methods.sde import SDE_HOST_SAMPLES_MAX, SDE_SUB_BINS  # noqa: F401 - names of 0.1
from gapsweep.sweep.schema import FLOAT_RESULTS, INT_RESULTS, STATUS, JobSpec, Task, TaskResult, Unit
from gapsweep.sweep.spec import check_extra

__all__ = [
    "FLOAT_RESULTS",
    "INT_RESULTS",
    "STATUS",
    "Context",
    "Task",
    "TaskResult",
    "Unit",
    "check_extra",
    "estimate_cost",
    "expand",
    "make_units",
    "needs_gpu",
    "run_task",
    "run_unit",
    "shard_units",
]


def expand(spec: JobSpec) -> list[Task]:
    """All tasks of a job in canonical order (method, hurst, rho, seed, n, sigma0). Ids are unique."""
    out: list[Task] = []
    for name, m in registry.all_methods().items():
        if name in spec.methods:
            out.extend(m.expand(spec))
    ids = [t.task_id for t in out]
    if len(set(ids)) != len(ids):  # pragma: no cover - only on a hash collision
        raise RuntimeError("duplicate task ids")
    return out


def estimate_cost(t: Task) -> float:
    """Rough wall time of a task on one CPU core [s] (the method's cost model); only ratios matter."""
    return registry.get(t.method).cost(t)


def needs_gpu(t: Task) -> bool:
    """A task that must run on a rank with a GPU (the method decides: SDE on CUDA, GFMD with cupy)."""
    return registry.get(t.method).needs_gpu(t)


def _set_key(t: Task) -> str:
    """Key of the tasks that share an expensive input and run as one set (the method decides), or ""."""
    return registry.get(t.method).set_key(t)


def make_units(tasks: list[Task]) -> list[Unit]:
    """Group chained tasks (same ``chain`` key) in their expansion order, and discrete-theory tasks of one
    surface into a set; others are single-task units. Units are sorted largest cost first (ties by first task
    id), the order a coordinator hands them out."""
    chains: OrderedDict[str, list[int]] = OrderedDict()
    sets: OrderedDict[str, list[int]] = OrderedDict()
    units: list[Unit] = []
    for i, t in enumerate(tasks):
        if t.chain:
            chains.setdefault(t.chain, []).append(i)
        elif key := _set_key(t):
            sets.setdefault(key, []).append(i)
        else:
            units.append(Unit((i,), estimate_cost(t), needs_gpu(t)))
    for kind, groups in (("chain", chains), ("set", sets)):
        for idx in groups.values():
            # a set pays its surface's spectrum once (the first task's estimate), each further task ~1 ms
            cost = (sum(estimate_cost(tasks[i]) for i in idx) if kind == "chain"
                    else estimate_cost(tasks[idx[0]]) + 1e-3 * (len(idx) - 1))
            units.append(Unit(tuple(idx), cost, any(needs_gpu(tasks[i]) for i in idx),
                              kind if len(idx) > 1 else "single"))
    units.sort(key=lambda u: (-u.cost, tasks[u.tasks[0]].task_id))
    return units


def shard_units(units: list[Unit], index: int, count: int) -> list[Unit]:
    """Units of shard ``index`` of ``count``: greedy longest-processing-time split of the cost-sorted units
    (deterministic, balanced by estimated cost)."""
    if not (isinstance(count, int) and count >= 1 and isinstance(index, int) and 0 <= index < count):
        raise ValueError(f"shard must be i/n with 0 <= i < n, got {index}/{count}")
    load = [0.0] * count
    mine = []
    for u in units:
        k = min(range(count), key=lambda j: (load[j], j))
        load[k] += u.cost
        if k == index:
            mine.append(u)
    return mine


def run_unit(tasks: list[Task], unit: Unit, ctx: Context, todo: set[int] | None = None,
             ) -> Iterator[tuple[int, TaskResult]]:
    """Run a unit's tasks in order, yielding ``(task index, result)`` for those in ``todo`` (all if None).
    A chain runs from its start up to its last wanted task, so warm starts are the same as in a full run; a set
    runs only its wanted tasks; a batch unit runs through :func:`gapsweep.batching.run_batch`."""
    if unit.kind == "batch":
        yield from batching.run_batch(tasks, unit, ctx, set(unit.tasks) if todo is None else todo)
        return
    want = [i for i in unit.tasks if todo is None or i in todo]
    if not want:
        return
    run = unit.tasks[: unit.tasks.index(want[-1]) + 1] if unit.kind == "chain" else want
    state = None
    for i in run:
        res, state = run_task(tasks[i], ctx, state)
        if todo is None or i in todo:
            yield i, res
