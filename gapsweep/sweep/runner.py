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

Beside the runner (docs/architecture.md, "The farm"): what to do with an existing store is
gapsweep.sweep.resume, rows copied from other stores gapsweep.sweep.reuse, rank 0's progress and ETA
gapsweep.sweep.progress, a job of distributed tasks gapsweep.sweep.collective; the farm's rules are
gapsweep.sweep.farm. The runner opens and closes the store, records the run and moves the farm's messages.
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
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from gapsweep.sweep import batching, budget, collective, gpus, lease, limits, provenance, storecheck
from gapsweep.sweep import methods as registry
from gapsweep.sweep import spec as specmod
from gapsweep.sweep.context import Context
from gapsweep.sweep.execute import run_task
from gapsweep.sweep.farm import DeviceFault, Farm, Worker, device_fault
from gapsweep.sweep.fields import fields_dir, remove_fields, remove_partial
from gapsweep.sweep.limits import Interrupted, TaskTimeout
from gapsweep.sweep.progress import Progress
from gapsweep.sweep.resume import RunError, decide, store_order, stored_order
from gapsweep.sweep.reuse import Reused, copy_reused, reusable_rows, reused_record
from gapsweep.sweep.schema import STATUS, Task, TaskResult, Unit
from gapsweep.sweep.spec import check_extra
from gapsweep.sweep.store import Store, StoreError, StoreWriteError
from gapsweep.sweep.store import io_failed as store_io_failed
from gapsweep.sweep.tasks import estimate_cost, expand, make_units, shard_units
from gapsweep.sweep.trace import Trace

__all__ = ["Interrupted", "RunError", "parse_shard", "plan", "reusable_rows", "run"]

log = logging.getLogger("gapsweep.runner")

TAG_READY, TAG_WORK, TAG_ROW, TAG_STOP, TAG_FAULT, TAG_ERROR = 1, 2, 3, 4, 5, 6
_MPI_ENV = ("OMPI_COMM_WORLD_SIZE", "PMI_SIZE", "PMIX_RANK", "MPI_LOCALNRANKS", "PMI_RANK")
_MPI_SIZE_ENV = ("OMPI_COMM_WORLD_SIZE", "PMI_SIZE", "PMIX_SIZE", "MPI_LOCALNRANKS")


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
    if spec.surface.get("kind") == "file":  # the map as solved: shape, box, unit, rms, missing data, boundaries
        from gapsweep.sweep.filesurface import describe

        lines.extend(describe(spec.surface))
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
    size = budget.store_bytes(len(tasks), spec.histogram["bins"], len(spec.text), len(registry.job_columns(spec)))
    lines.extend(_check_resources(tasks, ranks_per_gpu))
    lines.extend(collective.check(tasks, ranks))  # distributed tasks: their slabs on `ranks` ranks
    lines.extend(_propose(units))
    lines.append(f"  store ~{budget.human(size)}")
    if store is not None:
        path = _store_path(store, shard)
        free = budget.disk_free(path.parent)
        lines.append(f"  free disk at {path.parent}: {budget.human(free)}")
        if size > free:
            raise RunError(f"store {path}: needs ~{budget.human(size)}, only {budget.human(free)} free there")
    return "\n".join(lines)


def _propose(units: list[Unit]) -> list[str]:
    """The plan's lines about this node (GPUs from nvidia-smi or CUDA_VISIBLE_DEVICES, no CUDA context; cores)
    and the layout to pick for the job here (gapsweep.sweep.gpus.layout)."""
    try:
        cores = len(os.sched_getaffinity(0))
    except (AttributeError, OSError):  # pragma: no cover - not Linux
        cores = os.cpu_count() or 1
    n = gpus.visible_count()
    found = gpus.query()
    names = sorted({f"{g['name']}, {budget.human(g['memory'])}" for g in found}) if len(found) == n else []
    gpu_units = sum(u.gpu for u in units)
    lay = gpus.layout(n, cores, gpu_units, len(units) - gpu_units)
    out = [f"  this node: {cores} core(s), {n} GPU(s)" + (f" ({'; '.join(names)})" if names else "")]
    if gpu_units and not n:
        out.append(f"  {gpu_units} GPU unit(s) but no GPU visible here: run the job on a GPU node")
    out.append(f"  layout here: {lay.ranks} rank(s) -- {lay.gpu_workers} GPU worker(s) (one per GPU), "
               f"{lay.cpu_workers} CPU worker(s)" + ("" if lay.ranks == 1 else ", rank 0 coordinates")
               + f": {lay.args()} (docs/running.md, \"Which layout\")")
    if lay.gpu_workers and lay.ranks > 1:
        k = gpus.auto_per_gpu(n, gpus.MPS_CLIENTS, True)
        out.append(f"  by default the run puts up to {k} of these ranks on each GPU under CUDA MPS "
                   "(started and stopped by the run where it may; else one per GPU): --ranks-per-gpu K to choose")
    return out


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
        have = gpus.memory()  # nvidia-smi: no CUDA context in this process
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
        if _cut(res, stop):
            return
        if i in todo:
            yield i, res
        if stop is not None and stop.mode == "flag" and stop.requested():
            return


