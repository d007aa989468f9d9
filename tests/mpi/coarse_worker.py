"""Worker of tests/mpi/test_coarse_mpi.py, run as ``mpiexec -n P python tests/mpi/coarse_worker.py OUT``: the
coarse-to-fine start (gapsweep.gfmd._coarse) split over the ranks against the plain single-process solve, and its
layout exchange against analytic values; rank 0 writes JSON to OUT. Not a test module (no ``test_`` prefix)."""

from __future__ import annotations

import json
import sys
import warnings

import numpy as np
from mpi4py import MPI

from gapsweep import gfmd
from gapsweep.core.slab import SlabFFT
from gapsweep.gfmd import _coarse, distributed
from gapsweep.surfaces.synthetic import self_affine

comm = MPI.COMM_WORLD
out: dict = {"ranks": comm.Get_size(), "prolong": [], "restrict": [], "solve": []}


def field(mx: int, my: int) -> np.ndarray:
    x = np.arange(mx)[:, None] / mx
    y = np.arange(my)[None, :] / my
    return 0.3 + np.cos(2 * np.pi * (3 * x + 5 * y)) + 0.5 * np.sin(2 * np.pi * (-7 * x + 2 * y))


def layouts() -> None:
    """A band-limited field prolonged from (24, 40) to 2x and 4x finer grids and restricted back: its exact
    samples (rank counts whose column blocks differ in size and do not align between the grids; once with
    host buffers of 50 coefficients, so that rank pairs exchange different numbers of chunks)."""
    nx, ny = 24, 40
    fc = SlabFFT((nx, ny), comm)
    Z = fc.rfft2(field(nx, ny)[fc.row]) / (nx * ny)
    for f, chunk in ((2, _coarse.CHUNK), (4, _coarse.CHUNK), (4, 50)):  # 50: many chunks per rank pair
        _coarse.CHUNK = chunk
        ff = SlabFFT((f * nx, f * ny), comm)
        fine = ff.irfft2(_coarse.remap(Z, fc, ff))
        err = float(np.abs(fine - field(f * nx, f * ny)[ff.row]).max())
        out["prolong"].append({"factor": f, "error": max(comm.allgather(err))})
        back = _coarse.restrict(field(f * nx, f * ny)[ff.row], ff, fc)
        err = float(np.abs(back - field(nx, ny)[fc.row]).max())
        out["restrict"].append({"factor": f, "error": max(comm.allgather(err))})
    _coarse.CHUNK = 1 << 24


def solves() -> None:
    h = self_affine(128, 0.8, lambda_l=0.5, lambda_s=1 / 32, rms_slope=0.5, seed=5)
    rect = self_affine(160, 0.8, lambda_l=0.5, lambda_s=1 / 20, rms_slope=0.5, seed=2)[:96, :]
    cases = [("exponential square", h, 1.0, dict(interaction="exponential", gamma0=1e-3, rho=2 / 128)),
             ("adhesive square", h, 1.0, dict(interaction="adhesive", work=2e-4, rho=2 / 128)),
             ("exponential rectangle", rect, (0.6, 1.0), dict(interaction="exponential", gamma0=1e-3, rho=1 / 160)),
             ("adhesive rectangle", rect, (0.6, 1.0), dict(interaction="adhesive", work=2e-4, rho=1 / 160))]
    for name, hh, length, kw in cases:
        kw = dict(kw, sigma0=1e-2, tol=1e-9, length=length)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            r1 = gfmd.solve(hh, backend="numpy", **kw)
            rows = gfmd.slab_rows(hh.shape[0], comm)
            r = distributed.solve(np.ascontiguousarray(hh[rows]), comm=comm, start="coarse", levels=2, **kw)
        gap_err = float(np.abs(r.gap - r1.gap[rows]).max() / np.abs(r1.gap).max())
        out["solve"].append({
            "case": name, "shape": list(hh.shape), "status": [r1.status, r.status],
            "mean_gap": [r1.mean_gap, r.mean_gap], "contact_area": [r1.contact_area, r.contact_area],
            "iterations": [r1.iterations, r.iterations], "levels": r.diagnostics["levels"],
            "gap_field": max(comm.allgather(gap_err)),
            "same_on_ranks": len({(x, y) for x, y in comm.allgather((r.mean_gap, r.iterations))}) == 1})


layouts()
solves()
if comm.Get_rank() == 0:
    with open(sys.argv[1], "w") as fh:
        json.dump(out, fh, default=float)
