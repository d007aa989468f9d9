"""The "bounded" minimiser: a hard wall with an adhesive energy (``HardWallAdhesive``) at fixed mean pressure,
compressive or tensile (docs/gfmd.md, "Hard wall with adhesion"; docs/model.md "Hard wall with exponential
adhesion").

Unknown: the gap ``g`` itself (real space, its mean included), bound ``g >= 0``; the displacement is
``u = g - <g> + h`` (``<h> = 0``), so ``u~ = g~ + h~`` for ``q != 0``. The energy per area

    F(g) = (E*/4) sum_{q != 0} q |u~(q)|^2 + <V(g)> + sigma0 <g>

has the gradient (per pixel, ``dF = <G dg>``) ``G = p_el + V'(g) + sigma0`` with ``p_el = IFFT[(E* q/2) u~]``.
Its KKT conditions are the equilibrium: ``G = 0`` where ``g > 0`` (``p_el = p - sigma0`` with ``p = -V'``),
``G = lambda >= 0`` where ``g = 0`` (the contact pressure), and ``<p> = sigma0`` follows from ``<p_el> = 0``. No
equality constraint: the load enters through the linear term, so tensile loads need no special treatment and a
body that loses every contact at a tensile load runs away (status "detached").

Algorithm: projected L-BFGS in the spirit of L-BFGS-B (Byrd, Lu, Nocedal & Zhu, SIAM J. Sci. Comput. 16, 1190,
1995), simplified to a diagonal bound: the free set ``F = {g > 0} | {G < 0}``; the search direction is the
L-BFGS two-loop recursion on the projected gradient ``P_F G`` with the initial inverse Hessian
``P_F C P_F``, ``C = (E* q/2)^-1`` the half-space compliance (exact for a free surface; ``q = 0`` takes the
lowest mode's value), restricted to ``F``; an Armijo backtracking search along the projected path
``max(g + alpha d, 0)``; pairs ``(s, y)`` restricted to the pixels free at both ends and kept only when
``s.y > 0`` (``V`` is concave: negative-curvature pairs are dropped). Written once for any array namespace
(numpy; cupy through ``Grid``): each iteration is two FFT pairs (the preconditioner and the gradient) plus one
forward transform per line-search trial.

Convergence on the returned fields: ``residual = rms(P G) / P_ref`` with the projected gradient ``P G`` (``G``
where ``g > 0``, ``min(G, 0)`` where ``g = 0``) and ``P_ref = max(|sigma0|, w/rho)``; ``load_error = |<p> -
sigma0| / P_ref`` (bounded by the residual); ``converged`` iff both ``<= tol``. Statuses: "converged", "stalled"
(no progress for ``_STALL_WINDOW`` iterations, or no descent left above round-off), "detached" (tensile load
and every gap beyond ``_DETACHED`` ranges: beyond pull-off), "max_iter", "non_finite".

Tensile loads (docs/gfmd.md "Tensile loads"): without ``initial`` the body first finds its zero-load equilibrium
from the flat body touching the highest summit, then the load is lowered in steps (each warm-started from the
last, halved when a step does not converge, the pull-off bracketed to ``_MIN_STEP`` of ``w/rho``), as the smooth
laws' continuation does (gfmd._smooth)."""

from __future__ import annotations

import logging
import math
import time
from typing import Any

import numpy as np

from gapsweep.core import deadline
from gapsweep.gfmd._continuation import next_load, record
from gapsweep.gfmd._grid import Grid
from gapsweep.gfmd._ops import _is_cupy
from gapsweep.gfmd._result import GFMDResult, fields_to_host, final_status

METHODS = ("plbfgs",)
log = logging.getLogger("gapsweep.gfmd")
_MEMORY = 10  # L-BFGS pairs
_DETACHED = 30.0  # every gap beyond this many ranges at a tensile load: the body has left
_STALL_WINDOW = 60  # iterations without the residual falling below 0.9 x its best and without energy decrease
_STALL_ENERGY = 1e-13  # relative energy change that counts as round-off
_ARMIJO = 1e-4
_MAX_BACKTRACK = 50
# Continuation to tensile loads (fractions of the law's pressure scale w/rho):
_STEP_TOL = 1e-7  # residual of the intermediate loads
_FIRST_STEP = 1 / 64
_MIN_STEP = 1e-4


