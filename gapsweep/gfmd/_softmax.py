"""The "softmax" minimiser: exponential repulsion at fixed mean pressure, the mean gap eliminated in closed form
(docs/model.md M3; the algorithm is described in the docstring of :mod:`gapsweep.gfmd`)."""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from gapsweep.core.fft import available_backends, get_backend
from gapsweep.gfmd._ops import _is_cupy
from gapsweep.gfmd._result import GFMDResult, fields_to_host, final_status, host_fields, law_result
from gapsweep.gfmd._solvers import _RUNNERS, _half_q, _Problem
from gapsweep.gfmd.interactions.exponential import Exponential

METHODS = ("cg", "lbfgs", "fire")
DEFAULT_METHOD = "cg"  # decided by benchmarks/bench_gfmd.py speed (docs/benchmarks_gfmd.md)


def minimise(heights: Any, law: Exponential, *, sigma0: float, e_star: float, length: float, tol: float,
             method: str, backend: str, max_iter: int, initial: Any, threads: int | None, host: bool,
             t_start: float, stiffness: Any = None) -> GFMDResult:
    """Exponential repulsion ``law`` on the square grid ``heights`` (inputs validated by ``gfmd.solve``).
    ``stiffness``: the substrate's ``k(q)`` on the rfft2 half grid instead of the half-space's ``E* q/2`` (an
    elastic layer, gfmd.substrates; numpy arrays, square grids)."""
    host_fields(host)  # validate before any work
    from gapsweep.gfmd._common import _make_ops

    shape = heights.shape
    lx, ly = length if isinstance(length, tuple) else (length, length)
    if shape[0] != shape[1] or lx != ly:
        # The fused softmax kernels are written for square grids; the same law on a rectangular grid runs on the
        # generic smooth minimiser (the mean gap as an unknown, L-BFGS), to the same residual definition.
        if method not in ("auto", "lbfgs"):
            raise ValueError(f"interaction {law.name!r} on a rectangular grid {shape} / box {length} takes method "
                             f"'auto' or 'lbfgs' (the generic smooth minimiser); got {method!r}")
        from gapsweep.gfmd import _smooth

        return _smooth.minimise(heights, law, sigma0=sigma0, e_star=e_star, length=length, tol=tol, method="lbfgs",
                                backend=backend, max_iter=max_iter, initial=initial, threads=threads, host=host,
                                t_start=t_start)
    length = lx
    n = int(shape[0])
    rho, gamma0 = law.rho, law.gamma0
    on_gpu = _is_cupy(heights)
    method = DEFAULT_METHOD if method == "auto" else method
    if backend == "auto":
        backend = "cupy" if on_gpu else ("pyfftw" if "pyfftw" in available_backends() else "numpy")
    fft = get_backend(backend, n, threads=threads)
    xp = fft.xp

    h = fft.asarray(heights)
    ops = _make_ops(xp, n)
    # GPU with the fused kernels (issue 22): set-up and result in single passes without temporaries, the surface
    # centred inside the pass that forms W (no centred copy), CG with one gradient array; see _solve_lean.
    lean = hasattr(ops, "final") and stiffness is None
    if lean:
        h = xp.ascontiguousarray(h)
        h_sum, bad = ops.sum_finite(h)
        if bad:
            raise ValueError("heights contain NaN or inf")
    elif not bool(xp.all(xp.isfinite(h))):
        raise ValueError("heights contain NaN or inf")
    if lean:
        return _solve_lean(h, h_sum / (n * n), law, fft, ops, sigma0=sigma0, e_star=e_star, length=length, tol=tol,
                           method=method, backend=backend, max_iter=max_iter, initial=initial, host=host,
                           t_start=t_start)
    h = h - h.mean()  # only h - <h> matters: the gap does not depend on <h> (docs/model.md M3, "Mean gap")

    if initial is None:
        Hq = fft.rfft2(h) * (1.0 / (n * n))
        k = 0.5 * e_star * _half_q(xp, n, length) if stiffness is None else stiffness
        x0 = Hq * ((sigma0 / rho) / (k + sigma0 / rho))  # linear response of M4: h~ / (1 + eta zeta)
        x0 = xp.array(x0, dtype=xp.complex128)
    else:
        x0 = _initial_modes(initial, n, fft)

    history: list[float] = []
    # Non-finite values are caught by the status checks (residual, fields), not by numpy warnings.
    with np.errstate(all="ignore"):
        pb = _Problem(h, x0, sigma0=sigma0, rho=rho, e_star=e_star, length=length, fft=fft, ops=ops,
                      stiffness=stiffness)
        status = _RUNNERS[method](pb, tol, max_iter, history)

        # Fields from the Fourier state (fresh transform, no accumulated drift between X and W).
        u = xp.array(fft.irfft2(pb.X))
        w = (h - u) * (1.0 / rho)
        e = xp.empty_like(w)
        m = float(w.max())
        S, _, _ = pb.ops.expstats(w, m, e)
        lse = m + math.log(S / (n * n)) if S > 0 else math.nan  # S >= 1 whenever m is finite
        g0 = law.mean_gap(lse, sigma0)
        p = e * (sigma0 * n * n / S) if S > 0 else e * math.nan
        gap = g0 - rho * w  # g = g0 + u - (h - <h>): invariant under h -> h + c
        # Residual of the returned fields (issue 9: the running value drifts from it at the round-off floor):
        # rms(p_el - (p - <p>)) / sigma0 by Parseval, one more forward FFT of u and of p.
        U = xp.array(fft.rfft2(u)) * (1.0 / (n * n))
        P = xp.array(fft.rfft2(p)) * (1.0 / (n * n))
        F = pb.k * U - P
        F[0, 0] = 0.0
        residual = math.sqrt(max(pb.ops.dot(F, F), 0.0)) / sigma0
        elastic = 0.5 * pb.ops.dot(U, pb.k * U)  # (E*/4) sum_q q |u~|^2 per area
        area = float(xp.count_nonzero(law.contact(gap, p))) / (n * n)
    load_error = abs(float(p.mean()) / sigma0 - 1.0)
    fields_ok = math.isfinite(g0) and bool(xp.all(xp.isfinite(gap))) and bool(xp.all(xp.isfinite(p)))
    status, _ = final_status(status, fields_ok, residual, load_error, tol)
    converged = status == "converged"
    gap, p, u = fields_to_host(fft, host, gap, p, u)
    fft.synchronize()
    return _record(law, t_start, g0, (gap, p, u), pb.nfev, status, converged, residual, load_error, history,
                   method=method, backend=backend, sigma0=sigma0, rho=rho, gamma0=gamma0, e_star=e_star,
                   length=length, tol=tol, contact_area=area, elastic_energy=elastic)


