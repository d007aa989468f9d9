"""One GFMD solve split over the ranks of a communicator (docs/gfmd.md, "One solve over several processes";
docs/model.md M3).

Each rank holds a slab of rows of the surface and of every real field, and a slab of columns of every half
spectrum (:mod:`gapsweep.core.slab`): the elastic operator ``E* q/2`` and the preconditioner ``M(q)`` are diagonal
there, the interaction is local in real space, so the only communication is the transposition inside the two
distributed FFTs of a force evaluation and scalar reductions (norms, Parseval sums, the softmax normalisation
``S = sum exp(w - max w)`` and its maximum, line-search slopes, the mean gap, contact counts).

The minimisers are the single-process ones (same iteration, same decisions): the exponential law's
:class:`gapsweep.gfmd._solvers._Problem` with the runners "cg", "lbfgs", "fire" on the array passes
:class:`gapsweep.gfmd._ops._Ops` given the ranks' reducer, the Parseval weights of the rank's columns and the
``q = 0`` owner flag (their fused cupy variant ``gfmd._cuda._SlabCupyOps`` on GPUs); the smooth minimiser
(``gfmd._smooth``, adhesion and the exponential law on rectangles) and the hard wall (``gfmd._constrained``,
methods "pcg" and "pk") on :class:`SlabGrid`, whose reductions (``mean``, ``dot``, ``amin``, ``mode0`` ...) combine
over the ranks where :class:`gapsweep.gfmd._grid.Grid` reduces locally. Results therefore equal the single-process
solve up to summation order (tests/mpi/test_distributed.py: mean gap and contact area to 1e-9).

This module never imports mpi4py: the caller passes ``comm`` (an ``mpi4py.MPI.Comm``; on GPUs one rank per
device, the device selected by the caller before the call)."""

from __future__ import annotations

import math
import time
import warnings
from dataclasses import dataclass
from typing import Any

import numpy as np

from gapsweep.core import checks as chk
from gapsweep.core.slab import Reducer, SlabFFT, check_comm, slab_rows
from gapsweep.gfmd._coarse import Start
from gapsweep.gfmd._grid import Grid
from gapsweep.gfmd._ops import Parseval, _is_cupy, _Ops
from gapsweep.gfmd._result import FIELDS, GFMDResult, final_status, host_fields
from gapsweep.gfmd._solvers import _RUNNERS, _centred, _Problem
from gapsweep.gfmd.interactions import Interaction, resolve

__all__ = ["SlabGrid", "SlabResult", "solve", "solve_memory"]

METHODS = {"softmax": ("cg", "lbfgs", "fire"), "variable": ("lbfgs",), "multiplier": ("pcg", "pk"),
           "bounded": ("plbfgs",)}
DEFAULT = {"softmax": "cg", "variable": "lbfgs", "multiplier": "pcg", "bounded": "plbfgs"}
PAIRS = {"bounded": 10}  # the default L-BFGS pairs (``memory=None``) where not 2: the bounded law's one-process 10