def solve_memory(shape: tuple[int, int]) -> int:
    """Bytes a solve of an ``nx x ny`` grid holds at its peak, counted from the code (not measured): the
    ``2 _MEMORY`` L-BFGS vectors plus about 16 grid arrays (state, gradient, spectra, the direction, the trial
    point and its spectrum, FFT temporaries), float64. ``65536^2``: about 1.3 TB (one process)."""
    nx, ny = (int(v) for v in shape)
    return (2 * _MEMORY + 16) * nx * ny * 8


class _State:
    """A gap field ``g >= 0`` with its spectrum, energy and gradient (module docstring)."""

    def __init__(self, grid: Grid, law: Any, H: Any, k: Any, sigma0: float, g: Any) -> None:
        self.grid, self.law, self.H, self.k, self.sigma0 = grid, law, H, k, sigma0
        self.xp = grid.xp
        self.nfev = 0
        self.set(g)

    def spectrum(self, g: Any) -> Any:
        U = self.grid.fwd(g) + self.H
        self.grid.set_mode0(U, 0.0)
        return U

    def energy_of(self, g: Any, U: Any) -> float:
        grid = self.grid
        return 0.5 * grid.dot(U, self.k * U) + grid.mean(self.law.energy(g, self.xp)) + self.sigma0 * grid.mean(g)

    def change(self, dg: Any) -> tuple[Any, float]:
        """``(U~ of g + dg, F(g + dg) - F(g))``, the energy change summed from the changes of each term (``dU``,
        ``expm1``), so that it keeps its relative precision when it is far below the energy itself (near
        convergence the energy's round-off would otherwise decide the line search)."""
        grid, xp, law = self.grid, self.xp, self.law
        dU = grid.fwd(dg)
        grid.set_mode0(dU, 0.0)
        d_el = grid.dot(dU, self.k * (self.U + 0.5 * dU))
        d_v = grid.mean(law.energy(self.g, xp) * xp.expm1(-dg / law.rho))
        return self.U + dU, d_el + d_v + self.sigma0 * grid.mean(dg)

    def set(self, g: Any, U: Any = None, f: float | None = None) -> None:
        self.g = g
        self.U = self.spectrum(g) if U is None else U
        self.f = self.energy_of(g, self.U) if f is None else f
        self.p_el = self.grid.inv(self.k * self.U)
        self.G = self.p_el + self.law.force(g, self.xp) + self.sigma0
        self.nfev += 1

    def projected(self) -> Any:
        """``P G``: ``G`` where ``g > 0``, ``min(G, 0)`` where ``g = 0``."""
        xp = self.xp
        return xp.where(self.g > 0, self.G, xp.minimum(self.G, 0.0))

    def free(self, eps: float = 0.0) -> Any:
        """Pixels the quasi-Newton step moves: all but the eps-active set ``{g <= eps, G > 0}``."""
        return (self.g > eps) | (self.G <= 0)


def _residual(st: _State, p_ref: float) -> float:
    pg = st.projected()
    return math.sqrt(max(st.grid.mean(pg * pg), 0.0)) / p_ref


