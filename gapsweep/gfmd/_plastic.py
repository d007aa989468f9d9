"""Elastic-perfectly-plastic hard-wall contact: the hard wall with a pressure cap ``p <= H`` (docs/gfmd.md,
"Plastic contact (pressure cap)"; docs/model.md M3).

Minimises the complementary energy ``(1/2) <p K p> - <p h>`` over pressures ``0 <= p <= H`` with ``<p> = sigma0``
(``K`` the compliance of the substrate: the half-space's ``u~ = p~ / (E* q/2)``, a layer's ``p~ / k(q)``
through :class:`gapsweep.gfmd.substrates.LayerGrid`, or the free-boundary Boussinesq response). KKT conditions,
``g = g0 + u - h`` the gap to the original surface and ``g0`` the multiplier of the load:

    p = 0      ->  g >= 0   (free surface)
    0 < p < H  ->  g = 0    (elastic contact, the set S)
    p = H      ->  g <= 0   (plastic flow: the surface is flattened by ``u_pl = -g``)

Algorithm: Polonsky & Keer's constrained conjugate gradients (Wear 231, 206, 1999) with the pressure saturated at
``H`` (tamaas' KatoSaturated and Almqvist et al., Wear 262, 2007, solve the same problem by other iterations). The
free set ``F`` is the elastic pixels ``S`` plus the violators (``p = 0`` with an overlap ``g < 0``, ``p = H``
with ``g > 0``); the conjugate direction ``t`` lives on ``F`` (preconditioned with ``M = E* q/2``, method "pcg",
or plain, "pk"), load-neutral there; the step ``tau = <g t>_F / <t K t>``; where ``p - tau t`` leaves the box,
the Euclidean projection of it on ``{0 <= p <= H, <p> = sigma0}`` over ``F`` (``clip(trial - lambda, 0, H)``,
``lambda`` by Newton steps on the piecewise-linear sum, bisection as a fallback) and conjugacy restarts (also when
``F`` changes). Rescaling the load instead (the plain hard wall's way) oscillates once many pixels sit at ``H``.
Method "mpcg": "pcg" started from the pressure of the coarsened surface (recursively, as the hard wall's "mpcg").
CPU: fused numba passes (gfmd._plastic_ops) with ``u`` following ``u - tau K t`` between projections; other
arrays (cupy) the array code of :func:`_iterate`.

Convergence on the returned fields: ``residual = max(rms_S(g), max(0, -min_{p=0} g), max(0, max_{p=H} g)) / h_rms``
with ``g0 = -<u - h>_S`` (without elastic pixels: the middle of the interval the KKT conditions leave);
``load_error = |<p> - sigma0| / sigma0``. Outputs: the gap ``max(g, 0)`` (0 on S and on the plastic set: the body
touches the flattened surface), the plastic displacement ``u_pl = max(0, -g)`` on the plastic set (0 elsewhere),
``contact_area`` (``p > 0``), ``plastic_area`` (``p = H``). The residual (unloaded) surface is
``h - u_pl`` (:func:`residual_surface`): loaded again to ``sigma0`` it carries the same pressure elastically."""

from __future__ import annotations

import logging
import math
import os
import time
from collections.abc import Callable
from typing import Any

import numpy as np

from gapsweep.core import deadline
from gapsweep.gfmd._grid import FreeGrid, Grid
from gapsweep.gfmd._ops import _is_cupy
from gapsweep.gfmd._result import GFMDResult, fields_to_host, final_status, host_fields, law_result
from gapsweep.gfmd.interactions.base import Interaction

METHODS = ("pk", "pcg", "mpcg")
DEFAULT_METHOD = "mpcg"
_COARSEST = 128
_COARSE_TOL = 1e-2
_REFRESH = 25  # fused loop: iterations between fresh K p while u follows linearly
log = logging.getLogger("gapsweep.gfmd")