# ---------------------------------------------------------------------------------------------- the grid
class SlabGrid(Grid):
    """:class:`Grid` of one rank's slabs (module docstring): ``fwd``/``inv`` are the distributed transforms
    (normalised coefficients ``a~ = rfft2(a)/(nx ny)``, spectrum layout ``[ky, kx]``), every reduction is combined
    over the ranks. ``shape`` and ``size`` are the global grid's; ``real_shape`` the rank's rows."""

    def __init__(self, shape: tuple[int, int], length: Any, comm: Any, backend: str = "numpy") -> None:
        from gapsweep.gfmd._grid import lengths

        nx, ny = (int(v) for v in shape)
        self.shape = (nx, ny)
        self.size = nx * ny
        self.lx, self.ly = lengths(length)
        self.backend = backend
        self.slab = SlabFFT(self.shape, comm, backend="cupy" if backend == "cupy" else "numpy")
        self.red = Reducer(comm)
        self.xp = self.slab.xp
        self._fft = None
        self.q = self.slab.q(self.lx, self.ly)
        self._w = self.slab.weights()
        self.owner = self.slab.owns_zero

    @property
    def real_shape(self) -> tuple[int, int]:
        return self.slab.real_shape

    def spectrum_zeros(self) -> Any:
        return self.xp.zeros(self.slab.spec_shape, dtype=self.xp.complex128)

    def fwd(self, a: Any) -> Any:
        return self.slab.rfft2(self.xp.ascontiguousarray(a)) * (1.0 / self.size)

    def inv(self, a: Any) -> Any:
        return self.slab.irfft2(a)

    def dot(self, a: Any, b: Any) -> float:
        return self.red.sum(Grid.dot(self, a, b))

    def mean(self, a: Any) -> float:
        return self.red.sum(float(self.xp.sum(a))) / self.size

    def total(self, a: Any) -> float:
        return self.red.sum(float(self.xp.sum(a)))

    def amin(self, a: Any) -> float:
        return self.red.min(float(a.min()) if a.size else math.inf)

    def amax(self, a: Any) -> float:
        return self.red.max(float(a.max()) if a.size else -math.inf)

    def count(self, mask: Any) -> int:
        return int(round(self.red.sum(float(self.xp.count_nonzero(mask)))))

    def agree(self, flag: bool) -> bool:
        return self.red.min(1.0 if flag else 0.0) > 0

    def mode0(self, a: Any) -> complex:
        v = complex(a[0, 0]) if self.owner else 0j
        re, im = self.red.sum(v.real, v.imag)
        return complex(re, im)

    def set_mode0(self, a: Any, value: complex) -> None:
        if self.owner:
            a[0, 0] = value

    def reduce_ops(self, ops: Any) -> Any:
        return _ReducedPK(ops, self.red)

    def synchronize(self) -> None:
        if self.xp is not np:
            self.xp.cuda.get_current_stream().synchronize()


class _ReducedPK:
    """The hard-wall passes of gfmd._constrained_ops on one rank's rows, their scalars combined over the ranks
    (one collective per pass that returns any)."""

    def __init__(self, ops: Any, red: Reducer) -> None:
        self.ops, self.red = ops, red

    def contact_sum(self, u, h, p) -> tuple[int, float]:
        n, s = self.ops.contact_sum(u, h, p)
        n, s = self.red.sum(float(n), s)
        return int(round(n)), s

    def gap(self, u, h, gbar: float, p, g, gs) -> tuple[float, float]:
        s, mn = self.ops.gap(u, h, gbar, p, g, gs)
        (s,), (mn,), _ = self.red.many(sums=(s,), mins=(mn,))
        return s, mn

    def zstats(self, z, gs, p) -> tuple[float, float]:
        return tuple(self.red.sum(*self.ops.zstats(z, gs, p)))

    def zstats5(self, z, t, gs, p) -> tuple[float, float, float, float, float]:
        return tuple(self.red.sum(*self.ops.zstats5(z, t, gs, p)))

    def direction(self, t, z, zbar: float, c: float, p) -> None:
        self.ops.direction(t, z, zbar, c, p)

    def rstats(self, r, t, gs, p) -> tuple[float, float, float, float]:
        return tuple(self.red.sum(*self.ops.rstats(r, t, gs, p)))

    def update(self, p, t, g, tau: float, tau_g: float) -> tuple[bool, int, float]:
        clipped, n_ov, s = self.ops.update(p, t, g, tau, tau_g)
        (n_ov, s), _, (c,) = self.red.many(sums=(float(n_ov), s), maxs=(1.0 if clipped else 0.0,))
        return c > 0, int(round(n_ov)), s

    def rescale(self, p, u, r, scale: float, tau: float, follow: bool) -> None:
        self.ops.rescale(p, u, r, scale, tau, follow)


# ---------------------------------------------------------------------------------------------- exponential law
def _slab_ops(grid: SlabGrid) -> _Ops:
    """The exponential law's passes on the rank's slabs: :class:`_Ops` with the grid's reducer, the Parseval
    weights of the rank's columns and the ``q = 0`` owner flag; on GPUs its fused cupy variant."""
    kw = dict(red=grid.red, weights=Parseval.columns(grid._w), owner=grid.owner)
    if grid.xp is np:
        return _Ops(np, grid.shape[0], **kw)
    from gapsweep.gfmd._cuda import _SlabCupyOps

    return _SlabCupyOps(grid.xp, grid.shape[0], **kw)


