"""Worker of tests/mpi/test_distributed.py, run as ``mpiexec -n P python tests/mpi/distributed_worker.py OUT``:
every check of one distributed solve against the single-process one on the same rank count, written by rank 0
as JSON to OUT (the test asserts on it). Not a test module itself (no ``test_`` prefix)."""

from __future__ import annotations

import json
import sys
import tracemalloc
import warnings

import numpy as np
from mpi4py import MPI

from gapsweep import gfmd
from gapsweep.core import slab
from gapsweep.core.slab import SlabFFT
from gapsweep.gfmd import _lean, distributed
from gapsweep.surfaces.synthetic import self_affine, self_affine_rows

comm = MPI.COMM_WORLD
out: dict = {"ranks": comm.Get_size(), "transform": [], "surface": [], "solve": [], "memory": []}


def gathered(value):
    return comm.allgather(value)


def transforms() -> None:
    """The distributed rfft2 against numpy's rfft2 (relative to the largest coefficient) and the round trip."""
    rng = np.random.default_rng(7)
    for shape in [(96, 160), (50, 50), (37, 50), (64, 63)]:
        a = rng.standard_normal(shape)
        for chunk in (1 << 26, 300):  # one chunk, and chunks of a few rows
            f = SlabFFT(shape, comm, chunk=chunk)
            A = f.rfft2(a[f.row])
            ref = np.fft.rfft2(a).T[f.col]
            fwd = float(np.abs(A - ref).max() / np.abs(np.fft.rfft2(a)).max())
            back = float(np.abs(f.irfft2(A) / a.size - a[f.row]).max() / np.abs(a).max())
            out["transform"].append({"shape": shape, "chunk": chunk, "forward": max(gathered(fwd)),
                                     "inverse": max(gathered(back))})


def surfaces() -> None:
    for n, kw in [(64, dict(hurst=0.8, lambda_l=0.25, lambda_s=1 / 20, seed=3)),
                  (50, dict(hurst=0.3, lambda_l=0.5, lambda_s=1 / 20, seed=11, rms_height=0.01,
                            amplitudes="gaussian"))]:
        h = self_affine(n, **kw)
        hl = self_affine_rows(n, comm=comm, **kw)
        same = bool(np.array_equal(h[gfmd.slab_rows(n, comm)], hl))
        out["surface"].append({"n": n, "identical": all(gathered(same))})


def compare(name: str, h: np.ndarray, dist: dict | None = None, strict: bool = True, **kw) -> None:
    """Single process (numpy backend, solved on rank 0 and sent to every rank: the same result each rank would
    get, without P-1 copies of it competing for the cores) against the distributed solve (with the extra keywords
    ``dist``; ``strict``: the same minimiser, so the same iterations, else agreement to the solver tolerance)."""
    rows = gfmd.slab_rows(h.shape[0], comm)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        ref = None
        if comm.Get_rank() == 0:
            r1 = gfmd.solve(h, backend="numpy", **kw)
            ref = {k: getattr(r1, k) for k in ("status", "iterations", "mean_gap", "contact_area", "elastic_energy",
                                               "gap")}
            ref["hist"] = r1.gap_histogram(40)
        ref = comm.bcast(ref, root=0)
        r = distributed.solve(h[rows], comm=comm, **kw, **(dist or {}))
    e1, d1, _ = ref["hist"]
    e, d, _ = r.gap_histogram(40)
    gap_err = float(np.abs(r.gap - ref["gap"][rows]).max() / np.abs(ref["gap"]).max())
    same_scalars = all(x == (r.mean_gap, r.contact_area, r.iterations) for x in
                       gathered((r.mean_gap, r.contact_area, r.iterations)))
    out["solve"].append({
        "case": name, "shape": list(h.shape), "strict": strict, "tol": kw.get("tol"),
        "status": [ref["status"], r.status], "iterations": [ref["iterations"], r.iterations],
        "mean_gap": [ref["mean_gap"], r.mean_gap], "contact_area": [ref["contact_area"], r.contact_area],
        "elastic_energy": [ref["elastic_energy"], r.elastic_energy],
        "gap_field": max(gathered(gap_err)), "same_on_ranks": same_scalars,
        "histogram": float(max(np.abs(e - e1).max(), np.abs(d - d1).max() / d1.max())),
        "shape_reported": list(r.shape)})


