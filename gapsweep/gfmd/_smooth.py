"""The "variable" minimiser: any smooth law (:class:`SmoothInteraction`) at fixed mean pressure, also
non-convex laws and tensile loads (docs/gfmd.md, "Smooth laws").

Unknown: the body's surface ``z = g0 + u`` as half-spectrum coefficients ``z~`` whose ``q = 0`` entry is the mean
gap ``g0`` (``<u> = 0``); the gap is ``g = z - h``. The energy per area

    F(z) = (E*/4) sum_{q != 0} q |z~(q)|^2 + <phi(z - h)> + sigma0 g0

has the Fourier gradient ``(E* q/2) z~ - p~`` for ``q != 0`` and ``sigma0 - <p>`` for ``g0``: stationary points
balance forces at mean pressure ``sigma0``. Minimised by L-BFGS (Nocedal & Wright, Alg. 7.4) with the initial
inverse Hessian ``M^-1``, ``M(q) = E* q/2 + c`` (``c`` from ``law.curvature``), and a strong-Wolfe line search
that moves in real space (``g + alpha d``, no FFT): one rfft2/irfft2 pair per iteration.

Convergence on the returned fields: ``residual = rms(p_el - (p - <p>)) / P``, ``load_error = |<p> - sigma0| / P``
with ``P = law.pressure_scale(sigma0)``; ``converged`` iff both ``<= tol``. A local minimum is what is found: on
a non-convex law the answer depends on the start, hence :func:`gapsweep.gfmd.solve_path`. At a tensile load
beyond pull-off there is no equilibrium: the body leaves the range of the law, status "detached"."""

from __future__ import annotations

import logging
import math
from typing import Any

import numpy as np

from gapsweep.core import deadline
from gapsweep.gfmd._continuation import next_load, record
from gapsweep.gfmd._grid import Grid
from gapsweep.gfmd._lbfgs import diagonal, remember_pair, two_loop
from gapsweep.gfmd._ops import _is_cupy
from gapsweep.gfmd._result import GFMDResult, fields_to_host, final_status, law_result
from gapsweep.gfmd.interactions.base import SmoothInteraction

METHODS = ("lbfgs",)
log = logging.getLogger("gapsweep.gfmd")
_DETACHED = 30.0  # every gap beyond this many ranges at a tensile load: the body has left (no equilibrium)
# Stall detection (issue 22): evaluations without progress, and the energy change that counts as round-off.
_STALL_WINDOW = 30
_STALL_ENERGY = 1e-12
# Continuation to tensile loads (docs/gfmd.md "Tensile loads"; chosen on the N = 128 surface of
# tests/test_adhesion.py, seed 3, and reported on other seeds and sizes there and in docs/benchmarks_gfmd.md):
_STEP_TOL = 1e-6  # residual of the intermediate loads (they only have to stay in the basin of the branch)
_FIRST_STEP = 1 / 16  # first load step at most, fraction of the law's pressure scale at zero load
_MIN_STEP = 1e-3  # smallest load step, same fraction: the pull-off load is bracketed to this
_STEP_BUDGET = 4  # a step may take this many times the mean evaluations of the accepted steps before it
_STEP_BUDGET_MIN = 200  # and at least this many
_MAX_DEV = 1.0  # a step is on the branch while the corrector moves z less (rms) than the secant predictor did


