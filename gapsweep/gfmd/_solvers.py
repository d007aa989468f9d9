"""Minimisers of the reduced GFMD energy (docs/model.md M3): the shared state :class:`_Problem` with its
FFT-free line search, and the "cg", "lbfgs" and "fire" loops."""

from __future__ import annotations

import functools
import importlib
import math
from typing import Any

import numpy as np

from gapsweep.core import deadline
from gapsweep.core.fft import FFTBackend
from gapsweep.gfmd._lbfgs import diagonal, remember_pair, two_loop
from gapsweep.gfmd._ops import _Ops


@functools.lru_cache(maxsize=8)
def _half_q_cached(xp_name: str, n: int, length: float):
    xp = importlib.import_module(xp_name)
    kx = xp.fft.fftfreq(n, d=1.0 / n)
    ky = xp.fft.rfftfreq(n, d=1.0 / n)
    return (2 * np.pi / length) * xp.hypot(kx[:, None], ky[None, :])


def _half_q(xp: Any, n: int, length: float):
    """``|q|`` on the rfft2 half grid (rad/length), built on the device and cached (read-only use)."""
    return _half_q_cached(xp.__name__, n, float(length))


# ------------------------------------------------------------------------------------------------ solver
def _next_trial(alpha: float, dphi: float, curv: float, lo: float, dlo: float, hi: float, dhi: float) -> float:
    """Next step length of the line search on phi'(alpha) = 0 (M3): the Newton step from ``alpha`` with the
    curvature ``curv``, else the secant of the bracket ``[lo, hi]`` (slopes ``dlo``, ``dhi``; expansion to
    ``4 alpha`` while ``hi`` is infinite), else its midpoint. Shared by the one-by-one and the batched solver, so
    both take the same trials."""
    new = alpha - dphi / curv if curv > 0 else math.inf
    if not (lo < new < hi):
        new = lo - dlo * (hi - lo) / (dhi - dlo) if math.isfinite(hi) else 4.0 * alpha
        if not (lo < new < hi):
            new = 0.5 * (lo + hi)
    return new


def first_step(phi0p: float, b: float, sr: float, S: float, s1: float, s2: float) -> float:
    """The line search's first step: Newton's from ``alpha = 0``, ``-phi'(0) / phi''(0)`` with
    ``phi''(0) = b + (sigma0/rho) (s2/S - (s1/S)^2)`` (1 when that curvature is not positive)."""
    curv = b + sr * (s2 / S - (s1 / S) ** 2)
    return -phi0p / curv if curv > 0 else 1.0


def search_steps(phi0p: float, a: float, b: float, s0: float, rho: float, alpha: float, eta: float,
                 max_trials: int = 40):
    """The trials of the line search on ``phi'(alpha) = a + alpha b - sigma0 s1/S = 0`` (M3) from the step
    ``alpha``, as a generator: yields the step of a trial point, receives its ``(m, S, s1, s2)`` (max of the
    shifted exponent and the sums ``sum e``, ``sum e d``, ``sum e d^2``); returns ``(alpha, ok, last)``,
    ``last`` saying whether the last trial is the accepted point (else the caller evaluates ``alpha`` once more).
    Accepts ``|phi'| <= eta |phi'(0)|``; Newton steps inside the bracket, secant or bisection when Newton leaves
    it (:func:`_next_trial`); a non-finite trial halves the step. Shared by :meth:`_Problem.line_search` and the
    batched solver (gfmd.batched), so both take the same trials."""
    lo, hi, dlo, dhi = 0.0, math.inf, phi0p, math.nan
    for _ in range(max_trials):
        if not math.isfinite(alpha) or alpha <= 0:
            break
        m, S, s1, s2 = yield alpha
        if not (math.isfinite(m) and math.isfinite(S) and math.isfinite(s1) and math.isfinite(s2)):
            hi = alpha
            alpha = 0.5 * (lo + alpha)
            continue
        dphi = a + alpha * b - s0 * s1 / S
        if abs(dphi) <= eta * abs(phi0p):
            return alpha, True, True
        if dphi < 0:
            lo, dlo = alpha, dphi
        else:
            hi, dhi = alpha, dphi
        if hi - lo <= 1e-13 * hi:
            break
        alpha = _next_trial(alpha, dphi, b + (s0 / rho) * (s2 / S - (s1 / S) ** 2), lo, dlo, hi, dhi)
    if lo <= 0.0:
        return 0.0, False, False
    return lo, True, False


