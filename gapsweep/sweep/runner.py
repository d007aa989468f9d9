"""Running a job: one process, or an MPI task farm with a dynamic coordinator (docs/running.md).

* Serial (``gapsweep run JOB --store PATH``): units largest-first, each row written and flushed as it finishes.
* MPI (``mpiexec -n P gapsweep run ...``): rank 0 is the coordinator. Workers ask for work; rank 0 hands out
  units from the head of the cost-sorted queue (largest first). When P is small (default: P <= 4) rank 0 also
  works, in a thread that takes units from the tail (smallest first) so that serving requests is never held up
  by a long unit; MPI calls stay on rank 0's main thread.
* Writer: with an MPI-enabled h5py every rank opens the store with ``driver="mpio"``; the structure is created
  collectively up front and each rank writes its own rows (independent I/O). Otherwise (or with
  ``--writer rank0`` / ``GAPSWEEP_WRITER=rank0``) workers send their rows to rank 0, which writes them: the same
  file content.
* Any exception outside a task on any rank ends the job with ``comm.Abort(1)`` (a rank leaving a collective call
  would otherwise hang the others). Exceptions inside a task are recorded in its row and the sweep goes on.
* Reliability (docs/reliability.md): the store's lease is taken by the process (rank 0) that decides, before
  any HDF5 open for writing; a new store is created under a temporary name and renamed into place; the store is
  validated on resume and incomplete rows are re-run; a write error stops the run with one line; SIGINT/SIGTERM
  or a ``<store>.stop`` file end the run cleanly, recorded as interrupted (exit 130/143).
"""

from __future__ import annotations

import json
import logging
import os
import queue
import socket
import sys
import threading
import time
from collections import deque
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from gapsweep.sweep import batching, budget, gpus, lease, limits, provenance, storecheck
from gapsweep.sweep import methods as registry
from gapsweep.sweep import spec as specmod
from gapsweep.sweep.context import Context
from gapsweep.sweep.execute import run_task
from gapsweep.sweep.fields import fields_dir, remove_fields
from gapsweep.sweep.limits import Interrupted, TaskTimeout
from gapsweep.sweep.schema import STATUS, Task, TaskResult, Unit
from gapsweep.sweep.spec import check_extra
from gapsweep.sweep.store import Store, StoreError, StoreWriteError, open_read
from gapsweep.sweep.store import io_failed as store_io_failed
from gapsweep.sweep.tasks import estimate_cost, expand, make_units, shard_units

__all__ = ["Interrupted", "RunError", "parse_shard", "plan", "run"]

log = logging.getLogger("gapsweep.runner")

TAG_READY, TAG_WORK, TAG_ROW, TAG_STOP = 1, 2, 3, 4
_MPI_ENV = ("OMPI_COMM_WORLD_SIZE", "PMI_SIZE", "PMIX_RANK", "MPI_LOCALNRANKS", "PMI_RANK")
_MPI_SIZE_ENV = ("OMPI_COMM_WORLD_SIZE", "PMI_SIZE", "PMIX_SIZE", "MPI_LOCALNRANKS")


class RunError(RuntimeError):
    """The run cannot start as asked (store exists, belongs to another job, writer unavailable)."""


def parse_shard(text: str | None) -> tuple[int, int] | None:
    """``"i/n"`` -> (i, n); ``"slurm"`` -> from ``SLURM_ARRAY_TASK_ID`` (minus ``SLURM_ARRAY_TASK_MIN``) and
    ``SLURM_ARRAY_TASK_COUNT``; None -> None."""
    if text is None:
        return None
    if text == "slurm":
        try:
            i = int(os.environ["SLURM_ARRAY_TASK_ID"]) - int(os.environ.get("SLURM_ARRAY_TASK_MIN", "0"))
            n = int(os.environ["SLURM_ARRAY_TASK_COUNT"])
        except (KeyError, ValueError):
            raise ValueError("--shard slurm: SLURM_ARRAY_TASK_ID and SLURM_ARRAY_TASK_COUNT must be set "
                             "(run inside a Slurm array job)") from None
    else:
        try:
            a, b = text.split("/")
            i, n = int(a), int(b)
        except ValueError:
            raise ValueError(f"--shard: expected i/n (0 <= i < n) or 'slurm', got {text!r}") from None
    if not (n >= 1 and 0 <= i < n):
        raise ValueError(f"--shard: expected i/n with 0 <= i < n, got {i}/{n}")
    return i, n


def _launcher_size() -> int:
    """Number of ranks the MPI launcher started, from its environment (1 when not under a launcher)."""
    for k in _MPI_SIZE_ENV:
        v = os.environ.get(k, "")
        if v.isdigit() and int(v) > 0:
            return int(v)
    return 1


