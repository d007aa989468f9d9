"""Steady laminar flow through the gap: the Reynolds equation on a finite-volume grid (docs/model.md, "M8 Leakage
through the gap").

The fluid is incompressible and Newtonian, the gap ``g(x, y)`` is fixed (no deformation by the fluid pressure) and
the flow is laminar and lubrication-like (slopes small, no cavitation):

    div( g^3 / (12 mu) grad p ) = 0,     q = -(g^3 / (12 mu)) grad p   (flux per unit width),

with ``p = dp`` on the inlet edge and ``p = 0`` on the outlet edge of the map along ``axis``; the other direction
is periodic (``periodic=True``) or closed (no flux through the sides: a measured, non-periodic map). Cells with
``g <= 0`` are contact: no flow enters or leaves them.

Discretisation: cell-centred finite volumes, one pressure per open cell. The conductivity of a cell is
``c = g^3 / (12 mu)``. The conductance of the face between two cells is the harmonic mean ``2 c_i c_j / (c_i +
c_j)`` of their conductivities -- two half cells in series, which conserves flux across a jump of ``g`` and is
exact for a gap that is piecewise constant on the cells (so a gap varying along one direction gives the exact
harmonic mean of ``g^3`` across the stripes and the exact arithmetic mean along them). A face next to a contact
cell is closed (harmonic mean of ``c`` and 0). A cell on the inlet or outlet edge is joined to the edge by its own
half cell (conductance ``c / (d / 2)``).

Open cells that are not connected (through open faces) to both edges carry no flux; they are dropped from the
linear system before it is solved (an isolated pocket would make the matrix singular), and their pressure is
reported as NaN. When no open cluster joins the edges, the gap does not percolate: the leak rate is exactly 0.

The linear system is symmetric positive definite; it is solved by conjugate gradients preconditioned with
algebraic multigrid (pyamg, the ``flow`` extra), by a direct sparse solve on small grids, by Jacobi-preconditioned
CG (scipy) when pyamg is missing, or on the GPU by Jacobi-preconditioned CG (cupyx.scipy.sparse).
"""

from __future__ import annotations

import logging
import math
import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import scipy.sparse as sp
from scipy.sparse import csgraph

log = logging.getLogger("gapsweep.flow")

__all__ = ["FlowResult", "open_clusters", "solve"]

BACKENDS = ("auto", "numpy", "cupy")
SOLVERS = ("auto", "amg", "direct", "cg")
# Up to this many unknowns (a 256^2 map) a direct sparse factorisation (SuperLU) is used: in exploratory runs on a
# hard-wall gap of 256^2 it took about half the time of AMG-CG with its setup (benchmarks/bench_flow.py times the
# solver "auto" picks, docs/benchmarks.md).
DIRECT_MAX = 70_000


@dataclass
class FlowResult:
    """The flow through one gap field (docs/model.md M8).

    ``leak_rate``: volume flux per unit width of the map across the pressure drop, in units of
    ``length^3 pressure / (viscosity length)`` (m^2/s for g in m, dp in Pa, mu in Pa s).
    ``conductance``: ``K = leak_rate * length[axis] / pressure_drop`` (``g^3 / (12 mu)`` for a uniform gap).
    ``percolating``: whether an open path joins inlet and outlet (False: ``leak_rate`` is exactly 0).
    ``ratio``: ``K`` over ``<g>^3 / (12 mu)`` with ``<g>`` the mean gap over the whole map (contact counted as 0).
    ``open_fraction``: area fraction with ``g > threshold``; ``connected_fraction``: the part of the area in
    clusters joining both edges (the unknowns of the linear system).
    ``balance``: ``|Q_in - Q_out| / Q_in``, the relative flux imbalance of the solution (a check of the solve).
    ``residual``: relative residual ``|A p - b| / |b|`` of the linear solve; ``converged``: it is at most
    ``10 tol`` (the iterative solvers stop on the residual of the Jacobi-scaled system, which differs by a
    bounded factor) and the leak rate is finite.
    ``pressure`` (optional, ``fields=True``): pressure per cell (NaN on contact and on cells not joined to both
    edges); ``flux``: cell-centred flux per unit width, shape ``(2, nx, ny)`` (component along array axis 0,
    then axis 1; the mean of the cell's two faces in each direction).
    """

    leak_rate: float
    conductance: float
    percolating: bool
    ratio: float
    open_fraction: float
    connected_fraction: float
    mean_gap: float
    balance: float
    residual: float
    converged: bool
    iterations: int
    solver: str
    backend: str
    wall_time: float
    axis: int
    periodic: bool
    length: tuple[float, float]
    viscosity: float
    pressure_drop: float
    pressure: np.ndarray | None = field(default=None, repr=False)
    flux: np.ndarray | None = field(default=None, repr=False)


