"""Several jobs of one launch through one farm (issue 38; docs/architecture.md, "The farm"; docs/running.md).

``gapsweep run A.toml B.toml --store a.h5 --store b.h5`` used to run the jobs one after the other, a farm each:
every job paid its own tail (the workers idle while the job's last, longest unit finished), its barriers and the
next job's start (store, placement) while every worker waited. With ``--farm together`` (the default for several
jobs) every job is prepared and its store opened first, then **one farm** runs the units of all of them, the
longest first whatever job they belong to (the same cost model: gapsweep.sweep.tasks), and each job's run is
recorded and its store closed at the end, in order.

Nothing about a row changes: a unit runs with its own job's context (surfaces, kept fields, writer), a chain
runs from its start on one worker with the same warm starts, and every row goes to its job's store -- so each
store is bit-identical (all but wall time and rank) to one of a separate run (tests/test_launch.py). Each
store's run record says the job shared its farm (``farm``: the stores of the launch).

:class:`Joint` is the farm drivers' view (gapsweep.sweep.runner: ``_serial``, ``_coordinate``, ``_work``) of the
jobs' runs (``runner._Run`` objects, started): their units and tasks numbered in one range (task ``i`` of job
``j`` is ``offset[j] + i``), rows routed to the job's store and progress, one stop request for all of them
(signals; any job's ``STORE.stop`` file). It falls back to one farm per job (logged) where a joint farm does not
apply: a distributed job (every rank solves each task together), or jobs whose GPU placement differs (the
ranks per GPU a job's GPU memory allows).
"""

from __future__ import annotations

import bisect
import logging
import signal
import time
from collections.abc import Iterator, Sequence
from pathlib import Path
from types import SimpleNamespace
from typing import Any

from gapsweep.sweep import limits, runner
from gapsweep.sweep.limits import Interrupted
from gapsweep.sweep.schema import TaskResult, Unit
from gapsweep.sweep.store import StoreWriteError

__all__ = ["FARM_MODES", "Joint", "run_jobs"]

log = logging.getLogger(__name__)

FARM_MODES = ("together", "each")


class _Stops(limits.Stop):
    """One stop request for every job of a joint farm: the signals (installed once) and any job's stop file; the
    callbacks of every job's rank-0 writer (``on_request``: each store says interrupted at once)."""

    def __init__(self, mode: str, files: Sequence[Path]) -> None:
        super().__init__(mode, None)
        self.files = list(files)
        self._calls: list[Any] = []

    def requested(self) -> bool:
        if self.signum is None and any(f.exists() for f in self.files):
            self.signum = signal.SIGTERM
        return self.signum is not None

    @property  # type: ignore[override]
    def on_request(self) -> Any:
        if not self._calls:
            return None
        return lambda sig: [f(sig) for f in self._calls]

    @on_request.setter
    def on_request(self, f: Any) -> None:
        if f is not None:
            self._calls.append(f)


class _Rows:
    """A joint farm's store and progress: a row of task ``i`` goes to its job's store (``write``) and is counted
    for its job (``update``)."""

    def __init__(self, joint: Joint, what: str) -> None:
        self.joint, self.what = joint, what

    def write(self, i: int, res: TaskResult) -> None:
        j, li = self.joint.owner_task(i)
        self.joint.runs[j].st.write(li, res)

    def update(self, res: TaskResult, i: int | None = None) -> None:
        j, _ = self.joint.owner_task(i)
        self.joint.runs[j].prog.update(res)


