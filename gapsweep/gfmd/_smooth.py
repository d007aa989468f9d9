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
import time
from typing import Any

import numpy as np

from gapsweep.core import deadline
from gapsweep.gfmd._grid import Grid
from gapsweep.gfmd._ops import _is_cupy
from gapsweep.gfmd._result import GFMDResult, host_fields
from gapsweep.gfmd.interactions.base import SmoothInteraction

METHODS = ("lbfgs",)
log = logging.getLogger("gapsweep.gfmd")
_DETACHED = 30.0  # every gap beyond this many ranges at a tensile load: the body has left (no equilibrium)


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
        self.e_law = float(xp.mean(self.law.energy(self.g, xp)))
        self.G = self.k * self.Z - self.grid.fwd(self.p)
        self.G[0, 0] += self.sigma0  # k(0) = 0: sigma0 - <p>
        self.nfev += 1

    def energy(self) -> float:
        return 0.5 * self.grid.dot(self.Z, self.k * self.Z) + self.e_law + self.sigma0 * float(self.Z[0, 0].real)

    def line(self, D: Any) -> tuple[Any, float, float, float]:
        """Real-space direction ``d`` and the scalars of ``phi(alpha) = F(Z + alpha D)``."""
        d = self.grid.inv(D)
        a = self.grid.dot(D, self.k * self.Z)
        b = self.grid.dot(D, self.k * D)
        return d, a, b, float(D[0, 0].real)

    def phi(self, alpha: float, d: Any, a: float, b: float, d0: float, e0: float) -> tuple[float, float]:
        """``(phi(alpha) - phi(0) + e_law(0), phi'(alpha))`` without FFT."""
        xp = self.xp
        g = self.g + alpha * d
        f = alpha * a + 0.5 * alpha * alpha * b + float(xp.mean(self.law.energy(g, xp))) + self.sigma0 * alpha * d0
        df = a + alpha * b - float(xp.mean(self.law.pressure(g, xp) * d)) + self.sigma0 * d0
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