def _comm(mpi: str) -> Any:
    """COMM_WORLD when launched by an MPI launcher (or ``mpi="on"``) and its size is > 1, else None.

    Refuses (RunError, on every rank) a launch of several ranks with ``mpi="off"`` -- each would run the whole
    job into the same store -- and an mpi4py that sees one rank where the launcher started several (mpi4py
    built against another MPI library)."""
    launched = _launcher_size()
    if mpi == "off":
        if launched > 1:
            raise RunError(f"started by an MPI launcher with {launched} ranks but with --mpi off: every rank would "
                           "run the whole job; drop --mpi off, or start one process")
        return None
    if mpi == "auto" and not any(k in os.environ for k in _MPI_ENV):
        return None
    try:
        from mpi4py import MPI
    except ImportError as e:
        raise RunError(f"MPI requested or launcher detected, but mpi4py cannot be imported ({e})") from None
    comm = MPI.COMM_WORLD
    if launched > 1 and comm.size != launched:
        raise RunError(f"the MPI launcher started {launched} ranks but mpi4py sees {comm.size}: mpi4py is built "
                       "against another MPI library than the launcher's (see docs/running.md)")
    return comm if comm.size > 1 else None


def _select(spec: specmod.JobSpec, shard: tuple[int, int] | None, batch: str = "off",
            ) -> tuple[list[Task], list[Unit]]:
    """Tasks of the job (or of one shard) in canonical order and their units (indices into that list); GFMD
    chains that batch on a GPU rank are grouped into batch units (gapsweep.batching) before sharding."""
    tasks_all = expand(spec)
    units = batching.batch_units(tasks_all, make_units(tasks_all), mode=batch)
    if shard is not None:
        units = shard_units(units, *shard)
    sel = sorted({i for u in units for i in u.tasks})
    remap = {old: new for new, old in enumerate(sel)}
    return [tasks_all[i] for i in sel], [u.remap(remap) for u in units]


def _load(job: str | Path | specmod.JobSpec) -> specmod.JobSpec:
    """Load and validate a spec, including its ``extra`` keys against the solvers' signatures."""
    if isinstance(job, specmod.JobSpec):
        check_extra(job)
        return job
    spec = specmod.load(job)
    try:
        check_extra(spec)
    except specmod.SpecError as e:
        raise specmod.SpecError(f"{job}: {e}") from None
    return spec


def plan(job: str | Path | specmod.JobSpec, shard: tuple[int, int] | None = None, ranks: int = 1,
         store: str | Path | None = None, ranks_per_gpu: int = 1) -> str:
    """Text summary of a job: tasks per method, units, cost estimate (core-seconds and wall time on ``ranks``),
    peak memory per rank and store size. Raises ``SpecError`` for what cannot run (an ``extra`` key the solver
    does not take) and ``RunError`` for what will not fit (memory of this machine, free disk at ``store``)."""
    if not isinstance(ranks, int) or ranks < 1:
        raise ValueError(f"--ranks: expected an integer >= 1, got {ranks!r}")
    spec = _load(job)
    tasks, units = _select(spec, shard)
    lines = [f"job {spec.name!r}: {len(tasks)} tasks in {len(units)} units"
             + (f" (shard {shard[0]}/{shard[1]})" if shard else "")]
    by: dict[str, list[float]] = {}
    for u in units:
        for i in u.tasks:
            by.setdefault(tasks[i].method, [])

    for t in tasks:
        by[t.method].append(estimate_cost(t))
    for m, c in by.items():
        lines.append(f"  {m:14s} {len(c):7d} tasks  ~{sum(c):10.1f} core-s  (max {max(c):.2f} s per task)")
    total = sum(u.cost for u in units)
    longest = max((u.cost for u in units), default=0.0)
    lines.append(f"  estimated cost ~{total:.1f} core-s; on {ranks} rank(s) ~{max(total / ranks, longest):.1f} s "
                 "wall (rough model, see docs/jobs.md)")
    size = budget.store_bytes(len(tasks), spec.histogram["bins"], len(spec.text))
    lines.extend(_check_resources(tasks, ranks_per_gpu))
    lines.append(f"  store ~{budget.human(size)}")
    if store is not None:
        path = _store_path(store, shard)
        free = budget.disk_free(path.parent)
        lines.append(f"  free disk at {path.parent}: {budget.human(free)}")
        if size > free:
            raise RunError(f"store {path}: needs ~{budget.human(size)}, only {budget.human(free)} free there")
    return "\n".join(lines)