class Joint:
    """The jobs' started runs (``runner._Run``, one per job, in the launch's order) as one run of the farm drivers
    (see the module doc). Unit ``k`` of the joint farm is unit ``k - unit_offset[j]`` of job ``j``."""

    def __init__(self, runs: list[Any]) -> None:
        self.runs = runs
        first = runs[0]
        self.comm, self.rank, self.size, self.wmode = first.comm, first.rank, first.size, first.wmode
        self.works, self.lookahead, self.limit = first.works, first.lookahead, first.limit
        self.together = False
        gpu_runs = [r for r in runs if r.gpu_of and any(g is not None for g in r.gpu_of)]
        lead = gpu_runs[0] if gpu_runs else first
        self.gpu, self.gpu_of = lead.gpu, lead.gpu_of
        self.ctx = lead.ctx
        for r in runs:  # the jobs' surface caches (host and GPU) share one context's budget: a worker holds no more
            if r.ctx is not None:  # surfaces than a farm of one job (a unit runs its chain on one surface anyway)
                r.ctx._max = max(1, r.ctx._max // len(runs))
        self.task_offset, self.unit_offset = [], []
        self.tasks: list[Any] = []
        self.units: list[Unit] = []
        self.todo: set[int] = set()
        for r in runs:
            off = len(self.tasks)
            self.task_offset.append(off)
            self.unit_offset.append(len(self.units))
            self.tasks.extend(r.tasks)
            self.units.extend(u.remap({i: i + off for i in u.tasks}) for u in r.units)
            self.todo |= {i + off for i in r.todo}
        # the units to run, largest estimated cost first across the jobs (ties: the launch's order, then each
        # job's own order -- the order a job's farm alone would hand them out)
        work = [(k + self.unit_offset[j], j, n) for j, r in enumerate(runs) for n, k in enumerate(r.work)]
        self.work = [k for k, _, _ in sorted(work, key=lambda x: (-self.units[x[0]].cost, x[1], x[2]))]
        self.st = _Rows(self, "st") if any(r.st is not None for r in runs) else None
        self.prog = _Rows(self, "prog")
        self.stop = first.stop  # shared by every run (share_stop)
        self.next_check = 0.0

    @staticmethod
    def applies(runs: list[Any]) -> str:
        """"" when the runs can share one farm, else why not (one line)."""
        if any(r.together for r in runs):
            return "a distributed job (every rank solves each of its tasks together) runs in a farm of its own"
        placed = {tuple(r.gpu_of) for r in runs if r.gpu_of and any(g is not None for g in r.gpu_of)}
        if len(placed) > 1:
            return "the jobs' GPU placements differ (the ranks per GPU their GPU memory allows)"
        return ""

    # -- numbering ------------------------------------------------------------------------------------------
    def owner_task(self, i: int | None) -> tuple[int, int]:
        j = bisect.bisect_right(self.task_offset, i) - 1
        return j, i - self.task_offset[j]

    def owner_unit(self, k: int) -> tuple[int, int]:
        j = bisect.bisect_right(self.unit_offset, k) - 1
        return j, k - self.unit_offset[j]

    # -- what the farm drivers call -------------------------------------------------------------------------
    def units_of(self, k: int, skip: frozenset[int]) -> Iterator[tuple[int, TaskResult]]:
        j, lk = self.owner_unit(k)
        off = self.task_offset[j]
        for i, res in self.runs[j].units_of(lk, frozenset(i - off for i in skip)):
            yield i + off, res

    def ahead_ok(self) -> list[bool]:
        return [x for r in self.runs for x in r.ahead_ok()]

    def prefetch(self, k: int) -> None:
        j, lk = self.owner_unit(k)
        self.runs[j].prefetch(lk)

    def ended(self, farm: Any) -> None:
        """Each job's outcome from the joint farm: the device faults (every job's record names them), its units
        taken out for want of a GPU, its rows recorded."""
        for j, r in enumerate(self.runs):
            lo, hi = self.unit_offset[j], self.unit_offset[j] + len(r.units)
            off = self.task_offset[j]
            view = SimpleNamespace(
                faults=farm.faults, no_gpu=farm.no_gpu if any(lo <= k < hi for k in farm.left) else "",
                left=[k - lo for k in farm.left if lo <= k < hi],
                recorded={k - lo: {i - off for i in v} for k, v in farm.recorded.items() if lo <= k < hi})
            r.ended(view)


def share_stop(runs: list[Any]) -> _Stops:
    """One stop request for the runs of a launch (started: their rank-0 callbacks set): the jobs' own signal
    handlers are put back (in reverse order: the handlers before the launch), a signal one of them took is the
    shared one's, and every run's ``stop`` is the shared one (a signal then stops whichever job's farm runs)."""
    stops = [r.stop for r in runs]
    shared = _Stops(stops[0].mode, [s.stop_file for s in stops if s.stop_file is not None])
    for s in reversed(stops):
        if s.signum is not None and shared.signum is None:
            shared.signum = s.signum
        if s.on_request is not None:
            shared.on_request = s.on_request
        s.restore()
    shared.install()
    for r in runs:
        r.stop = shared
    return shared


def run_jobs(jobs: Sequence[Any], stores: Sequence[Any], *, farm: str = "together", **kw: Any,
             ) -> list[dict[str, Any]]:
    """Run several jobs of one launch (``gapsweep run J1 J2 ... --store S1 --store S2 ...``): through one farm
    (``farm="together"``, see the module doc) or one farm each, in order (``"each"``: as before issue 38). The
    options are :func:`gapsweep.sweep.runner.run`'s (the same for every job). Returns each job's summary."""
    if farm not in FARM_MODES:
        raise ValueError(f"--farm: expected one of {', '.join(FARM_MODES)}, got {farm!r}")
    if len(jobs) != len(stores):
        raise ValueError(f"--store: give one store per job ({len(jobs)} job(s), {len(stores)} store(s))")
    paths = [str(Path(x).resolve()) for x in stores]
    if len(set(paths)) != len(paths):
        raise ValueError("--store: each job needs a store of its own (a store path is given twice)")
    if farm == "each" or len(jobs) == 1 or kw.get("shard") is not None:
        return [runner.run(j, s, **kw) for j, s in zip(jobs, stores)]
    run_kw = {k: kw[k] for k in ("writer", "progress", "coordinator_works") if k in kw}
    prep_kw = {k: v for k, v in kw.items() if k not in run_kw}
    writer = run_kw.get("writer", "auto")
    progress = run_kw.get("progress", "auto")
    works = run_kw.get("coordinator_works", "auto")
    gpu_opts = (prep_kw.get("batch", "off"), prep_kw.get("ranks_per_gpu"), prep_kw.get("lookahead", 4))
    preps: list[runner.Prepared] = []
    try:
        for j, s in zip(jobs, stores):
            preps.append(runner._prepare(j, s, **prep_kw))
        return _joint(preps, writer, progress, works, prep_kw.get("task_timeout"), gpu_opts)
    finally:
        for p in preps:
            if p.held is not None:
                p.held.release()


def _finish(r: Any, summary: dict[str, Any], caught: Interrupted | None) -> Interrupted | None:
    """``r.finish`` (collective: every rank calls it for every job in the same order); an interruption is kept
    (the first) so that the later jobs record theirs too."""
    try:
        r.finish(summary)
    except Interrupted as e:
        return caught or e
    return caught


def _summary(p: runner.Prepared) -> dict[str, Any]:
    mode, todo_list, old_failed, _ = p.decision
    return {"store": str(p.path), "tasks": len(p.tasks), "todo": len(todo_list), "mode": mode, "mpi_size": p.size,
            "rank": p.rank, **dict.fromkeys(runner.STATUS, 0), "pending": 0, "unfinished": old_failed}


def _joint(preps: list[runner.Prepared], writer: str, progress: str, works: str, limit: float | None,
           gpu_opts: tuple) -> list[dict[str, Any]]:
    """The jobs with work through one farm (those with none: their summary as a run would give it)."""
    sums = [_summary(p) for p in preps]
    live = [n for n, p in enumerate(preps) if p.decision[0] != "noop"]
    for n, p in enumerate(preps):
        if n not in live and p.rank == 0 and progress != "none":
            log.info("%s: all %d tasks finished already; nothing to do", p.path, len(p.tasks))
    if not live:
        return sums
    p0 = preps[live[0]]
    wmode = runner._writer_mode(p0.comm, writer)
    runs = []
    for n in live:
        p = preps[n]
        sums[n]["writer"] = wmode
        r = runner._Run(p.spec, p.comm, p.tasks, p.units, p.path, p.shard_text, p.decision, wmode, progress, works,
                        limit, p.held, gpu_opts)
        r.reused = p.reused
        runs.append(r)
    stop = None
    try:
        for r in runs:
            r.start()
        stop = share_stop(runs)
        caught = _drive_all(runs, live, sums, p0)
        if caught is not None:
            raise caught
    except Interrupted as e:
        _interrupted(runs, p0, e)
        raise
    except (StoreWriteError, OSError) as e:
        _write_failed(runs, p0, wmode, e)
        raise
    except BaseException as e:
        if p0.comm is not None:
            runner._abort(p0.comm, p0.rank, wmode, runs[0].held, e, (runs[0].path, runs[0].run_id))
        raise
    finally:
        _close(runs, p0, stop)
    return sums


def _drive_all(runs: list[Any], live: list[int], sums: list[dict[str, Any]], p0: Any) -> BaseException | None:
    """Drive the started runs: one farm for all (Joint) or, where that does not apply, one farm per job in order;
    every store records its end (also after a stop request). Returns the first error of a store's end."""
    why = Joint.applies(runs)
    if why:  # one farm per job, in order (their stores are open already)
        if p0.rank == 0:
            log.info("farm: one farm per job (%s)", why)
        caught = None
        for r, n in zip(runs, live):
            runner._drive(r)
            caught = _finish(r, sums[n], caught)
        return caught
    joint = Joint(runs)
    names = [str(r.path) for r in runs]
    now = round(time.time(), 3)
    for r in runs:  # the record says the job shared its farm, and when that farm started
        r.record["farm"] = {"together_with": [x for x in names if x != str(r.path)]}
        if "farm_started_unix" in r.record:
            r.record["farm_started_unix"] = now
    if p0.rank == 0 and p0.comm is not None:
        log.info("farm: %d jobs in one farm (%d units)", len(runs), len(joint.work))
    runner._drive(joint)
    caught = None
    for r, n in zip(runs, live):  # every store records its end, also after a stop request
        caught = _finish(r, sums[n], caught)
    return caught


def _interrupted(runs: list[Any], p0: Any, e: Interrupted) -> None:
    """One process: each store records the interruption (with its counts) and is closed (under MPI the
    caller re-raises at once: the collective stop path records it)."""
    if p0.comm is not None:
        return
    for r in runs:
        if r.st is not None:
            try:
                r.interrupted(e)
            except Interrupted:
                pass


def _write_failed(runs: list[Any], p0: Any, wmode: str, e: BaseException) -> None:
    """A failed write: under MPI the job aborts; on one process every open store says why the launch stopped
    (the first store's RunError is raised in place of ``e``)."""
    if p0.comm is not None:
        runner._abort(p0.comm, p0.rank, wmode, runs[0].held, e, (runs[0].path, runs[0].run_id))
    first = None
    for r in runs:
        if r.st is not None:
            try:
                r.write_failed(e)
            except runner.RunError as err:
                first = first or err
    if first is not None:
        raise first from None


def _close(runs: list[Any], p0: Any, stop: Any) -> None:
    """Restore the signal handlers, close each run's context and (one process) its store."""
    if stop is not None:
        stop.restore()
    else:
        for r in reversed(runs):
            r.stop.restore()
    for r in runs:
        if r.ctx is not None:
            r.ctx.close()
        if r.st is not None and p0.comm is None:
            runner._abandon(r.st)