def _cut(res: TaskResult, stop: limits.Stop | None) -> bool:
    """A task cut by a stop request (its error says ``interrupted:``): its row is not written -- it stays pending,
    run again by --resume (issue 31) -- and the unit ends; in raise mode (serial) the run stops now. Without a stop
    request (an interruption seen only in the error) the row is written as failed with that prefix, and
    --resume runs it again."""
    if res.status != "failed" or not limits.is_interrupted(res.message):
        return False
    if stop is None or not stop.requested():
        return False
    if stop.mode == "raise":
        raise Interrupted(stop.signum)
    return True


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
        task_timeout: float | None = None, batch: str = "off", ranks_per_gpu: int | None = None,
        lookahead: int = 4, reuse: Sequence[str | Path] = (), reuse_older: bool = False) -> dict[str, Any]:
    """Run a job into a store (serially or as an MPI task farm). Returns a summary dict on every rank.

    ``writer``: auto | mpio | rank0 (env ``GAPSWEEP_WRITER`` overrides auto); ``progress``: auto | bar | log |
    none; ``coordinator_works``: auto (rank 0 works when P <= 4) | yes | no; ``mpi``: auto | on | off;
    ``break_lease``: take over the lease of a run that is gone; ``task_timeout``: per-task wall-time limit [s];
    ``batch``: off (default: one solve at a time, faster in the sweep) | auto (GFMD chains batched on GPU ranks,
    gapsweep.batching) | all (also CPU backends: for tests and comparisons); ``ranks_per_gpu``: ranks sharing
    one GPU (None: the default of gapsweep.sweep.gpus -- several under CUDA MPS, started by the run where it
    may); ``lookahead``: GPU units a GPU worker holds beyond the one it runs, their surfaces
    made on as many host threads while its GPU works (0: none; docs/architecture.md, "The farm"); ``reuse``:
    other stores whose verified ``done`` rows of the same tasks (task id) are copied instead of run
    (:func:`reusable_rows`; the run record names the sources), only rows of the methods' current algorithm
    version unless ``reuse_older``.

    Raises :class:`RunError` when the run cannot start or a write fails (rows finished before stay done),
    :class:`~gapsweep.limits.Interrupted` after a clean stop on SIGINT/SIGTERM or a ``<store>.stop`` file (the
    run is recorded as interrupted in the store)."""
    p = _prepare(job, store, resume=resume, overwrite=overwrite, shard=shard, mpi=mpi, break_lease=break_lease,
                 task_timeout=task_timeout, batch=batch, ranks_per_gpu=ranks_per_gpu, lookahead=lookahead,
                 reuse=reuse, reuse_older=reuse_older)
    try:
        return _execute(p.spec, p.comm, p.rank, p.size, p.tasks, p.units, p.path, p.shard_text, p.decision, writer,
                        progress, coordinator_works, task_timeout, p.held, (batch, ranks_per_gpu, lookahead),
                        p.reused)
    finally:
        if p.held is not None:
            p.held.release()


@dataclass
class Prepared:
    """A job ready to run (:func:`_prepare`): its tasks and units in the store's order, the decision of rank 0
    (``(mode, todo, failed before, run id)``), the lease rank 0 holds, the rows reused from other stores."""

    spec: specmod.JobSpec
    comm: Any
    rank: int
    size: int
    tasks: list[Task]
    units: list[Unit]
    path: Path
    shard_text: str
    decision: tuple
    held: lease.Lease | None
    reused: Reused


def _prepare(job: str | Path | specmod.JobSpec, store: str | Path, *, resume: bool = False, overwrite: bool = False,
             shard: tuple[int, int] | None = None, mpi: str = "auto", break_lease: bool = False,
             task_timeout: float | None = None, batch: str = "off", ranks_per_gpu: int | None = None,
             lookahead: int = 4, reuse: Sequence[str | Path] = (), reuse_older: bool = False) -> Prepared:
    """Check the options, load the job, take the store's lease and decide what to run (every rank; rank 0 looks
    at the file system and tells the others); the caller releases ``held``."""
    _check_options(resume, overwrite, task_timeout, batch, ranks_per_gpu, lookahead)
    spec = _load(job)
    comm = _comm(mpi)
    rank, size = (comm.rank, comm.size) if comm is not None else (0, 1)
    tasks, units = _select(spec, shard, batch)
    collective.check_options(tasks, task_timeout, batch)
    path = _store_path(store, shard)
    shard_text = f"{shard[0]}/{shard[1]}" if shard else ""

    # Rank 0 takes the lease and decides (file system checks once), then shares: every rank raises the same
    # error. Nothing opens the store for writing before the lease is held.
    decision: Any = None
    held: lease.Lease | None = None
    reused: Reused = {}
    if rank == 0:
        decision, held, reused = _rank0_decide(job, spec, tasks, path, shard_text, size, resume, overwrite,
                                               break_lease, ranks_per_gpu, reuse, reuse_older)
    if comm is not None:
        decision = comm.bcast(decision, root=0)
    if isinstance(decision, RunError):
        raise decision
    tasks, units = store_order(tasks, units, decision[0])  # a reordered axis: the store's row order (issue 31)
    return Prepared(spec, comm, rank, size, tasks, units, path, shard_text, decision[1:], held, reused)


def _check_options(resume: bool, overwrite: bool, task_timeout: float | None, batch: str,
                   ranks_per_gpu: int | None, lookahead: int) -> None:
    """:func:`run`'s options, each refused (ValueError) with the allowed range before anything is read."""
    if resume and overwrite:
        raise ValueError("--resume and --overwrite exclude each other: --resume keeps the finished rows, "
                         "--overwrite discards them")
    if task_timeout is not None and not (isinstance(task_timeout, (int, float)) and 0 < task_timeout < 1e9):
        raise ValueError(f"--task-timeout: expected seconds > 0, got {task_timeout!r}")
    if batch not in batching.MODES:
        raise ValueError(f"--batch: expected one of {', '.join(batching.MODES)}, got {batch!r}")
    if ranks_per_gpu is not None:
        gpus.assign(None, 0, ranks_per_gpu)  # validates ranks_per_gpu
    if isinstance(lookahead, bool) or not isinstance(lookahead, int) or not 0 <= lookahead <= 64:
        raise ValueError(f"--lookahead: expected an integer in [0, 64], got {lookahead!r}")