def _check_resources(tasks: list[Task], ranks_per_gpu: int = 1) -> list[str]:
    """The memory a rank needs (and the GPU memory of its GPU tasks), the same check for ``plan`` and ``run``:
    raises ``RunError`` for what will not fit this machine (its RAM; a visible GPU's memory), saying how much is
    needed. Returns the plan's lines."""
    mem = budget.peak_memory(tasks)
    lines = [f"  peak memory ~{budget.human(mem)} per rank"]
    ram = budget.memory_total()
    if ram and mem > ram:
        raise RunError(f"the job needs ~{budget.human(mem)} per rank, more than this machine's "
                       f"{budget.human(ram)}: use smaller grids (n, samples) or fewer tasks per job (shards)")
    need = budget.gpu_memory(tasks, ranks_per_gpu)
    if need:
        lines.append(f"  GPU memory ~{budget.human(need)} per GPU ({ranks_per_gpu} rank(s) per GPU)")
        have = budget.gpu_memory_total()
        if have and need > have:
            raise RunError(f"the GPU tasks need ~{budget.human(need)} per GPU, more than this GPU's "
                           f"{budget.human(have)}: use smaller grids (n), fewer ranks per GPU, or a larger GPU")
    return lines


def _store_path(path: str | Path, shard: tuple[int, int] | None) -> Path:
    p = str(path)
    if shard is None and ("{i}" in p or "{n}" in p):  # else a file literally named x{i}.h5 (issue 19)
        raise ValueError(f"--store {p}: {{i}} and {{n}} are filled in only with --shard i/n; pass --shard or "
                         "name the store without them")
    if shard is not None:
        p = p.replace("{i}", str(shard[0])).replace("{n}", str(shard[1]))
    return Path(p)


def _decide(path: Path, spec: specmod.JobSpec, tasks: list[Task], shard_text: str, resume: bool,
            overwrite: bool) -> tuple[str, list[int]]:
    """('create' | 'resume' | 'noop', task indices to run). Raises RunError when the store cannot be used.
    On resume the store is validated (docs/reliability.md): pending rows, rows of unknown status and done rows
    without a complete result are run again."""
    if not path.exists() or overwrite:
        size = budget.store_bytes(len(tasks), spec.histogram["bins"], len(spec.text))
        free = budget.disk_free(path.parent)
        if size > free:
            raise RunError(f"store {path}: needs ~{budget.human(size)}, only {budget.human(free)} free there")
        try:  # a file-size limit (ulimit -f) would otherwise fail inside the collective creation under mpio
            budget.probe_growth(path, min(size, budget.PROBE_BYTES), size=size)
        except OSError as e:
            raise RunError(f"store {path}: cannot be created ({e.strerror}: full disk or file-size limit, "
                           f"~{budget.human(size)} needed); nothing was written") from None
        return "create", list(range(len(tasks)))
    try:
        with open_read(path, check=False) as f:
            report = storecheck.check(f, path, tolerate_tasks=resume)  # once: it reads and checksums every row
            sha, shard = f.attrs.get("spec_sha256"), f.attrs.get("shard")
            ids = [x.decode() for x in f["tasks"].fields("task_id")[...]] if f["tasks"].shape[0] else []
            todo = storecheck.incomplete_rows(f, path, report)
            damaged = set(report.damaged)
    except (OSError, StoreError) as e:
        raise RunError(f"{e}; pass --overwrite to replace it") from None
    if isinstance(sha, bytes):
        sha = sha.decode()
    want = [t.task_id for t in tasks]
    # rows whose task parameters were damaged (checksum mismatch) are rewritten from the spec and run again
    moved = {i for i, (a, b) in enumerate(zip(ids, want)) if a != b}
    if report.tasks_damaged:  # format 4: /tasks failed its checksum, the rows that differ are the damage
        damaged |= moved
        todo = sorted(set(todo) | moved)
    if sha not in (spec.sha256, spec.text_sha256) or shard != shard_text or len(ids) != len(want) \
            or not moved <= damaged:
        raise RunError(f"store {path} was written for another job spec or shard; pass --overwrite to replace "
                       "it or choose another --store")
    if not todo:
        return "noop", []
    if not resume:
        raise RunError(f"store {path} exists with {len(todo)} of {len(tasks)} tasks pending: pass --resume to "
                       "finish it or --overwrite to start again")
    try:
        budget.probe_growth(path)
    except OSError as e:
        raise RunError(f"store {path}: no room to record a new run ({e.strerror}: full disk or file-size "
                       "limit); nothing was changed: free space and run again") from None
    return "resume", todo