def check_hardness(hardness: Any, sigma0: float) -> float | None:
    """``H`` validated (a pressure in the units of ``sigma0``, ``sigma0 < H``), or None (no cap; ``inf`` too)."""
    if hardness is None:
        return None
    if isinstance(hardness, bool) or not isinstance(hardness, (int, float, np.integer, np.floating)) \
            or math.isnan(float(hardness)) or not float(hardness) > 0:
        raise ValueError(f"hardness must be a positive pressure (units of sigma0) or None, got {hardness!r}")
    hardness = float(hardness)
    if math.isinf(hardness):
        return None
    if not sigma0 < hardness:
        raise ValueError(f"hardness must exceed the mean pressure sigma0 = {sigma0!r} (at sigma0 >= H the whole "
                         f"surface flows: no equilibrium), got hardness = {hardness!r}")
    return hardness


def residual_surface(heights: Any, result: GFMDResult) -> Any:
    """The permanently deformed surface after unloading, ``h - u_pl`` (units of ``heights``): the input surface
    less the plastic displacement of a capped hard-wall result (docstring of this module). Usable as the
    ``heights`` of a second loading or of any other solve."""
    if result.plastic_displacement is None:
        raise ValueError("residual_surface needs a result of solve(..., interaction='hard_wall', hardness=H)")
    return heights - result.plastic_displacement


def _project(trial: Any, on: Any, H: float, target: float, xp: Any) -> Any:
    """The Euclidean projection of ``trial`` on ``{0 <= p <= H, sum p = target}`` moving only the pixels ``on``:
    ``p = clip(trial - lambda, 0, H)`` there, ``lambda`` the root of the piecewise-linear, non-increasing sum
    (Newton steps on its linear pieces, bisection if they do not settle). If the pixels ``on`` cannot carry the
    load (or must carry a negative one), every pixel moves."""
    rest = float(xp.sum(xp.where(on, 0.0, trial)))
    n_on = int(xp.count_nonzero(on))
    if not (0.0 <= target - rest <= H * n_on):
        on = xp.ones(trial.shape, dtype=bool)
        rest = 0.0

    def total(lam: float) -> tuple[float, Any]:
        q = xp.where(on, xp.clip(trial - lam, 0.0, H), trial)
        return float(q.sum()), q

    lam = 0.0
    for _ in range(40):
        s, q = total(lam)
        if abs(s - target) <= 1e-14 * target:
            return q
        n_free = int(xp.count_nonzero(on & (q > 0) & (q < H)))
        if n_free == 0:
            break
        lam -= (target - s) / n_free
    span = float(xp.max(xp.abs(trial))) + H
    lo, hi = -span, span  # total(lo) >= target >= total(hi)
    for _ in range(200):
        mid = 0.5 * (lo + hi)
        if total(mid)[0] > target:
            lo = mid
        else:
            hi = mid
    return total(0.5 * (lo + hi))[1]


def _kkt(u: Any, h: Any, p: Any, H: float, xp: Any, g_ref: float) -> tuple[float, Any, Any, Any, float]:
    """``(g0, g, S, plastic, residual)`` of the pressure ``p`` with displacement ``u`` (module docstring)."""
    d = u - h
    S = (p > 0) & (p < H)
    plastic = p >= H
    zero = p <= 0
    n_s = int(xp.count_nonzero(S))
    if n_s:
        g0 = -float(xp.sum(xp.where(S, d, 0.0))) / n_s
    else:  # g0 >= max_zero(-d) and g0 <= min_plastic(-d): the middle of that interval
        lower = float(xp.max(xp.where(zero, -d, -xp.inf))) if bool(xp.any(zero)) else -math.inf
        upper = float(xp.min(xp.where(plastic, -d, xp.inf))) if bool(xp.any(plastic)) else math.inf
        g0 = lower if not math.isfinite(upper) else upper if not math.isfinite(lower) else 0.5 * (lower + upper)
    g = g0 + d
    rms = math.sqrt(float(xp.sum(xp.where(S, g * g, 0.0))) / max(n_s, 1))
    overlap = max(0.0, -float(xp.min(xp.where(zero, g, xp.inf)))) if bool(xp.any(zero)) else 0.0
    lift = max(0.0, float(xp.max(xp.where(plastic, g, -xp.inf)))) if bool(xp.any(plastic)) else 0.0
    return g0, g, S, plastic, max(rms, overlap, lift) / g_ref


