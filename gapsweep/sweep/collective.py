"""Collective runs: a job whose GFMD tasks each span every MPI rank (``[methods.gfmd] distributed = true``;
docs/jobs.md, docs/gfmd.md "One solve over several processes").

Every rank goes through the job's units in the same order; a distributed task is solved by all ranks together
(``gapsweep.gfmd.solve(h_rows, comm=comm)``: each rank holds its rows of the surface and of the fields), the
row's scalars (global: mean gap, contact area, energies, the gap's statistics and histograms, reduced over the
ranks) are the same on every rank and rank 0 writes them into the store, as for any row. The surface is made in
place (each rank its rows, gapsweep.sweep.slabs) and kept fields are written by rows, every rank its own
(``gapsweep.sweep.fields.write_field_rows``: collectively under ``mpio``, else through rank 0). Tasks of other
methods in the same job run on rank 0 alone. This replaces the coordinator/worker farm for such a job (the farm hands
whole tasks to single ranks); it is chosen by :func:`is_collective`. The task itself is solved by the GFMD
plug-in (``gapsweep.sweep.methods.gfmd.run_slab``, when the runner gives the context a communicator).

A distributed solve raises the same errors on every rank (its checks are collective), so a failed task is a
failed row on every rank and the run goes on together; an error on one rank alone ends the job (``Abort``),
as any error outside a task does in the farm."""

from __future__ import annotations

import logging
from collections.abc import Callable, Iterator
from typing import Any

from gapsweep.sweep import budget, gpus
from gapsweep.sweep.context import Context
from gapsweep.sweep.resume import RunError
from gapsweep.sweep.schema import Task, TaskResult, Unit

__all__ = ["DoesNotFit", "check", "check_memory", "check_options", "is_collective", "run_collective"]

log = logging.getLogger("gapsweep.runner")
CUDA_CONTEXT = 0.5e9  # bytes a CUDA context and NCCL take on each GPU (as gapsweep.sweep.budget counts)


def is_collective(tasks: list[Task]) -> bool:
    """Whether the job asks for distributed tasks (then every rank runs the job together)."""
    return any(t.opt("distributed") for t in tasks)


def _kind(t: Task) -> str:
    """``gfmd.distributed.solve_memory``'s kind of a task's solve."""
    if t.law == "hard_wall":
        return "hard_wall"
    if t.law == "exponential":
        return "exponential"
    if t.law == "hard_wall_adhesive":  # its projected L-BFGS (gfmd._bounded.memory_plan, 10 pairs)
        return "bounded"
    return "smooth"


class DoesNotFit(RuntimeError):
    """A distributed task's memory exceeds the GPU's or the host's (the runner raises it as its RunError)."""


def check_memory(tasks: list[Task], ranks: int, on_gpu_total: float | None = None,
                 host_total: float | None = None) -> list[str]:
    """Plan lines for the distributed tasks over ``ranks`` ranks; raises :class:`DoesNotFit` when the largest
    does not fit: on GPUs (``backend = "cupy"``, one GPU per rank) the solve's slabs
    (``gfmd.distributed.solve_memory``) and a CUDA context against one GPU's memory; on the CPU the slabs of all
    ranks (one node; the surface's rows among them: it is made in place) against the host's memory.
    ``on_gpu_total`` / ``host_total``: the memory to check against (default: this machine's, 0 or None: not checked)."""
    from gapsweep.gfmd.distributed import solve_memory

    dist = [t for t in tasks if t.opt("distributed")]
    if not dist:
        return []
    gpu_need = host_need = 0.0
    for t in dist:
        per_rank = solve_memory((t.n, t.n), ranks, _kind(t), memory=t.opt("extra.memory"),  # L-BFGS pairs
                                tensile=t.sigma0 < 0)["bytes_per_rank"]
        if t.opt("backend") == "cupy":
            gpu_need = max(gpu_need, per_rank + CUDA_CONTEXT)
        else:
            host_need = max(host_need, per_rank)
    lines = []
    if gpu_need:
        lines.append(f"  distributed GFMD: ~{budget.human(gpu_need)} per GPU ({ranks} GPUs, one rank each)")
        have = budget.gpu_memory_total() if on_gpu_total is None else on_gpu_total
        if have and gpu_need > have:
            raise DoesNotFit(f"a distributed GFMD task needs ~{budget.human(gpu_need)} per GPU on {ranks} GPUs, more "
                           f"than this GPU's {budget.human(have)}: use more GPUs (ranks) or smaller grids (n)")
    if host_need:
        lines.append(f"  distributed GFMD: ~{budget.human(host_need)} per rank for the solve ({ranks} ranks)")
        ram = budget.memory_total() if host_total is None else host_total
        # each rank's rows of the surface are among the solve's arrays (made in place, gapsweep.sweep.slabs);
        # beyond them every rank's interpreter, and rank 0 a file map it reads whole (the plug-in's memory)
        whole = ranks * host_need + budget.peak_memory(dist) + (ranks - 1) * budget.BASE_MEMORY
        if ram and whole > ram:
            raise DoesNotFit(f"a distributed GFMD task needs ~{budget.human(host_need)} per rank for the solve, "
                           f"~{budget.human(whole)} over {ranks} ranks, more than this "
                           f"machine's {budget.human(ram)}: use more nodes or smaller grids (n)")
    return lines