def _softmax(h, law: Any, grid: SlabGrid, *, sigma0: float, e_star: float, tol: float, method: str,
             max_iter: int, initial: Any) -> tuple[dict, dict[str, Any]]:
    """The exponential law (``gfmd._softmax``'s algorithm) on slabs; returns ``(scalars, fields)``."""
    xp, slab = grid.xp, grid.slab
    rho, n2 = law.rho, grid.size
    h_shift = grid.mean(h)  # h is not copied: its mean is taken out where W is formed
    ops = _slab_ops(grid)
    k, grid.q = grid.q, None  # E* q/2 in the grid's |q| array (this grid serves this solve only)
    k *= 0.5 * e_star
    if isinstance(initial, Start):  # coarse-to-fine start (gfmd._coarse): the displacement's spectrum, taken over
        x0 = initial.take()
    elif initial is None:  # linear response of M4 (the q = 0 mode of the uncentred h is dropped: <u> = 0)
        x0 = slab.rfft2(h)
        x0 *= (1.0 / n2) * (sigma0 / rho) / (k + sigma0 / rho)
    else:
        x0 = xp.asarray(slab.rfft2(_initial_field(initial, "displacement", grid)) * (1.0 / n2), dtype=xp.complex128)
    history: list[float] = []
    with np.errstate(all="ignore"):
        pb = _Problem(h, x0, sigma0=sigma0, rho=rho, fft=slab, ops=ops, stiffness=k, h_shift=h_shift,
                      keep_mass=False)
        del x0
        status = _RUNNERS[method](pb, tol, max_iter, history)
        nfev = pb.nfev
        u = slab.irfft2(pb.X)
        pb.X = pb.G = pb.G_old = pb.Wt = pb.et = pb.minv = pb.W = None
        w = _centred(h, u, h_shift, rho)
        e = pb.e
        m = grid.amax(w)
        S, _, _ = ops.expstats(w, m, e)
        lse = m + math.log(S / n2) if S > 0 else math.nan
        g0 = law.mean_gap(lse, sigma0)
        e *= sigma0 * n2 / S if S > 0 else math.nan
        p = e
        gap = w
        gap *= -rho
        gap += g0  # g = g0 + u - (h - <h>), in w's memory: invariant under h -> h + c (model.md M3)
        del w
        U = grid.fwd(u)
        F = k * U - grid.fwd(p)
        grid.set_mode0(F, 0.0)
        residual = math.sqrt(max(grid.dot(F, F), 0.0)) / sigma0
        elastic = 0.5 * grid.dot(U, k * U)
        del F, U
        area = grid.count(law.contact(gap, p)) / n2
        load_error = abs(grid.mean(p) / sigma0 - 1.0)
    fields_ok = math.isfinite(g0) and grid.all_finite(gap) and grid.all_finite(p)
    status, _ = final_status(status, fields_ok, residual, load_error, tol)
    converged = status == "converged"
    scalars = dict(mean_gap=g0, iterations=nfev, converged=converged, residual=residual,
                   load_error=load_error, method=method, status=status, history=history, contact_area=area,
                   elastic_energy=elastic, diagnostics={"running_residual": history[-1] if history else math.inf})
    return scalars, {"gap": gap, "pressure": p, "displacement": u}


def _smooth_initial(initial: Any, grid: SlabGrid) -> Any:
    """``((displacement rows, mean gap), source result or None)`` of the smooth laws' ``initial``, or None (or
    the coarse-to-fine start, passed on)."""
    if initial is None or isinstance(initial, Start):
        return initial
    if isinstance(initial, GFMDResult):
        return (_initial_field(initial, "displacement", grid), float(initial.mean_gap)), initial
    from gapsweep.gfmd._smooth import initial_pair

    u0, g0 = initial_pair(initial)  # a displacement alone: mean gap NaN, the body placed touching (_lean)
    if not grid.agree(not math.isinf(g0)):
        raise ValueError("initial must be a result of a distributed solve of the same grid, a pair (this rank's "
                         "rows of a displacement, mean gap) or this rank's rows of a displacement")
    return (_initial_field(u0, "displacement", grid), g0), None


