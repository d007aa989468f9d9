"""Which GPU a rank of a sweep uses (docs/running.md, "GPUs"): one rank per GPU, chosen by node-local rank.

Policy. The ranks of a node that work (the coordinator, world rank 0, is left out when it does not work) are
numbered ``r = 0, 1, ...`` in node-local order; with ``G`` visible GPUs and ``K`` ranks allowed per GPU
(``--ranks-per-gpu``, default 1), working rank ``r`` uses GPU ``r mod G`` if ``r < K G``, else none. So with the
default, ranks beyond the GPU count work the CPU units (theory, Fokker-Planck, CPU GFMD) and GPU units wait for a
GPU rank; with ``K = 2`` two ranks share each GPU (their CPU work -- surfaces, statistics -- overlaps the other's
GPU work). A process outside MPI (serial runs, ``--shard`` processes) is working rank 0 of its node: start one
per GPU with ``CUDA_VISIBLE_DEVICES=i`` (benchmarks/bench_multi_gpu.py does).

Visible GPUs: ``CUDA_VISIBLE_DEVICES`` when set (its entries; ``""`` or ``-1``: none), else ``nvidia-smi -L``
(no nvidia-smi: none). The tests replace :func:`visible_count` to try the policy on machines without GPUs
(tests/hooks). Under MPI one rank per node looks (``rank_gpu``) and tells the others: start-up does not grow with
the rank count.

No function here creates a CUDA context or imports cupy: the coordinator and the CPU ranks never touch a GPU.
The memory of the GPUs (``memory``, for the checks of ``plan`` and ``run``) and their names come from
``nvidia-smi --query-gpu``, a separate process that opens no context in this one.
"""

from __future__ import annotations

import os
import shutil
import subprocess
from dataclasses import dataclass
from typing import Any

__all__ = ["Layout", "assign", "layout", "memory", "query", "rank_gpu", "visible_count"]


def visible_count() -> int:
    """Number of GPUs this process may use (see the module docstring)."""
    vis = os.environ.get("CUDA_VISIBLE_DEVICES")
    if vis is not None:
        return len([x for x in vis.split(",") if x.strip() and x.strip() != "-1"])
    if not shutil.which("nvidia-smi"):
        return 0
    try:
        out = subprocess.run(["nvidia-smi", "-L"], capture_output=True, text=True, timeout=20).stdout
    except (OSError, subprocess.SubprocessError):
        return 0
    return sum(1 for line in out.splitlines() if line.startswith("GPU "))


def _visible_ids() -> list[str] | None:
    """The entries of ``CUDA_VISIBLE_DEVICES`` (None: unset, every GPU of the node is visible)."""
    vis = os.environ.get("CUDA_VISIBLE_DEVICES")
    if vis is None:
        return None
    return [x.strip() for x in vis.split(",") if x.strip() and x.strip() != "-1"]


def query() -> list[dict[str, Any]]:
    """The visible GPUs as ``nvidia-smi --query-gpu`` reports them: ``index``, ``uuid``, ``name`` and
    ``memory`` [bytes], in the order CUDA numbers them in this process (``CUDA_VISIBLE_DEVICES`` by index or
    UUID). Empty without nvidia-smi (or when it fails). Creates no CUDA context."""
    if not shutil.which("nvidia-smi"):
        return []
    try:
        out = subprocess.run(["nvidia-smi", "--query-gpu=index,uuid,name,memory.total",
                              "--format=csv,noheader,nounits"], capture_output=True, text=True, timeout=20).stdout
    except (OSError, subprocess.SubprocessError):
        return []
    gpus = []
    for line in out.splitlines():
        parts = [x.strip() for x in line.split(",")]
        if len(parts) == 4 and parts[0].isdigit():
            try:
                mem = int(float(parts[3]) * 2**20)  # MiB
            except ValueError:
                mem = 0
            gpus.append({"index": parts[0], "uuid": parts[1], "name": parts[2], "memory": mem})
    ids = _visible_ids()
    if ids is None:
        return gpus
    by = {g["index"]: g for g in gpus} | {g["uuid"]: g for g in gpus}
    return [by[i] for i in ids if i in by]