class _State:
    """Point ``z~`` with its real-space gap, pressure, energy and gradient."""

    def __init__(self, grid: Grid, law: SmoothInteraction, h: Any, k: Any, sigma0: float, Z: Any) -> None:
        self.grid, self.law, self.h, self.k, self.sigma0 = grid, law, h, k, sigma0
        self.xp = grid.xp
        self.Z = Z
        self.g = grid.inv(Z) - h
        self.nfev = 0
        self._evaluate()

    def _evaluate(self) -> None:
        xp = self.xp
        self.p = self.law.pressure(self.g, xp)
        self.e_law = self.grid.mean(self.law.energy(self.g, xp))
        self.G = self.k * self.Z - self.grid.fwd(self.p)
        self.grid.set_mode0(self.G, self.grid.mode0(self.G) + self.sigma0)  # k(0) = 0: sigma0 - <p>
        self.nfev += 1

    def energy(self) -> float:
        return 0.5 * self.grid.dot(self.Z, self.k * self.Z) + self.e_law + self.sigma0 * self.grid.mode0(self.Z).real

    def line(self, D: Any) -> tuple[Any, float, float, float]:
        """Real-space direction ``d`` and the scalars of ``phi(alpha) = F(Z + alpha D)``."""
        d = self.grid.inv(D)
        a = self.grid.dot(D, self.k * self.Z)
        b = self.grid.dot(D, self.k * D)
        return d, a, b, self.grid.mode0(D).real

    def phi(self, alpha: float, d: Any, a: float, b: float, d0: float, e0: float) -> tuple[float, float]:
        """``(phi(alpha) - phi(0) + e_law(0), phi'(alpha))`` without FFT."""
        xp, grid = self.xp, self.grid
        g = self.g + alpha * d
        f = alpha * a + 0.5 * alpha * alpha * b + grid.mean(self.law.energy(g, xp)) + self.sigma0 * alpha * d0
        df = a + alpha * b - grid.mean(self.law.pressure(g, xp) * d) + self.sigma0 * d0
        return f, df

    def move(self, alpha: float, D: Any, d: Any) -> None:
        self.Z = self.Z + alpha * D
        self.g = self.g + alpha * d
        self._evaluate()


def _wolfe(st: _State, D: Any, slope: float, alpha: float, c1: float = 1e-4, c2: float = 0.9,
           max_trials: int = 40) -> tuple[float, Any] | None:
    """Strong-Wolfe step along ``D`` (Nocedal & Wright Alg. 3.5/3.6 with bisection zoom), or None."""
    d, a, b, d0 = st.line(D)
    f0 = st.e_law
    # Energy differences below the round-off of the energy itself cannot decide (near the floor): allow them.
    slack = 1e-14 * (abs(f0) + abs(st.energy()))

    def ev(al: float) -> tuple[float, float]:
        with np.errstate(all="ignore"):
            return st.phi(al, d, a, b, d0, f0)

    lo, f_lo = 0.0, f0
    hi = math.inf
    for _ in range(max_trials):
        f, df = ev(alpha)
        if not (math.isfinite(f) and math.isfinite(df)):
            hi = alpha
        elif f > f0 + c1 * alpha * slope + slack or (f >= f_lo + slack and alpha > lo):
            hi = alpha
        else:
            if abs(df) <= -c2 * slope:
                return alpha, d
            if df > 0:
                hi, lo, f_lo = lo, alpha, f
            else:
                lo, f_lo = alpha, f
        if math.isfinite(hi):
            if abs(hi - lo) <= 1e-14 * max(abs(hi), abs(lo)):
                break
            alpha = 0.5 * (lo + hi)
        else:
            alpha *= 4.0
    return (lo, d) if lo > 0 else None


def _stalled(st: Any, res: float, best: list) -> bool:
    """The stall test of :func:`_lbfgs` (its docstring); ``best = [residual, energy, at]`` updated in place."""
    f = st.energy()
    approach = st.delta if hasattr(st, "delta") else st.grid.mode0(st.Z).real  # free boundaries: the approach
    f_scale = _STALL_ENERGY * (abs(f) + abs(st.e_law) + abs(st.sigma0 * approach))
    if res < 0.9 * best[0] or best[1] - f > f_scale:
        best[:] = [min(res, best[0]), f, st.nfev]
        return False
    if st.nfev - best[2] >= _STALL_WINDOW:
        log.debug("stalled: residual %.3g, energy unchanged for %d evaluations", res, _STALL_WINDOW)
        return True
    return False