def _initial_field(initial: Any, name: str, grid: SlabGrid) -> Any:
    xp = grid.xp
    a = getattr(initial, name) if isinstance(initial, GFMDResult) else initial
    a = xp.asarray(a, dtype=xp.float64)
    ok = tuple(a.shape) == tuple(grid.real_shape) and bool(xp.all(xp.isfinite(a)))
    if not grid.agree(ok):
        raise ValueError(f"initial must be a result of a distributed solve of the same grid or this rank's rows "
                         f"of a finite {name} field, shape {grid.real_shape}")
    return a


# ---------------------------------------------------------------------------------------------- result
@dataclass
class SlabResult(GFMDResult):
    """:class:`GFMDResult` of a distributed solve: the scalars (mean gap, contact area, energies, residual) are
    global and equal on every rank; the fields ``gap``, ``pressure``, ``displacement`` are this rank's rows
    (``rows`` of the global ``global_shape``). The histogram methods are collective (every rank calls them with
    the same arguments) and return the global histogram on every rank."""

    comm: Any = None
    global_shape: tuple[int, int] = (0, 0)
    rows: Any = None  # slice of the global rows this rank holds

    @property
    def n(self) -> int:
        return int(self.global_shape[0])

    @property
    def shape(self) -> tuple[int, int]:
        return (int(self.global_shape[0]), int(self.global_shape[1]))

    def _red(self) -> Reducer:
        return Reducer(self.comm)

    def _hist(self, a: Any, bins: Any, range: tuple[float, float] | None) -> tuple[np.ndarray, np.ndarray]:
        """Global counts and edges of the local values ``a`` (numpy's edges for the global data)."""
        if isinstance(bins, str):
            raise ValueError("a distributed result takes bins as a number or an array of edges, not a rule name")
        red = self._red()
        a = a.get() if _is_cupy(a) else np.asarray(a)
        if range is None and isinstance(bins, (int, np.integer)):
            lo = red.min(float(a.min()) if a.size else math.inf)
            hi = red.max(float(a.max()) if a.size else -math.inf)
            if not (math.isfinite(lo) and math.isfinite(hi)):
                lo, hi = 0.0, 1.0
            if lo == hi:
                lo, hi = lo - 0.5, hi + 0.5
            range = (lo, hi)
        counts, edges = np.histogram(a, bins=bins, range=range)
        total = red.sum(*[float(c) for c in counts])
        return np.asarray(total if isinstance(total, list) else [total], dtype=np.float64), edges

    def gap_histogram(self, bins: Any = 100, range: tuple[float, float] | None = None
                      ) -> tuple[np.ndarray, np.ndarray, float]:
        g = self.gap.get() if _is_cupy(self.gap) else np.asarray(self.gap)
        free = g[g != 0.0]
        n_free = self._red().sum(float(free.size))
        atom = 1.0 - n_free / (self.shape[0] * self.shape[1])
        if n_free == 0:
            edges = np.linspace(0.0, 1.0, (bins if isinstance(bins, int) else 1) + 1)
            return edges, np.zeros(edges.size - 1), atom
        counts, edges = self._hist(free, bins, range)
        return edges, counts / (self.shape[0] * self.shape[1] * np.diff(edges)), atom

    def pressure_histogram(self, bins: Any = 100, range: tuple[float, float] | None = None
                           ) -> tuple[np.ndarray, np.ndarray, float]:
        p = self.pressure.get() if _is_cupy(self.pressure) else np.asarray(self.pressure)
        loaded = p[p != 0.0]
        n_l = self._red().sum(float(loaded.size))
        atom = 1.0 - n_l / (self.shape[0] * self.shape[1])
        if n_l == 0:
            edges = np.linspace(0.0, 1.0, (bins if isinstance(bins, int) else 1) + 1)
            return edges, np.zeros(edges.size - 1), atom
        counts, edges = self._hist(loaded, bins, range)
        return edges, counts / (self.shape[0] * self.shape[1] * np.diff(edges)), atom

    def histogram(self, bins: Any = 100, range: tuple[float, float] | None = None) -> tuple[np.ndarray, np.ndarray]:
        counts, edges = self._hist(self.gap, bins, range)
        return edges, counts / (counts.sum() * np.diff(edges))

    def contact_atom(self) -> float:
        g = self.gap.get() if _is_cupy(self.gap) else np.asarray(self.gap)
        return self._red().sum(float(np.count_nonzero(g == 0.0))) / (self.shape[0] * self.shape[1])