def _iterate(grid: Grid, compliance: Callable, stiff: Any, h: Any, p: Any, H: float, sigma0: float, tol: float,
             g_ref: float, max_iter: int, history: list[float]) -> tuple[Any, int, str, int]:
    """The constrained CG of the module docstring; returns ``(p, iterations, status, fft_pairs)``."""
    xp = grid.xp
    target = sigma0 * grid.size
    t = xp.zeros(grid.real_shape)
    delta, gz_old, it, pairs, status = 0.0, 1.0, 0, 0, "max_iter"
    F_old = None
    with np.errstate(all="ignore"):
        while True:
            deadline.check()
            u = compliance(p)
            pairs += 1
            _, g, S, plastic, res = _kkt(u, h, p, H, xp, g_ref)
            history.append(res)
            if not math.isfinite(res):
                status = "non_finite"
                break
            if res <= tol:
                status = "converged"
                break
            if it >= max_iter:
                break
            it += 1
            # the free variables: elastic pixels and the violators (overlap at p = 0, lift-off at p = H)
            F = S | ((p <= 0) & (g < 0)) | (plastic & (g > 0))
            n_f = int(xp.count_nonzero(F))
            changed = not bool(xp.array_equal(F, F_old)) if F_old is not None else True
            F_old = F
            gs = xp.where(F, g, 0.0)
            if stiff is not None:
                z = xp.where(F, grid.convolve(gs, stiff), 0.0)
                pairs += 1
            else:
                z = gs
            gz = float(xp.sum(gs * z))
            c = delta * gz / gz_old if (gz_old > 0 and not changed) else 0.0
            t = xp.where(F, z + c * t, 0.0)
            t = xp.where(F, t - float(xp.sum(t)) / max(n_f, 1), 0.0)  # load-neutral on F
            gz_old = gz
            r = compliance(t)
            pairs += 1
            rt = float(xp.sum(r * t))
            if not rt > 0:
                status = "stalled" if math.isfinite(rt) else "non_finite"
                break
            tau = float(xp.sum(gs * t)) / rt
            trial = p - tau * t
            clipped = bool(xp.any((trial < 0) | (trial > H)))
            p = _project(trial, F, H, target, xp) if clipped else trial
            delta = 0.0 if clipped else 1.0
    return p, it, status, pairs


def _project_fused(K: Any, trial: Any, on: Any, H: float, target: float, out: Any) -> Any:
    """:func:`_project` through the fused pass ``K.proj_total`` (``on``: uint8 mask); the result into ``out``."""
    on_b = on.view(bool)
    rest = float(trial.sum()) - float(np.sum(trial, where=on_b))
    n_on = int(np.count_nonzero(on_b))
    if not (0.0 <= target - rest <= H * n_on):
        on = np.ones_like(on)
    lam = 0.0
    for _ in range(40):
        s, n_free = K.proj_total(trial, on, H, lam, out)
        if abs(s - target) <= 1e-14 * target:
            return out
        if n_free == 0:
            break
        lam -= (target - s) / n_free
    span = float(np.max(np.abs(trial))) + H
    lo, hi = -span, span
    for _ in range(200):
        mid = 0.5 * (lo + hi)
        if K.proj_total(trial, on, H, mid, out)[0] > target:
            lo = mid
        else:
            hi = mid
    K.proj_total(trial, on, H, 0.5 * (lo + hi), out)
    return out