def minimise(heights: Any, law: SmoothInteraction, *, sigma0: float, e_star: float, length: Any, tol: float,
             method: str, backend: str, max_iter: int, initial: Any, threads: int | None, host: Any,
             t_start: float, memory: int = 8) -> GFMDResult:
    """Smooth ``law`` on the periodic grid ``heights`` (inputs validated by ``gfmd.solve``)."""
    grid = Grid(heights.shape, length, backend, threads, _is_cupy(heights))
    xp = grid.xp
    h = grid.asarray(heights)
    if not bool(xp.all(xp.isfinite(h))):
        raise ValueError("heights contain NaN or inf")
    h = h - float(h.mean())  # the gap does not depend on <h> (the body follows the surface)
    k = (0.5 * e_star) * grid.q
    c = law.curvature(sigma0)
    minv = 1.0 / (k + c) if c > 0 else xp.where(k > 0, 1.0 / xp.where(k > 0, k, 1.0), 1.0)
    p_ref = law.pressure_scale(sigma0)
    rng = law.range()
    if initial is None:
        Z = xp.zeros((grid.shape[0], grid.shape[1] // 2 + 1), dtype=xp.complex128)
        Z[0, 0] = float(h.max())  # touching the highest summit, the body flat
    else:
        if isinstance(initial, GFMDResult):
            u0, g0 = initial.displacement, initial.mean_gap
        else:
            u0, g0 = initial
        u0 = xp.asarray(u0, dtype=xp.float64)
        if u0.shape != grid.shape or not bool(xp.all(xp.isfinite(u0))) or not math.isfinite(g0):
            raise ValueError(f"initial must be a GFMDResult or (displacement of shape {grid.shape}, mean gap)")
        Z = grid.fwd(u0 - u0.mean())
        Z[0, 0] = float(g0)
    st = _State(grid, law, h, k, sigma0, Z)
    history: list[float] = []
    s_hist: list = []
    y_hist: list = []
    r_hist: list[float] = []
    status = "max_iter"
    with np.errstate(all="ignore"):
        while True:
            deadline.check()  # a task time limit ends the solve between iterations
            g00 = complex(st.G[0, 0])
            rr = max(grid.dot(st.G, st.G) - abs(g00) ** 2, 0.0)
            res = max(math.sqrt(rr), abs(g00.real)) / p_ref
            history.append(res)
            if not math.isfinite(res):
                status = "non_finite"
                break
            if res <= tol:
                status = "converged"
                break
            if sigma0 < 0 and rng is not None and float(st.g.min()) > _DETACHED * rng:
                status = "detached"
                break
            if st.nfev >= max_iter:
                break
            q = st.G.copy()
            alphas = []
            for s, y, r in zip(reversed(s_hist), reversed(y_hist), reversed(r_hist)):
                al = r * grid.dot(s, q)
                alphas.append(al)
                q -= al * y
            q *= minv
            if y_hist:
                yhy = grid.dot(y_hist[-1], minv * y_hist[-1])
                if yhy > 0:
                    q *= 1.0 / (r_hist[-1] * yhy)
            for s, y, r, al in zip(s_hist, y_hist, r_hist, reversed(alphas)):
                q += (al - r * grid.dot(y, q)) * s
            D = -q
            slope = grid.dot(st.G, D)
            if not slope < 0:
                s_hist.clear(), y_hist.clear(), r_hist.clear()
                D = -(minv * st.G)
                slope = grid.dot(st.G, D)
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
            G_old = st.G
            st.move(alpha, D, d)
            s = alpha * D
            y = st.G - G_old
            sy = grid.dot(s, y)
            if sy > 0:
                s_hist.append(s)
                y_hist.append(y)
                r_hist.append(1.0 / sy)
                if len(s_hist) > memory:
                    s_hist.pop(0), y_hist.pop(0), r_hist.pop(0)

        # Returned fields from the Fourier state, their residual decides (issue 9).
        z = grid.inv(st.Z)
        u = z - float(st.Z[0, 0].real)
        gap = z - h
        p = law.pressure(gap, xp)
        U = grid.fwd(u)
        F = k * U - grid.fwd(p)
        F[0, 0] = 0.0
        residual = math.sqrt(max(grid.dot(F, F), 0.0)) / p_ref
        load_error = abs(float(p.mean()) - sigma0) / p_ref
        elastic = grid.elastic_energy(U, e_star)
        area = float(xp.count_nonzero(law.contact(gap, p))) / grid.size
        g0 = float(gap.mean())
        e_int = float(xp.mean(law.energy(gap, xp)))
    fields_ok = math.isfinite(residual) and bool(xp.all(xp.isfinite(gap))) and bool(xp.all(xp.isfinite(p)))
    if not fields_ok:
        status = "non_finite"
    converged = fields_ok and status == "converged" and residual <= tol and load_error <= tol
    if status == "converged" and not converged:
        status = "stalled"
    log.debug("%s: %s after %d evaluations, residual %.3g", law.name, status, st.nfev, residual)
    fields = {"gap": gap, "pressure": p, "displacement": u}
    fields.update(grid.to_host_many({k: fields[k] for k in host_fields(host)}))  # only those asked for
    gap, p, u = fields["gap"], fields["pressure"], fields["displacement"]
    grid.synchronize()
    return GFMDResult(
        mean_gap=g0, gap=gap, pressure=p, displacement=u, iterations=st.nfev, converged=converged,
        residual=residual, load_error=load_error, wall_time=time.perf_counter() - t_start, method="lbfgs",
        backend=grid.backend, status=status, sigma0=sigma0, rho=getattr(law, "rho", math.nan), e_star=e_star,
        length=length, tol=tol, history=history, interaction=law.name, params=law.params(), contact_area=area,
        elastic_energy=elastic, contact_criterion=law.contact_criterion,
        diagnostics={"pressure_scale": p_ref, "interaction_energy": e_int},
    )