def _plbfgs(st: _State, minv: Any, p_ref: float, tol: float, max_iter: int, history: list[float]) -> str:
    """Projected L-BFGS from ``st`` (module docstring) until ``residual <= tol``; ``st`` holds the last point.
    ``max_iter`` counts iterations (each one gradient evaluation)."""
    grid, xp, law = st.grid, st.xp, st.law
    s_hist: list = []
    y_hist: list = []
    r_hist: list[float] = []
    best = [math.inf, math.inf, 0]
    it = 0
    rng = law.range()
    with np.errstate(all="ignore"):
        while True:
            deadline.check()
            res = _residual(st, p_ref)
            history.append(res)
            if not math.isfinite(res) or not math.isfinite(st.f):
                return "non_finite"
            if res <= tol:
                return "converged"
            if st.sigma0 < 0 and grid.amin(st.g) > _DETACHED * rng:
                return "detached"
            if it >= max_iter:
                return "max_iter"
            f_scale = _STALL_ENERGY * (abs(st.f) + abs(st.sigma0 * grid.mean(st.g)) + law.work)
            if res < 0.9 * best[0] or best[1] - st.f > f_scale:
                best[:] = [min(res, best[0]), min(st.f, best[1]), it]
            elif it - best[2] >= _STALL_WINDOW:
                return "stalled"
            it += 1
            # eps-active set (Bertsekas, SIAM J. Control Optim. 20, 221, 1982): pixels within eps of the bound
            # and pushed onto it go to it straight (d = -g there); without it a pixel a round-off above the
            # bound, which the preconditioned direction moves upward, stalls the iteration. eps: the gap that
            # one projected-gradient step with the pixel compliance dx/E* would close, at most rho/100.
            pg_step = st.g - xp.maximum(st.g - st.pixel_compliance * st.G, 0.0)
            eps = min(0.01 * rng, math.sqrt(max(grid.mean(pg_step * pg_step), 0.0)))
            free = st.free(eps)
            q = xp.where(free, st.G, 0.0)
            alphas = []
            for s, y, r in zip(reversed(s_hist), reversed(y_hist), reversed(r_hist)):
                al = r * grid.mean(s * q)
                alphas.append(al)
                q = q - al * y
            q = xp.where(free, grid.inv(minv * grid.fwd(xp.where(free, q, 0.0))), 0.0)
            if y_hist:
                y = y_hist[-1]
                yhy = grid.mean(y * xp.where(free, grid.inv(minv * grid.fwd(xp.where(free, y, 0.0))), 0.0))
                if yhy > 0:
                    q = q * (1.0 / (r_hist[-1] * yhy))
            for s, y, r, al in zip(s_hist, y_hist, r_hist, reversed(alphas)):
                q = q + (al - r * grid.mean(y * q)) * s
            d = -xp.where(free, q, st.g)
            slope = grid.mean(st.G * d)
            if not slope < 0:
                s_hist.clear(), y_hist.clear(), r_hist.clear()
                d = -xp.where(free, grid.inv(minv * grid.fwd(xp.where(free, st.G, 0.0))), st.g)
                slope = grid.mean(st.G * d)
                if not slope < 0:
                    return "stalled" if math.isfinite(slope) else "non_finite"
            alpha = 1.0
            if not s_hist:  # no curvature yet: a first step that moves no pixel by more than the surface's rms
                dmax = grid.amax(xp.abs(d))
                if dmax > 0:
                    alpha = min(1.0, st.scale / dmax)
            accepted = False
            for _ in range(_MAX_BACKTRACK):
                g_t = xp.maximum(st.g + alpha * d, 0.0)
                dg = g_t - st.g
                U_t, df = st.change(dg)
                st.nfev += 1
                dec = grid.mean(st.G * dg)
                if math.isfinite(df) and df <= _ARMIJO * dec:
                    f_t = st.f + df
                    accepted = True
                    break
                alpha *= 0.5
            if not accepted:
                if not s_hist:
                    return "stalled"
                s_hist.clear(), y_hist.clear(), r_hist.clear()
                continue
            g_old, G_old, free_old = st.g, st.G, free
            st.set(g_t, U_t, f_t)
            both = free_old & st.free()
            s = xp.where(both, st.g - g_old, 0.0)
            y = xp.where(both, st.G - G_old, 0.0)
            sy = grid.mean(s * y)
            if sy > 1e-12 * math.sqrt(max(grid.mean(s * s) * grid.mean(y * y), 0.0)):
                s_hist.append(s), y_hist.append(y), r_hist.append(1.0 / sy)
                if len(s_hist) > _MEMORY:
                    s_hist.pop(0), y_hist.pop(0), r_hist.pop(0)