def _host(a: Any) -> np.ndarray:
    mod = type(a).__module__ or ""
    if mod.startswith("cupy"):
        return a.get()
    return np.asarray(a)


def _positive(name: str, v: Any) -> float:
    try:
        x = float(v)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a positive finite number, got {v!r}") from None
    if not (math.isfinite(x) and x > 0):
        raise ValueError(f"{name} must be a positive finite number, got {v!r}")
    return x


def _faces(open_: np.ndarray, c: np.ndarray, a: int, periodic: bool) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Open faces between neighbours along array axis ``a``: flat indices (i, j) of the two cells and the
    harmonic-mean conductivity of the face. ``periodic``: the face between the last and the first row counts."""
    nx, ny = open_.shape
    idx = np.arange(nx * ny).reshape(nx, ny)
    nxt = np.roll(idx, -1, axis=a)
    cn = np.roll(c, -1, axis=a)
    on = open_ & np.roll(open_, -1, axis=a)
    if not periodic:  # drop the wrap-around faces
        sl = [slice(None), slice(None)]
        sl[a] = -1
        on = on.copy()
        on[tuple(sl)] = False
    i, j = idx[on], nxt[on]
    ci, cj = c[on], cn[on]
    return i, j, 2.0 * ci * cj / (ci + cj)


def open_clusters(gap: Any, *, axis: int = 1, periodic: bool = True, threshold: float = 0.0,
                  ) -> tuple[np.ndarray, bool]:
    """The open cells (``gap > threshold``) joined through open faces to both the inlet (index 0) and the outlet
    (last index) edge along ``axis``, as a boolean map, and whether any exist (the gap percolates). Neighbours
    are the 4 nearest cells; the direction across ``axis`` wraps when ``periodic``. docs/model.md M8."""
    g = _host(gap)
    open_ = g > threshold
    nx, ny = g.shape
    n = nx * ny
    across = 1 - axis
    rows, cols = [], []
    for a in (0, 1):
        i, j, _ = _faces(open_, open_.astype(float), a, periodic and a == across)
        rows.append(i)
        cols.append(j)
    r, cc = np.concatenate(rows), np.concatenate(cols)
    adj = sp.coo_matrix((np.ones(r.size, dtype=np.int8), (r, cc)), shape=(n, n)).tocsr()
    _, labels = csgraph.connected_components(adj, directed=False)
    labels = labels.reshape(nx, ny)
    first = [slice(None), slice(None)]
    last = [slice(None), slice(None)]
    first[axis], last[axis] = 0, -1
    lin = labels[tuple(first)][open_[tuple(first)]]
    lout = labels[tuple(last)][open_[tuple(last)]]
    both = np.intersect1d(lin, lout)
    keep = open_ & np.isin(labels, both)
    return keep, bool(both.size)


def _gap_array(gap: Any) -> np.ndarray:
    """The gap field as a float64 host array: 2-D, real, finite (TypeError / ValueError naming the problem)."""
    if isinstance(gap, (str, bytes)) or gap is None:
        raise TypeError(f"gap must be a 2-D real array, got {type(gap).__name__}")
    g = _host(gap)
    if not (np.issubdtype(g.dtype, np.floating) or np.issubdtype(g.dtype, np.integer)):
        raise TypeError(f"gap must be a real array, got dtype {g.dtype}")
    if g.ndim != 2 or min(g.shape) < 1:
        raise ValueError(f"gap must be a 2-D array (nx x ny), got shape {g.shape}")
    if not np.all(np.isfinite(g)):
        raise ValueError("gap must be finite everywhere (NaN or inf found)")
    return g.astype(np.float64)


def solve(
    gap: Any,
    *,
    length: float | tuple[float, float] = 1.0,
    axis: int = 1,
    viscosity: float = 1.0,
    pressure_drop: float = 1.0,
    periodic: bool = True,
    threshold: float = 0.0,
    tol: float = 1e-8,
    max_iter: int | None = None,
    solver: str = "auto",
    backend: str = "auto",
    fields: bool = False,
) -> FlowResult:
    """Leak rate through the gap field ``gap`` (``nx x ny``, units of ``length``; numpy or cupy) under the
    pressure drop ``pressure_drop`` along array ``axis`` (0 or 1), by the Reynolds equation
    ``div(g^3/(12 mu) grad p) = 0`` (docs/model.md M8; module docstring for the discretisation).

    ``length``: the map's size, a number or ``(Lx, Ly)`` (one entry per array axis, as in ``gfmd.solve``).
    ``viscosity`` (``mu``) and ``pressure_drop`` (``dp``) are positive; the leak rate is
    ``K dp / length[axis]`` per unit width, ``K`` the effective conductance (``g^3 / (12 mu)`` for a uniform gap).
    ``periodic``: the direction across ``axis`` wraps (a periodic map); False closes the sides (a measured map).
    ``threshold``: cells with ``gap <= threshold`` are contact (default 0, the hard wall's contact).
    ``tol``: relative residual of the linear solve. ``solver``: "auto" (direct up to 70 000 unknowns, else
    "amg" when pyamg is installed, else "cg"), "amg" (pyamg smoothed-aggregation AMG as the preconditioner of
    CG), "direct" (scipy's sparse LU) or "cg" (Jacobi-preconditioned CG). ``backend``: "auto" (cupy for a cupy
    array, else numpy), "numpy" or "cupy" (Jacobi-preconditioned CG on the GPU with cupyx.scipy.sparse; the
    cluster analysis runs on the host). ``fields``: also return the pressure and flux fields.
    A solve that does not reach ``tol`` in ``max_iter`` iterations returns ``converged=False`` (never silently).
    """
    t0 = time.perf_counter()
    if backend not in BACKENDS:
        raise ValueError(f"backend must be one of {BACKENDS}, got {backend!r}")
    if solver not in SOLVERS:
        raise ValueError(f"solver must be one of {SOLVERS}, got {solver!r}")
    on_gpu = backend == "cupy" or (backend == "auto" and (type(gap).__module__ or "").startswith("cupy"))
    g = _gap_array(gap)
    if axis not in (0, 1):
        raise ValueError(f"axis must be 0 or 1 (the array axis of the pressure drop), got {axis!r}")
    lx, ly = (length, length) if np.ndim(length) == 0 else tuple(length)  # type: ignore[misc]
    lx, ly = _positive("length[0]", lx), _positive("length[1]", ly)
    mu = _positive("viscosity", viscosity)
    dp = _positive("pressure_drop", pressure_drop)
    if not isinstance(periodic, (bool, np.bool_)):
        raise ValueError(f"periodic must be True or False, got {periodic!r}")
    threshold = float(threshold)
    if not (math.isfinite(threshold) and threshold >= 0):
        raise ValueError(f"threshold must be a finite number >= 0, got {threshold!r}")
    tol = _positive("tol", tol)
    if tol >= 1:
        raise ValueError(f"tol must be in (0, 1), got {tol!r}")
    nx, ny = g.shape
    d = (lx / nx, ly / ny)  # cell sizes along array axes 0 and 1
    along, across = axis, 1 - axis
    open_ = g > threshold
    mean_gap = float(np.where(open_, g, 0.0).mean())
    keep, perc = open_clusters(g, axis=axis, periodic=bool(periodic), threshold=threshold)
    common = dict(open_fraction=float(open_.mean()), connected_fraction=float(keep.mean()), mean_gap=mean_gap,
                  axis=axis, periodic=bool(periodic), length=(lx, ly), viscosity=mu, pressure_drop=dp)
    if not perc:
        p = np.full(g.shape, np.nan) if fields else None
        return FlowResult(0.0, 0.0, False, 0.0, balance=0.0, residual=0.0, converged=True, iterations=0,
                          solver="none", backend="cupy" if on_gpu else "numpy",
                          wall_time=time.perf_counter() - t0, pressure=p,
                          flux=np.zeros((2, nx, ny)) if fields else None, **common)
    c = np.where(keep, g ** 3 / (12.0 * mu), 0.0)
    # Unknowns: the kept cells, numbered in C order.
    num = np.full(nx * ny, -1, dtype=np.int64)
    kflat = keep.ravel()
    m = int(kflat.sum())
    num[kflat] = np.arange(m)
    diag = np.zeros(m)
    rows, cols, vals = [], [], []
    face = {}
    for a in (0, 1):
        i, j, cf = _faces(keep, c, a, bool(periodic) and a == across)
        t = cf * d[1 - a] / d[a]  # face transmissibility: conductivity x face length / distance of centres
        face[a] = (i, j, t)
        ui, uj = num[i], num[j]
        np.add.at(diag, ui, t)
        np.add.at(diag, uj, t)
        rows += [ui, uj]
        cols += [uj, ui]
        vals += [-t, -t]
    # Edge cells: joined to the inlet (p = dp) and outlet (p = 0) by their half cell.
    first = [slice(None), slice(None)]
    last = [slice(None), slice(None)]
    first[along], last[along] = 0, -1
    idx = np.arange(nx * ny).reshape(nx, ny)
    tb = 2.0 * d[across] / d[along]  # c x face length / half cell
    cin, cout = idx[tuple(first)][keep[tuple(first)]], idx[tuple(last)][keep[tuple(last)]]
    tin, tout = c.ravel()[cin] * tb, c.ravel()[cout] * tb
    np.add.at(diag, num[cin], tin)
    np.add.at(diag, num[cout], tout)
    b = np.zeros(m)
    np.add.at(b, num[cin], tin * dp)
    rows.append(np.arange(m))
    cols.append(np.arange(m))
    vals.append(diag)
    A = sp.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(m, m))
    x, its, name, bk = _linear_solve(A, b, diag, tol=tol, max_iter=max_iter, solver=solver, gpu=on_gpu)
    bnorm = float(np.linalg.norm(b))
    residual = float(np.linalg.norm(A @ x - b) / bnorm)
    qin = float(np.sum(tin * (dp - x[num[cin]])))
    qout = float(np.sum(tout * x[num[cout]]))
    width = (lx, ly)[across]
    leak = qout / width  # flux per unit width: the outflow (equal to the inflow at convergence)
    balance = abs(qin - qout) / abs(qin) if qin else math.inf
    K = leak * (lx, ly)[along] / dp
    k_mean = mean_gap ** 3 / (12.0 * mu)
    converged = residual <= tol * 10 and math.isfinite(leak)  # CG's own test is on the preconditioned residual
    if not converged:
        log.warning("flow solve not converged: relative residual %.3g > tol %.3g after %d iterations (%s)",
                    residual, tol, its, name)
    pres = flux = None
    if fields:
        pf = np.full(nx * ny, np.nan)
        pf[kflat] = x
        pres = pf.reshape(nx, ny)
        flux = np.zeros((2, nx, ny))
        for a in (0, 1):
            i, j, t = face[a]
            q = t * (pf[i] - pf[j]) / d[1 - a]  # flux per unit face length, from i to j along +a
            fa = np.zeros(nx * ny)
            np.add.at(fa, i, 0.5 * q)
            np.add.at(fa, j, 0.5 * q)
            if a == along:  # the edge faces
                np.add.at(fa, cin, 0.5 * tin * (dp - pf[cin]) / d[across])
                np.add.at(fa, cout, 0.5 * tout * pf[cout] / d[across])
            flux[a] = fa.reshape(nx, ny)
    return FlowResult(leak, K, True, K / k_mean if k_mean > 0 else math.inf, balance=balance, residual=residual,
                      converged=converged, iterations=its, solver=name, backend=bk,
                      wall_time=time.perf_counter() - t0, pressure=pres, flux=flux, **common)


def _linear_solve(A: sp.csr_matrix, b: np.ndarray, diag: np.ndarray, *, tol: float, max_iter: int | None,
                  solver: str, gpu: bool) -> tuple[np.ndarray, int, str, str]:
    """Solve the SPD system ``A x = b``: (solution, iterations, solver name, backend)."""
    m = A.shape[0]
    # defaults: AMG-CG's iterations stay flat with the grid; Jacobi-CG's grow with its side
    maxit = max_iter if max_iter is not None else max(1000, 10 * int(math.sqrt(m)) + 200)
    maxit_cg = max_iter if max_iter is not None else 20 * int(math.sqrt(m)) + 1000
    if gpu:
        return (*_gpu_cg(A, b, diag, tol=tol, max_iter=maxit_cg), "cupy")
    if solver == "auto":
        if m <= DIRECT_MAX:
            solver = "direct"
        else:
            from gapsweep.core.extras import has

            solver = "amg" if has("pyamg") else "cg"
            if solver == "cg":
                log.info("flow: pyamg is not installed (pip install 'gapsweep[flow]'); Jacobi-preconditioned CG "
                         "is used, slower on large grids")
    if solver == "direct":
        from scipy.sparse.linalg import spsolve

        return np.asarray(spsolve(A.tocsc(), b)), 1, "direct", "numpy"
    if solver == "amg":
        from gapsweep.core.extras import require

        pyamg = require("pyamg", "the flow solve's multigrid preconditioner (solver='amg')")
        # On the unscaled matrix, with the evolution strength measure (exploratory runs, pyamg 5.4): a symmetric
        # Jacobi scaling first made AMG-CG need about 8x the iterations on a lognormal gap (512^2); the evolution
        # measure follows the decades of g^3 near contact edges, about 5x fewer iterations than the default
        # measure and 8x fewer than classical Ruge-Stuben on a hard-wall GFMD gap (256^2, 20% contact); energy
        # smoothing, root-node aggregation, W-cycles and Jacobi smoothing were slower (docs/benchmarks.md).
        ml = pyamg.smoothed_aggregation_solver(A, symmetry="symmetric", strength="evolution", max_coarse=500)
        res: list[float] = []
        y = ml.solve(b, tol=tol, maxiter=maxit, accel="cg", residuals=res)
        return np.asarray(y), max(len(res) - 1, 0), "amg", "numpy"
    from scipy.sparse.linalg import cg

    s = 1.0 / np.sqrt(diag)
    S = sp.diags(s)
    As = (S @ A @ S).tocsr()
    count = [0]

    def cb(_: Any) -> None:
        count[0] += 1
    y, _info = cg(As, b * s, rtol=tol, atol=0.0, maxiter=maxit_cg, callback=cb)
    return np.asarray(y) * s, count[0], "cg", "numpy"


def _gpu_cg(A: sp.csr_matrix, b: np.ndarray, diag: np.ndarray, *, tol: float, max_iter: int,
            ) -> tuple[np.ndarray, int, str]:
    """Jacobi-preconditioned CG on the GPU (cupyx.scipy.sparse): the symmetrically scaled matrix
    ``D^-1/2 A D^-1/2`` is sent once; the solution comes back to the host."""
    from gapsweep.core.extras import require

    cp = require("cupy", "the flow solve on the GPU (backend='cupy')")
    csp = require("cupyx.scipy.sparse", "the flow solve on the GPU (backend='cupy')")
    cla = require("cupyx.scipy.sparse.linalg", "the flow solve on the GPU (backend='cupy')")
    s = 1.0 / np.sqrt(diag)
    As = (sp.diags(s) @ A @ sp.diags(s)).tocsr()
    Ad = csp.csr_matrix((cp.asarray(As.data), cp.asarray(As.indices), cp.asarray(As.indptr)), shape=As.shape)
    count = [0]

    def cb(_: Any) -> None:
        count[0] += 1
    y, _info = cla.cg(Ad, cp.asarray(b * s), tol=tol, atol=0.0, maxiter=max_iter, callback=cb)
    return _host(y) * s, count[0], "cg-jacobi"