def _stop(st: Any, dot: Any, p_ref: float, tol: float, max_iter: int, rng: float | None, history: list[float],
          best: list) -> str | None:
    """The stopping tests of :func:`_lbfgs` at the current point (None: go on); ``dot`` the Parseval product of
    the state's spectra (``grid.dot``, or the lean path's own). Shared by ``gfmd._lean``."""
    grid = st.grid
    g00 = grid.mode0(st.G)
    rr = max(dot(st.G, st.G) - abs(g00) ** 2, 0.0)
    res = max(math.sqrt(rr), abs(g00.real)) / p_ref
    history.append(res)
    if not math.isfinite(res):
        return "non_finite"
    if res <= tol:
        return "converged"
    if st.sigma0 < 0 and rng is not None and grid.amin(st.g) > _DETACHED * rng:
        return "detached"
    if st.nfev >= max_iter:
        return "max_iter"
    return "stalled" if _stalled(st, res, best) else None


class _ListPairs:
    """The L-BFGS memory of :func:`_lbfgs` as lists of arrays (``gfmd._lbfgs``): the direction by the two-loop
    recursion over them, each step recorded as a new pair (a new array each: the one-process state)."""

    def __init__(self, grid: Grid, minv: Any, memory: int) -> None:
        self.dot, self.minv, self.memory = grid.dot, minv, memory
        self.steps = diagonal(grid.dot, minv)
        self.s: list = []
        self.y: list = []
        self.r: list[float] = []

    def __bool__(self) -> bool:
        return bool(self.s)

    def clear(self) -> None:
        self.s.clear(), self.y.clear(), self.r.clear()

    def direction(self, st: Any) -> Any:
        """``D = -H G`` (two-loop recursion, ``H0 = gamma M^-1``)."""
        return -two_loop(st.G.copy(), list(zip(self.s, self.y, self.r)), **self.steps)

    def steepest(self, st: Any) -> Any:
        return -(self.minv * st.G)

    def step(self, st: Any, alpha: float, D: Any, d: Any) -> None:
        """Move ``st`` by ``alpha D`` (``d`` its real-space form) and keep the pair ``(alpha D, G_new - G_old)``."""
        G_old = st.G
        st.move(alpha, D, d)
        s = alpha * D
        y = st.G - G_old
        remember_pair(self.s, self.y, self.r, s, y, self.dot(s, y), self.memory)


def _lbfgs(st: Any, pairs: Any, p_ref: float, tol: float, max_iter: int, rng: float | None,
           history: list[float]) -> str:
    """L-BFGS from ``st`` until ``residual <= tol`` (module docstring), at most ``max_iter`` evaluations of
    ``st``. Returns the status; ``st`` holds the last point. ``pairs``: the memory and its two-loop recursion
    (:class:`_ListPairs`; the lean form's ring of preallocated pairs, ``gfmd._lean._Pairs``).

    "stalled" when the residual stops moving: for ``_STALL_WINDOW`` evaluations the residual has not fallen
    below 0.9 times its best value and the energy has not fallen by more than its round-off
    (``_STALL_ENERGY`` relative), i.e. the steps no longer change anything (the line search returns steps at
    round-off, issue 22), instead of spending the rest of ``max_iter`` there."""
    best = [math.inf, math.inf, 0]
    with np.errstate(all="ignore"):
        while True:
            deadline.check()  # a task time limit ends the solve between iterations
            status = _stop(st, pairs.dot, p_ref, tol, max_iter, rng, history, best)
            if status is not None:
                return status
            D = pairs.direction(st)
            slope = pairs.dot(st.G, D)
            if not slope < 0:
                pairs.clear()
                D = pairs.steepest(st)
                slope = pairs.dot(st.G, D)
                if not slope < 0:
                    return "stalled" if math.isfinite(slope) else "non_finite"
            step = _wolfe(st, D, slope, 1.0)
            if step is None:
                if not pairs:
                    return "stalled"
                pairs.clear()
                continue
            alpha, d = step
            pairs.step(st, alpha, D, d)