class _Problem:
    """State shared by the methods: surface, operators and the current point ``(X, W, e, G)``.

    ``X = u~`` (half spectrum), ``W = (h - u)/rho`` and ``e = exp(W - m)`` (real space), ``S = sum e``, the
    Fourier gradient ``G = (E* q/2) u~ - p~`` and ``r2 = <G G>`` (M3)."""

    def __init__(self, h, x0, *, sigma0, rho, fft: FFTBackend, ops: _Ops, e_star: float | None = None,
                 length: float | None = None, h_mean: float | None = None, h_shift: float | None = None,
                 share_gold: bool = False, stiffness: Any = None, keep_mass: bool = True) -> None:
        """``h_mean`` (GPU, ops with ``field``): ``h`` is the caller's surface, centred in the pass that forms
        ``W`` (no centred copy is kept). ``share_gold`` (CG on the GPU): ``G_old`` is ``G`` itself, the
        gradient pass reading each old mode before writing the new one (one half spectrum less). A rank's slabs
        (gfmd.distributed): ``fft`` the slab transforms, ``ops`` the slab passes (``ops.owner``: these columns
        hold ``q = 0``), ``stiffness`` ``k`` on the rank's columns, ``h_shift`` the mean of the caller's
        surface ``h`` (taken out where ``W`` is formed: :func:`_centred`), ``keep_mass=False`` (the masses
        ``M(q)`` made when FIRE asks, not kept: memory)."""
        xp = fft.xp
        self.xp, self.n, self.fft, self.ops = xp, ops.n, fft, ops
        self.sigma0, self.rho = sigma0, rho
        # elastic stiffness E* q / 2 per mode; ``stiffness``: another substrate's k(q) on the same half grid (an
        # elastic layer, gfmd.substrates; CPU ops only: the GPU's fused kernels recompute E* q / 2 per mode)
        self.k = 0.5 * e_star * _half_q(xp, ops.n, length) if stiffness is None else stiffness
        self._mass = self.k + sigma0 / rho if keep_mass else None  # Fourier-diagonal Hessian estimate M(q)
        if keep_mass:
            self.minv = 1.0 / self._mass
        else:
            self.minv = self.k + sigma0 / rho
            xp.reciprocal(self.minv, out=self.minv)
        if ops.owner:
            self.minv[0, 0] = 0.0  # <u> = 0: the q = 0 mode is not an unknown
        if hasattr(ops, "bind_stiffness") and stiffness is None:  # GPU: k, M^-1 recomputed per mode beat reading
            ops.bind_stiffness(self.k, self.minv, 0.5 * e_star, 2 * np.pi / length, sigma0 / rho)
        self.h = h
        self.X = x0
        if ops.owner:
            self.X[0, 0] = 0.0
        if h_shift is not None:
            self.W = _centred(h, fft.irfft2(self.X), h_shift, rho)
        elif h_mean is not None and hasattr(ops, "field"):
            self.W = xp.empty(h.shape, dtype=xp.float64)
            # the pass returns max W: the start point's exponentials need no separate max pass
            ops._guess = ops.field(h, h_mean, fft.irfft2(self.X), 1.0 / rho, self.W)
        else:
            self.W = (h - fft.irfft2(self.X)) * (1.0 / rho)
        self.Wt = xp.empty_like(self.W)
        self.e = xp.empty_like(self.W)
        self.et = xp.empty_like(self.W)
        self.G = xp.empty_like(self.X)
        self.G_old = self.G if share_gold else xp.empty_like(self.X)
        self.nfev = 0
        self.m = ops.trial(self.W, self.W, 0.0, self.Wt)
        self.S, _, _ = ops.expstats(self.Wt, self.m, self.e)
        self.r2 = self._gradient(None, 0.0)

    @property
    def mass(self) -> Any:
        """FIRE's masses ``M(q) = k + sigma0/rho`` (kept, or made when asked: ``keep_mass``)."""
        return self._mass if self._mass is not None else self.k + self.sigma0 / self.rho

    def _gradient(self, D, alpha: float) -> float:
        """``X += alpha D`` and the Fourier gradient of the accepted point (its ``e``, ``S``): one rfft2.
        ``p~ = rfft2(p)/n^2 = sigma0 rfft2(e)/S``."""
        self.nfev += 1
        E = self.fft.rfft2(self.e)
        return self.ops.grad_step(self.X, self.X if D is None else D, alpha, E, self.sigma0 / self.S, self.k,
                                  self.G)

    def residual(self) -> float:
        """rms force imbalance over sigma0 (docs/gfmd.md, convergence), by Parseval."""
        return math.sqrt(max(self.r2, 0.0)) / self.sigma0

    def line_search(self, D, phi0p: float, a: float, b: float, eta: float, alpha0: float | None = None,
                    max_trials: int = 40, d=None, first: tuple | None = None):
        """Find ``alpha > 0`` with ``|phi'(alpha)| <= eta |phi'(0)|`` for the convex ``phi(alpha) = F(X + alpha D)``
        (the trials: :func:`search_steps`, shared with the batched solver).

        ``phi'(alpha) = a + alpha b - <p_alpha d>`` with ``a = <kD, X>``, ``b = <kD, D>`` (Fourier sums) and the
        softmax pressure at ``W - alpha d / rho``, ``d = irfft2(D)`` (real space): no further FFT. Leaves the
        accepted point in (Wt, et) and returns ``(alpha, m, S, ok)``. GPU, chained CG: ``d`` is ``irfft2(D)``
        already and ``first = (alpha, m, S, s1, s2)`` the first trial, already evaluated on the device (the
        same step as below)."""
        ops, rho, s0 = self.ops, self.rho, self.sigma0
        d = self.fft.irfft2(D) if d is None else d
        if first is not None:
            alpha = first[0]
        elif alpha0 is None:
            s1, s2 = ops.moments(self.e, d)
            alpha = first_step(phi0p, b, s0 / rho, self.S, s1, s2)
        else:
            alpha = alpha0
        steps = search_steps(phi0p, a, b, s0, rho, alpha, eta, max_trials)
        point = first[1:] if first is not None else None
        try:
            alpha = next(steps)
            while True:
                if point is None:
                    m = ops.trial(self.W, d, -alpha / rho, self.Wt)
                    S, s1, s2 = ops.expstats(self.Wt, m, self.et, d)
                else:
                    (m, S, s1, s2), point = point, None
                alpha = steps.send((m, S, s1, s2))
        except StopIteration as stop:
            alpha, ok, last = stop.value
        if not ok:
            return 0.0, 0.0, 0.0, False
        if not last:  # round-off or out of trials: the last point known to lie downhill of the line minimum
            m = ops.trial(self.W, d, -alpha / rho, self.Wt)
            S, _, _ = ops.expstats(self.Wt, m, self.et)
        return alpha, m, S, True

    def accept(self, alpha: float, D, m: float, S: float) -> None:
        """Move to ``X + alpha D`` (its real-space state is in Wt, et); keep the old gradient in G_old."""
        self.W, self.Wt = self.Wt, self.W
        self.e, self.et = self.et, self.e
        self.m, self.S = m, S
        self.G, self.G_old = self.G_old, self.G
        self.r2 = self._gradient(D, alpha)


