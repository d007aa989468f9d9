"""gapsweep.sweep.collective's run loop and its refusals, in-process: a stand-in communicator plays one rank of
several (its ``allgather`` returns what the other ranks would say), so which units a rank runs, which rows rank 0
writes and how a stop request on any rank ends the run on every rank are checked without MPI or a solver. The
real collective solve on several ranks is tests/mpi/test_collective.py."""

from __future__ import annotations

from typing import Any

import pytest

from gapsweep.sweep import collective, runner
from gapsweep.sweep import spec as specmod
from gapsweep.sweep.limits import Stop
from gapsweep.sweep.schema import TaskResult, Unit


class Comm:
    """One rank of ``size``; ``others``: the stop signals the other ranks report at each allgather, in turn."""

    def __init__(self, rank: int, size: int, others: list[list[int]] | None = None) -> None:
        self.rank, self.size, self.others, self.gathers = rank, size, list(others or []), 0

    def Get_rank(self) -> int:  # mpi4py's names
        return self.rank

    def Get_size(self) -> int:
        return self.size

    def allgather(self, mine: int) -> list[int]:
        self.gathers += 1
        rest = self.others.pop(0) if self.others else [0] * (self.size - 1)
        return [*rest[: self.rank], mine, *rest[self.rank:]]


class T:
    """A stand-in task: only its ``distributed`` option matters here."""

    def __init__(self, distributed: bool) -> None:
        self.d = distributed

    def opt(self, k: str) -> Any:
        return self.d if k == "distributed" else None


class Ctx:
    comm: Any = None


# tasks 0, 1: a distributed chain; 2: a theory-like task (rank 0 alone); 3, 4: another distributed chain
TASKS = [T(True), T(True), T(False), T(True), T(True)]
UNITS = [Unit((0, 1), 1.0, kind="chain"), Unit((2,), 1.0), Unit((3, 4), 1.0, kind="chain")]


def _run(comm: Comm, todo: set[int], stop: Stop | None = None, work: list[int] | None = None,
         ) -> tuple[list[tuple[int, int]], list[int]]:
    """Run the loop; returns (unit, task) in the order run_unit yielded them and the rows written."""
    ran: list[tuple[int, int]] = []
    written: list[int] = []

    def run_unit(tasks: list, unit: Unit, ctx: Any, want: set[int], limit: Any, stop_: Any) -> Any:
        assert limit is None and stop_ is None and ctx.comm is comm  # collective: no limit, no per-task stop
        for i in unit.tasks:
            if i in want:
                ran.append((UNITS.index(unit), i))
                yield i, TaskResult("done", "", {})

    collective.run_collective(comm, TASKS, UNITS, [0, 1, 2] if work is None else work, Ctx(), run_unit, todo,
                              lambda i, res: written.append(i), stop or Stop("flag"))
    return ran, written


def test_rank0_runs_every_unit_and_writes_every_row() -> None:
    ran, written = _run(Comm(0, 3), {0, 1, 2, 3, 4})
    assert ran == [(0, 0), (0, 1), (1, 2), (2, 3), (2, 4)] and written == [0, 1, 2, 3, 4]


def test_other_ranks_run_only_distributed_units_and_write_nothing() -> None:
    comm = Comm(2, 3)
    ran, written = _run(comm, {0, 1, 2, 3, 4})
    assert ran == [(0, 0), (0, 1), (2, 3), (2, 4)] and written == []
    # every rank makes the same collective calls (a rank that made one more would hang the others): a gather
    # after each distributed row and after each unit, also after a unit it does not run
    zero = Comm(0, 3)
    _run(zero, {0, 1, 2, 3, 4})
    assert comm.gathers == zero.gathers == 2 + 1 + 1 + 2 + 1


def test_only_work_and_todo_run() -> None:
    ran, written = _run(Comm(0, 2), {1, 4}, work=[2, 0])  # the runner's order of units with work
    assert ran == [(2, 4), (0, 1)] and written == [4, 1]


def test_a_signal_to_another_rank_stops_every_rank() -> None:
    """Rank 1 alone got SIGTERM (15) during the first row: rank 0 writes that row, adopts the signal and runs
    nothing more."""
    stop = Stop("flag")
    ran, written = _run(Comm(0, 2, others=[[15]]), {0, 1, 2, 3, 4}, stop=stop)
    assert ran == [(0, 0)] and written == [0] and stop.signum == 15
    own = Stop("flag")
    own.signum = 2  # this rank's own SIGINT: the others learn it from the gather; nothing runs after the row
    ran, _ = _run(Comm(1, 2), {0, 1, 2, 3, 4}, stop=own)
    assert ran == [(0, 0)] and own.signum == 2


def test_refusals(tmp_path: Any) -> None:
    """Options that a collective run cannot honour, and a job without distributed tasks (nothing to check)."""
    from tests.storekit import UNITS_JOB

    dist = [T(True)]
    for timeout, batch in ((10.0, "off"), (None, "auto")):
        with pytest.raises(runner.RunError, match="--task-timeout and --batch do not apply"):
            collective.check_options(dist, timeout, batch)
    collective.check_options(dist, None, "off")
    collective.check_options([T(False)], 10.0, "all")  # not collective: the farm takes both
    tasks = runner._select(specmod.load(UNITS_JOB), None)[0]
    assert not collective.is_collective(tasks) and collective.check(tasks, 4) == []
