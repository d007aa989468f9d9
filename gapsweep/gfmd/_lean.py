"""The smooth laws' minimiser (``gfmd._smooth``: L-BFGS with a strong-Wolfe line search in real space, the same
energy, gradient, starts, continuation to tensile loads and convergence test) with a fixed, small set of arrays,
for one solve split over the ranks of a communicator (docs/gfmd.md, "One solve over several processes", memory).

The energy per area (docs/gfmd.md, "Smooth laws"; docs/model.md M3) of the body's surface ``z = g0 + u``, with
half-spectrum coefficients ``z~`` (``z~(0) = g0``) and the gap ``g = z - h``,

    F(z) = (E*/4) sum_{q != 0} q |z~(q)|^2 + <phi(z - h)> + sigma0 g0,

has the Fourier gradient ``G = (E* q/2) z~ - p~`` (``q != 0``) and ``sigma0 - <p>`` (``q = 0``); pressures in
the units of ``E*``, lengths in the units of ``h``.

Arrays (``A`` = one float64 field of the rank's rows; a half spectrum of the rank's columns is ~1 A): the caller's
surface ``h``, the gap ``g`` and one real buffer ``d`` (the line search's direction in real space, reused for the
pressure when the gradient is formed), the coefficients ``Z``, the gradient ``G``, the direction ``D`` (the two-loop
recursion runs in it), ``E* q/2`` and ``M^-1`` (real, half a spectrum each), and ``memory`` pairs ``(s, y)``:
``8 + 2 memory`` A, 12 A at the default of 2 pairs. The transforms write into these buffers (``out=``); every
other pass runs over chunks of rows (temporaries of ``chunk`` elements, not of the grid). Differences from
``gfmd._smooth`` (same iteration otherwise): the pairs live in a ring of ``memory`` slots, so a pair the curvature
test rejects (``s.y <= 0``) drops the oldest one; the default keeps 2 pairs, where one process keeps 8. The
answer agrees with the single-process solve to the solver tolerance (tests/mpi/test_distributed.py).

Continuation to tensile loads (:meth:`_smooth._Solver.follow`) keeps the last two equilibria and the predictor
beside the state: 3 A more while it runs (:func:`gapsweep.gfmd.distributed.solve_memory`)."""

from __future__ import annotations

import logging
import math
from typing import Any

import numpy as np

from gapsweep.gfmd._coarse import Start
from gapsweep.gfmd._lbfgs import two_loop
from gapsweep.gfmd._result import GFMDResult, final_status, law_result
from gapsweep.gfmd._smooth import _STEP_TOL, _lbfgs, _Solver, touching_gap

log = logging.getLogger("gapsweep.gfmd")
CHUNK = {"numpy": 1 << 22, "cupy": 1 << 25}  # elements per chunk of an elementwise pass (32 / 256 MiB of float64)