# ---------------------------------------------------------------------------------------------- driver
def _global_shape(h: Any, red: Reducer, comm: Any) -> tuple[int, int]:
    nr, ny = (int(v) for v in h.shape)
    s, lo, hi = red.many(sums=(float(nr),), mins=(float(ny),), maxs=(float(ny),))
    nx = int(round(s[0]))
    if lo[0] != hi[0]:
        raise ValueError(f"the ranks' row blocks have different numbers of columns ({int(lo[0])} .. {int(hi[0])})")
    want = slab_rows(nx, comm)
    if red.min(1.0 if nr == want.stop - want.start else 0.0) == 0:
        raise ValueError(f"heights: rank {red.rank} holds {nr} rows of {nx}; each rank must hold its rows "
                         f"heights[gapsweep.gfmd.slab_rows({nx}, comm)] (this rank: {want.start}:{want.stop})")
    return nx, ny


def _options(law: Interaction, shape: tuple[int, int], box: tuple[float, float], method: Any, backend: Any,
             on_gpu: bool, max_iter: Any, memory: Any) -> tuple[str, str, str]:
    """Checked ``(load control, method, backend)`` of a distributed solve."""
    for name, v in (("max_iter", max_iter), ("memory", 2 if memory is None else memory)):
        if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < 1:
            raise ValueError(f"{name} must be an integer >= 1, got {v!r}")
    control = law.load_control
    if control == "softmax" and not (shape[0] == shape[1] and box[0] == box[1]):
        control = "variable"  # as one process: the exponential law on rectangles runs on the smooth minimiser
    if control not in METHODS:
        raise ValueError(f"interaction {law.name!r} has no distributed solver yet (comm= and start='coarse' "
                         "are for the exponential, hard-wall and adhesive laws); solve it on one process")
    methods = METHODS[control]
    if not isinstance(method, str) or method not in ("auto", *methods):
        raise ValueError(f"method must be one of {', '.join(map(repr, ('auto', *methods)))} for interaction "
                         f"{law.name!r} in a distributed solve; got {method!r}")
    method = DEFAULT[control] if method == "auto" else method
    backend = ("cupy" if on_gpu else "numpy") if backend == "auto" else backend
    if backend not in ("numpy", "cupy"):
        raise ValueError(f"backend must be 'auto', 'numpy' or 'cupy' in a distributed solve; got {backend!r}")
    return control, method, backend


