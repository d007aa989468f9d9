"""Smooth laws (exponential repulsion, adhesion, any :class:`SmoothInteraction`) on a finite map with free
boundaries (``gfmd.solve(..., periodic=False)``; docs/gfmd.md, "Periodic or free boundaries").

The map (``nx x ny`` pixels, box ``Lx x Ly``, pixel area ``a``) sits at the corner of the doubled grid
(``2nx x 2ny``) of :class:`gapsweep.gfmd._grid.FreeGrid`, on which the half-space's pixel response ``G``
(Boussinesq, integrated over a pixel) is a circular convolution, ``u = G * f``; every distance between two map
pixels appears once, so no periodic image enters. Unknowns: the displacement ``u`` on the whole doubled grid (as
its normalised half spectrum ``u~``) and the rigid approach ``delta``; the gap exists on the map only,
``g = delta + u - h``. The energy per map area

    F(u, delta) = (1/2) sum_q k(q) |u~(q)|^2 + <phi(g)>_map + sigma0 delta,       k(q) = (N_pad/N_map) / G^(q)

(``G^ = rfft2(G)``, real and positive; the first term is ``(1/2) sum_i f_i u_i a / A_map`` with ``f = G^-1 * u``
the elastic pressure) has the gradient ``k u~ - (N_pad/N_map) FFT[p 1_map]/N_pad`` in ``u~`` and
``sigma0 - <p>_map`` in ``delta``. At a stationary point the elastic pressure equals ``p`` on the map and
vanishes outside it (the free surface around the map carries no load), and the mean pressure over the map's own
area is ``sigma0``. Minimised by L-BFGS with the initial inverse Hessian ``1/(k(q) + c N_map/N_pad)`` (``c``
from ``law.curvature``, averaged over the doubled grid) and ``1/c`` for ``delta``, the strong-Wolfe line search
of :mod:`gapsweep.gfmd._smooth` moving in real space (per iteration one forward transform of the map's pressure
and one inverse to the map's rows, FreeGrid.pad_fwd/pad_inv). Method "cg" (opt-in): preconditioned nonlinear
conjugate gradients with the same preconditioner and line search (``_cg``), one direction instead of the L-BFGS
pairs (less memory traffic per evaluation on the GPU, more evaluations). The same array code runs on numpy and
cupy.

Exponential law at ``sigma0 > 0`` (issue 39): the approach is eliminated in closed form, as in the periodic
softmax minimiser (docs/model.md M3): at every point and trial step ``delta`` is the value at which
``<p>_map = sigma0``, ``delta = rho [ln(gamma0/(rho sigma0)) + ln <exp(-(u - h)/rho)>_map]`` (log-sum-exp,
``_FreeState._shift``), so ``G_delta = 0`` and the minimisers move ``u~`` alone. The CPU's L-BFGS keeps
``_MEMORY_CPU`` pairs and runs its two-loop recursion with each update fused with the next dot product (numba,
``_fused``).

Tensile loads (adhesion): :class:`_FreeSolver` is the periodic minimiser's ``_smooth._Solver`` on the pair
``(u~, delta)``: without ``initial`` a tensile load is reached from the zero-load equilibrium by its quasi-static
continuation (secant predictor, branch test, pull-off bracket ``diagnostics["last_attached_load"]``), and a warm
start that detaches or stalls is followed down from ``initial.sigma0`` (docs/gfmd.md "Tensile loads"). L-BFGS
runs ``_smooth``'s stall test.

Convergence on the returned fields: ``residual = rms_map-normalised(f - p 1_map) / P`` (the force imbalance on
the whole doubled grid, summed and divided by the map's pixel count: outside the map it is the load that would
have to act on the free surface), ``load_error = |<p>_map - sigma0| / P``, ``P = law.pressure_scale(sigma0)``;
``converged`` iff both ``<= tol``."""

from __future__ import annotations

import logging
import math
from typing import Any

import numpy as np

from gapsweep.core import deadline
from gapsweep.core.vec import axpy
from gapsweep.gfmd._grid import FreeGrid, Grid
from gapsweep.gfmd._lbfgs import remember_pair, two_loop
from gapsweep.gfmd._ops import _is_cupy
from gapsweep.gfmd._result import GFMDResult, fields_to_host, final_status, law_result
from gapsweep.gfmd._smooth import _DETACHED, _STEP_TOL, _Solver, _stalled, _wolfe
from gapsweep.gfmd.interactions.base import SmoothInteraction