def _centred(h: Any, u: Any, h_shift: float, rho: float) -> Any:
    """``W = (h - <h> - u) / rho`` as a new array (one temporary-free pass chain), ``h_shift = <h>``."""
    w = h - u
    w -= h_shift
    w *= 1.0 / rho
    return w


def _check(pb: _Problem, tol: float, max_iter: int, history: list[float]) -> str | None:
    deadline.check()  # a task time limit ends the solve here, between iterations (gapsweep.core.deadline)
    r = pb.residual()
    history.append(r)
    if not math.isfinite(r):
        return "non_finite"
    if r <= tol:
        return "converged"
    if pb.nfev >= max_iter:
        return "max_iter"
    return None


def _run_cg(pb: _Problem, tol: float, max_iter: int, history: list[float], eta: float = 0.1) -> str:
    """Preconditioned Polak-Ribiere+ nonlinear CG with the Newton line search of _Problem.line_search. One loop
    for every engine; its direction comes from :class:`_Directions` (synchronous passes) or, on the GPU with one
    gradient array, :class:`_ChainedDirections` (one host synchronisation per iteration): the same decisions
    in the same order."""
    ops = pb.ops
    chained = hasattr(ops, "chain_read") and pb.G_old is pb.G
    cg = _ChainedDirections(pb) if chained else _Directions(pb)
    zg_old = 0.0
    restart = True
    while True:
        cg.queue(restart, zg_old)
        status = _check(pb, tol, max_iter, history)
        if status is not None:
            return status
        zg, beta, (phi0p, a, b) = cg.direction(restart, zg_old)
        trial: dict = {}
        if phi0p >= 0 and beta > 0:  # not a descent direction (round-off): restart along -M^-1 G
            phi0p, a, b = ops.cg_update(pb.G, pb.minv, cg.D, 0.0, pb.k, pb.X)
        else:
            trial = cg.first_trial()
        if not phi0p < 0:
            return "stalled" if math.isfinite(phi0p) else "non_finite"
        alpha, m, S, ok = pb.line_search(cg.D, phi0p, a, b, eta, **trial)
        if not ok:
            if restart:
                return "stalled"
            restart = True
            continue
        restart = False
        zg_old = zg
        cg.accept(alpha, m, S)