class Progress:
    """Rank 0's progress: a tqdm bar on a terminal, plain log lines (every ``every`` s) otherwise."""

    def __init__(self, total: int, mode: str = "auto", every: float = 10.0) -> None:
        self.total, self.count = total, dict.fromkeys(STATUS, 0)
        self.t0 = self.last = time.monotonic()
        self.every = every
        tty = sys.stderr.isatty()
        self.mode = ("bar" if tty else "log") if mode == "auto" else mode
        self.bar = None
        if self.mode == "bar" and total:
            try:
                from tqdm import tqdm
            except ImportError:  # the `progress` extra is not installed: log lines instead of a bar
                self.mode = "log"
            else:
                self.bar = tqdm(total=total, unit="task", dynamic_ncols=True, file=sys.stderr)

    def update(self, res: TaskResult) -> None:
        self.count[res.status] += 1
        if self.bar is not None:
            self.bar.update(1)
            self.bar.set_postfix(failed=self.count["failed"], not_conv=self.count["not_converged"], refresh=False)
        elif self.mode == "log":
            t = time.monotonic()
            if t - self.last >= self.every:
                self.last = t
                log.info(self.line())

    def line(self) -> str:
        n = sum(self.count.values())
        el = time.monotonic() - self.t0
        eta = el / n * (self.total - n) if n else float("nan")
        return (f"{n}/{self.total} finished ({self.count['done']} done, {self.count['failed']} failed, "
                f"{self.count['not_converged']} not converged), {self.total - n} remaining, "
                f"elapsed {el:.1f} s, ETA {eta:.1f} s")

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()
        if self.mode != "none":
            log.info(self.line())


def _run_unit(tasks: list[Task], unit: Unit, ctx: Context, todo: set[int], limit: float | None,
              stop: limits.Stop | None) -> Iterator[tuple[int, TaskResult]]:
    """Run a unit's tasks in order, yielding ``(task index, result)`` for those in ``todo``; a chain runs from
    its start up to its last wanted task, so warm starts are the same as in a full run. ``limit``: per-task
    wall-time limit [s] (an overrunning task is a failed row, ``timeout: ...``). In flag mode (MPI) a stop
    request ends the unit after the current task."""
    if unit.kind == "batch":  # GFMD chains run side by side, one batched solve per chain step
        yield from batching.run_batch(tasks, unit, ctx, todo, limit, stop)
        return
    want = [i for i in unit.tasks if i in todo]
    if not want:
        return
    # a chain runs from its start (warm starts as in a full run); a set of independent tasks only what is wanted
    run = unit.tasks[: unit.tasks.index(want[-1]) + 1] if unit.kind == "chain" else want
    state = None
    for i in run:
        res, state = run_task(tasks[i], ctx, state) if not limit else _run_limited(tasks[i], ctx, state, limit)
        if i in todo:
            yield i, res
        if stop is not None and stop.mode == "flag" and stop.requested():
            return


def _run_limited(t: Task, ctx: Context, state: Any, limit: float) -> tuple[TaskResult, Any]:
    """Run a task under ``--task-timeout``: its method is warmed up first, outside the limit (imports, JIT
    compilation, kernel builds: a cold cache must not time out, and nothing asynchronous may interrupt a
    compiler), then the limit is kept between the solver's iterations (limits.task_limit). A timed-out task is a
    failed row whose message says so; ``--resume`` runs it again."""
    warm_up(t, ctx)
    msg = limits.timeout_message(limit)
    try:
        with limits.task_limit(limit):
            res, state = run_task(t, ctx, state)
    except TaskTimeout:  # the late asynchronous fallback, delivered just after the task returned
        res, state = TaskResult("failed", msg, {"wall_time": limit, "rank": ctx.rank}), None
    if res.status == "failed" and limits.is_timeout(res.message):
        res.message, state = msg, None
    return res, state


def warm_up(t: Task, ctx: Context) -> None:
    """The method's warm-up for this kind of task, once per process (registry: ``Method.warm_up``)."""
    key = registry.get(t.method).warm_up_key(t)
    if key is None or key in ctx.warmed:
        return
    ctx.warmed.add(key)
    try:
        registry.get(t.method).warm_up(t, ctx)
    except Exception as e:  # the task itself will meet (and record) the same problem
        log.debug("warm-up of %s failed: %s: %s", t.method, type(e).__name__, e)


