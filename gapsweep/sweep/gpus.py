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
(tests/hooks).
"""

from __future__ import annotations

import os
import shutil
import subprocess
from typing import Any

__all__ = ["assign", "rank_gpu", "visible_count"]


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
    n = visible_count()
    if comm is None:
        return assign(0, n, per_gpu)
    from mpi4py import MPI

    node = comm.Split_type(MPI.COMM_TYPE_SHARED)
    try:
        root_here = node.allreduce(1 if comm.rank == 0 else 0, op=MPI.SUM) > 0
        local = node.rank
    finally:
        node.Free()
    if not coordinator_works and root_here:
        if comm.rank == 0:
            return None
        local -= 1  # node-local ranks are ordered by world rank, so world rank 0 is local rank 0 here
    return assign(local, n, per_gpu)