def check(tasks: list[Task], ranks: int) -> list[str]:
    """:func:`check_memory` against this node's GPU memory (from nvidia-smi: no CUDA context here) and host
    memory, its refusal as the runner's RunError; the plan's lines (none for a job without distributed tasks).
    ``gapsweep plan`` and ``gapsweep run`` (rank 0, before anything is written) refuse the same jobs."""
    if not is_collective(tasks):
        return []
    try:
        return check_memory(tasks, ranks, on_gpu_total=gpus.memory())
    except DoesNotFit as e:
        raise RunError(str(e)) from None


def check_options(tasks: list[Task], task_timeout: float | None, batch: str) -> None:
    """Refuse (RunError) the run options a collective run cannot honour: ``--task-timeout`` (a limit on one rank
    would leave the others in a collective call) and ``--batch`` (every rank solves one task at a time)."""
    if is_collective(tasks) and (task_timeout is not None or batch != "off"):
        raise RunError("[methods.gfmd] distributed = true: every rank solves each task together; "
                       "--task-timeout and --batch do not apply (leave them out)")


# ---------------------------------------------------------------------------------------------- the run
def run_collective(comm: Any, tasks: list[Task], units: list[Unit], work: list[int], ctx: Context,
                   run_unit: Callable[..., Iterator[tuple[int, TaskResult]]], todo: set[int],
                   write: Callable[[int, TaskResult], None], stop: Any) -> None:
    """Go through the units ``work`` in order on every rank (module docstring): a unit of distributed tasks on
    all ranks (``ctx.comm = comm``), any other on rank 0 alone; rank 0 writes each row (``write``). A stop
    request (a signal to any rank, or the stop file) ends the run after the current task, on every rank.
    ``run_unit(tasks, unit, ctx, todo, limit, stop)`` is the runner's unit loop."""
    rank = comm.Get_rank()
    ctx.comm = comm
    if rank == 0:
        n = sum(1 for k in work for i in units[k].tasks if tasks[i].opt("distributed") and i in todo)
        log.info("collective run: %d distributed task(s), each solved by all %d ranks together", n,
                 comm.Get_size())
    for k in work:
        unit = units[k]
        together = any(tasks[i].opt("distributed") for i in unit.tasks)
        if together or rank == 0:
            for i, res in run_unit(tasks, unit, ctx, todo, None, None):
                if rank == 0:
                    write(i, res)
                if together and _stopping(comm, stop):
                    return
        if _stopping(comm, stop):
            return


def _stopping(comm: Any, stop: Any) -> bool:
    """Whether any rank has a stop request (a signal to any rank -- a SIGTERM to rank 1 alone, as a batch system
    or a user may send -- or the stop file), on every rank: one allgather of the ranks' signal numbers. A rank
    that learns of another's request adopts its signal, so that every rank, rank 0 recording the run included,
    ends the run as interrupted by it. (Before issue 40 rank 0's view was broadcast: a signal to any other rank
    was ignored and the run went on to the end.)"""
    mine = int(stop.signum) if stop.requested() else 0
    sig = max(comm.allgather(mine))
    if sig and stop.signum is None:
        stop.signum = sig
    return bool(sig)