def _rank0_decide(job: str | Path | specmod.JobSpec, spec: specmod.JobSpec, tasks: list[Task], path: Path,
                  shard_text: str, size: int, resume: bool, overwrite: bool, break_lease: bool,
                  ranks_per_gpu: int | None, reuse: Sequence[str | Path], reuse_older: bool,
                  ) -> tuple[Any, lease.Lease | None, Reused]:
    """Rank 0: check the resources, take the store's lease and decide what to run (gapsweep.sweep.resume), the
    rows copied from ``reuse`` stores left out. Returns ``((row order, mode, rows to run, failed rows, run id)
    or the RunError every rank raises, the lease held or None, the reused rows)``."""
    decision: Any = None
    held: lease.Lease | None = None
    reused: Reused = {}
    try:
        _check_resources(tasks, ranks_per_gpu or 1)  # the same refusal as `plan`, looked at once (rank 0)
        collective.check(tasks, size)  # every rank runs each distributed task together: its slabs fit?
        _guard_store(path, _inputs(job, spec), overwrite)
        path.parent.mkdir(parents=True, exist_ok=True)
        held = lease.acquire(path, break_lease=break_lease)
        lease.remove_leftovers(path, held=True)  # of a killed creation or merge (issue 40 item 7)
        order = stored_order(path, spec, tasks, shard_text, overwrite)
        ordered = store_order(tasks, [], order)[0]
        decision = (order, *decide(path, spec, ordered, shard_text, resume, overwrite,
                                   reordered=order is not None), held.run_id)
        if reuse and decision[1] != "noop":
            reused = reusable_rows(reuse, path, ordered, decision[2], spec.histogram["bins"], reuse_older)
            decision = (decision[0], decision[1], [i for i in decision[2] if i not in reused], *decision[3:])
        _stop_file(path).unlink(missing_ok=True)  # a stop request of an earlier run
    except Exception as e:  # every rank must learn about it, or the others wait in bcast forever
        decision = e if isinstance(e, RunError) else RunError(
            str(e) if isinstance(e, (lease.LeaseError, StoreError)) else f"store {path}: {e}")
        if held is not None:
            held.release()
            held = None
    return decision, held, reused


def _inputs(job: str | Path | specmod.JobSpec, spec: specmod.JobSpec) -> list[Path]:
    """The files a run reads: its job spec and a measured height map (``[surface] kind = "file"``)."""
    from gapsweep.sweep.filesurface import _FILES

    out = [] if isinstance(job, specmod.JobSpec) else [Path(job)]
    if spec.surface.get("kind") == "file" and _FILES.get(spec.surface.get("sha256", "")):
        out.append(Path(_FILES[spec.surface["sha256"]]))
    return out


def _guard_store(path: Path, inputs: list[Path], overwrite: bool) -> None:
    """The output rule (gapsweep.sweep.outputs, issue 31) for ``run --store``: never an input (the job spec, the
    height map; by device and inode) nor a folder; ``--overwrite`` replaces only a gapsweep store."""
    from gapsweep.sweep import outputs

    try:
        outputs.guard_output(path, inputs, "run --store", overwrite=True, own=lambda o: None if not overwrite or
                             outputs.is_store(o) else "is not a gapsweep store (a plain HDF5 file or another file)")
    except FileExistsError as e:
        raise RunError(str(e)) from None


def _stop_file(path: Path) -> Path:
    return path.with_name(path.name + ".stop")


def _writer_mode(comm: Any, writer: str) -> str:
    """serial | mpio | rank0, from ``--writer`` (``GAPSWEEP_WRITER`` for auto) and h5py's build."""
    req = os.environ.get("GAPSWEEP_WRITER", "auto") if writer == "auto" else writer
    if req not in ("auto", "mpio", "rank0"):
        raise RunError(f"writer must be auto, mpio or rank0, got {req!r}")
    import h5py

    if comm is None:
        return "serial"
    if req == "rank0" or (req == "auto" and not h5py.get_config().mpi):
        return "rank0"
    if not h5py.get_config().mpi:
        raise RunError("writer 'mpio' needs h5py built with MPI (h5py.get_config().mpi is False)")
    return "mpio"


def _execute(spec: specmod.JobSpec, comm: Any, rank: int, size: int, tasks: list[Task], units: list[Unit],
             path: Path, shard_text: str, decision: tuple, writer: str, progress: str, coordinator_works: str,
             task_timeout: float | None, held: lease.Lease | None, gpu_opts: tuple = ("auto", 1, 0),
             reused: Reused | None = None) -> dict[str, Any]:
    mode, todo_list, old_failed, _ = decision
    summary: dict[str, Any] = {"store": str(path), "tasks": len(tasks), "todo": len(todo_list), "mode": mode,
                               "mpi_size": size, "rank": rank, **dict.fromkeys(STATUS, 0), "pending": 0,
                               "unfinished": old_failed}
    if mode == "noop":
        if rank == 0 and progress != "none":
            log.info("%s: all %d tasks finished already; nothing to do", path, len(tasks))
        return summary
    summary["writer"] = wmode = _writer_mode(comm, writer)
    r = _Run(spec, comm, tasks, units, path, shard_text, decision, wmode, progress, coordinator_works,
             task_timeout, held, gpu_opts)
    r.reused = reused
    try:
        r.start()
        _drive(r)
        r.finish(summary)
    except Interrupted as e:
        if comm is not None or r.st is None:  # MPI: raised after the collective close in finish()
            raise
        r.interrupted(e)
    except (StoreWriteError, OSError) as e:
        if comm is None:
            r.write_failed(e)
        _abort(comm, rank, wmode, held, e, (path, r.run_id))
    except BaseException as e:
        if comm is not None:
            _abort(comm, rank, wmode, held, e, (path, r.run_id))
        raise
    finally:
        r.stop.restore()
        if r.ctx is not None:
            r.ctx.close()
        if r.st is not None and comm is None:
            _abandon(r.st)
    return summary