def memory() -> int:
    """Memory of the smallest visible GPU [bytes] (0: unknown -- no nvidia-smi, or no GPU). No CUDA context."""
    return min((g["memory"] for g in query() if g["memory"]), default=0)


def assign(working_rank: int | None, n_gpus: int, per_gpu: int = 1) -> int | None:
    """GPU index of node-local working rank ``working_rank`` (None: a rank that does not work) with ``n_gpus``
    visible GPUs and at most ``per_gpu`` ranks per GPU; None: this rank works CPU units only."""
    if not isinstance(per_gpu, int) or isinstance(per_gpu, bool) or per_gpu < 1:
        raise ValueError(f"--ranks-per-gpu: expected an integer >= 1, got {per_gpu!r}")
    if working_rank is None or n_gpus <= 0 or working_rank >= n_gpus * per_gpu:
        return None
    return working_rank % n_gpus


def rank_gpu(comm: Any, coordinator_works: bool, per_gpu: int = 1) -> int | None:
    """This rank's GPU (collective over ``comm`` when it is not None: every rank must call it)."""
    if comm is None:
        return assign(0, visible_count(), per_gpu)
    from mpi4py import MPI

    node = comm.Split_type(MPI.COMM_TYPE_SHARED)
    try:
        n = node.bcast(visible_count() if node.rank == 0 else None, root=0)  # one look per node
        root_here = node.allreduce(1 if comm.rank == 0 else 0, op=MPI.SUM) > 0
        local = node.rank
    finally:
        node.Free()
    if not coordinator_works and root_here:
        if comm.rank == 0:
            return None
        local -= 1  # node-local ranks are ordered by world rank, so world rank 0 is local rank 0 here
    return assign(local, n, per_gpu)


@dataclass(frozen=True)
class Layout:
    """A farm layout for one node (docs/running.md, "Which layout"): ``ranks`` MPI ranks, of which ``gpu_workers``
    drive one GPU each and ``cpu_workers`` run CPU units; rank 0 coordinates (and works itself only where
    ``coordinator_works``)."""

    ranks: int
    gpu_workers: int
    cpu_workers: int
    coordinator_works: bool

    def args(self) -> str:
        """The mpiexec and gapsweep options that give this layout."""
        if self.ranks == 1:
            return "gapsweep run (one process, no mpiexec)"
        extra = "" if self.coordinator_works == (self.ranks <= 4) else (
            " --coordinator-works " + ("yes" if self.coordinator_works else "no"))
        bind = " --bind-to none" if self.gpu_workers else ""
        return f"mpiexec -n {self.ranks}{bind} gapsweep run ...{extra}"


def layout(n_gpus: int, cores: int, gpu_units: int, cpu_units: int) -> Layout:
    """The layout to pick on a node of ``n_gpus`` GPUs and ``cores`` cores for a job of ``gpu_units`` GPU units and
    ``cpu_units`` CPU units: one GPU worker per GPU (capped by the GPU units; one process and one CUDA context
    per GPU, no MPS needed), one rank per remaining core for the CPU units (capped by their count), and a
    coordinator that only coordinates; on up to 4 cores the coordinator works too, and one worker is a single
    process. Without a visible GPU, GPU units get no worker (they need a GPU node)."""
    g = min(n_gpus, gpu_units) if n_gpus > 0 else 0
    if cores <= 4:  # a small machine: the coordinator works too (the default up to 4 ranks)
        p = max(g, min(cores, g + cpu_units), 1)
        return Layout(p, g, p - g, True)
    c = max(0, min(cores - g - 1, cpu_units))
    if g + c <= 1:  # one worker: a single process does it all (serial run)
        return Layout(1, g, 1 - g, True)
    return Layout(1 + g + c, g, c, False)