def run(job: str | Path | specmod.JobSpec, store: str | Path, *, resume: bool = False, overwrite: bool = False,
        shard: tuple[int, int] | None = None, writer: str = "auto", progress: str = "auto",
        coordinator_works: str = "auto", mpi: str = "auto", break_lease: bool = False,
        task_timeout: float | None = None, batch: str = "off", ranks_per_gpu: int = 1) -> dict[str, Any]:
    """Run a job into a store (serially or as an MPI task farm). Returns a summary dict on every rank.

    ``writer``: auto | mpio | rank0 (env ``GAPSWEEP_WRITER`` overrides auto); ``progress``: auto | bar | log |
    none; ``coordinator_works``: auto (rank 0 works when P <= 4) | yes | no; ``mpi``: auto | on | off;
    ``break_lease``: take over the lease of a run that is gone; ``task_timeout``: per-task wall-time limit [s];
    ``batch``: off (default: one solve at a time, faster in the sweep) | auto (GFMD chains batched on GPU ranks,
    gapsweep.batching) | all (also CPU backends: for tests and comparisons); ``ranks_per_gpu``: ranks sharing
    one GPU (gapsweep.gpus).

    Raises :class:`RunError` when the run cannot start or a write fails (rows finished before stay done),
    :class:`~gapsweep.limits.Interrupted` after a clean stop on SIGINT/SIGTERM or a ``<store>.stop`` file (the
    run is recorded as interrupted in the store)."""
    if resume and overwrite:
        raise ValueError("--resume and --overwrite exclude each other: --resume keeps the finished rows, "
                         "--overwrite discards them")
    if task_timeout is not None and not (isinstance(task_timeout, (int, float)) and 0 < task_timeout < 1e9):
        raise ValueError(f"--task-timeout: expected seconds > 0, got {task_timeout!r}")
    if batch not in batching.MODES:
        raise ValueError(f"--batch: expected one of {', '.join(batching.MODES)}, got {batch!r}")
    gpus.assign(None, 0, ranks_per_gpu)  # validates ranks_per_gpu
    spec = _load(job)
    comm = _comm(mpi)
    rank, size = (comm.rank, comm.size) if comm is not None else (0, 1)
    if os.environ.get("GAPSWEEP_TEST_PIDDIR"):  # test hook: lets a test kill -9 one particular rank
        Path(os.environ["GAPSWEEP_TEST_PIDDIR"], f"rank{rank}.pid").write_text(str(os.getpid()))
    tasks, units = _select(spec, shard, batch)
    _check_resources(tasks, ranks_per_gpu)  # the same refusal as `plan`
    path = _store_path(store, shard)
    shard_text = f"{shard[0]}/{shard[1]}" if shard else ""

    # Rank 0 takes the lease and decides (file system checks once), then shares: every rank raises the same
    # error. Nothing opens the store for writing before the lease is held.
    decision: Any = None
    held: lease.Lease | None = None
    if rank == 0:
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
            held = lease.acquire(path, break_lease=break_lease)
            decision = (*_decide(path, spec, tasks, shard_text, resume, overwrite), held.run_id)
            _stop_file(path).unlink(missing_ok=True)  # a stop request of an earlier run
        except Exception as e:  # every rank must learn about it, or the others wait in bcast forever
            decision = e if isinstance(e, RunError) else RunError(
                str(e) if isinstance(e, (lease.LeaseError, StoreError)) else f"store {path}: {e}")
            if held is not None:
                held.release()
                held = None
    if comm is not None:
        decision = comm.bcast(decision, root=0)
    if isinstance(decision, RunError):
        raise decision
    try:
        return _execute(spec, comm, rank, size, tasks, units, path, shard_text, decision, writer, progress,
                        coordinator_works, task_timeout, held, (batch, ranks_per_gpu))
    finally:
        if held is not None:
            held.release()


def _stop_file(path: Path) -> Path:
    return path.with_name(path.name + ".stop")