class _Run:
    """One job's run on this rank, from opening its store to closing it (driven by :func:`_execute`)."""

    def __init__(self, spec: specmod.JobSpec, comm: Any, tasks: list[Task], units: list[Unit], path: Path,
                 shard_text: str, decision: tuple, wmode: str, progress: str, coordinator_works: str,
                 limit: float | None, held: lease.Lease | None, gpu_opts: tuple) -> None:
        self.spec, self.comm, self.tasks, self.units, self.path = spec, comm, tasks, units, path
        self.shard_text, self.wmode, self.progress, self.limit, self.held = shard_text, wmode, progress, limit, held
        self.rank, self.size = (comm.rank, comm.size) if comm is not None else (0, 1)
        self.mode, self.todo_list, self.old_failed, self.run_id = decision
        self.batch, self.per_gpu, self.lookahead = gpu_opts
        self.ctx: Context | None = None
        # rank 0 works (in a thread, beside coordinating) when asked, or by default with few ranks
        self.together = comm is not None and collective.is_collective(tasks)  # every rank solves (a GPU each)
        self.works = (comm is None or self.together or coordinator_works == "yes"
                      or (coordinator_works == "auto" and self.size <= 4))
        self.stop = limits.Stop("raise" if comm is None else "flag", _stop_file(path)).install()
        self.st: Store | None = None
        self.prog: Progress | None = None
        self.record: dict[str, Any] = {}
        self.outcome: dict[str, Any] = {}  # the coordinator's: device faults, GPU units left pending
        self.next_check = 0.0  # the coordinator's next look for a stop request
        self.reused: Reused | None = None  # rows copied from other stores (rank 0)

    def start(self) -> None:
        """Place this rank (its GPU), agree on the run record, open the store and record the run."""
        comm, rank = self.comm, self.rank
        # Static attributes and the run record come from rank 0 so that every rank writes identical values.
        hosts = sorted(set(comm.allgather(socket.gethostname()))) if comm is not None else [socket.gethostname()]
        attrs = provenance.store_attrs(self.spec, shard=self.shard_text) if rank == 0 else None
        need_gpu = any(u.gpu for u in self.units)
        self.gpu: int | None = None
        mps_note = self._place() if need_gpu else None  # None: no GPU units, no GPU layout to record
        self.gpu_of = comm.allgather(self.gpu) if comm is not None else [self.gpu]
        record = self._record(hosts, mps_note)
        # A signal that arrived while the process started (adopted from the early handler) is in the record the
        # store is born with: mpiexec SIGKILLs its ranks 1 s after forwarding it, maybe before anything else is
        # written, and the store must then say interrupted, not "running or killed" (issue 40). Rank 0's view,
        # broadcast, so that a collective creation writes the same record everywhere.
        early = self.stop.signum if (rank == 0 and self.stop.requested()) else None
        if comm is not None:
            attrs, record, early = comm.bcast((attrs, record, early), root=0)
        self.record = record
        birth = {**record, **_interrupted(early, {})} if early is not None else record
        self.ctx = Context(rank=rank, gpu=self.gpu)
        if self.gpu is not None:
            self.ctx.ahead(self.lookahead)  # host threads for the surfaces of the units held ahead
        self.ctx.fields_dir = _fields_dir(self.path)  # kept GFMD fields, if the spec asks (gapsweep.dataset)
        self.ctx.writer = self.wmode  # how a distributed task's kept fields are written (gapsweep.sweep.fields)
        self.todo = set(self.todo_list)
        self.work = [k for k, u in enumerate(self.units) if any(i in self.todo for i in u.tasks)]
        if early is not None and self.held is not None and comm is not None:
            # the lease says so before the store is made: a SIGKILL from here on leaves either no store or one
            # born interrupted, and the next run takes the lease over without --break-lease
            self.held.mark_interrupted()
        if self.wmode == "mpio" or rank == 0:
            self._open(attrs, birth)
        self.prog = Progress(len(self.todo), self.progress if rank == 0 else "none")
        if comm is not None and rank == 0 and self.wmode == "rank0":  # issue 19: mpiexec's 1-s grace, see below
            self.stop.on_request = lambda sig: _mark_interrupted(self.st, record, self.prog, self.held, sig)
            if early is None and self.stop.requested():  # signalled during the creation: say so at once
                _mark_interrupted(self.st, record, self.prog, self.held, self.stop.signum)
        if rank == 0:  # when the farm starts (wall clock): start-up = this minus the launch (benchmarks)
            record["farm_started_unix"] = round(time.time(), 3)
        if rank == 0 and comm is not None and need_gpu:
            ngpu = sum(g is not None for g in self.gpu_of)
            log.info("farm: %d ranks: %d GPU worker(s), %d CPU worker(s), coordinator %s", self.size, ngpu,
                     self.size - ngpu - (0 if self.works else 1), "works" if self.works else "only coordinates")

    def _place(self) -> str:
        """This rank's GPU for a job with GPU units (``self.gpu``, ``self.per_gpu``): the default ranks per GPU
        no more than the GPU memory holds (gapsweep.sweep.gpus.place). Returns what became of CUDA MPS."""
        gpu_tasks = [self.tasks[i] for u in self.units if u.gpu for i in u.tasks]
        placed = gpus.place(self.comm, self.works, self.per_gpu, need=budget.gpu_memory(gpu_tasks, 1))
        self.gpu, self.per_gpu = placed.gpu, placed.per_gpu
        if placed.note and (self.comm is None or self.comm.rank == 0):
            log.info("%s", placed.note)
        return placed.note

    def _record(self, hosts: list[str], mps_note: str | None) -> dict[str, Any]:
        """This run's record (its provenance extras and reused rows on rank 0, which broadcasts it); ``mps_note``:
        None for a job without GPU units, else the GPU layout is recorded (rank 0's node: ranks per GPU, MPS)."""
        record = {"started": provenance.now(), "finished": None, "mpi_size": self.size, "hosts": hosts,
                  "writer": self.wmode, "mode": self.mode, "todo": len(self.todo_list), "run_id": self.run_id,
                  **(provenance.run_extras(self.spec, gpu_ranks=self.gpu_of, batch=self.batch,
                                           batch_units=sum(u.kind == "batch" for u in self.units))
                     if self.rank == 0 else {})}
        record.update(reused_record(self.reused))
        if mps_note is not None:
            record.update(ranks_per_gpu=self.per_gpu, mps=mps_note)
        return record

    def _open(self, attrs: dict[str, Any], birth: dict[str, Any]) -> None:
        """Open (or create) the store on a rank that writes, record this run (``birth``: its record as the store
        is born) and copy the reused rows."""
        with self.stop.critical():
            # A new store is created with this run's record among its attributes (issue 40): it appears at
            # its path (a rename) with the record, so no kill (mpiexec SIGKILLs its ranks 1 s after
            # forwarding a SIGTERM) between its creation and a later attribute write leaves a store that
            # names no run.
            if self.mode == "create":
                attrs = {**attrs, "runs": json.dumps([birth])}
            self.st = _open_store(self.path, self.mode, self.tasks, attrs, self.spec.histogram["bins"],
                                  self.comm if self.wmode == "mpio" else None, self.rank, self.run_id,
                                  registry.job_columns(self.spec))
            if self.held is not None:  # the file opened is the one leased (issue 19: keyed by device and inode)
                self.held.bind(self.path)
            if self.mode == "resume":  # every byte of a re-run row is written again, NaN histograms included
                self.st.force_histograms(self.todo_list)
            if self.mode != "create":
                runs = _earlier_runs(self.st, self.path)
                self.st.set_attrs({"runs": json.dumps([*runs, birth])}, flush=True)  # survives a kill -9
            copy_reused(self.st, self.reused, self.tasks)

    def finish(self, summary: dict[str, Any]) -> None:
        """Agree on the counts and the outcome, record how the run ended, close the store."""
        comm, prog = self.comm, self.prog
        prog.close()
        counts = dict(prog.count)
        stopped = self.stop.signum if self.stop.requested() else None
        outcome = self.outcome
        if comm is not None:
            _quiet_barrier(comm)  # ranks done early wait here without spinning on a core the GPU workers need
            counts, stopped, outcome = comm.bcast((counts, stopped, outcome) if self.rank == 0 else None, root=0)
            comm.Barrier()
        summary.update(counts)
        summary["pending"] = len(self.todo_list) - sum(counts.values())
        summary["unfinished"] = self.old_failed + counts["failed"] + summary["pending"]
        record = self.record
        if outcome.get("faults"):
            record["device_faults"] = outcome["faults"]
        if outcome.get("no_gpu"):
            record.update(stopped=outcome["no_gpu"], stopped_at=provenance.now(), pending=summary["pending"])
        if stopped is not None:
            record.update(_interrupted(stopped, counts))
        else:
            record["finished"] = provenance.now()
        if comm is not None and self.wmode == "mpio":
            record = comm.bcast(record, root=0)
        if self.st is not None:
            _close_record(self.st, record)
            self.st = None
        if stopped is not None:
            raise Interrupted(stopped, counts)

    def interrupted(self, e: Interrupted) -> None:
        """Serial run: record the interruption, close the store, raise it again with the counts."""
        counts = dict(self.prog.count) if self.prog is not None else {}
        if self.prog is not None:
            self.prog.close()
        self.record.update(_interrupted(e.signum, counts))
        try:
            _close_record(self.st, self.record)
        except StoreError as w:
            log.error("%s", w)
        self.st = None
        raise Interrupted(e.signum, counts) from None

    def write_failed(self, e: BaseException) -> None:
        """Serial run: a write failed; record why the run stopped (if that can be written) and raise RunError."""
        if self.st is not None:
            self.record.update(stopped=str(e)[:200], stopped_at=provenance.now())
            _abandon(self.st, self.record)
            self.st = None
        raise RunError(f"{e if isinstance(e, StoreWriteError) else f'store {self.path}: {e}'}; every row finished "
                       "before is intact: fix the cause (free space, file-size limit) and run again with "
                       "--resume") from None

    def units_of(self, k: int, skip: frozenset[int]) -> Iterator[tuple[int, TaskResult]]:
        """Rows of unit ``k`` (its wanted tasks but ``skip``, already recorded by a worker whose device failed).
        A device fault outside a task (a batch's surfaces moving to the GPU) raises DeviceFault too."""
        todo = self.todo - skip if skip else self.todo
        try:
            yield from _run_unit(self.tasks, self.units[k], self.ctx, todo, self.limit, self.stop)
        except (DeviceFault, StoreError, Interrupted):
            raise
        except Exception as e:
            why = device_fault(e)
            if why:
                raise DeviceFault(why) from e
            raise

    def ahead_ok(self) -> list[bool]:
        """Units worth holding ahead: GPU units with surfaces to make on the host (tasks on a grid, ``n > 0``,
        whose GPU does not make them itself: Context.makes_on_gpu). A unit held ahead is committed to its worker
        early, which unbalances the largest-first order where there is nothing to prepare."""
        return [u.gpu and any(self.tasks[i].n > 0 and (u.kind == "batch" or not self.ctx.makes_on_gpu(self.tasks[i]))
                              for i in u.tasks) for u in self.units]  # a batch stacks host surfaces

    def prefetch(self, k: int) -> None:
        """A GPU unit just held: its surfaces start on the host threads (``ahead``) while the GPU works."""
        u = self.units[k]
        if not (u.gpu and self.gpu is not None):
            return
        for i in u.tasks:
            t = self.tasks[i]
            if t.n > 0 and i in self.todo:
                self.ctx.prefetch(t, t.n)

    def ended(self, farm: Farm) -> None:
        """The coordinator, once every worker has left: what the run's record must say about devices."""
        faults = [f"rank {w} (GPU {g}): {why}" for w, g, why in farm.faults]
        left = sorted({i for k in farm.left for i in self.units[k].tasks if i in self.todo} - {
            i for k in farm.left for i in farm.recorded.get(k, ())})
        self.outcome = {"faults": faults}
        if farm.no_gpu:
            self.outcome["no_gpu"] = (f"{farm.no_gpu}: {len(left)} GPU task(s) left pending; run again with "
                                      "--resume where a GPU works")
            log.error("%s", self.outcome["no_gpu"])


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
        runs = storecheck.run_records(st.f.attrs.get("runs", "[]")) or [{}]
        runs[-1] = {**record, **_interrupted(signum, dict(prog.count))}
        st.set_attrs({"runs": json.dumps(runs)}, flush=True)
    except (OSError, StoreError) as e:
        log.warning("%s: cannot record the interruption early (%s)", st.path, e)
        return
    if held is not None:
        held.mark_interrupted()