class _Passes:
    """Chunked elementwise passes and weighted sums on one rank's real rows ``(nr, ny)`` and spectrum columns
    ``(nc, nx)``; sums are combined over the ranks by the grid's reducer (one collective per call)."""

    def __init__(self, grid: Any, chunk: int | None = None) -> None:
        self.grid, self.xp, self.w, self.red = grid, grid.xp, grid._w, grid.red
        self.chunk = int(CHUNK["numpy" if self.xp is np else "cupy"] if chunk is None else chunk)

    def rows(self, a: Any) -> list[slice]:
        n, m = a.shape
        step = max(1, self.chunk // max(m, 1))
        return [slice(i, min(i + step, n)) for i in range(0, n, step)]

    def wsum(self, a: Any, b: Any, k: Any = None) -> float:
        """This rank's ``sum w k (a.re b.re + a.im b.im)`` over its spectrum (Parseval; ``k`` = 1 if None)."""
        xp, s = self.xp, 0.0
        for ch in self.rows(a):
            t = a[ch].real * b[ch].real
            t += a[ch].imag * b[ch].imag
            if k is not None:
                t *= k[ch]
            t *= self.w[ch]
            s = s + xp.sum(t)  # on the device: one transfer per call
        return float(s)

    def dot(self, a: Any, b: Any, k: Any = None) -> float:
        return self.red.sum(self.wsum(a, b, k))

    def axpy(self, y: Any, a: float, x: Any) -> None:
        """``y += a x`` in place."""
        for ch in self.rows(y):
            y[ch] += a * x[ch]

    def scale(self, y: Any, m: Any) -> None:
        """``y *= m`` in place (``m`` an array of ``y``'s shape or a number)."""
        for ch in self.rows(y):
            y[ch] *= m[ch] if hasattr(m, "shape") else m


class _LeanState:
    """Point ``z~`` with its gap, the law's mean energy and the gradient (the interface of ``_smooth._State``
    that ``_smooth._wolfe`` and the solver use), in preallocated buffers (module docstring)."""

    def __init__(self, grid: Any, law: Any, h: Any, k: Any, sigma0: float, Z: Any, ps: _Passes) -> None:
        self.grid, self.law, self.h, self.k, self.sigma0, self.ps = grid, law, h, k, sigma0, ps
        self.xp = grid.xp
        self.Z = Z
        self.g = grid.slab.irfft2(Z)
        self.g -= h
        self.d = self.xp.empty_like(self.g)
        self.G = self.xp.empty_like(Z)
        self.nfev = 0
        self._evaluate()

    def _evaluate(self) -> None:
        xp, grid, law, ps = self.xp, self.grid, self.law, self.ps
        p, e = self.d, 0.0  # the direction's buffer holds the pressure (the direction is used up)
        for ch in ps.rows(p):
            p[ch] = law.pressure(self.g[ch], xp)
            e = e + xp.sum(law.energy(self.g[ch], xp))
        self.e_law = grid.red.sum(float(e)) / grid.size
        grid.slab.rfft2(p, out=self.G)
        for ch in ps.rows(self.G):  # G = k Z - p~  (p~ = rfft2(p) / (nx ny))
            self.G[ch] *= -1.0 / grid.size
            self.G[ch] += self.k[ch] * self.Z[ch]
        grid.set_mode0(self.G, grid.mode0(self.G) + self.sigma0)  # k(0) = 0: sigma0 - <p>
        self.nfev += 1

    def energy(self) -> float:
        return 0.5 * self.ps.dot(self.Z, self.Z, self.k) + self.e_law + self.sigma0 * self.grid.mode0(self.Z).real

    def line(self, D: Any) -> tuple[Any, float, float, float]:
        """Real-space direction ``d`` (into the buffer) and the scalars of ``phi(alpha) = F(Z + alpha D)``."""
        self.grid.slab.irfft2(D, out=self.d)
        a, b = self.grid.red.sum(self.ps.wsum(D, self.Z, self.k), self.ps.wsum(D, D, self.k))
        return self.d, a, b, self.grid.mode0(D).real

    def phi(self, alpha: float, d: Any, a: float, b: float, d0: float, e0: float) -> tuple[float, float]:
        """``(phi(alpha) - phi(0) + e_law(0), phi'(alpha))`` without FFT (one collective)."""
        xp, law, n2 = self.xp, self.law, self.grid.size
        fe = fp = 0.0
        for ch in self.ps.rows(d):
            g = d[ch] * alpha
            g += self.g[ch]
            fe = fe + xp.sum(law.energy(g, xp))
            p = law.pressure(g, xp)
            p *= d[ch]
            fp = fp + xp.sum(p)
        fe, fp = self.grid.red.sum(float(fe), float(fp))
        f = alpha * a + 0.5 * alpha * alpha * b + fe / n2 + self.sigma0 * alpha * d0
        df = a + alpha * b - fp / n2 + self.sigma0 * d0
        return f, df

    def move(self, alpha: float, D: Any, d: Any) -> None:
        self.ps.axpy(self.Z, alpha, D)
        self.ps.axpy(self.g, alpha, d)
        self._evaluate()

    def release(self) -> None:
        """Drop every buffer but ``Z`` (the solver keeps only the point of a finished state)."""
        self.g = self.d = self.G = None


class _Pairs:
    """The L-BFGS memory of ``_smooth._lbfgs`` on the lean state: a ring of ``memory`` pairs ``(s, y, 1/s.y)`` in
    preallocated spectra (allocated when first used) and the direction's buffer; the two-loop recursion and the
    pairs' updates in place, in row chunks (``_Passes``)."""

    def __init__(self, st: _LeanState, minv: Any, memory: int) -> None:
        self.xp, self.like, self.memory, self.minv = st.xp, st.Z, memory, minv
        self.ps = st.ps
        self.dot = st.ps.dot
        self.s: list = []
        self.y: list = []
        self.r: list[float] = []
        self.order: list[int] = []  # slots, oldest first
        self.D = st.xp.empty_like(st.Z)

    def __bool__(self) -> bool:
        return bool(self.order)

    def clear(self) -> None:
        self.order.clear()

    def slot(self) -> int:
        """A slot for the next pair: a fresh one while fewer than ``memory`` exist, else the oldest (dropped)."""
        if len(self.s) < self.memory:
            self.s.append(self.xp.empty_like(self.like))
            self.y.append(self.xp.empty_like(self.like))
            self.r.append(0.0)
            return len(self.s) - 1
        free = [i for i in range(self.memory) if i not in self.order]
        if free:
            return free[0]
        return self.order.pop(0)

    def drop(self, i: int) -> None:
        if i in self.order:
            self.order.remove(i)

    def direction(self, st: _LeanState) -> Any:
        """``D = -H G`` by the two-loop recursion (``gfmd._lbfgs.two_loop``, Nocedal & Wright Alg. 7.4) with
        ``H0 = gamma M^-1``, in the buffer ``D``."""
        ps, red, minv, D = self.ps, st.grid.red, self.minv, self.D

        def axpy(q: Any, a: float, x: Any) -> Any:
            ps.axpy(q, a, x)
            return q

        def scale(q: Any, c: Any) -> Any:
            ps.scale(q, c)
            return q

        st.xp.copyto(D, st.G)
        two_loop(D, [(self.s[i], self.y[i], self.r[i]) for i in self.order], dot=ps.dot, axpy=axpy,
                 precondition=lambda q: scale(q, minv), curvature=lambda y: red.sum(ps.wsum(y, y, minv)),
                 scale=scale)
        ps.scale(D, -1.0)
        return D

    def steepest(self, st: _LeanState) -> Any:
        D, minv = self.D, self.minv
        for ch in st.ps.rows(D):
            D[ch] = st.G[ch] * minv[ch]
            D[ch] *= -1.0
        return D

    def step(self, st: _LeanState, alpha: float, D: Any, d: Any) -> None:
        """Move ``st`` by ``alpha D`` and keep ``(s, y) = (alpha D, G_new - G_old)`` in a slot of the ring."""
        ps = self.ps
        i = self.slot()
        s, y = self.s[i], self.y[i]
        st.xp.copyto(y, st.G)
        st.move(alpha, D, d)
        for ch in ps.rows(s):  # s = alpha D, y = G_new - G_old
            st.xp.multiply(D[ch], alpha, out=s[ch])
            y[ch] *= -1.0
            y[ch] += st.G[ch]
        sy = ps.dot(s, y)
        self.drop(i)
        if sy > 0:
            self.r[i] = 1.0 / sy
            self.order.append(i)


class LeanSolver(_Solver):
    """:class:`gapsweep.gfmd._smooth._Solver` (same starts and continuation) on the lean state: ``k = E* q/2``
    takes over the grid's ``|q|`` array (the grid serves this solve only)."""

    def __init__(self, grid: Any, law: Any, h: Any, e_star: float, max_iter: int, memory: int,
                 chunk: int | None = None) -> None:
        self.grid, self.law, self.h, self.max_iter, self.memory = grid, law, h, max_iter, memory
        self.k, grid.q = grid.q, None
        self.k *= 0.5 * e_star
        self.rng = law.range()
        self.nfev = 0
        self.history: list[float] = []
        self.info: dict[str, float] = {}
        self.ps = _Passes(grid, chunk)

    def _minv(self, sigma0: float) -> Any:
        xp, c = self.grid.xp, self.law.curvature(sigma0)
        if c > 0:
            m = self.k + c
        else:
            m = xp.where(self.k > 0, self.k, 1.0)
        xp.reciprocal(m, out=m)
        return m

    def at(self, sigma0: float, Z: Any, tol: float, budget: int | None = None, own: bool = False) -> tuple[Any, str]:
        """As :meth:`_Solver.at`; ``own``: start from ``Z`` itself (it becomes the state's), not a copy. The
        returned state keeps only ``Z``."""
        minv = self._minv(sigma0)
        st = _LeanState(self.grid, self.law, self.h, self.k, sigma0, Z if own else Z.copy(), self.ps)
        left = max(self.max_iter - self.nfev, 1)
        status = _lbfgs(st, _Pairs(st, minv, self.memory), self.law.pressure_scale(sigma0), tol,
                        left if budget is None else min(budget, left), self.rng, self.history)
        self.nfev += st.nfev
        st.release()
        return st, status


def minimise(h: Any, law: Any, *, sigma0: float, e_star: float, length: Any, tol: float, max_iter: int,
             initial: Any, memory: int, grid: Any, t_start: float, chunk: int | None = None) -> Any:
    """``gfmd._smooth.minimise`` on the lean solver (same starts, see there) for a :class:`SlabGrid`; ``h``
    this rank's rows, used as given (not copied, not centred: the gap ``z - h`` and the fields do not depend on
    ``<h>``, which the body's mean position ``z~(0)`` takes up). ``initial``: None or ``((displacement rows,
    mean gap), the result it came from or None)`` (the result for the tensile fallback), or a
    :class:`gapsweep.gfmd._coarse.Start` (the spectrum ``z~`` of the body's surface, taken over as the state)."""
    xp = grid.xp
    sv = LeanSolver(grid, law, h, e_star, max_iter, memory, chunk)
    if isinstance(initial, Start):  # coarse-to-fine start (gfmd._coarse): the body surface's spectrum, taken over
        Z = initial.take()
        lift_out_of_surface(grid, Z, h, SINK_RANGES * (law.range() or 0.0))
        st, status = sv.at(sigma0, Z, tol, own=True)
        del Z
    elif initial is None:
        Z = grid.spectrum_zeros()
        grid.set_mode0(Z, grid.amax(h))  # touching the highest summit, the body flat
        if sigma0 < 0:
            st, status = sv.at(0.0, Z, max(tol, _STEP_TOL), own=True)
            if status == "converged":
                st, status = sv.follow(0.0, st.Z, sigma0, tol)
        else:
            st, status = sv.at(sigma0, Z, tol, own=True)
        del Z
    else:
        (u0, g0), source = initial
        uc = u0 - grid.mean(u0)
        Z0 = grid.slab.rfft2(uc)
        Z0 *= 1.0 / grid.size
        grid.set_mode0(Z0, float(g0) if math.isfinite(g0) else touching_gap(grid, h, uc))
        del uc
        st, status = sv.at(sigma0, Z0, tol)
        s_init = float(getattr(source, "sigma0", math.nan))
        if (status in ("detached", "stalled") and source is not None and getattr(source, "converged", False)
                and sigma0 < 0 and s_init > sigma0 and sv.nfev < max_iter):
            log.info("%s: %s at sigma0=%g from the initial state; following the load from %g", law.name, status,
                     sigma0, s_init)
            st2, status = sv.follow(s_init, Z0, sigma0, tol)
            st = st2 if st2 is not None else st
        del Z0
    assert st is not None and xp is grid.xp
    return _lean_result(sv, st, status, sigma0, e_star, length, tol, t_start)


SINK_RANGES = 4.0  # a coarse-to-fine start may overlap the surface by this many interaction ranges, no more


def lift_out_of_surface(grid: Any, Z: Any, h: Any, allowed: float = 0.0) -> float:
    """Raise the body ``z`` (spectrum ``Z``, normalised coefficients, changed in place) by
    ``max(0, -min(z - h) - allowed)`` so that the start's gap is nowhere below ``-allowed`` (the solver starts
    with :data:`SINK_RANGES` ranges of overlap at most: a small overlap is information the law handles, a deep one
    overflows it); returns the lift (length units). Why: a state prolonged from a
    coarser grid meets the finer surface's new summits; where it sinks into them by many ranges the adhesive law's
    repulsion overflows (measured at the challenge's constants on 32768^2: 64^2 -> 128^2 sank ~100 rho, residual
    7e45 after one evaluation, benchmarks/results/distributed/h200x2_challenge_32768_before.json). One inverse
    transform and one real array of scratch."""
    g = grid.slab.irfft2(Z)
    g -= h
    lift = max(0.0, -grid.amin(g) - allowed)
    del g
    if lift > 0:
        grid.set_mode0(Z, grid.mode0(Z) + lift)
    return lift


def _lean_result(sv: LeanSolver, st: Any, status: str, sigma0: float, e_star: float, length: Any, tol: float,
                 t_start: float) -> GFMDResult:
    """``_smooth._result`` in chunked passes: the fields and the convergence of the state's point (the returned
    fields' residual decides, issue 9). Arrays: ``h``, ``k``, the fields ``gap``, ``pressure``,
    ``displacement`` and two spectra (``u~`` and the force balance), the state's ``Z`` dropped first."""
    grid, law, h, k, ps, xp = sv.grid, sv.law, sv.h, sv.k, sv.ps, sv.grid.xp
    p_ref = law.pressure_scale(sigma0)
    with np.errstate(all="ignore"):
        z0 = grid.mode0(st.Z).real
        grid.set_mode0(st.Z, 0.0)  # u from the q != 0 modes alone (no round-off of g0 in u: _smooth._result)
        u = grid.slab.irfft2(st.Z)
        st.Z = None
        gap = u + z0
        gap -= h
        p = xp.empty_like(gap)
        e_int = n_c = 0.0
        for ch in ps.rows(gap):
            p[ch] = law.pressure(gap[ch], xp)
            e_int = e_int + xp.sum(law.energy(gap[ch], xp))
            n_c = n_c + xp.count_nonzero(law.contact(gap[ch], p[ch]))
        e_int, n_c, g_sum, p_sum = grid.red.sum(float(e_int), float(n_c), float(xp.sum(gap)), float(xp.sum(p)))
        U = grid.slab.rfft2(u)
        ps.scale(U, 1.0 / grid.size)
        F = grid.slab.rfft2(p)
        for ch in ps.rows(F):  # F = k U - p~
            F[ch] *= -1.0 / grid.size
            F[ch] += k[ch] * U[ch]
        grid.set_mode0(F, 0.0)
        residual = math.sqrt(max(ps.dot(F, F), 0.0)) / p_ref
        del F
        elastic = 0.5 * ps.dot(U, U, k)
        del U
        n2 = grid.size
        load_error = abs(p_sum / n2 - sigma0) / p_ref
    fields_ok = math.isfinite(residual) and grid.all_finite(gap) and grid.all_finite(p)
    status, _ = final_status(status, fields_ok, residual, load_error, tol)
    converged = status == "converged"
    log.debug("%s: %s after %d evaluations, residual %.3g", law.name, status, sv.nfev, residual)
    diagnostics = {"pressure_scale": p_ref, "interaction_energy": e_int / n2, "lbfgs_memory": sv.memory, **sv.info}
    return law_result(law, t_start, mean_gap=g_sum / n2, gap=gap, pressure=p, displacement=u, iterations=sv.nfev,
                      converged=converged, residual=residual, load_error=load_error, method="lbfgs",
                      backend=grid.backend, status=status, sigma0=sigma0, rho=getattr(law, "rho", math.nan),
                      e_star=e_star, length=length, tol=tol, history=sv.history, contact_area=n_c / n2,
                      elastic_energy=elastic, diagnostics=diagnostics)