def _execute(spec: specmod.JobSpec, comm: Any, rank: int, size: int, tasks: list[Task], units: list[Unit],
             path: Path, shard_text: str, decision: tuple, writer: str, progress: str, coordinator_works: str,
             task_timeout: float | None, held: lease.Lease | None, gpu_opts: tuple[str, int] = ("auto", 1),
             ) -> dict[str, Any]:
    mode, todo_list, run_id = decision
    summary: dict[str, Any] = {"store": str(path), "tasks": len(tasks), "todo": len(todo_list), "mode": mode,
                               "mpi_size": size, "rank": rank, **dict.fromkeys(STATUS, 0)}
    if mode == "noop":
        if rank == 0 and progress != "none":
            log.info("%s: all %d tasks finished already; nothing to do", path, len(tasks))
        return summary

    req = os.environ.get("GAPSWEEP_WRITER", "auto") if writer == "auto" else writer
    if req not in ("auto", "mpio", "rank0"):
        raise RunError(f"writer must be auto, mpio or rank0, got {req!r}")
    import h5py

    if comm is None:
        wmode = "serial"
    elif req == "rank0" or (req == "auto" and not h5py.get_config().mpi):
        wmode = "rank0"
    elif not h5py.get_config().mpi:
        raise RunError("writer 'mpio' needs h5py built with MPI (h5py.get_config().mpi is False)")
    else:
        wmode = "mpio"
    summary["writer"] = wmode
    stop = limits.Stop("raise" if comm is None else "flag", _stop_file(path)).install()
    st: Store | None = None
    prog: Progress | None = None
    record: dict[str, Any] = {}
    try:
        # Static attributes and the run record come from rank 0 so that every rank writes identical values.
        hosts = sorted(set(comm.allgather(socket.gethostname()))) if comm is not None else [socket.gethostname()]
        attrs = provenance.store_attrs(spec, shard=shard_text) if rank == 0 else None
        # rank 0 works (in a thread, beside coordinating) when asked, or by default with few ranks
        works = comm is None or coordinator_works == "yes" or (coordinator_works == "auto" and size <= 4)
        need_gpu = any(u.gpu for u in units)
        gpu = gpus.rank_gpu(comm, works, gpu_opts[1]) if need_gpu else None
        gpu_ranks = comm.allgather(gpu) if comm is not None else [gpu]
        record = {"started": provenance.now(), "finished": None, "mpi_size": size, "hosts": hosts,
                  "writer": wmode, "mode": mode, "todo": len(todo_list), "run_id": run_id,
                  **(provenance.run_extras(spec, gpu_ranks=gpu_ranks, batch=gpu_opts[0],
                                           batch_units=sum(u.kind == "batch" for u in units)) if rank == 0 else {})}
        if comm is not None:
            attrs, record = comm.bcast((attrs, record), root=0)
        ctx = Context(rank=rank, gpu=gpu)
        ctx.fields_dir = _fields_dir(path)  # kept GFMD fields, if the spec asks (gapsweep.dataset)
        todo = set(todo_list)
        work = [k for k, u in enumerate(units) if any(i in todo for i in u.tasks)]
        if wmode == "mpio" or rank == 0:
            with stop.critical():
                st = _open_store(path, mode, tasks, attrs, spec.histogram["bins"], comm if wmode == "mpio" else None,
                                 rank, run_id)
                if held is not None:  # the file opened is the one leased (issue 19: keyed by device and inode)
                    held.bind(path)
                runs = json.loads(st.f.attrs.get("runs", "[]"))
                st.set_attrs({"runs": json.dumps([*runs, record])}, flush=True)  # survives a kill -9
        if os.environ.get("GAPSWEEP_TEST_ABORT_RANK", "") == str(rank):
            raise RuntimeError(f"injected error on rank {rank} (GAPSWEEP_TEST_ABORT_RANK)")
        prog = Progress(len(todo), progress if rank == 0 else "none")
        if comm is not None and rank == 0 and wmode == "rank0":  # issue 19: mpiexec's 1-s grace, see below
            stop.on_request = lambda sig: _mark_interrupted(st, record, prog, held, sig)
        if comm is None:
            for k in work:
                for i, res in _run_unit(tasks, units[k], ctx, todo, task_timeout, stop):
                    with stop.critical():  # a row written is a row counted (a signal acts after both)
                        st.write(i, res)
                        prog.update(res)
                    if stop.requested():  # the stop file (a signal raises by itself)
                        raise Interrupted(stop.signum)
        elif rank == 0:
            _coordinate(comm, tasks, units, work, todo, ctx, st, prog, works, wmode, gpu_ranks, task_timeout, stop)
        else:
            _work(comm, tasks, units, todo, ctx, st, wmode, task_timeout, stop)
        prog.close()
        counts = dict(prog.count)
        stopped = stop.signum if stop.requested() else None
        if comm is not None:
            counts, stopped = comm.bcast((counts, stopped) if rank == 0 else None, root=0)
            comm.Barrier()
        summary.update(counts)
        if stopped is not None:
            record.update(_interrupted(stopped, counts))
        else:
            record["finished"] = provenance.now()
        if comm is not None and wmode == "mpio":
            record = comm.bcast(record, root=0)
        if st is not None:
            _close_record(st, record)
            st = None
        if stopped is not None:
            raise Interrupted(stopped, counts)
    except Interrupted as e:
        if comm is not None or st is None:  # MPI: raised after the collective close above
            raise
        counts = dict(prog.count) if prog is not None else {}
        if prog is not None:
            prog.close()
        record.update(_interrupted(e.signum, counts))
        try:
            _close_record(st, record)
        except StoreError as w:
            log.error("%s", w)
        st = None
        raise Interrupted(e.signum, counts) from None
    except (StoreWriteError, OSError) as e:
        if comm is None:
            if st is not None:
                record.update(stopped=str(e)[:200], stopped_at=provenance.now())
                _abandon(st, record)
                st = None
            raise RunError(f"{e if isinstance(e, StoreWriteError) else f'store {path}: {e}'}; every row finished "
                           "before is intact: fix the cause (free space, file-size limit) and run again with "
                           "--resume") from None
        _abort(comm, rank, wmode, held, e)
    except BaseException as e:
        if comm is not None:
            _abort(comm, rank, wmode, held, e)
        raise
    finally:
        stop.restore()
        if st is not None and comm is None:
            _abandon(st)
    return summary