def _earlier_runs(st: Store, path: Path) -> list[dict[str, Any]]:
    """The store's run records before this run's; a damaged list (issue 31) is rebuilt: one record saying the
    earlier ones were lost (the rows do not depend on them)."""
    raw = st.f.attrs.get("runs", "[]")
    why = storecheck.runs_problem(raw)
    if why is None:
        return storecheck.run_records(raw)
    log.warning("store %s: its run records were damaged (%s); rebuilt as a new list (the earlier run history is "
                "lost, every row is kept)", path, why)
    return [{"rebuilt": provenance.now(), "note": f"the earlier run records were damaged ({why}) and are lost"}]


def _interrupted(signum: int, counts: dict[str, int]) -> dict[str, Any]:
    name = limits.SIGNAL_NAMES.get(signum, f"signal {signum}")
    return {"interrupted": name, "interrupted_at": provenance.now(), "counts": counts}


def _open_store(path: Path, mode: str, tasks: list[Task], attrs: dict[str, Any], bins: int, comm: Any, rank: int,
                run_id: str, columns: Sequence[tuple[str, str]] = ()) -> Store:
    """Open the store for writing; a new one is created under a temporary name and renamed into place
    (collectively under mpio), so that a store path never holds a half-created file."""
    if mode == "create":
        tmp = path.with_name(f".{path.name}.tmp-{run_id}")
        try:
            try:
                Store.create(tmp, tasks, attrs, bins, comm=comm, columns=columns).close()
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
    restore = {k: v for k, v in attrs.items() if k in ("job_name", "spec_text", "spec_sha256", "units", "spec_dir")}
    st = Store.open(path, comm=comm, repair_tasks=mode == "resume", restore=restore if mode == "resume" else None)
    if mode == "resume" and rank == 0 and (gone := remove_partial(fields_dir(path))):
        log.info("store %s: removed %d partial kept-field file(s) of an interrupted run", path, gone)
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
    runs = storecheck.run_records(st.f.attrs.get("runs", "[]")) or [{}]
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