def solve(h_local: Any, *, comm: Any, sigma0: float, interaction: str | Interaction = "exponential",
          gamma0: float | None = None, rho: float | None = None, work: float | None = None, e_star: float = 1.0,
          length: Any = 1.0, tol: float = 1e-6, method: str = "auto", backend: str = "auto", max_iter: int = 5000,
          initial: Any = None, host: bool | tuple[str, ...] = True, memory: int | None = None, start: str = "flat",
          levels: int | None = None, coarse_tol: float | None = None) -> SlabResult:
    """Periodic equilibrium of docs/model.md M3 (and the hard wall and adhesion of docs/gfmd.md) with the grid
    split over the ranks of ``comm``: ``h_local`` is this rank's rows ``heights[slab_rows(nx, comm)]`` (numpy, or
    cupy for one GPU per rank; units of ``length``). Collective: every rank calls it with the same arguments.
    Keywords as :func:`gapsweep.gfmd.solve`. Methods: exponential "cg" (default), "lbfgs", "fire" (square
    grids; rectangles "lbfgs" on the smooth minimiser, as one process does); adhesive "lbfgs"; hard wall "pcg"
    (default), "pk" ("mpcg"'s coarse levels are not distributed). Returns a :class:`SlabResult`: global scalars
    on every rank, this rank's rows of the fields. ``initial``: a :class:`SlabResult` of the same grid (or this
    rank's rows of a displacement; hard wall: of a pressure; adhesive: ``(displacement rows, mean gap)``).
    ``memory``: L-BFGS pairs (None: 2; hard_wall_adhesive: 10, as one process). The smooth laws' L-BFGS
    (adhesion, exponential rectangles) runs in fixed buffers (``gfmd._lean``: 8 + 2 ``memory`` arrays of the
    rank's rows, 12 at the default 2; one process keeps 8 pairs, so the two agree to the solver tolerance, not bit
    for bit; see :func:`solve_memory`); hard_wall_adhesive runs the one-process projected L-BFGS
    (``gfmd._bounded``) on the slabs, same iteration to round-off, in about ``7.6 + 2 memory`` arrays of the
    rank's rows plus the transform's scratch (``gfmd._bounded.memory_plan``).

    ``start``: "flat" (default: the starts above) or "coarse": the coarse-to-fine start of ``gfmd._coarse``
    (docs/gfmd.md, "Coarse-to-fine start"): the same problem on ``levels`` grids ``(nx/2^l, ny/2^l)`` of the same
    box (None: as many as keep ``>= 64`` pixels a side), each to ``coarse_tol`` (None: ``10 tol``) within
    ``max_iter`` evaluations, the spectrally truncated surface on each, the answer prolonged by zero-padding its
    spectrum; then the requested grid from there to ``tol``. Smooth laws and hard_wall_adhesive at compressive loads,
    no ``initial``; the peak memory is the requested grid's own. ``iterations`` counts the requested grid's
    evaluations; ``diagnostics["levels"]`` holds each coarse level's (shape, evaluations, status, residual, mean
    gap, contact area, wall time) and ``diagnostics["coarse_cost"]`` their sum weighted by the grid size
    (``sum_l evaluations_l 4^-l``, in evaluations of the requested grid)."""
    t_start = time.perf_counter()
    check_comm(comm)
    red = Reducer(comm)
    on_gpu = _is_cupy(h_local)
    if not on_gpu:
        h_local = np.asarray(h_local)
        if not (np.issubdtype(h_local.dtype, np.floating) or np.issubdtype(h_local.dtype, np.integer)):
            raise TypeError(f"heights must be a real array, got dtype {h_local.dtype}")
    if h_local.ndim != 2:
        raise ValueError(f"heights must be this rank's rows of a 2-D grid, got shape {h_local.shape}")
    shape = _global_shape(h_local, red, comm)
    if min(shape) < 2:
        raise ValueError(f"heights must be at least 2 x 2, got {shape}")
    law = resolve(interaction, gamma0=gamma0, rho=rho, work=work)
    sigma0 = law.check_load(sigma0)
    e_star = chk.positive(e_star, "e_star")
    lx, ly = (chk.positive(v, "length") for v in np.broadcast_to(np.asarray(length, dtype=float), 2))
    tol = chk.positive(tol, "tol")
    control, method, backend = _options(law, shape, (lx, ly), method, backend, on_gpu, max_iter, memory)
    memory = PAIRS.get(control, 2) if memory is None else int(memory)
    if start not in ("flat", "coarse"):
        raise ValueError(f"start must be 'flat' or 'coarse', got {start!r}")
    host_fields(host)
    length = lx if lx == ly and not isinstance(length, (tuple, list, np.ndarray)) else (lx, ly)
    if backend == "cupy":
        kind = {"softmax": "exponential", "variable": "smooth", "multiplier": "hard_wall",
                "bounded": "bounded"}[control]
        _check_gpu_memory(shape, red, kind, memory, sigma0 < 0)
    grid = SlabGrid(shape, (lx, ly), comm, backend)
    h = grid.asarray(h_local)
    if not grid.all_finite(h):
        raise ValueError("heights contain NaN or inf")
    coarse = None  # the coarse levels' records (start="coarse")
    if start == "coarse":
        n_levels, coarse_tol = _check_coarse(law, control, sigma0, initial, levels, coarse_tol, tol, shape, red.size)
        kw = dict(comm=comm, sigma0=sigma0, interaction=law, e_star=e_star, length=length, method=method,
                  backend=backend, max_iter=max_iter, host=False, memory=memory, tol=coarse_tol)
        initial, coarse = _run_coarse(h, grid, n_levels, control != "softmax", kw)
    from gapsweep.gfmd._common import UnderResolvedWarning, under_resolved

    text = under_resolved(law, shape, (lx, ly))
    if text is not None and red.rank == 0:  # every law with a range (docs/gfmd.md, "Warnings and errors")
        warnings.warn(text, UnderResolvedWarning, stacklevel=2)
    common = dict(sigma0=sigma0, e_star=e_star, length=length, tol=tol, method=method, backend=backend,
                  max_iter=max_iter, threads=None, host=False, t_start=t_start, grid=grid)
    if control == "softmax":
        scalars, fields = _softmax(h, law, grid, sigma0=sigma0, e_star=e_star, tol=tol, method=method,
                                   max_iter=max_iter, initial=initial)
        r = None
    elif control == "variable":
        from gapsweep.gfmd import _lean

        r = _lean.minimise(h, law, sigma0=sigma0, e_star=e_star, length=length, tol=tol, max_iter=max_iter,
                           initial=_smooth_initial(initial, grid), memory=memory, grid=grid, t_start=t_start)
    elif control == "bounded":  # the adhesive hard wall's projected L-BFGS on the slabs (gfmd._bounded)
        from gapsweep.gfmd import _bounded

        r = _bounded.minimise(h, law, initial=initial, memory=memory, **common)
    else:
        from gapsweep.gfmd import _constrained

        init = None if initial is None else _initial_field(initial, "pressure", grid)
        r = _constrained.minimise(h, law, initial=init, **common)
    if r is not None:
        scalars = {k: getattr(r, k) for k in ("mean_gap", "iterations", "converged", "residual", "load_error",
                                              "method", "status", "history", "contact_area", "elastic_energy",
                                              "diagnostics")}
        fields = {k: getattr(r, k) for k in FIELDS}
    fields.update(grid.to_host_many({k: fields[k] for k in host_fields(host)}))
    grid.synchronize()
    scalars["diagnostics"] = {**scalars["diagnostics"], "ranks": red.size, "exchanges": grid.slab.exchanges,
                              "reductions": grid.red.calls}
    if coarse is not None:
        scalars["diagnostics"]["levels"] = coarse
        scalars["diagnostics"]["coarse_cost"] = sum(
            rec["evaluations"] * rec["shape"][0] * rec["shape"][1] / (shape[0] * shape[1]) for rec in coarse)
    return SlabResult(
        gap=fields["gap"], pressure=fields["pressure"], displacement=fields["displacement"],
        wall_time=time.perf_counter() - t_start, backend=backend, sigma0=sigma0, rho=getattr(law, "rho", math.nan),
        gamma0=getattr(law, "gamma0", math.nan), e_star=e_star, length=length, tol=tol, interaction=law.name,
        params=law.params(), contact_criterion=law.contact_criterion, comm=comm, global_shape=shape,
        rows=grid.slab.row, **scalars)