def _iterate_fused(grid: Grid, compliance: Callable, stiff: Any, h: Any, p: Any, H: float, sigma0: float,
                   tol: float, g_ref: float, max_iter: int, history: list[float]) -> tuple[Any, int, str, int]:
    """:func:`_iterate` with numba's fused passes (gfmd._plastic_ops; numpy arrays): the same iteration, and ``u``
    follows ``u - tau K t`` when nothing was projected (a fresh ``K p`` after a projection and every
    ``_REFRESH`` iterations)."""
    from gapsweep.gfmd._plastic_ops import kernels

    K = kernels()
    target = sigma0 * grid.size
    shape = grid.real_shape
    t, gs, z, r, trial = (np.zeros(shape) for _ in range(5))
    F, F_old = np.zeros(shape, dtype=np.uint8), np.zeros(shape, dtype=np.uint8)
    p = np.ascontiguousarray(p, dtype=np.float64)
    h = np.ascontiguousarray(h)
    delta, gz_old, it, status, since = 0.0, 1.0, 0, "max_iter", 0
    with np.errstate(all="ignore"):
        u = np.ascontiguousarray(compliance(p))
        pairs = 1
        while True:
            deadline.check()
            n_s, sd, lower, upper = K.kkt1(u, h, p, H)
            if n_s:
                g0 = -sd / n_s
            else:
                lo = lower if lower > -1e308 else -math.inf
                up = upper if upper < 1e308 else math.inf
                g0 = lo if not math.isfinite(up) else up if not math.isfinite(lo) else 0.5 * (lo + up)
            F, F_old = F_old, F
            s2, overlap, lift, n_f, same = K.kkt2(u, h, p, H, g0, gs, F, F_old)
            res = max(math.sqrt(s2 / max(n_s, 1)), overlap, lift) / g_ref
            history.append(res)
            if not math.isfinite(res):
                status = "non_finite"
                break
            if res <= tol:
                if since:  # decide on a fresh K p
                    u = np.ascontiguousarray(compliance(p, u))
                    pairs += 1
                    since = 0
                    continue
                status = "converged"
                break
            if it >= max_iter:
                break
            it += 1
            if stiff is not None:
                z = grid.convolve(gs, stiff, z)
                pairs += 1
                gz = K.dot(gs, z)
            else:
                z, gz = gs, s2
            c = delta * gz / gz_old if (gz_old > 0 and same) else 0.0
            t_sum = K.direction(t, z, F, c)
            gst = K.centre(t, F, t_sum / max(n_f, 1), gs)
            gz_old = gz
            r = compliance(t, r)
            pairs += 1
            rt = K.dot(r, t)
            if not rt > 0:
                status = "stalled" if math.isfinite(rt) else "non_finite"
                break
            tau = gst / rt
            np.copyto(trial, p)
            clipped = K.step(trial, t, tau, H)
            if clipped:
                p = _project_fused(K, trial, F, H, target, p)
                delta = 0.0
                u = compliance(p, u)
                pairs += 1
                since = 0
            else:
                p, trial = trial, p
                delta = 1.0
                if since >= _REFRESH:
                    u = compliance(p, u)
                    pairs += 1
                    since = 0
                else:
                    K.follow(u, r, tau)
                    since += 1
    return p, it, status, pairs