def _abort(comm: Any, rank: int, wmode: str, held: lease.Lease | None, e: BaseException,
           run: tuple[Path, str] | None = None) -> None:
    log.error("rank %d: fatal error, aborting the MPI job: %s: %s", rank, type(e).__name__, e,
              exc_info=not isinstance(e, (StoreError, OSError)))
    if held is not None and wmode != "mpio":  # rank 0 alone wrote: its rows are flushed, the store is free
        held.release()
    elif run is not None:  # issue 31: the lease says its run ended (MPI_Abort ends every rank); once its holder
        lease.mark_ended(*run)  # is gone the next run takes it over without --break-lease
    sys.stderr.flush()
    comm.Abort(1)


def _quiet_barrier(comm: Any) -> None:
    """A barrier that sleeps while it waits (MPI's blocking calls spin on a core): a worker that has left the
    farm while GPU workers finish their last units gives its core to their host threads."""
    req = comm.Ibarrier()
    delay = 1e-4
    while not req.Test():
        time.sleep(delay)
        delay = min(2 * delay, 0.01)


def _fault(rank: int, gpu: int | None, e: BaseException) -> str:
    log.warning("rank %d: GPU %s failed (%s): this rank takes no more GPU tasks, its unit goes back to the queue",
                rank, gpu, e)
    return str(e)