def _check_coarse(law: Interaction, control: str, sigma0: float, initial: Any, levels: Any, coarse_tol: Any,
                  tol: float, shape: tuple[int, int], ranks: int) -> tuple[int, float]:
    """Checked ``(levels, coarse tolerance)`` of ``start="coarse"``."""
    from gapsweep.gfmd import _coarse

    if control == "multiplier":
        raise ValueError(f"start='coarse' is for the smooth laws (exponential, adhesive); interaction {law.name!r} "
                         "takes start='flat'")
    if not sigma0 > 0:
        raise ValueError(f"start='coarse' needs a compressive load sigma0 > 0, got {sigma0!r} (tensile loads: "
                         "start='flat', which follows the load from zero)")
    if initial is not None:
        raise ValueError("start='coarse' makes its own initial state: leave initial=None")
    lv = _coarse.check_levels(levels, shape, ranks)
    ctol = 10.0 * tol if coarse_tol is None else chk.positive(coarse_tol, "coarse_tol")
    return lv, ctol


def _run_coarse(h: Any, grid: SlabGrid, levels: int, smooth: bool, kw: dict) -> tuple[Any, list[dict]]:
    """The coarse levels of ``start="coarse"`` (gfmd._coarse.chain): the requested grid's :class:`Start` (or None
    when no level gave a finite answer) and the levels' records. On GPUs the memory pool's free blocks and
    cupy's FFT plans of the coarse grids are dropped before the requested grid runs (its peak stays its own)."""
    from gapsweep.gfmd import _coarse
    from gapsweep.gfmd._common import UnderResolvedWarning

    def level(hl: Any, init: Any) -> Any:
        with warnings.catch_warnings():  # a coarse level's own spacing: the requested grid's warning is the one
            warnings.simplefilter("ignore", UnderResolvedWarning)
            return solve(hl, initial=init, start="flat", **kw)

    Z, records = _coarse.chain(h, grid.slab, levels, level, smooth)
    if grid.xp is not np:
        grid.xp.fft.config.get_plan_cache().clear()
        grid.xp.get_default_memory_pool().free_all_blocks()
    return (None if Z is None else Start(Z)), records