METHODS = ("lbfgs", "cg")
# Stored (s, y) pairs of the L-BFGS, on the CPU and the GPU. On the GPU the two-loop recursion over the doubled
# grid's spectra is most of an evaluation's memory traffic (about 40 grid arrays of the map's size per pair and
# iteration; a periodic evaluation moves about 36): benchmarks/bench_gpu_floor.py times other values side by side.
_MEMORY = 12
# On the CPU the two-loop recursion's passes over the doubled grid's spectra were half of an evaluation (issue 39);
# fewer pairs cost a few more evaluations and less time: on the crops of benchmarks/bench_free.py (exponential,
# tol 1e-8, approach eliminated) 12 / 6 / 4 / 3 pairs took 105 / 120 / 116 / 121 evaluations and 1.38 / 1.09 /
# 0.97 / 0.94 s (256 x 192), 142 / 147 / 169 / 158 and 4.93 / 3.76 / 3.78 / 3.49 s (320 x 448); 4 kept as the
# margin for the adhesive laws' harder Hessians.
_MEMORY_CPU = 4
# The exponential law's approach in closed form (_FreeState; False: an unknown of the minimisers, as before issue 39;
# tests/test_free_boundaries.py compares the two)
ELIMINATE = True
log = logging.getLogger("gapsweep.gfmd")


_FUSED: Any = None


def _fused() -> Any:
    """numba kernels of the CPU's L-BFGS on the doubled grid's half spectrum (its width ``ny + 1`` with ``2ny``
    even: the columns ``ky = 0`` and Nyquist weigh 1, the others 2; ``Grid.dot``): ``wdot(a, b)`` the Parseval
    sum in one pass, ``axpy_dot(y, a, x, z)`` ``y += a x`` and then ``<z y>`` in the same pass (the two-loop
    recursion's update and the next pair's dot: half its passes). None without numba."""
    global _FUSED
    if _FUSED is None:
        from gapsweep.gfmd._ops import _have_numba

        if not _have_numba():
            _FUSED = False
            return None
        from gapsweep.core.numba_cache import njit

        jit = njit(fastmath=False, nogil=True)

        @jit
        def wdot(a, b):  # pragma: no cover - compiled
            n0, nh = a.shape
            se = 0.0
            sm = 0.0
            for i in range(n0):
                x, y = a[i, 0], b[i, 0]
                se += x.real * y.real + x.imag * y.imag
                x, y = a[i, nh - 1], b[i, nh - 1]
                se += x.real * y.real + x.imag * y.imag
                for j in range(1, nh - 1):
                    x, y = a[i, j], b[i, j]
                    sm += x.real * y.real + x.imag * y.imag
            return se + 2.0 * sm

        @jit
        def axpy_dot(y, a, x, z):  # pragma: no cover - compiled
            n0, nh = y.shape
            se = 0.0
            sm = 0.0
            for i in range(n0):
                for j in range(nh):
                    v = y[i, j] + a * x[i, j]
                    y[i, j] = v
                    w = z[i, j]
                    t = w.real * v.real + w.imag * v.imag
                    if j == 0 or j == nh - 1:
                        se += t
                    else:
                        sm += t
            return se + 2.0 * sm

        _FUSED = (wdot, axpy_dot)
    return _FUSED or None


def _fits(a: Any, shape: tuple[int, int]) -> bool:
    return isinstance(a, np.ndarray) and a.dtype == np.complex128 and a.shape == shape and a.flags.c_contiguous