class _Directions:
    """The CG's directions by synchronous passes: ``cg_dots``, then ``cg_update`` (on the GPU the gradient pass
    also yields the next ``cg_dots``: ``bind_cg``, no extra pass)."""

    def __init__(self, pb: _Problem) -> None:
        self.pb, self.ops = pb, pb.ops
        if hasattr(self.ops, "bind_cg"):
            self.ops.bind_cg(pb.minv)
        self.D = pb.xp.zeros_like(pb.X)

    def queue(self, restart: bool, zg_old: float) -> None:
        """Nothing is queued ahead of the convergence check."""

    def direction(self, restart: bool, zg_old: float) -> tuple[float, float, tuple]:
        """``(<Z G>, beta, (phi0p, a, b))`` of ``D = beta D - M^-1 G``."""
        pb, ops = self.pb, self.ops
        zg, zg_cross = ops.cg_dots(pb.G, None if restart else pb.G_old, pb.minv)
        beta = 0.0 if restart else max(0.0, (zg - zg_cross) / zg_old)
        return zg, beta, ops.cg_update(pb.G, pb.minv, self.D, beta, pb.k, pb.X)

    def first_trial(self) -> dict:
        return {}  # the line search evaluates its own first trial

    def accept(self, alpha: float, m: float, S: float) -> None:
        self.pb.accept(alpha, self.D, m, S)


class _ChainedDirections(_Directions):
    """The CG's directions on the GPU with one host synchronisation per iteration (issue 22, item 3): the
    gradient of the accepted point, the next direction (``beta`` on the device), ``irfft2`` of it, the moments
    and the first trial of the line search are queued back to back (gfmd/_cuda.py, ``chain_*``) and their
    scalars read in one copy. Further trials, a restart with ``beta = 0`` and a shift re-run go through the plain
    synchronous operations. Work queued past convergence (one direction and one trial) is discarded. Needs
    ``pb.G_old is pb.G`` (the gradient pass reads the old gradient in place)."""

    def __init__(self, pb: _Problem) -> None:
        super().__init__(pb)  # binds the CG dots to the gradient pass
        # the start point's <Z G> (its gradient had no CG dots)
        self.zg, self.zc = self.ops.cg_dots(pb.G, None, pb.minv)[0], 0.0
        self.fresh = False  # slot GRAD holds the gradient of an accepted point that the host has not read yet
        self.d = self.r = None
        self.shift = 0.0

    def queue(self, restart: bool, zg_old: float) -> None:
        from gapsweep.gfmd._cuda import SLOT_GRAD

        pb, ops = self.pb, self.ops
        ops.chain_cgdir(pb.G, pb.minv, self.D, pb.k, pb.X, None if restart else zg_old)
        self.d = pb.fft.irfft2(self.D)
        ops.chain_moments(pb.e, self.d)
        self.shift = ops.chain_trial(pb.W, self.d, pb.S, pb.sigma0 / pb.rho, pb.rho, pb.Wt, pb.et)
        r = self.r = ops.chain_read()
        if self.fresh:
            pb.r2, self.zg, self.zc = float(r[SLOT_GRAD]), float(r[SLOT_GRAD + 1]), float(r[SLOT_GRAD + 2])
            self.fresh = False

    def direction(self, restart: bool, zg_old: float) -> tuple[float, float, tuple]:
        from gapsweep.gfmd._cuda import SLOT_CGDIR

        beta = 0.0 if restart else max(0.0, (self.zg - self.zc) / zg_old)
        return self.zg, beta, tuple(float(x) for x in self.r[SLOT_CGDIR:SLOT_CGDIR + 3])

    def first_trial(self) -> dict:
        """The queued first trial (gs_trial0), redone with the exact shift when its max lies too far from the
        guessed one."""
        from gapsweep.gfmd._cuda import _SHIFT_SLACK, SLOT_TRIAL

        pb, ops = self.pb, self.ops
        mt, St, s1, s2, alpha = (float(x) for x in self.r[SLOT_TRIAL:SLOT_TRIAL + 5])  # gs_trial0 order
        if math.isfinite(mt):
            if abs(mt - self.shift) > _SHIFT_SLACK:  # guessed shift too far off: the pass again, shifted exactly
                St, s1, s2 = ops.retrial(pb.W, self.d, -alpha / pb.rho, pb.Wt, pb.et, mt)
            ops._guess = mt
        return {"d": self.d, "first": (alpha, mt, St, s1, s2)}

    def accept(self, alpha: float, m: float, S: float) -> None:
        """``pb.accept`` with the gradient pass queued instead of read."""
        pb = self.pb
        pb.W, pb.Wt = pb.Wt, pb.W
        pb.e, pb.et = pb.et, pb.e
        pb.m, pb.S = float(m), S
        pb.nfev += 1
        self.ops.chain_grad(pb.X, self.D, alpha, pb.fft.rfft2(pb.e), pb.sigma0 / S, pb.k, pb.G)
        self.fresh = True