def _check_gpu_memory(shape: tuple[int, int], red: Reducer, interaction: str, memory: int, tensile: bool) -> None:
    """Refuse, on every rank, a GPU solve whose :func:`solve_memory` estimate exceeds the free memory of the
    fullest GPU (an out-of-memory error on one rank would leave the others waiting in a collective)."""
    import cupy

    est = solve_memory(shape, red.size, interaction, memory=memory, tensile=tensile)
    free = float(cupy.cuda.runtime.memGetInfo()[0]) + float(cupy.get_default_memory_pool().free_bytes())
    free = red.min(free)
    need = est["bytes_per_rank"] - est["array_bytes"]  # the caller's rows are on the GPU already
    if need > free:
        raise MemoryError(f"a distributed {interaction} solve of {shape[0]} x {shape[1]} on {red.size} GPUs needs "
                          f"about {need / 1e9:.3g} GB per GPU beyond the surface (gfmd.distributed.solve_memory), "
                          f"the fullest GPU has {free / 1e9:.3g} GB free: use more GPUs")


def solve_memory(shape: tuple[int, int], ranks: int, interaction: str = "exponential",
                 memory: int | None = None, tensile: bool = False) -> dict[str, float]:
    """Estimated peak memory per rank (bytes) of :func:`solve`: the minimiser's grid-sized arrays on the rank's
    slabs plus the transform's scratch (send and receive buffers, 2 A, and the chunked 1-D transforms' and
    elementwise passes' temporaries, within 1 A at 65536^2). Counted from the code (docs/gfmd.md, "One solve over
    several processes"), ``A`` = one float64 field of the rank's rows, the surface ``h`` included (a half spectrum
    of the rank's columns counts as 1 A, a real one as 1/2): exponential CG 12 A (h, W, Wt, e, et; X, G, G_old,
    D; k and M^-1; the line search's real-space direction; one temporary of the array passes); adhesive and the
    other smooth laws (``gfmd._lean``): 7 A (h, g, d; Z, G, D; k and M^-1) + 2 A per L-BFGS pair (``memory``;
    the default 2: 11 A), 3 A more while a tensile load is followed (``tensile``); hard wall pcg 12 A; scratch
    3 A (4 A for the smooth laws: their chunked passes' temporaries measured 0.75 A more at 65536^2 on 4 H200s,
    benchmarks/results/distributed/h200x4_challenge.json). Checked on the CPU under mpiexec
    (tests/mpi/test_distributed.py: the traced numpy peak is within the estimate) and on GPUs by
    benchmarks/bench_distributed.py (the memory pool's peak beside it; at 16384^2 over 2-4 GPUs the pool held up to
    1.3x this estimate: the transform's chunk buffers, a few GB whatever the grid, are not yet counted)."""
    memory = PAIRS.get(interaction, 2) if memory is None else memory  # the solve's default pairs
    if interaction == "bounded":  # the adhesive hard wall's own count (gfmd._bounded.memory_plan)
        from gapsweep.gfmd._bounded import memory_plan

        p = memory_plan(shape, ranks, memory=memory, tensile=tensile, backend="slab-cupy")
        return {**{k: p[k] for k in ("bytes_per_rank", "array_bytes", "arrays")}, "scratch_arrays": 0.0}
    nx, ny = (int(v) for v in shape)
    a = 8.0 * math.ceil(nx / ranks) * ny
    smooth = 7.0 + 2.0 * memory + (3.0 if tensile else 0.0)
    arrays = {"exponential": 12.0, "adhesive": smooth, "smooth": smooth, "hard_wall": 12.0}[interaction]
    scratch = 4.0 if interaction in ("adhesive", "smooth") else 3.0
    return {"bytes_per_rank": (arrays + scratch) * a, "array_bytes": a, "arrays": arrays, "scratch_arrays": scratch}