class _HostOps:
    """The passes of the free-boundary L-BFGS as numpy array expressions and, with numba, single-pass kernels
    (the CPU; the GPU's fused variant is ``gfmd._cuda._FreeCupyOps`` with the same methods)."""

    def __init__(self, pad: Grid) -> None:
        self.pad = pad
        self.spec = (pad.shape[0], pad.shape[1] // 2 + 1)
        k = _fused() if pad.shape[1] % 2 == 0 else None
        self._wdot, self._axpy_dot = k if k is not None else (None, None)

    def dot(self, a: Any, b: Any) -> float:
        if self._wdot is not None and _fits(a, self.spec) and _fits(b, self.spec):
            return float(self._wdot(a, b))
        return self.pad.dot(a, b)

    def axpy_dot(self, y: Any, a: float, x: Any, z: Any) -> float:
        """``y += a x`` in place, then ``<z y>`` (one pass with numba)."""
        if self._axpy_dot is not None and _fits(y, self.spec) and _fits(x, self.spec) and _fits(z, self.spec):
            return float(self._axpy_dot(y, float(a), x, z))
        self.axpy(y, a, x)
        return self.dot(z, y)

    def kdot(self, a: Any, k: Any, b: Any) -> float:
        """``<A k B>``, ``k`` real."""
        return self.pad.dot(a, k * b)

    def axpy(self, y: Any, a: float, x: Any) -> None:
        axpy(a, x, y)  # chunked, no BLAS threads (gapsweep.core.vec)

    def grad(self, k: Any, U: Any, c: float, F: Any) -> Any:
        return k * U - c * F

    def trial(self, g: Any, a: float, d: Any) -> Any:
        return g + a * d

    def mean(self, a: Any) -> float:
        return float(np.mean(a))

    def mean_product(self, p: Any, d: Any) -> float:
        return float(np.mean(p * d))


def _make_ops(pad: Grid) -> Any:
    if pad.xp is np:
        return _HostOps(pad)
    from gapsweep.gfmd._cuda import _FreeCupyOps

    return _FreeCupyOps(pad.xp, (pad.shape[0], pad.shape[1] // 2 + 1), pad.shape[1] % 2 == 0)


class _FreeState:
    """Point ``(u~, delta)`` with the map's gap, pressure, energy and gradient ``(G_u, G_delta)``; the interface
    that :func:`gapsweep.gfmd._smooth._wolfe` uses (``line``, ``phi``, ``e_law``, ``energy``)."""

    def __init__(self, free: FreeGrid, pad: Grid, law: SmoothInteraction, h: Any, k: Any, sigma0: float,
                 U: Any, delta: float, ops: Any = None) -> None:
        self.free, self.pad, self.law, self.h, self.k, self.sigma0 = free, pad, law, h, k, sigma0
        self.ratio = pad.size / free.size  # N_pad / N_map
        self.xp = pad.xp
        self.ops = ops if ops is not None else _make_ops(pad)
        self.U, self.delta = U, float(delta)
        self.g = self.map_field(U) + self.delta - h
        self.nfev = 0
        # The exponential law at a compressive load: the approach in closed form (as the periodic softmax
        # minimiser, docs/model.md M3), so that the minimisers move u~ alone (G_delta = 0 at every point)
        self.eliminate = ELIMINATE and law.load_control == "softmax" and sigma0 > 0 and hasattr(law, "rho")
        if self.eliminate:
            self._c = math.log(law.gamma0 / (law.rho * sigma0))
        self._evaluate()

    def _shift(self, g: Any) -> float:
        """Exponential law: the change ``s`` of the approach that makes ``<p(g + s)>_map = sigma0``,
        ``s = rho [ln(gamma0/(rho sigma0)) + ln <exp(-g/rho)>]`` (log-sum-exp, no overflow)."""
        rho = self.law.rho
        m = -float(self.xp.min(g)) / rho  # max of w = -g/rho
        S = self.ops.mean(self.xp.exp(g * (-1.0 / rho) - m))
        return rho * (self._c + m + math.log(S)) if S > 0 else math.nan

    def map_field(self, A: Any) -> Any:
        """The map block of the real field of the normalised doubled-grid coefficients ``A`` (only the map's
        rows are transformed back: FreeGrid.pad_inv); on the GPU a view of a transform buffer (use it at once)."""
        return self.free.pad_sum(A)

    def _evaluate(self) -> None:
        xp, ops = self.xp, self.ops
        self._energy: float | None = None
        if self.eliminate:
            sh = self._shift(self.g)
            self.g += sh
            self.delta += sh
        self.p = self.law.pressure(self.g, xp)
        self.e_law = ops.mean(self.law.energy(self.g, xp))
        # FFT of p zero-padded to the doubled grid, normalised (FreeGrid.pad_fwd never forms the padding)
        self.Gu = ops.grad(self.k, self.U, self.ratio / self.pad.size, self.free.pad_fwd(self.p))
        self.Gd = 0.0 if self.eliminate else self.sigma0 - ops.mean(self.p)
        self.nfev += 1

    @property
    def Z(self) -> tuple[Any, float]:  # the periodic state's name for its unknowns (_Solver.follow)
        """The unknowns ``(u~, delta)`` (not copied: the minimisers replace ``U``, never write into it)."""
        return self.U, self.delta

    def dot(self, a: tuple[Any, float], b: tuple[Any, float]) -> float:
        return self.ops.dot(a[0], b[0]) + a[1] * b[1]

    def energy(self) -> float:
        # once per point: the stall test and the line search's slack both ask for it (one grid pass each)
        if self._energy is None:
            self._energy = 0.5 * self.ops.kdot(self.U, self.k, self.U) + self.e_law + self.sigma0 * self.delta
        return self._energy

    def line(self, D: tuple[Any, float]) -> tuple[Any, float, float, float]:
        """Real-space direction of the map's gap and the scalars of ``phi(alpha) = F(x + alpha D)``."""
        DU, dd = D
        d = self.map_field(DU) + dd
        if self.xp is np:  # k D~ once for both sums (one pass less)
            kD = self.k * DU
            a, b = self.ops.dot(kD, self.U), self.ops.dot(kD, DU)
        else:
            a = self.ops.kdot(DU, self.k, self.U)
            b = self.ops.kdot(DU, self.k, DU)
        return d, a, b, dd

    def phi(self, alpha: float, d: Any, a: float, b: float, d0: float, e0: float) -> tuple[float, float]:
        """``(phi(alpha) - phi(0) + e_law(0), phi'(alpha))`` without FFT (``d0``: the step of ``delta``)."""
        xp, ops = self.xp, self.ops
        g = ops.trial(self.g, alpha, d)
        if self.eliminate:  # the approach follows the step: <p> = sigma0 on the line too (d0 = 0 here)
            sh = self._shift(g)
            g += sh
            # phi' = a + alpha b - <p d> (the terms of d delta / d alpha cancel, as <p> = sigma0)
            f = alpha * a + 0.5 * alpha * alpha * b + ops.mean(self.law.energy(g, xp)) + self.sigma0 * sh
            return f, a + alpha * b - ops.mean_product(self.law.pressure(g, xp), d)
        f = alpha * a + 0.5 * alpha * alpha * b + ops.mean(self.law.energy(g, xp)) + self.sigma0 * alpha * d0
        df = a + alpha * b - ops.mean_product(self.law.pressure(g, xp), d) + self.sigma0 * d0
        return f, df

    def move(self, alpha: float, D: tuple[Any, float], d: Any) -> None:
        self.U = self.U + alpha * D[0]
        self.delta += alpha * D[1]
        self.g = self.ops.trial(self.g, alpha, d)
        self._evaluate()


def _check(st: _FreeState, ratio: float, p_ref: float, tol: float, max_iter: int, rng: float | None,
           history: list[float], best: list | None) -> str | None:
    """The stopping tests of the minimisers at the current point (None: go on); the residual as in the module
    docstring, appended to ``history``; the periodic minimiser's stall test (``_smooth._stalled``: no progress in
    residual or energy for 30 evaluations), ``best`` its record (None: no stall test, method "cg")."""
    # G_u = ratio FFT[f - p 1_map]/N_pad: sqrt(dot/ratio) is the imbalance's rms normalised to the map
    res = max(math.sqrt(max(st.ops.dot(st.Gu, st.Gu), 0.0) / ratio), abs(st.Gd)) / p_ref
    history.append(res)
    if not math.isfinite(res):
        return "non_finite"
    if res <= tol:
        return "converged"
    if st.sigma0 < 0 and rng is not None and float(st.g.min()) > _DETACHED * rng:
        return "detached"
    if st.nfev >= max_iter:
        return "max_iter"
    return "stalled" if best is not None and _stalled(st, res, best) else None


def _cg(st: _FreeState, minv_u: Any, minv_d: float, ratio: float, p_ref: float, tol: float, max_iter: int,
        rng: float | None, history: list[float]) -> str:
    """Method "cg": preconditioned nonlinear conjugate gradients (Polak-Ribiere+, restarted when a direction is
    not a descent direction or the line search fails) with the L-BFGS method's preconditioner and strong-Wolfe
    line search (``c2 = 0.4``: on a 128 x 128 map 2.4 trials per evaluation and 134 evaluations, where 0.1 took 23
    and 216); the first trial step ``alpha_prev slope_prev / slope`` (Nocedal & Wright, Numerical Optimization,
    Eq. 3.60). One direction and the previous gradient instead of the L-BFGS pairs: less memory traffic per
    evaluation on the doubled grid (the GPU's cost), more evaluations."""
    ops = st.ops
    D: Any = None
    zg_old = alpha = slope_old = 0.0
    G_old: Any = None
    best = None  # no stall test: CG wanders at ~1e-7 for hundreds of evaluations before it reaches 1e-9
    while True:
        deadline.check()  # a task time limit ends the solve between iterations
        stop = _check(st, ratio, p_ref, tol, max_iter, rng, history, best)
        if stop:
            return stop
        Zu, zd = minv_u * st.Gu, minv_d * st.Gd
        zg = ops.dot(Zu, st.Gu) + zd * st.Gd
        beta = 0.0
        if D is not None and zg_old > 0:
            beta = max(0.0, (zg - ops.dot(Zu, G_old[0]) - zd * G_old[1]) / zg_old)
        if beta > 0:
            Du = D[0]
            Du *= beta
            Du -= Zu
            D = (Du, beta * D[1] - zd)
        else:
            Zu *= -1.0
            D = (Zu, -zd)
        slope = ops.dot(st.Gu, D[0]) + st.Gd * D[1]
        if not slope < 0 and beta > 0:  # not a descent direction: steepest descent
            D = (-(minv_u * st.Gu), -zd)
            slope, beta = -zg, 0.0
        if not slope < 0:
            return "stalled" if math.isfinite(slope) else "non_finite"
        a0 = alpha * slope_old / slope if alpha > 0 else 1.0
        step = _wolfe(st, D, slope, a0 if math.isfinite(a0) and a0 > 0 else 1.0, c2=0.4)
        if step is None:
            if beta == 0.0:
                return "stalled"
            D, alpha = None, 0.0  # restart along the preconditioned gradient
            continue
        alpha, d = step
        slope_old, zg_old, G_old = slope, zg, (st.Gu, st.Gd)
        st.move(alpha, D, d)


def _two_loop_first(ops: Any, s_hist: list, y_hist: list, r_hist: list, q: tuple[Any, float]
                    ) -> tuple[Any, float, list[float]]:
    """The first loop of the L-BFGS two-loop recursion (newest pair first: ``al_i = r_i <s_i q>``,
    ``q -= al_i y_i``) with each update and the next dot product in one pass; ``q[0]`` updated in place.
    Returns ``(q0, q1, alphas newest first)``."""
    q0, q1 = q
    k = len(s_hist)
    alphas: list[float] = []
    if not k:
        return q0, q1, alphas
    i = k - 1
    d = ops.dot(s_hist[i][0], q0) + s_hist[i][1] * q1
    while True:
        al = r_hist[i] * d
        alphas.append(al)
        q1 -= al * y_hist[i][1]
        if i == 0:
            ops.axpy(q0, -al, y_hist[i][0])
            return q0, q1, alphas
        d = ops.axpy_dot(q0, -al, y_hist[i][0], s_hist[i - 1][0]) + s_hist[i - 1][1] * q1
        i -= 1


def _two_loop_second(ops: Any, s_hist: list, y_hist: list, r_hist: list, alphas: list[float],
                     q: tuple[Any, float]) -> tuple[Any, float]:
    """The second loop (oldest pair first: ``q += (al_i - r_i <y_i q>) s_i``), fused as the first one."""
    q0, q1 = q
    k = len(s_hist)
    if not k:
        return q0, q1
    d = ops.dot(y_hist[0][0], q0) + y_hist[0][1] * q1
    for i in range(k):
        c = alphas[k - 1 - i] - r_hist[i] * d
        q1 += c * s_hist[i][1]
        if i == k - 1:
            ops.axpy(q0, c, s_hist[i][0])
        else:
            d = ops.axpy_dot(q0, c, s_hist[i][0], y_hist[i + 1][0]) + y_hist[i + 1][1] * q1
    return q0, q1


def _lbfgs(st: _FreeState, minv_u: Any, minv_d: float, ratio: float, p_ref: float, tol: float, max_iter: int,
           rng: float | None, memory: int, history: list[float]) -> str:
    """Method "lbfgs" (the default): L-BFGS with ``memory`` pairs, the preconditioner ``(minv_u, minv_d)`` as
    its initial inverse Hessian (module docstring). Returns the status; ``st`` holds the last point."""
    ops = st.ops
    s_hist: list = []
    y_hist: list = []
    r_hist: list[float] = []
    status = "max_iter"
    best = [math.inf, math.inf, 0]

    def precondition(G: tuple[Any, float]) -> tuple[Any, float]:
        return minv_u * G[0], minv_d * G[1]

    def axpy_pair(a: float, x: tuple[Any, float], y: tuple[Any, float]) -> tuple[Any, float]:
        """``y + a x``, in place on ``y`` (a direction being built by the two-loop recursion, owned here)."""
        ops.axpy(y[0], a, x[0])
        return y[0], y[1] + a * x[1]

    def scale(q: tuple[Any, float], c: float) -> tuple[Any, float]:
        q0 = q[0]  # owned (a copy of the gradient): scaled in place
        q0 *= c
        return q0, q[1] * c

    def precondition_owned(q: tuple[Any, float]) -> tuple[Any, float]:
        q0 = q[0]
        q0 *= minv_u
        return q0, minv_d * q[1]

    steps: dict[str, Any] = dict(
        dot=st.dot, axpy=lambda q, a, x: axpy_pair(a, x, q), precondition=precondition_owned, scale=scale,
        # <y M^-1 y> in one pass (no preconditioned copy)
        curvature=lambda y: ops.kdot(y[0], minv_u, y[0]) + y[1] * (minv_d * y[1]))
    if hasattr(ops, "axpy_dot"):  # each update fused with the next pair's dot product (_HostOps.axpy_dot)
        def first(q: tuple[Any, float]) -> tuple[tuple[Any, float], list[float]]:
            q0, q1, alphas = _two_loop_first(ops, s_hist, y_hist, r_hist, q)
            return (q0, q1), alphas

        steps.update(first=first, second=lambda q, alphas: _two_loop_second(ops, s_hist, y_hist, r_hist, alphas, q))

    while True:
        deadline.check()  # a task time limit ends the solve between iterations
        grad = (st.Gu, st.Gd)
        stop = _check(st, ratio, p_ref, tol, max_iter, rng, history, best)
        if stop:
            status = stop
            break
        q = two_loop((st.Gu.copy(), st.Gd), list(zip(s_hist, y_hist, r_hist)), **steps)
        q0 = q[0]
        q0 *= -1.0
        D = (q0, -q[1])
        slope = st.dot(grad, D)
        if not slope < 0:
            s_hist.clear(), y_hist.clear(), r_hist.clear()
            pg = precondition(grad)
            D = (-pg[0], -pg[1])
            slope = st.dot(grad, D)
            if not slope < 0:
                status = "stalled" if math.isfinite(slope) else "non_finite"
                break
        step = _wolfe(st, D, slope, 1.0)
        if step is None:
            if not s_hist:
                status = "stalled"
                break
            s_hist.clear(), y_hist.clear(), r_hist.clear()
            continue
        alpha, d = step
        old = grad
        st.move(alpha, D, d)
        s = (alpha * D[0], alpha * D[1])
        y = (st.Gu - old[0], st.Gd - old[1])
        remember_pair(s_hist, y_hist, r_hist, s, y, st.dot(s, y), memory)
    return status


class _FreeSolver(_Solver):
    """The periodic minimiser's solver (``gfmd._smooth._Solver``: solves at any load from any start, follows
    loads by continuation, brackets pull-off) on the free-boundary state: the unknowns are the pair
    ``(u~ on the doubled grid, delta)``, the minimiser this module's L-BFGS (or CG)."""

    def __init__(self, free: FreeGrid, pad: Grid, law: SmoothInteraction, h: Any, k: Any, ratio: float,
                 method: str, memory: int, max_iter: int) -> None:
        self.free, self.pad, self.law, self.h, self.k, self.ratio = free, pad, law, h, k, ratio
        self.grid = pad
        self.method, self.memory, self.max_iter = method, memory, max_iter
        self.ops = _make_ops(pad)
        self.rng = law.range()
        self.nfev = 0  # evaluations spent by every stage together (the result's ``iterations``)
        self.history: list[float] = []
        self.info: dict[str, float] = {}

    def at(self, sigma0: float, Z: Any, tol: float, budget: int | None = None) -> tuple[_FreeState, str]:
        """Minimise at load ``sigma0`` from ``Z = (u~, delta)`` (not modified) to ``tol``, with at most ``budget``
        evaluations (default: what is left of ``max_iter``)."""
        law, k, ratio = self.law, self.k, self.ratio
        c = law.curvature(sigma0)
        # Local stiffness c acts on the map only, a quarter of the doubled grid: its mean over the grid, c/ratio,
        # is the Fourier-diagonal estimate (as the periodic preconditioner takes the mean of p/rho). Measured on a
        # 256 x 192 crop (exponential, sigma0 = 0.05): 146 iterations against 215 with c.
        minv_u = 1.0 / (k + c / ratio) if c > 0 else 1.0 / k
        minv_d = 1.0 / c if c > 0 else 1.0 / max(law.pressure_scale(sigma0) / (law.range() or 1.0), 1e-300)
        p_ref = law.pressure_scale(sigma0)
        st = _FreeState(self.free, self.pad, law, self.h, k, sigma0, Z[0], Z[1], self.ops)
        left = max(self.max_iter - self.nfev, 1)
        cap = left if budget is None else min(budget, left)
        if self.method == "cg":
            status = _cg(st, minv_u, minv_d, ratio, p_ref, tol, cap, self.rng, self.history)
        else:
            status = _lbfgs(st, minv_u, minv_d, ratio, p_ref, tol, cap, self.rng, self.memory, self.history)
        self.nfev += st.nfev
        return st, status

    def _lin(self, a: Any, b: Any, t: float) -> Any:
        return a[0] + (a[0] - b[0]) * t, a[1] + (a[1] - b[1]) * t

    def _dist(self, a: Any, b: Any) -> float:
        du = a[0] - b[0]
        return math.sqrt(max(self.pad.dot(du, du), 0.0) + (a[1] - b[1]) ** 2)


def minimise(heights: Any, law: SmoothInteraction, *, sigma0: float, e_star: float, length: Any, tol: float,
             method: str, backend: str, max_iter: int, initial: Any, threads: int | None, host: Any,
             t_start: float, periodic: bool = False, memory: int | None = None) -> GFMDResult:
    """Smooth ``law`` on the finite map ``heights`` with free boundaries (module docstring; inputs validated by
    ``gfmd.solve``). ``initial``: None (the body flat, touching the highest summit) or a GFMDResult of a free
    solve of the same map (its pressure is turned into the displacement on the doubled grid)."""
    if periodic:
        raise ValueError("gfmd._free solves finite maps only (periodic=False)")
    method = "lbfgs" if method == "auto" else method
    if method not in METHODS:
        raise ValueError(f"method must be one of 'auto', {', '.join(map(repr, METHODS))}, got {method!r}")
    on_gpu = _is_cupy(heights)
    memory = (_MEMORY if on_gpu else _MEMORY_CPU) if memory is None else int(memory)
    free = FreeGrid(heights.shape, length, backend, threads, on_gpu)
    nx, ny = free.shape
    pad = Grid((2 * nx, 2 * ny), (2 * free.lx, 2 * free.ly), free.backend, threads, on_gpu)
    xp = free.xp
    h = free.asarray(heights)
    if not bool(xp.all(xp.isfinite(h))):
        raise ValueError("heights contain NaN or inf")
    h = h - float(h.mean())  # only h - <h> matters at fixed load (delta absorbs the rest)
    green = free.green(e_star)  # rfft2 of G on the doubled grid, real and > 0
    if not bool(xp.all(green > 0)):  # never seen; a non-positive mode would make the energy unbounded
        raise FloatingPointError("free-boundary Green's function has a non-positive Fourier mode")
    ratio = pad.size / (nx * ny)
    k = ratio / green
    p_ref = law.pressure_scale(sigma0)
    if initial is None:
        U = xp.zeros((2 * nx, ny + 1), dtype=xp.complex128)
        delta = float(h.max())
    elif isinstance(initial, GFMDResult) and not initial.periodic and initial.shape == (nx, ny):
        f = xp.zeros(pad.shape)
        f[:nx, :ny] = xp.asarray(initial.pressure, dtype=xp.float64)
        U = pad.fwd(f) * green  # u = G * f (circular convolution; G^ unnormalised)
        u_map = pad.inv(U)[:nx, :ny]
        delta = float(initial.mean_gap) - float(xp.mean(u_map - h))
        if not math.isfinite(delta) or not bool(xp.all(xp.isfinite(U))):
            raise ValueError("initial: the result's fields are not finite")
    else:
        raise ValueError(f"initial must be None or a GFMDResult of a free-boundary (periodic=False) solve of a "
                         f"{nx} x {ny} map")
    sv = _FreeSolver(free, pad, law, h, k, ratio, method, memory, max_iter)
    step_tol = max(tol, _STEP_TOL)
    with np.errstate(all="ignore"):
        if initial is None and sigma0 < 0:
            # the periodic minimiser's start at tensile loads (docs/gfmd.md "Tensile loads"): zero load from the
            # flat body, then unloaded quasi-statically to sigma0 (a direct solve from the flat body is pulled
            # off before contact forms: "detached" where an attached equilibrium exists, issue 36)
            st, status = sv.at(0.0, (U, delta), step_tol)
            if status == "converged":
                st2, status = sv.follow(0.0, st.Z, sigma0, tol)
                st = st2 if st2 is not None else st
        else:
            st, status = sv.at(sigma0, (U, delta), tol)
            s_init = float(getattr(initial, "sigma0", math.nan))
            if (status in ("detached", "stalled") and isinstance(initial, GFMDResult) and initial.converged
                    and sigma0 < 0 and s_init > sigma0 and sv.nfev < max_iter):
                log.info("%s (free boundaries): %s at sigma0=%g from the initial state; following the load from %g",
                         law.name, status, sigma0, s_init)
                st2, status = sv.follow(s_init, (U, delta), sigma0, tol, retry=True)
                st = st2 if st2 is not None else st
        history = sv.history

        # Returned fields from the state; their residual decides (issue 9).
        u_pad = pad.inv(st.U)
        u = u_pad[:nx, :ny]
        gap = st.delta + u - h
        p = law.pressure(gap, xp)
        pm = xp.zeros(pad.shape)
        pm[:nx, :ny] = p
        imbalance = pad.inv(st.U * k) * (1.0 / ratio) - pm  # elastic pressure f minus the law's, doubled grid
        residual = math.sqrt(float(xp.sum(imbalance * imbalance)) / (nx * ny)) / p_ref
        load_error = abs(float(p.mean()) - sigma0) / p_ref
        elastic = 0.5 * pad.dot(st.U, k * st.U)
        area = float(xp.count_nonzero(law.contact(gap, p))) / (nx * ny)
        g0 = float(gap.mean())
        e_int = float(xp.mean(law.energy(gap, xp)))
        u = xp.ascontiguousarray(u)
    fields_ok = math.isfinite(residual) and bool(xp.all(xp.isfinite(gap))) and bool(xp.all(xp.isfinite(p)))
    status, _ = final_status(status, fields_ok, residual, load_error, tol)
    converged = status == "converged"
    log.debug("%s (free boundaries): %s after %d evaluations, residual %.3g", law.name, status, sv.nfev, residual)
    gap, p, u = fields_to_host(pad, host, gap, p, u)
    pad.synchronize()
    diagnostics = {"pressure_scale": p_ref, "interaction_energy": e_int, "approach": st.delta, **sv.info}
    return law_result(law, t_start, mean_gap=g0, gap=gap, pressure=p, displacement=u, iterations=sv.nfev,
                      converged=converged, residual=residual, load_error=load_error, method=method,
                      backend=pad.backend, status=status, sigma0=sigma0, rho=getattr(law, "rho", math.nan),
                      gamma0=getattr(law, "gamma0", math.nan), e_star=e_star, length=length, tol=tol,
                      history=history, contact_area=area, elastic_energy=elastic, periodic=False,
                      diagnostics=diagnostics)