def _drive(r: _Run) -> None:
    """This rank's part of the run: one process, a collective run (every rank solves each distributed task
    together, gapsweep.sweep.collective), or the farm's coordinator or a worker."""
    if r.together:
        def write(i: int, res: TaskResult) -> None:
            with r.stop.critical():
                r.st.write(i, res)
                r.prog.update(res)

        collective.run_collective(r.comm, r.tasks, r.units, r.work, r.ctx, _run_unit, r.todo, write, r.stop)
    elif r.comm is None:
        _serial(r)
    elif r.rank == 0:
        _coordinate(r)
    else:
        _work(r)


def _serial(r: _Run) -> None:
    """One process: the farm with one worker (a device fault leaves the GPU units pending, the CPU units run)."""
    farm = Farm([u.gpu for u in r.units], r.work, {0: Worker(gpu=r.gpu, ahead=r.lookahead)}, ahead_ok=r.ahead_ok())
    held: deque = deque()
    sends = farm.request(0)
    while True:
        for _, k in sends:
            if k is not None:
                held.append(k)
                r.prefetch(k)
        if not held:
            break
        k = held.popleft()
        try:
            for i, res in r.units_of(k, farm.skip(k)):
                with r.stop.critical():  # a row written is a row counted (a signal acts after both)
                    r.st.write(i, res)
                    farm.row(k, i)
                    r.prog.update(res, i)
                if r.stop.requested():  # the stop file (a signal raises by itself)
                    raise Interrupted(r.stop.signum)
        except DeviceFault as e:
            held.clear()
            sends = farm.fault(0, _fault(0, r.gpu, e))
            continue
        sends = farm.request(0, k)
    r.ended(farm)


class _Held:
    """The units a worker holds (the one it runs, then those ahead), as sent by the coordinator: ``(unit, rows
    to skip, epoch)``; a unit of an earlier epoch (sent before this worker's last device fault) is stale and
    dropped. ``get(block)`` returns the next message from the coordinator (None: nothing arrived);
    ``release(unit)`` hands a unit back unrun (after a stop request: its rows stay pending)."""

    def __init__(self, r: _Run, get: Any, release: Any) -> None:
        self.r, self.get, self.release = r, get, release
        self.units: deque = deque()
        self.epoch, self.done = 0, False

    def next(self) -> tuple[int, frozenset[int]] | None:
        """The next unit to run (waiting for one while none is held), or None: leave the farm."""
        while not self.done:
            if self.units and self.r.stop.requested():  # stopping: only the unit in progress finishes
                while self.units:
                    self.release(self.units.popleft()[0])
            msg = self.get(not self.units)
            if msg is None and self.units:  # nothing more arrived: run what is held
                break
            if msg is None:  # the coordinator's stop (it sends one only to a worker that holds nothing)
                self.done = True
            elif msg[2] == self.epoch:
                self.units.append(msg[:2])
                self.r.prefetch(msg[0])
        return self.units.popleft() if self.units else None

    def fault(self) -> None:
        self.units.clear()
        self.epoch += 1


class _Local:
    """The coordinator's own worker: a thread that runs units from the tail of the queue and reports through a
    queue (rows, device faults, requests), so that every farm decision and every MPI call stays on rank 0's
    main thread."""

    def __init__(self, r: _Run, tr: Trace | None = None) -> None:
        self.r, self.tr = r, tr  # tr: rank 0's timeline, which records this thread's units too
        self.inbox: queue.Queue = queue.Queue()
        self.events: queue.Queue = queue.Queue()
        self.thread = threading.Thread(target=self._main, name="gapsweep-rank0-worker", daemon=True)
        self.thread.start()

    def _get(self, block: bool) -> Any:
        if block:
            return self.inbox.get()
        try:
            return self.inbox.get_nowait()
        except queue.Empty:
            return None

    def _main(self) -> None:
        held = _Held(self.r, self._get, lambda k: self.events.put((TAG_READY, k)))
        try:
            self.events.put((TAG_READY, None))
            while (msg := held.next()) is not None:
                t0 = time.time()
                try:
                    for i, res in self.r.units_of(*msg):
                        self.events.put((TAG_ROW, (msg[0], i, res)))
                except DeviceFault as e:
                    held.fault()
                    self.events.put((TAG_FAULT, _fault(0, self.r.gpu, e)))
                    continue
                finally:
                    if self.tr is not None:
                        u = self.r.units[msg[0]]
                        self.tr.unit(msg[0], t0, u.gpu, len(u.tasks))
                self.events.put((TAG_READY, msg[0]))
        except BaseException as e:  # surfaced on the main thread, which aborts the job
            self.events.put((TAG_ERROR, e))