def _initial_modes(initial: Any, n: int, fft: Any) -> Any:
    """Half spectrum ``u~`` of a warm start (a result or a displacement on any square grid), a new array."""
    from gapsweep.gfmd._common import _transfer_modes

    xp = fft.xp
    u0 = initial.displacement if isinstance(initial, GFMDResult) else initial
    # a field already on this GPU stays there (a warm-started pressure chain copies nothing)
    u0 = (u0 if xp is not np and u0.shape[0] == n else fft.to_host(u0)) if _is_cupy(u0) else \
        np.asarray(u0, dtype=np.float64)
    uxp = xp if _is_cupy(u0) else np
    if u0.ndim != 2 or u0.shape[0] != u0.shape[1] or not bool(uxp.all(uxp.isfinite(u0))):
        raise ValueError("initial must be a GFMDResult or a finite square displacement field")
    if u0.shape[0] == n:
        return xp.array(fft.rfft2(xp.asarray(u0, dtype=xp.float64)) * (1.0 / (n * n)), dtype=xp.complex128)
    return xp.asarray(_transfer_modes(u0, n), dtype=xp.complex128)


def _solve_lean(h: Any, h_mean: float, law: Exponential, fft: Any, ops: Any, *, sigma0: float, e_star: float,
                length: float, tol: float, method: str, backend: str, max_iter: int, initial: Any, host: Any,
                t_start: float) -> GFMDResult:
    """The GPU branch of :func:`minimise` (fused cupy kernels, gfmd/_cuda.py): the same equations and algorithm
    (docs/model.md M3, M4), arranged for memory and passes (issue 22, items 3 and 5).

    Memory: the caller's ``h`` is read, never copied (centred inside the pass that forms ``W``); CG keeps one
    gradient array; the result fields reuse the solver's buffers (``u`` in ``Wt``, ``gap`` in ``W``, ``p`` in
    ``e``), so a solve holds about 8 grid-sized arrays plus cuFFT's (see :func:`gapsweep.gfmd._cuda.solve_memory`).
    Passes: the linear response (M4), the result fields, their residual and elastic energy are one CUDA pass
    each (kernels.cu, "set-up, result") instead of a chain of array expressions with a temporary per step."""
    xp = fft.xp
    n = h.shape[0]
    rho = law.rho
    ka, kb, sr = 0.5 * e_star, 2 * np.pi / length, sigma0 / rho
    if initial is None:
        x0 = xp.empty((n, n // 2 + 1), dtype=xp.complex128)
        # rfft2 of the uncentred h: only the q = 0 mode differs, and the linear response sets it to 0 (<u> = 0)
        ops.linresp(fft.rfft2(h), 1.0 / (n * n), sr, ka, kb, x0)
    else:
        x0 = _initial_modes(initial, n, fft)
    history: list[float] = []
    with np.errstate(all="ignore"):
        pb = _Problem(h, x0, sigma0=sigma0, rho=rho, e_star=e_star, length=length, fft=fft, ops=ops,
                      h_mean=h_mean, share_gold=method == "cg")
        del x0  # pb.X holds it (and lets it go before the result passes)
        status = _RUNNERS[method](pb, tol, max_iter, history)
        nfev = pb.nfev
        # Result fields from the Fourier state (fresh transform, no drift between X and W), in the solver's buffers.
        u, w, e = pb.Wt, pb.W, pb.e
        pb.et = pb.G_old = pb.D = None  # free what the result does not need
        xp.copyto(u, fft.irfft2(pb.X))
        m = ops.field(h, h_mean, u, 1.0 / rho, w)
        S, _, _ = ops.expstats(w, m, e)
        lse = m + math.log(S / (n * n)) if S > 0 else math.nan  # S >= 1 whenever m is finite
        g0 = law.mean_gap(lse, sigma0)
        # gap = g0 - rho W with W of the centred surface: the gap of h - <h> (docs/model.md M3, "Mean gap")
        p_sum, n_contact, n_bad = ops.final(w, e, sigma0 * n * n / S if S > 0 else math.nan, g0, rho, 0.0, rho)
        gap, p = w, e
        if type(law).contact is not Exponential.contact:  # a law with its own contact criterion
            n_contact = int(xp.count_nonzero(law.contact(gap, p)))
        # Residual of the returned fields (issue 9), rms(p_el - (p - <p>)) / sigma0 by Parseval, and the elastic
        # energy (E*/4) sum_q q |u~|^2 from one pass over rfft2(u) (kept in G) and rfft2(p).
        U = pb.G
        pb.X = None
        xp.copyto(U, fft.rfft2(u))
        ff, uku = ops.resid(U, fft.rfft2(p), 1.0 / (n * n), ka, kb)
        residual = math.sqrt(max(ff, 0.0)) / sigma0
        elastic = 0.5 * uku
        area = n_contact / (n * n)
        del U, pb
    load_error = abs(p_sum / (n * n) / sigma0 - 1.0)
    fields_ok = math.isfinite(g0) and n_bad == 0
    status, _ = final_status(status, fields_ok, residual, load_error, tol)
    converged = status == "converged"
    gap, p, u = fields_to_host(fft, host, gap, p, u)
    fft.synchronize()
    return _record(law, t_start, g0, (gap, p, u), nfev, status, converged, residual, load_error, history,
                   method=method, backend=backend, sigma0=sigma0, rho=rho, gamma0=law.gamma0, e_star=e_star,
                   length=length, tol=tol, contact_area=area, elastic_energy=elastic)


def _record(law: Any, t_start: float, g0: float, fields: tuple, nfev: int, status: str, converged: bool,
            residual: float, load_error: float, history: list[float], **kw: Any) -> GFMDResult:
    """The result of both branches (:func:`law_result`; the running residual among the diagnostics)."""
    gap, p, u = fields
    return law_result(law, t_start, mean_gap=g0, gap=gap, pressure=p, displacement=u, iterations=nfev,
                      converged=converged, residual=residual, load_error=load_error, status=status, history=history,
                      diagnostics={"running_residual": history[-1] if history else math.inf}, **kw)