def _clear(*lists: list) -> None:
    for lst in lists:
        lst.clear()


def _run_lbfgs(pb: _Problem, tol: float, max_iter: int, history: list[float], memory: int = 5,
               eta: float = 0.5) -> str:
    """L-BFGS (``gfmd._lbfgs``: two-loop recursion, Nocedal & Wright Alg. 7.4) with ``H0 = gamma M^-1``, same
    line search."""
    ops = pb.ops
    steps = diagonal(ops.dot, pb.minv, ops.axpy)
    s_hist: list = []
    y_hist: list = []
    r_hist: list[float] = []
    while (status := _check(pb, tol, max_iter, history)) is None:
        D = -two_loop(pb.G.copy(), list(zip(s_hist, y_hist, r_hist)), **steps)
        phi0p = ops.dot(pb.G, D)
        if not phi0p < 0:
            _clear(s_hist, y_hist, r_hist)
            D = -(pb.minv * pb.G)
            phi0p = ops.dot(pb.G, D)
            if not phi0p < 0:
                return "stalled" if math.isfinite(phi0p) else "non_finite"
        kD = pb.k * D
        alpha, m, S, ok = pb.line_search(D, phi0p, ops.dot(kD, pb.X), ops.dot(kD, D), eta,
                                         alpha0=1.0 if s_hist else None)
        if not ok:
            if not s_hist:
                return "stalled"
            _clear(s_hist, y_hist, r_hist)
            continue
        pb.accept(alpha, D, m, S)
        s = alpha * D
        y = pb.G - pb.G_old
        remember_pair(s_hist, y_hist, r_hist, s, y, ops.dot(s, y), memory)
    return status


def _run_fire(pb: _Problem, tol: float, max_iter: int, history: list[float], dt0: float = 0.5,
              dt_max: float = 1.0, n_min: int = 5, f_inc: float = 1.1, f_dec: float = 0.5,
              alpha0: float = 0.1, f_alpha: float = 0.99) -> str:
    """Mass-weighted FIRE on the Fourier modes (Bitzek et al. 2006; Zhou, Moseler & Muser 2019): masses
    ``M(q)`` make the linearised dynamics of every mode oscillate at unit frequency, so ``dt ~ 1``.
    Semi-implicit Euler; one force evaluation per step."""
    ops, xp = pb.ops, pb.xp
    V = xp.zeros_like(pb.X)
    dt, alpha, npos = dt0, alpha0, 0
    while (status := _check(pb, tol, max_iter, history)) is None:
        F = -pb.G
        P = ops.dot(F, V)
        if P > 0:
            npos += 1
            if npos > n_min:
                dt = min(dt * f_inc, dt_max)
                alpha *= f_alpha
        else:
            npos = 0
            dt *= f_dec
            alpha = alpha0
            V[...] = 0
        Fm = F * pb.minv
        ops.axpy(V, dt, Fm)
        if P > 0:
            vnorm = math.sqrt(max(ops.dot(V, pb.mass * V), 0.0))
            fnorm = math.sqrt(max(ops.dot(F, Fm), 0.0))
            if fnorm > 0:
                V *= 1.0 - alpha
                ops.axpy(V, alpha * vnorm / fnorm, Fm)
        d = pb.fft.irfft2(V)
        m = ops.trial(pb.W, d, -dt / pb.rho, pb.Wt)
        S, _, _ = ops.expstats(pb.Wt, m, pb.et)
        if not (math.isfinite(S) and math.isfinite(m)):
            return "non_finite"
        pb.accept(dt, V, m, S)
    return status


_RUNNERS = {"cg": _run_cg, "lbfgs": _run_lbfgs, "fire": _run_fire}