def _mark_interrupted(st: Store, record: dict[str, Any], prog: Progress, held: lease.Lease | None,
                      signum: int) -> None:
    """Rank 0 (rank-0 writer) as the farm starts stopping: record the interruption now, and mark the lease.
    Open MPI's mpiexec forwards SIGINT/SIGTERM to the ranks and SIGKILLs them 1 s later
    (``odls_base_sigkill_timeout``), usually before the tasks in flight finish; the store then still says
    interrupted, and the next run takes the dead run's lease over without --break-lease. A clean end
    rewrites the record with the final counts and releases the lease as usual. (Under mpio the attribute
    write is collective and cannot be done by rank 0 alone.)"""
    try:
        budget.probe_growth(st.path)  # a metadata write only where the file can grow
        runs = json.loads(st.f.attrs.get("runs", "[]"))
        runs[-1] = {**record, **_interrupted(signum, dict(prog.count))}
        st.set_attrs({"runs": json.dumps(runs)}, flush=True)
    except (OSError, StoreError) as e:
        log.warning("%s: cannot record the interruption early (%s)", st.path, e)
        return
    if held is not None:
        held.mark_interrupted()


def _interrupted(signum: int, counts: dict[str, int]) -> dict[str, Any]:
    name = limits.SIGNAL_NAMES.get(signum, f"signal {signum}")
    return {"interrupted": name, "interrupted_at": provenance.now(), "counts": counts}


def _open_store(path: Path, mode: str, tasks: list[Task], attrs: dict[str, Any], bins: int, comm: Any, rank: int,
                run_id: str) -> Store:
    """Open the store for writing; a new one is created under a temporary name and renamed into place
    (collectively under mpio), so that a store path never holds a half-created file."""
    if mode == "create":
        tmp = path.with_name(f".{path.name}.tmp-{run_id}")
        try:
            try:
                Store.create(tmp, tasks, attrs, bins, comm=comm).close()
            except StoreWriteError as e:
                raise StoreWriteError(f"store {path}: cannot be created ({str(e).split(': ', 1)[-1]}); "
                                      "nothing was written") from None
            if comm is not None:
                comm.Barrier()
            if rank == 0:
                os.replace(tmp, path)
                # the kept fields of a store this one replaces (run --overwrite) must not outlive it
                gone = remove_fields(fields_dir(path))
                if gone:
                    log.info("store %s replaced: removed %d kept-field file(s) of the old store", path, gone)
            if comm is not None:
                comm.Barrier()
        except BaseException:
            if rank == 0:
                tmp.unlink(missing_ok=True)
            raise
    st = Store.open(path, comm=comm, repair_tasks=mode == "resume")
    if mode == "resume":  # task rows damaged since they were written come back from the spec (their rows re-run)
        fixed = st.repair_tasks(tasks, write=rank == 0)
        if fixed:
            log.warning("store %s: task parameters of %d damaged row(s) restored from the job spec: %s", path,
                        len(fixed), fixed[:5])
    return st


def _close_record(st: Store, record: dict[str, Any]) -> None:
    """Replace the run's record (the last one) and close the store (collective under mpio). The record is
    written only if the file can grow (budget.probe_growth; a failed metadata write can ruin an HDF5 file):
    otherwise it is left as it was (the run then reads as "running or killed") and a warning says why."""
    runs = json.loads(st.f.attrs.get("runs", "[]"))
    runs[-1] = record
    new = {"runs": json.dumps(runs)}
    if record.get("finished"):
        new["finished"] = record["finished"]
    ok: Any = True
    if st.comm is None or st.comm.rank == 0:
        try:
            budget.probe_growth(st.path)
        except OSError as e:
            ok = e.strerror
    if st.comm is not None:
        ok = st.comm.bcast(ok, root=0)
    try:
        if ok is True:
            st.set_attrs(new, flush=True)
        else:
            log.warning("%s: the run record was not updated (%s); every row is written", st.path, ok)
    finally:
        st.close()


def _abandon(st: Store, record: dict[str, Any] | None = None) -> None:
    """Close a store after an error (recording why the run stopped, if that can still be written) without
    letting a second error (a full disk again) escape."""
    try:
        if record is not None and not store_io_failed():
            _close_record(st, record)
        else:
            st.close()
    except Exception as e:  # the rows were flushed one by one; only this last flush is lost
        log.warning("closing %s after an error: %s", st.path, e)


def _abort(comm: Any, rank: int, wmode: str, held: lease.Lease | None, e: BaseException) -> None:
    log.error("rank %d: fatal error, aborting the MPI job: %s: %s", rank, type(e).__name__, e,
              exc_info=not isinstance(e, (StoreError, OSError)))
    if held is not None and wmode != "mpio":  # rank 0 alone wrote: its rows are flushed, the store is free
        held.release()
    sys.stderr.flush()
    comm.Abort(1)