class _Solver:
    """One grid, surface and law: solves at any load from any start and follows loads by continuation."""

    def __init__(self, grid: Grid, law: Any, h: Any, e_star: float, max_iter: int) -> None:
        self.grid, self.law, self.h, self.max_iter = grid, law, h, max_iter
        xp = grid.xp
        self.k = (0.5 * e_star) * grid.q
        self.H = grid.fwd(h)
        grid.set_mode0(self.H, 0.0)
        kpos = self.k[self.k > 0]
        kmin = float(kpos.min()) if kpos.size else 0.5 * e_star
        self.minv = 1.0 / xp.where(self.k > 0, self.k, kmin)
        self.scale = math.sqrt(max(grid.mean(h * h), 0.0)) or law.range()
        self.pixel_compliance = min(grid.lx / grid.shape[0], grid.ly / grid.shape[1]) / e_star
        self.nit = 0
        self.history: list[float] = []
        self.info: dict[str, float] = {}

    def at(self, sigma0: float, g: Any, tol: float, budget: int | None = None) -> tuple[_State, str]:
        st = _State(self.grid, self.law, self.H, self.k, sigma0, self.grid.xp.maximum(g, 0.0))
        st.scale = max(self.scale, self.law.range())
        st.pixel_compliance = self.pixel_compliance
        left = max(self.max_iter - self.nit, 1)
        n0 = len(self.history)
        status = _plbfgs(st, self.minv, self.law.pressure_scale(sigma0), tol,
                         left if budget is None else min(budget, left), self.history)
        self.nit += max(len(self.history) - n0 - 1, 0)
        return st, status

    def follow(self, s_from: float, g_from: Any, target: float, tol: float) -> tuple[_State | None, str]:
        """Quasi-static unloading from the equilibrium ``g_from`` at ``s_from`` to ``target < s_from``: each
        step warm-started from the last accepted one (secant predictor, projected), halved when it does not
        converge to ``_STEP_TOL``; the steps double while two in a row converge. At the smallest step
        (``_MIN_STEP`` of ``w/rho``) the target is tried once from the last attached state: converged, the
        equilibrium after a jump (counted in ``info["jumps"]``); else "detached" (the branch ends: pull-off
        lies between ``info["last_attached_load"]`` and one smallest step below)."""
        xp = self.grid.xp
        pscale = self.law.max_tension
        ds = -min(s_from - target, pscale * _FIRST_STEP)
        ds_min = pscale * _MIN_STEP
        s_k, g_k, g_prev, ds_prev = s_from, g_from, None, 0.0
        accepted = attempts = jumps = 0
        st: _State | None = None
        status = "max_iter"
        while s_k > target and self.nit < self.max_iter:
            attempts += 1
            s_new, step, final = next_load(s_k, ds, target, pscale)
            g_p = g_k if g_prev is None else xp.maximum(g_k + (g_k - g_prev) * (step / ds_prev), 0.0)
            st, status = self.at(s_new, g_p, tol if final else max(tol, _STEP_TOL))
            if status == "converged":
                g_prev, ds_prev, g_k, s_k = g_k, step, st.g, s_new
                accepted += 1
                ds = 2 * step
                if final:
                    break
                continue
            if status == "non_finite" or self.nit >= self.max_iter:
                break
            if abs(step) <= ds_min * (1 + 1e-9):
                st, status = self.at(target, g_k, tol)
                if status == "converged":
                    jumps += 1
                elif status != "non_finite":
                    status = "detached"
                break
            ds = 0.5 * step
        record(self.info, s_from=s_from, accepted=accepted, ds_min=ds_min, attempts=attempts, jumps=jumps,
               status=status, target=target, s_k=s_k)
        return st, status