def minimise(heights: Any, law: Interaction, *, hardness: float, sigma0: float, e_star: float, length: Any,
             tol: float, method: str, backend: str, max_iter: int, initial: Any, threads: int | None, host: Any,
             t_start: float, periodic: bool = True, make_grid: Callable[[tuple[int, int]], Grid] | None = None
             ) -> GFMDResult:
    """Hard wall with the pressure cap ``hardness`` (inputs validated by ``gfmd.solve``). ``make_grid``: the grid
    of a shape (a layer's :class:`LayerGrid`); default the half-space's periodic or free grid."""
    on_gpu = _is_cupy(heights)
    if make_grid is None:
        def make_grid(shape: tuple[int, int]) -> Grid:
            return (Grid if periodic else FreeGrid)(shape, length, backend, threads, on_gpu)
    grid = make_grid(heights.shape)
    if method == "auto":
        method = DEFAULT_METHOD
    if method not in METHODS:
        raise ValueError(f"method must be 'auto' or one of {METHODS} with hardness; got {method!r}")
    host_fields(host)
    xp = grid.xp
    H = float(hardness)
    h, h_rms, g_ref = grid.centred(heights)  # g_ref: h_rms, or the pixel size on a flat map
    if periodic:
        with np.errstate(divide="ignore", invalid="ignore"):
            kinv = 1.0 / ((0.5 * e_star) * grid.q)
        grid.set_mode0(kinv, 0.0)
        kinv = grid.multiplier(kinv)

        def compliance(a: Any, out: Any = None) -> Any:
            return grid.convolve(a, kinv, out)
    else:
        compliance = grid.compliance(e_star)
    stiff = grid.multiplier((0.5 * e_star) * grid.q) if method != "pk" else None
    coarse_its: list[int] = []
    nx, ny = grid.shape
    if initial is None and method == "mpcg" and min(nx, ny) >= 2 * _COARSEST and nx % 2 == 0 and ny % 2 == 0:
        from gapsweep.gfmd._constrained import coarsen

        hc = coarsen(h, xp) if periodic else h.reshape(nx // 2, 2, ny // 2, 2).mean(axis=(1, 3))
        rc = minimise(hc, law, hardness=H, sigma0=sigma0, e_star=e_star, length=length, tol=_COARSE_TOL,
                      method="mpcg", backend=backend, max_iter=2000, initial=None, threads=threads, host=False,
                      t_start=time.perf_counter(), periodic=periodic, make_grid=make_grid)
        p = xp.clip(xp.repeat(xp.repeat(xp.asarray(rc.pressure), 2, axis=0), 2, axis=1), 0.0, H)
        coarse_its = [rc.iterations, *rc.diagnostics.get("coarse_iterations", [])]
        p = _project(p, p > 0, H, sigma0 * grid.size, xp)
    elif initial is None:
        p = xp.full(grid.real_shape, sigma0)
    else:
        p0 = initial.pressure if isinstance(initial, GFMDResult) else initial
        p = xp.clip(xp.asarray(p0, dtype=xp.float64), 0.0, H)
        if tuple(p.shape) != tuple(grid.real_shape) or not bool(xp.all(xp.isfinite(p))) or not float(p.sum()) > 0:
            raise ValueError(f"initial must be a GFMDResult or a finite pressure field of shape {grid.real_shape} "
                             "with a positive sum")
        p = _project(p, p > 0, H, sigma0 * grid.size, xp)
    history: list[float] = []
    from gapsweep.gfmd._constrained_ops import _have_numba

    fused = xp is np and _have_numba() and os.environ.get("GAPSWEEP_GENERIC_KERNELS") != "1"
    p, it, status, pairs = (_iterate_fused if fused else _iterate)(grid, compliance, stiff, h, p, H, sigma0, tol,
                                                                   g_ref, max_iter, history)
    with np.errstate(all="ignore"):
        u = compliance(p)
        _, g, S, plastic, residual = _kkt(u, h, p, H, xp, g_ref)
        load_error = abs(float(p.mean()) / sigma0 - 1.0)
        gap = xp.where(p > 0, 0.0, xp.maximum(g, 0.0))
        u_pl = xp.where(plastic, xp.maximum(-g, 0.0), 0.0)
        elastic = 0.5 * float(xp.mean(p * u))
    fields_ok = math.isfinite(residual) and grid.all_finite(p) and grid.all_finite(u)
    status, converged = final_status(status, fields_ok, residual, load_error, tol)
    area = int(xp.count_nonzero(p > 0)) / grid.size
    plastic_area = int(xp.count_nonzero(plastic)) / grid.size
    log.debug("plastic hard wall: %s after %d iterations, residual %.3g, area %.4g, plastic %.4g", status, it,
              residual, area, plastic_area)
    gap_h, p_h, u_h = fields_to_host(grid, host, gap, p, u)
    if host is not False:
        u_pl = grid.to_host(u_pl)
    diagnostics = {"h_rms": h_rms, "fft_pairs": pairs, "coarse_iterations": coarse_its,
                   "elastic_area": int(xp.count_nonzero(S)) / grid.size}
    return law_result(law, t_start, mean_gap=float(xp.mean(gap)), gap=gap_h, pressure=p_h, displacement=u_h,
                      iterations=it, converged=converged, residual=residual, load_error=load_error, method=method,
                      backend=grid.backend, status=status, sigma0=sigma0, e_star=e_star, length=length, tol=tol,
                      history=history, params={**law.params(), "hardness": H}, contact_area=area,
                      elastic_energy=elastic, contact_criterion="p > 0 (elastic 0 < p < H, plastic p = H)",
                      diagnostics=diagnostics, periodic=periodic, plastic_area=plastic_area,
                      plastic_displacement=u_pl)