def _coordinate(comm: Any, tasks: list[Task], units: list[Unit], work: list[int], todo: set[int], ctx: Context,
                st: Store | None, prog: Progress, works: bool, wmode: str, gpu_of: list[int | None],
                limit: float | None, stop: limits.Stop) -> None:
    """Rank 0: hand out units largest-first to workers, optionally work on the smallest ones in a thread,
    write rows sent by workers (rank0 writer) and track progress. A stop request (signal, stop file, a
    worker's TAG_STOP) empties the queue: the units in flight finish, then every rank leaves the farm."""
    from mpi4py import MPI

    q = deque(work)  # unit indices, largest first
    lock = threading.Lock()
    # GPU units wait for a GPU rank only if some rank that works has one; otherwise any rank takes them.
    any_gpu = any(g is not None for r, g in enumerate(gpu_of) if r > 0 or works)

    def take(from_tail: bool, gpu_ok: bool) -> int | None:
        with lock:
            order = range(len(q) - 1, -1, -1) if from_tail else range(len(q))
            if gpu_ok and any_gpu:
                # a GPU rank takes GPU units first: only GPU ranks can run them, so they are the critical path;
                # it helps with the CPU units once none is left
                for j in order:
                    if units[q[j]].gpu:
                        k = q[j]
                        del q[j]
                        return k
            for j in order:
                if not units[q[j]].gpu or gpu_ok or not any_gpu:
                    k = q[j]
                    del q[j]
                    return k
        return None

    results: queue.Queue = queue.Queue()

    def local_worker() -> None:
        try:
            while (k := take(True, gpu_of[0] is not None)) is not None:
                for item in _run_unit(tasks, units[k], ctx, todo, limit, stop):
                    results.put(item)
        except BaseException as e:  # surfaced on the main thread, which aborts the job
            results.put(e)
        results.put(None)

    thread = None
    if works:
        thread = threading.Thread(target=local_worker, name="gapsweep-rank0-worker", daemon=True)
        thread.start()
    local_alive = works
    active = set(range(1, comm.size))

    def handle(item: Any, local: bool) -> None:
        i, res = item
        # rank0 writer: rank 0 writes every row; mpio: workers wrote theirs, rank 0 writes its own.
        if st is not None and (wmode != "mpio" or local):
            st.write(i, res)
        prog.update(res)

    status = MPI.Status()
    stopping, next_check = False, 0.0
    while active or local_alive:
        progressed = False
        now = time.monotonic()
        if not stopping and (now >= next_check or stop.signum is not None):
            next_check = now + 0.5
            if stop.requested():
                stopping = True
                with lock:
                    q.clear()
                log.warning("stop requested (%s): finishing the tasks in flight",
                            limits.SIGNAL_NAMES.get(stop.signum, stop.signum))
                if stop.on_request is not None:
                    stop.on_request(stop.signum)
        while active and comm.Iprobe(source=MPI.ANY_SOURCE, tag=MPI.ANY_TAG, status=status):
            src, tag = status.Get_source(), status.Get_tag()
            msg = comm.recv(source=src, tag=tag)
            if tag == TAG_ROW:
                handle(msg, False)
            elif tag == TAG_STOP:
                if stop.signum is None:
                    stop.signum = msg
                next_check = 0.0
            elif tag == TAG_READY:
                k = take(False, gpu_of[src] is not None)
                comm.send(k, dest=src, tag=TAG_WORK)
                if k is None:
                    active.discard(src)
            progressed = True
        while local_alive:
            try:
                item = results.get_nowait()
            except queue.Empty:
                break
            progressed = True
            if item is None:
                local_alive = False
            elif isinstance(item, BaseException):
                raise item
            else:
                handle(item, True)
        if not progressed:
            time.sleep(2e-4 if local_alive else 2e-3)
    if thread is not None:
        thread.join()


def _work(comm: Any, tasks: list[Task], units: list[Unit], todo: set[int], ctx: Context, st: Store | None,
          wmode: str, limit: float | None, stop: limits.Stop) -> None:
    """Worker rank: ask for a unit, run it, write (mpio) or send (rank0 writer) each row as it finishes. A
    signal to this rank is passed on to rank 0 (TAG_STOP), which stops handing out work."""
    told = False
    comm.send(None, dest=0, tag=TAG_READY)
    while (k := comm.recv(source=0, tag=TAG_WORK)) is not None:
        for i, res in _run_unit(tasks, units[k], ctx, todo, limit, stop):
            if wmode == "mpio":
                st.write(i, res)
                res = TaskResult(res.status, "", {})  # rank 0 only counts it
            comm.send((i, res), dest=0, tag=TAG_ROW)
        if stop.signum is not None and not told:
            comm.send(stop.signum, dest=0, tag=TAG_STOP)
            told = True
        comm.send(None, dest=0, tag=TAG_READY)


def _fields_dir(store: str | Path) -> Path:

    return fields_dir(store)
