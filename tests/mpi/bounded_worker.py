"""Worker of tests/mpi/test_bounded_mpi.py, run as ``mpiexec -n P python tests/mpi/bounded_worker.py OUT``: the
challenge's law (``interaction="hard_wall_adhesive"``, gapsweep.gfmd._bounded) split over the ranks against the
one-process solve of the same surface, and each rank's traced numpy peak against
``gfmd._bounded.memory_plan``; rank 0 writes JSON to OUT (the test asserts on it). Not a test module itself."""

from __future__ import annotations

import json
import sys
import tracemalloc
import warnings

import numpy as np
from mpi4py import MPI

from gapsweep import gfmd
from gapsweep.gfmd import _bounded

comm = MPI.COMM_WORLD
out: dict = {"ranks": comm.Get_size(), "solve": [], "memory": []}
LAW = "hard_wall_adhesive"


def rough(nx: int, ny: int, seed: int, h_rms: float = 0.01) -> np.ndarray:
    """A random rough surface with a power-law spectrum (every rank draws the same)."""
    rng = np.random.default_rng(seed)
    q = np.hypot(np.fft.fftfreq(nx, 1 / nx)[:, None], np.fft.fftfreq(ny, 1 / ny)[None, :])
    amp = np.where((q >= 2) & (q <= min(nx, ny) / 4), np.where(q > 0, q, 1.0) ** -1.8, 0.0)
    h = np.fft.ifft2(amp * np.exp(2j * np.pi * rng.random((nx, ny)))).real
    return (h - h.mean()) * (h_rms / h.std()) + 0.37  # a mean the solvers must drop


def gathered_rows(a: np.ndarray) -> np.ndarray:
    return np.concatenate(comm.allgather(np.asarray(a)), axis=0)


def compare(name: str, shape: tuple[int, int], seed: int, **kw) -> None:
    h = rough(*shape, seed)
    rows = gfmd.slab_rows(shape[0], comm)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        r1 = gfmd.solve(h, backend="numpy", **kw)
        r = gfmd.solve(h[rows], comm=comm, **kw)
    gap = gathered_rows(r.gap)
    scalars = (r.mean_gap, r.contact_area, r.elastic_energy, r.iterations, r.status)
    out["solve"].append({
        "name": name, "shape": list(shape), "status": [r1.status, r.status],
        "iterations": [r1.iterations, r.iterations], "mean_gap": [r1.mean_gap, r.mean_gap],
        "contact_area": [r1.contact_area, r.contact_area], "elastic_energy": [r1.elastic_energy, r.elastic_energy],
        "same_contact": bool(np.array_equal(r1.gap <= 0, gap <= 0)),
        "gap_field": float(np.abs(gap - r1.gap).max() / np.abs(r1.gap).max()),
        "residual": r.residual, "same_on_ranks": len({repr(s) for s in comm.allgather(scalars)}) == 1,
        "continuation_steps": r.diagnostics.get("continuation_steps", 0), "sigma0": kw["sigma0"]})


def memory(shape: tuple[int, int], sigma0: float, pairs: int) -> None:
    """Each rank's traced numpy peak of a distributed solve against the plan, in arrays of the rank's rows (the
    surface, allocated before, counted as one): 4096-element chunks of the passes and of the slab transform's 1-D
    transforms, so that the chunks are small against the grid as at large n."""
    from gapsweep.core import slab

    nx, ny = shape
    h = rough(*shape, 5)
    hl = np.ascontiguousarray(h[gfmd.slab_rows(nx, comm)])
    kw = dict(sigma0=sigma0, interaction=LAW, work=4e-4 / nx, rho=1.0 / nx, tol=1e-8, memory=pairs,
              length=(1.0, ny / nx), host=False)
    old = _bounded._CHUNK, slab.DEFAULT_CHUNK
    _bounded._CHUNK = slab.DEFAULT_CHUNK = 4096
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        tracemalloc.start()
        base = tracemalloc.get_traced_memory()[0]
        r = gfmd.solve(hl, comm=comm, **kw)
        peak = tracemalloc.get_traced_memory()[1] - base
        tracemalloc.stop()
    plan = _bounded.memory_plan(shape, comm.Get_size(), memory=pairs, tensile=sigma0 < 0, backend="slab")
    _bounded._CHUNK, slab.DEFAULT_CHUNK = old
    a = plan["array_bytes"]
    out["memory"].append({"shape": list(shape), "sigma0": sigma0, "pairs": pairs, "status": r.status,
                          "measured_arrays": 1.0 + max(comm.allgather(peak)) / a,
                          "estimated_arrays": plan["arrays"], "grid_arrays": plan["grid_arrays"]})


compare("square, compressive", (50, 50), 1, sigma0=2e-3, interaction=LAW, work=8e-4 / 50, rho=1 / 50, tol=1e-11)
compare("odd rectangle, tensile from zero", (37, 50), 2, sigma0=-3e-5, interaction=LAW, work=4e-4 / 37,
        rho=1 / 37, length=(0.74, 1.0), e_star=1.5, tol=1e-10)
compare("odd columns, zero load, 3 pairs", (64, 63), 3, sigma0=0.0, interaction=LAW, work=6e-4 / 64, rho=1 / 64,
        length=(1.0, 63 / 64), tol=1e-11, memory=3)
memory((192, 160), 1e-3, 4)
memory((150, 192), -5e-6, 2)
if comm.Get_rank() == 0:
    with open(sys.argv[1], "w") as f:
        json.dump(out, f)