def solves() -> None:
    h = self_affine(50, 0.8, lambda_l=0.25, lambda_s=1 / 20, seed=5)  # 50 rows: not divisible by 3 or 4
    compare("exponential cg", h, sigma0=1e-2, gamma0=1e-3, rho=0.02, tol=1e-10)
    compare("exponential fire", h, sigma0=1e-2, gamma0=1e-3, rho=0.02, tol=1e-8, method="fire")
    compare("hard wall pcg", h, sigma0=1e-2, interaction="hard_wall", tol=1e-10, method="pcg")
    # the lean L-BFGS (gfmd._lean) with one process's 8 pairs: the same iteration as gfmd._smooth
    compare("adhesive", h, dict(memory=8), sigma0=1e-3, interaction="adhesive", work=1e-3, rho=0.02, tol=1e-9)
    compare("adhesive tensile", h, dict(memory=8), sigma0=-2e-3, interaction="adhesive", work=1e-3, rho=0.02,
            tol=1e-8)
    # its default, 2 pairs (12 arrays): another iteration, the same equilibrium to the solver tolerance
    for s0 in (1e-3, -2e-3):
        compare(f"adhesive lean {s0:g}", h, strict=False, sigma0=s0, interaction="adhesive", work=1e-3, rho=0.02,
                tol=1e-10)
    rect = np.random.default_rng(2).standard_normal((96, 160)) * 0.01
    compare("exponential rectangle", rect, dict(memory=8), sigma0=1e-2, gamma0=1e-3, rho=0.01, tol=1e-10,
            length=(0.6, 1.0))
    compare("hard wall rectangle", rect, sigma0=5e-2, interaction="hard_wall", tol=1e-10, method="pk",
            length=(0.6, 1.0))


def memory() -> None:
    """Peak memory per rank of distributed solves (numpy arrays traced by tracemalloc, 4-row chunks so that the
    chunked passes' temporaries are small as at large n), in arrays ``A`` of the rank's rows (the surface counted
    as one), against gfmd.distributed.solve_memory's estimate."""
    n = 256
    old = slab.DEFAULT_CHUNK, dict(_lean.CHUNK)
    slab.DEFAULT_CHUNK, _lean.CHUNK["numpy"] = 4 * n, 4 * n
    h = self_affine(n, 0.8, lambda_l=0.25, lambda_s=1 / 20, seed=5)[gfmd.slab_rows(n, comm)].copy()
    a = 8.0 * -(-n // comm.Get_size()) * n
    for kind, kw in [("exponential", dict(sigma0=1e-2, gamma0=1e-3, rho=0.01)),
                     ("adhesive", dict(sigma0=1e-3, interaction="adhesive", work=1e-3, rho=0.01)),
                     ("adhesive", dict(sigma0=-1e-3, interaction="adhesive", work=1e-3, rho=0.01))]:
        tracemalloc.start()
        base = tracemalloc.get_traced_memory()[0]
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            r = distributed.solve(h, comm=comm, host=False, tol=1e-8, **kw)
        peak = tracemalloc.get_traced_memory()[1] - base
        tracemalloc.stop()
        est = distributed.solve_memory((n, n), comm.Get_size(), kind, tensile=kw["sigma0"] < 0)
        out["memory"].append({"kind": kind, "sigma0": kw["sigma0"], "status": r.status,
                              "measured_arrays": 1.0 + max(gathered(peak)) / a,  # + the surface
                              "estimated_arrays": est["arrays"] + est["scratch_arrays"]})
    slab.DEFAULT_CHUNK, _lean.CHUNK = old


transforms()
surfaces()
solves()
memory()
if comm.Get_rank() == 0:
    with open(sys.argv[1], "w") as f:
        json.dump(out, f, indent=1)