class _Solver:
    """One grid, surface and law; solves at any load from any start, and follows loads by continuation."""

    def __init__(self, grid: Grid, law: SmoothInteraction, h: Any, e_star: float, max_iter: int,
                 memory: int) -> None:
        self.grid, self.law, self.h, self.max_iter, self.memory = grid, law, h, max_iter, memory
        self.k = (0.5 * e_star) * grid.q
        self.rng = law.range()
        self.nfev = 0  # evaluations spent by every stage together (the result's ``iterations``)
        self.history: list[float] = []
        self.info: dict[str, float] = {}

    def at(self, sigma0: float, Z: Any, tol: float, budget: int | None = None) -> tuple[_State, str]:
        """Minimise at load ``sigma0`` from the surface coefficients ``Z`` (not modified) to ``tol``, with at
        most ``budget`` evaluations (default: what is left of ``max_iter``)."""
        xp = self.grid.xp
        c = self.law.curvature(sigma0)
        k = self.k
        minv = 1.0 / (k + c) if c > 0 else xp.where(k > 0, 1.0 / xp.where(k > 0, k, 1.0), 1.0)
        st = _State(self.grid, self.law, self.h, k, sigma0, Z.copy())
        left = max(self.max_iter - self.nfev, 1)
        status = _lbfgs(st, _ListPairs(self.grid, minv, self.memory), self.law.pressure_scale(sigma0), tol,
                        left if budget is None else min(budget, left), self.rng, self.history)
        self.nfev += st.nfev
        return st, status

    def _lin(self, a: Any, b: Any, t: float) -> Any:
        """The secant predictor ``a + t (a - b)`` of two states' unknowns (a new array)."""
        return a + (a - b) * t

    def _dist(self, a: Any, b: Any) -> float:
        """rms distance of two states' unknowns (Parseval)."""
        return math.sqrt(max(self.grid.dot(a - b, a - b), 0.0))

    def follow(self, s_from: float, Z_from: Any, target: float, tol: float,
               retry: bool = False) -> tuple[_State | None, str]:
        """Quasi-static unloading from the equilibrium ``Z_from`` at ``s_from`` to the tensile ``target``.

        Each step starts from the secant predictor ``Z_k + (Z_k - Z_{k-1}) ds_k / ds_{k-1}`` and is accepted
        when it converges (to ``_STEP_TOL``; the target itself to ``tol``) in contact and the corrector moved
        ``z`` by at most ``_MAX_DEV`` times what the predictor did (rms): the equilibrium is on the branch it
        started on. A rejected step is halved; steps double again while the predictor is good. At the
        smallest step (``_MIN_STEP`` of the load scale) a converged step that jumps is accepted (a snap that
        the quasi-static path takes too: logged, counted in ``info["jumps"]``) and a step that detaches ends
        the branch: its last load is ``info["last_attached_load"]`` (the pull-off load to within that step),
        and the target is then tried once from there. Returns the last state and its status.

        First step: at most ``_FIRST_STEP`` of the law's scale (a small target in one step) when nothing was
        tried yet; ``_FIRST_STEP`` of the load scale ``min(|target - s_from|, law scale)`` when ``retry`` (a
        solve straight from ``Z_from`` at ``target`` has just failed: a whole-span first step would repeat it,
        and near pull-off land in the same stall)."""
        law = self.law
        span = target - s_from
        scale = min(abs(span), law.pressure_scale(0.0))
        first = scale if retry else min(abs(span), law.pressure_scale(0.0) * _FIRST_STEP)
        ds, ds_min = -(first * _FIRST_STEP if retry else first), scale * _MIN_STEP
        s_k, Z_k, Z_prev, ds_prev = s_from, Z_from, None, 0.0
        accepted = jumps = attempts = 0
        st: _State | None = None
        status = "max_iter"
        while s_k > target and self.nfev < self.max_iter:
            attempts += 1
            s_new, step, final = next_load(s_k, ds, target, scale)
            Zp = Z_k if Z_prev is None else self._lin(Z_k, Z_prev, step / ds_prev)
            # A step on the branch converges in about as many evaluations as the steps before it; one that
            # takes many more is leaving it (a body peeling off slowly), and is cut short and halved.
            budget = max(_STEP_BUDGET_MIN, _STEP_BUDGET * self.nfev // (accepted + 1))
            st, status = self.at(s_new, Zp, tol if final else max(tol, _STEP_TOL), budget)
            ok = status == "converged"
            dev = 0.0
            if ok and Z_prev is not None:
                dev = self._dist(st.Z, Zp) / max(self._dist(Zp, Z_k), 1e-300)
            smallest = abs(step) <= ds_min * (1 + 1e-9)
            if ok and (dev <= _MAX_DEV or smallest):
                if dev > _MAX_DEV:
                    jumps += 1
                    log.info("continuation: jump at sigma0=%g (corrector/predictor %.3g at the smallest step)",
                             s_new, dev)
                Z_prev, ds_prev, Z_k, s_k = Z_k, step, st.Z, s_new
                accepted += 1
                ds = 2 * step if dev <= 0.25 * _MAX_DEV else step
                if final:
                    break
                continue
            if status == "non_finite" or self.nfev >= self.max_iter:
                break
            if smallest:
                # The branch ends between s_k and s_new (pull-off): no equilibrium connected to the contact
                # beyond s_k. The target is tried once from s_k (fields at the target load; a converged try is
                # an equilibrium after a jump and is reported as such); a try that does not converge within a step's
                # budget (a body peeling off slowly) is "detached", as the continuation showed.
                st, status = self.at(target, Z_k, tol, budget)
                if status == "converged":
                    jumps += 1
                    s_k = target
                elif status != "non_finite":
                    status = "detached"
                break
            ds = 0.5 * step
        else:
            if s_k > target:
                status = "max_iter"
        record(self.info, s_from=s_from, accepted=accepted, ds_min=ds_min, attempts=attempts, jumps=jumps,
               status=status, target=target, s_k=s_k)
        return st, status


def initial_pair(initial: Any) -> tuple[Any, float]:
    """``(displacement, mean gap)`` of a smooth law's ``initial``: a GFMDResult, such a pair, or a displacement
    field alone (what a pressure chain of the exponential law keeps, docs/gfmd.md "Warm starts"), whose mean gap
    is then NaN: :func:`touching_gap` places the body."""
    if isinstance(initial, GFMDResult):
        return initial.displacement, float(initial.mean_gap)
    if isinstance(initial, (tuple, list)) and len(initial) == 2 and np.ndim(initial[1]) == 0:
        return initial[0], float(initial[1])
    return initial, math.nan


def touching_gap(grid: Any, h: Any, uc: Any) -> float:
    """The mean gap ``g0`` at which the body with the zero-mean displacement ``uc`` touches the surface ``h``
    (zero mean) at one point: ``g = g0 + uc - h >= 0`` with equality at the highest point of ``h - uc`` (the
    start without ``initial`` is the case ``uc = 0``). Length units of ``h``."""
    return float(grid.amax(h - uc))


def minimise(heights: Any, law: SmoothInteraction, *, sigma0: float, e_star: float, length: Any, tol: float,
             method: str, backend: str, max_iter: int, initial: Any, threads: int | None, host: Any,
             t_start: float, memory: int = 8, grid: Grid | None = None) -> GFMDResult:
    """Smooth ``law`` on the periodic grid ``heights`` (inputs validated by ``gfmd.solve``).

    Starts (docs/gfmd.md, "Tensile loads"): ``initial`` when given; if that run detaches or stalls at a tensile
    load and ``initial`` is a converged result at a higher load, the load is followed down from it
    (:meth:`_Solver.follow`). Without ``initial``: the flat body touching the highest summit, solved directly
    at ``sigma0 >= 0``; at ``sigma0 < 0`` solved at zero load from there and unloaded to ``sigma0``."""
    if grid is None:
        grid = Grid(heights.shape, length, backend, threads, _is_cupy(heights))
    xp = grid.xp
    h = grid.asarray(heights)
    if not grid.all_finite(h):
        raise ValueError("heights contain NaN or inf")
    h = h - grid.mean(h)  # the gap does not depend on <h> (the body follows the surface)
    sv = _Solver(grid, law, h, e_star, max_iter, memory)
    step_tol = max(tol, _STEP_TOL)
    if initial is None:
        Z = grid.spectrum_zeros()
        grid.set_mode0(Z, grid.amax(h))  # touching the highest summit, the body flat
        if sigma0 < 0:
            st, status = sv.at(0.0, Z, step_tol)
            if status == "converged":
                st, status = sv.follow(0.0, st.Z, sigma0, tol)
                assert st is not None
        else:
            st, status = sv.at(sigma0, Z, tol)
    else:
        u0, g0 = initial_pair(initial)
        u0 = xp.asarray(u0, dtype=xp.float64)
        shape_ok = tuple(u0.shape) == tuple(grid.real_shape)
        if not grid.agree(shape_ok and bool(xp.all(xp.isfinite(u0))) and not math.isinf(g0)):
            raise ValueError(f"initial must be a GFMDResult, (displacement of shape {grid.real_shape}, mean gap) "
                             "or a finite displacement field of that shape")
        uc = u0 - grid.mean(u0)
        Z0 = grid.fwd(uc)
        grid.set_mode0(Z0, float(g0) if math.isfinite(g0) else touching_gap(grid, h, uc))
        st, status = sv.at(sigma0, Z0, tol)
        s_init = float(getattr(initial, "sigma0", math.nan))
        if (status in ("detached", "stalled") and isinstance(initial, GFMDResult) and initial.converged
                and sigma0 < 0 and s_init > sigma0 and sv.nfev < max_iter):
            log.info("%s: %s at sigma0=%g from the initial state; following the load from %g", law.name, status,
                     sigma0, s_init)
            st2, status = sv.follow(s_init, Z0, sigma0, tol, retry=True)
            st = st2 if st2 is not None else st
    return _result(sv, st, status, sigma0, e_star, length, tol, host, t_start)


def _result(sv: _Solver, st: _State, status: str, sigma0: float, e_star: float, length: Any, tol: float,
            host: Any, t_start: float) -> GFMDResult:
    """The result of the state ``st`` at load ``sigma0``: fields and convergence from the Fourier state (the
    returned fields' residual decides, issue 9)."""
    grid, law, h, k = sv.grid, sv.law, sv.h, sv.k
    xp = grid.xp
    p_ref = law.pressure_scale(sigma0)
    with np.errstate(all="ignore"):
        # u from the q != 0 coefficients alone: forming z = g0 + u first and subtracting g0 leaves the round-off
        # of g0 (~1e-16 g0) in u, which k u amplifies to a residual of ~1e-16 g0 q_max E*/sigma0 (6.7e-6 at
        # sigma0 = 1e-9: "stalled" on converged states, issue 36)
        z0 = grid.mode0(st.Z).real
        Zc = st.Z.copy()
        grid.set_mode0(Zc, 0.0)
        u = grid.inv(Zc)
        gap = (u + z0) - h
        p = law.pressure(gap, xp)
        U = grid.fwd(u)
        F = k * U - grid.fwd(p)
        grid.set_mode0(F, 0.0)
        residual = math.sqrt(max(grid.dot(F, F), 0.0)) / p_ref
        load_error = abs(grid.mean(p) - sigma0) / p_ref
        elastic = grid.elastic_energy(U, e_star)
        area = grid.count(law.contact(gap, p)) / grid.size
        g0 = grid.mean(gap)
        e_int = grid.mean(law.energy(gap, xp))
    fields_ok = math.isfinite(residual) and grid.all_finite(gap) and grid.all_finite(p)
    status, _ = final_status(status, fields_ok, residual, load_error, tol)
    converged = status == "converged"
    log.debug("%s: %s after %d evaluations, residual %.3g", law.name, status, sv.nfev, residual)
    gap, p, u = fields_to_host(grid, host, gap, p, u)  # only those asked for
    grid.synchronize()
    diagnostics = {"pressure_scale": p_ref, "interaction_energy": e_int, **sv.info}
    return law_result(law, t_start, mean_gap=g0, gap=gap, pressure=p, displacement=u, iterations=sv.nfev,
                      converged=converged, residual=residual, load_error=load_error, method="lbfgs",
                      backend=grid.backend, status=status, sigma0=sigma0, rho=getattr(law, "rho", math.nan),
                      e_star=e_star, length=length, tol=tol, history=sv.history, contact_area=area,
                      elastic_energy=elastic, diagnostics=diagnostics)