def minimise(heights: Any, law: Any, *, sigma0: float, e_star: float, length: Any, tol: float, method: str,
             backend: str, max_iter: int, initial: Any, threads: int | None, host: Any, t_start: float,
             periodic: bool = True, grid: Grid | None = None) -> GFMDResult:
    """``law`` (a hard wall with an adhesive energy) on the periodic grid ``heights`` (inputs validated by
    ``gfmd.solve``). ``initial``: a GFMDResult (its gap) or a gap field; default the flat body touching the
    highest summit, solved at ``sigma0 >= 0`` directly and, at a tensile load, at zero load and then unloaded
    (:meth:`_Solver.follow`). A tensile solve from ``initial`` that detaches or stalls follows the load down
    from ``initial`` when that is a converged result at a higher load. ``max_iter`` counts iterations."""
    if not periodic:
        raise ValueError(f"interaction {law.name!r} runs on periodic surfaces only (periodic=True); free "
                         "boundaries are not implemented for it yet (docs/gfmd.md, 'Hard wall with adhesion')")
    if grid is None:
        grid = Grid(heights.shape, length, backend, threads, _is_cupy(heights))
    xp = grid.xp
    h = grid.asarray(heights)
    if not grid.all_finite(h):
        raise ValueError("heights contain NaN or inf")
    h = h - grid.mean(h)
    sv = _Solver(grid, law, h, e_star, max_iter)
    step_tol = max(tol, _STEP_TOL)
    if initial is None:
        g0 = grid.amax(h) - h  # flat body touching the highest summit
        if sigma0 < 0:
            st, status = sv.at(0.0, g0, step_tol)
            if status == "converged":
                st2, status = sv.follow(0.0, st.g, sigma0, tol)
                st = st2 if st2 is not None else st
        else:
            st, status = sv.at(sigma0, g0, tol)
    else:
        g_init = initial.gap if isinstance(initial, GFMDResult) else initial
        g_init = xp.asarray(g_init, dtype=xp.float64)
        if tuple(g_init.shape) != tuple(grid.real_shape) or not grid.all_finite(g_init):
            raise ValueError(f"initial must be a GFMDResult or a finite gap field of shape {grid.real_shape}")
        st, status = sv.at(sigma0, g_init, tol)
        s_init = float(getattr(initial, "sigma0", math.nan))
        if (status in ("detached", "stalled") and isinstance(initial, GFMDResult) and initial.converged
                and sigma0 < 0 and s_init > sigma0 and sv.nit < max_iter):
            log.info("%s: %s at sigma0=%g from the initial state; following the load from %g", law.name, status,
                     sigma0, s_init)
            st2, status = sv.follow(s_init, xp.maximum(g_init, 0.0), sigma0, tol)
            st = st2 if st2 is not None else st
    return _result(sv, st, status, sigma0, e_star, length, tol, host, t_start)


def _result(sv: _Solver, st: _State, status: str, sigma0: float, e_star: float, length: Any, tol: float,
            host: Any, t_start: float) -> GFMDResult:
    """The result of ``st``: fields and convergence recomputed from the returned gap (issue 9)."""
    grid, law = sv.grid, sv.law
    xp = grid.xp
    p_ref = law.pressure_scale(sigma0)
    with np.errstate(all="ignore"):
        g = xp.maximum(st.g, 0.0)
        fin = _State(grid, law, sv.H, sv.k, sigma0, g)
        residual = _residual(fin, p_ref)
        contact = g <= 0
        # pressure on the body: the multiplier G where g = 0 (clipped at 0: its negative part is in the
        # residual), the adhesive tension -V'(g) everywhere
        p = xp.where(contact, xp.maximum(fin.G, 0.0), 0.0) - law.force(g, xp)
        load_error = abs(grid.mean(p) - sigma0) / p_ref
        u = grid.inv(fin.U)
        elastic = grid.elastic_energy(fin.U, e_star)
        e_int = grid.mean(law.energy(g, xp))
        area = grid.count(contact) / grid.size
        g0 = grid.mean(g)
    fields_ok = math.isfinite(residual) and grid.all_finite(g) and grid.all_finite(p)
    status, _ = final_status(status, fields_ok, residual, load_error, tol)
    converged = status == "converged"
    dx = min(grid.lx / grid.shape[0], grid.ly / grid.shape[1])
    log.debug("%s: %s after %d iterations, residual %.3g", law.name, status, sv.nit, residual)
    gap, p, u = fields_to_host(grid, host, g, p, u)
    grid.synchronize()
    return GFMDResult(
        mean_gap=g0, gap=gap, pressure=p, displacement=u, iterations=sv.nit, converged=converged,
        residual=residual, load_error=load_error, wall_time=time.perf_counter() - t_start, method="plbfgs",
        backend=grid.backend, status=status, sigma0=sigma0, rho=law.rho, e_star=e_star, length=length, tol=tol,
        history=sv.history, interaction=law.name, params=law.params(), contact_area=area, elastic_energy=elastic,
        contact_criterion=law.contact_criterion,
        diagnostics={"pressure_scale": p_ref, "interaction_energy": e_int, "evaluations": st.nfev,
                     "mu_rho": law.mu_rho(dx, e_star), **sv.info},
    )