def _coordinate(r: _Run) -> None:
    """Rank 0: run the farm (gapsweep.sweep.farm) -- answer requests from the queue, write rows sent by workers
    (rank0 writer), put the units of a failed device back, track progress. A stop request (signal, stop file, a
    worker's TAG_STOP) empties the queue: the units held finish, then every worker leaves. Protocol:
    docs/architecture.md, "The farm"."""
    from mpi4py import MPI

    comm = r.comm
    workers = {w: Worker(gpu=r.gpu_of[w], ahead=r.lookahead) for w in range(1, comm.size)}
    if r.works:
        workers[0] = Worker(gpu=r.gpu_of[0], tail=True, ahead=r.lookahead)
    farm = Farm([u.gpu for u in r.units], r.work, workers, ahead_ok=r.ahead_ok())
    tr = Trace(0, r.gpu)  # GAPSWEEP_TRACE: the farm's timeline (gapsweep.sweep.trace)
    local = _Local(r, tr) if r.works else None
    status = MPI.Status()
    while farm.busy():
        progressed = False
        _send(r, farm, local, _stop_check(r, farm))
        while comm.Iprobe(source=MPI.ANY_SOURCE, tag=MPI.ANY_TAG, status=status):
            src, tag = status.Get_source(), status.Get_tag()
            t0 = time.perf_counter()
            if tag == TAG_READY:
                tr.handle(src)
            tr.rows += tag == TAG_ROW
            _send(r, farm, local, _on_message(r, farm, src, tag, comm.recv(source=src, tag=tag)))
            tr.busy_s += time.perf_counter() - t0
            progressed = True
        while local is not None:
            try:
                tag, msg = local.events.get_nowait()
            except queue.Empty:
                break
            if tag == TAG_ERROR:
                raise msg
            _send(r, farm, local, _on_message(r, farm, 0, tag, msg))
            progressed = True
        if not progressed:
            time.sleep(2e-4 if local is not None else 2e-3)
    if local is not None:
        local.thread.join()
    tr.write()
    r.ended(farm)


def _stop_check(r: _Run, farm: Farm) -> list[tuple[int, int | None]]:
    """A stop request (signal, stop file: looked for every 0.5 s) empties the farm's queue, once."""
    now = time.monotonic()
    if farm.stopping or (now < r.next_check and r.stop.signum is None):
        return []
    r.next_check = now + 0.5
    if not r.stop.requested():
        return []
    log.warning("stop requested (%s): finishing the tasks in flight", limits.SIGNAL_NAMES.get(r.stop.signum,
                                                                                            r.stop.signum))
    if r.stop.on_request is not None:
        r.stop.on_request(r.stop.signum)
    return farm.stop()


def _on_message(r: _Run, farm: Farm, src: int, tag: int, msg: Any) -> list[tuple[int, int | None]]:
    """One message of worker ``src`` (0: the coordinator's own thread); returns the farm's dispatches."""
    if tag == TAG_ROW:
        k, i, res = msg
        farm.row(k, i)
        # rank0 writer: rank 0 writes every row; mpio: workers wrote theirs, rank 0 writes its own.
        if r.st is not None and (r.wmode != "mpio" or src == 0):
            r.st.write(i, res)
        r.prog.update(res, i)
        return []
    if tag == TAG_READY:
        return farm.request(src, msg)
    if tag == TAG_FAULT:
        return farm.fault(src, msg)
    if tag == TAG_STOP and r.stop.signum is None:
        r.stop.signum = msg
    r.next_check = 0.0
    return []


def _send(r: _Run, farm: Farm, local: _Local | None, sends: list[tuple[int, int | None]]) -> None:
    """Hand out the farm's dispatches: ``(unit, rows to skip, epoch)`` or None (leave the farm)."""
    for wid, k in sends:
        msg = None if k is None else (k, farm.skip(k), farm.workers[wid].epoch)
        if wid == 0:
            local.inbox.put(msg)
        else:
            r.comm.send(msg, dest=wid, tag=TAG_WORK)


def _work(r: _Run) -> None:
    """Worker rank: ask for work, run the units it is sent (holding some ahead on a GPU worker), write (mpio)
    or send (rank0 writer) each row as it finishes, and say when a unit is done (TAG_READY). A device fault is
    reported (TAG_FAULT) instead of rows: the coordinator gives the units this rank held to other workers and
    this rank only CPU units from then on. A signal to this rank is passed on to rank 0 (TAG_STOP), which stops
    handing out work."""
    comm, told = r.comm, False

    def get(block: bool) -> Any:
        if block or comm.Iprobe(source=0, tag=TAG_WORK):
            return comm.recv(source=0, tag=TAG_WORK)
        return None

    tr = Trace(r.rank, r.gpu)  # GAPSWEEP_TRACE: the farm's timeline (gapsweep.sweep.trace)

    def ready(k: int | None) -> None:
        tr.ask()
        comm.send(k, dest=0, tag=TAG_READY)

    held = _Held(r, get, ready)
    ready(None)
    while (msg := held.next()) is not None:
        t0, io = time.time(), 0.0
        try:
            for i, res in r.units_of(*msg):
                t1 = time.perf_counter()
                if r.wmode == "mpio":
                    r.st.write(i, res)
                    res = TaskResult(res.status, "", {})  # rank 0 only counts it
                comm.send((msg[0], i, res), dest=0, tag=TAG_ROW)
                io += time.perf_counter() - t1
        except DeviceFault as e:
            held.fault()
            comm.send(_fault(r.rank, r.gpu, e), dest=0, tag=TAG_FAULT)
            continue
        finally:
            tr.unit(msg[0], t0, r.units[msg[0]].gpu, len(r.units[msg[0]].tasks), io)
        if r.stop.signum is not None and not told:
            comm.send(r.stop.signum, dest=0, tag=TAG_STOP)
            told = True
        ready(msg[0])
    tr.write()


def _fields_dir(store: str | Path) -> Path:

    return fields_dir(store)

