"""Green's function molecular dynamics (GFMD) at fixed mean pressure with exponential repulsion (docs/model.md M3).

An elastic half-space (contact modulus ``E*``) is pressed with mean pressure ``sigma0`` onto a rigid periodic
rough surface ``h`` (``n x n`` grid, side ``length``); the surfaces repel with ``p(g) = (gamma0/rho) exp(-g/rho)``.

Formulation (M3, "Identities"). With ``<u> = 0`` and the mean gap ``g0`` eliminated exactly, the equilibrium
displacement minimises the reduced convex energy per area

    F(u) = (E*/4) sum_q q |u~(q)|^2 + sigma0 rho ln < exp(w) >,      w = (h - u) / rho,

whose gradient (per area, real space) is ``p_el - p + sigma0`` with ``p_el = IFFT[(E* q/2) u~]`` and the softmax
pressure ``p = sigma0 exp(w) / <exp(w)>``. Every exponential is taken after subtracting ``max(w)``, so nothing
over- or underflows whatever ``sigma0``, ``rho`` or ``h_rms/rho`` is (M7), and ``<p> = sigma0`` holds by
construction. The mean gap follows exactly from the log-sum-exp

    g0 = rho [ ln(gamma0 / (rho sigma0)) + max(w) + ln <exp(w - max(w))> ],

the gap is ``g = g0 + u - h`` and ``p = (gamma0/rho) exp(-g/rho)`` is the same field as the softmax.

Convergence (docs/gfmd.md): ``residual = rms(p_el - (p - <p>)) / sigma0`` and ``load_error = |<p> - sigma0|/sigma0``;
``converged`` iff both are ``<= tol``. The residual is evaluated in Fourier space by Parseval, at no extra FFT.

Methods, one algorithm for every backend (numpy, pyFFTW, cupy); the unknowns are the Fourier modes ``u~(q)``:

- ``"cg"``: Polak-Ribiere+ nonlinear conjugate gradients, preconditioned with the Fourier-diagonal Hessian
  estimate ``M(q) = E* q/2 + sigma0/rho`` (elastic part exact, local part ``p/rho`` replaced by its mean).
- ``"lbfgs"``: limited-memory BFGS with ``M^-1`` as the initial inverse Hessian.
- ``"fire"``: GFMD proper, damped dynamics of the modes with masses ``M(q)`` (all modes then oscillate at about
  the same frequency, Campana & Muser 2006; Zhou, Moseler & Muser 2019) and FIRE damping.

Every method costs one rfft2/irfft2 pair per force evaluation: the descent direction is transformed once and
the line search moves along it in real space (the energy along a line needs no FFT), then the pressure of the
accepted point is transformed back. ``iterations`` counts these force evaluations. The default start is the
linear response ``u~ = h~ / (1 + eta zeta)`` of M4 (one preconditioned Newton step from ``u = 0``).

Kernels: fused numba loops on the CPU (numpy's SIMD exp); on the GPU one CUDA pass per step that does the
elementwise work and its reductions together and returns its scalars in one small device-to-host copy (the only
host synchronisation), see :class:`_CupyOps`; plain array code otherwise; FFTs from gapsweep.fft. On the GPU a
trial point is shifted by the previous point's max instead of its own when the two lie within 50 of each other
(``e <= e^50``, nothing overflows; the common factor cancels in ``p = sigma0 e / S``), else by its own max.
Default method "cg": fewest force evaluations and least time in docs/benchmarks_gfmd.md. User guide:
docs/gfmd.md.
"""

from __future__ import annotations

import math
import os
import time
import warnings
from typing import Any

import numpy as np

# Package layout: _ops (array operations, numba CPU kernels), _cuda (cupy GPU kernels, kernels.cu), _solvers
# (cg, lbfgs, fire), _result (GFMDResult). solve looks up _have_numba here, so tests monkeypatch gfmd._have_numba;
# benchmarks use gfmd._Problem and gfmd._make_ops.
from gapsweep import _checks as chk
from gapsweep.fft import BACKENDS, available_backends, get_backend
from gapsweep.gfmd._cuda import _CupyOps
from gapsweep.gfmd._ops import _have_numba, _is_cupy, _NumbaOps, _Ops
from gapsweep.gfmd._result import GFMDResult
from gapsweep.gfmd._solvers import _RUNNERS, _half_q, _Problem

__all__ = ["METHODS", "GFMDResult", "UnderResolvedWarning", "solve"]

METHODS = ("cg", "lbfgs", "fire")
DEFAULT_METHOD = "cg"  # decided by benchmarks/bench_gfmd.py speed (docs/benchmarks_gfmd.md)
STATUSES = ("converged", "max_iter", "non_finite", "stalled")


class UnderResolvedWarning(UserWarning):
    """The interaction range ``rho`` is shorter than the grid spacing (M7)."""


# ------------------------------------------------------------------------------------------------ helpers
def _make_ops(xp: Any, n: int) -> _Ops:
    """Kernels for the namespace: numba on the CPU when installed, fused cupy kernels on the GPU (unless
    ``GAPSWEEP_GENERIC_KERNELS=1``), else the generic array code."""
    if os.environ.get("GAPSWEEP_GENERIC_KERNELS") == "1":
        return _Ops(xp, n)
    if xp is np:
        return _NumbaOps(xp, n) if _have_numba() else _Ops(xp, n)
    if xp.__name__ == "cupy":
        return _CupyOps(xp, n)
    return _Ops(xp, n)


def _transfer_modes(u: np.ndarray, n: int) -> np.ndarray:
    """Normalised half spectrum on an ``n`` grid of the displacement ``u`` given on another grid: modes that
    both grids carry are copied, the rest set to zero (surfaces are resolution independent, M2)."""
    m = u.shape[0]
    full = np.fft.fft2(u) / (m * m)
    kmax = (min(m, n) - 1) // 2  # strictly below both Nyquist frequencies
    ks = np.r_[0 : kmax + 1, -kmax:0]
    out = np.zeros((n, n), dtype=np.complex128)
    out[np.ix_(ks % n, ks % n)] = full[np.ix_(ks % m, ks % m)]
    return out[:, : n // 2 + 1]


def solve(
    heights: Any,
    *,
    sigma0: float,
    gamma0: float,
    rho: float,
    e_star: float = 1.0,
    length: float = 1.0,
    tol: float = 1e-6,
    method: str = "auto",
    backend: str = "auto",
    max_iter: int = 5000,
    initial: GFMDResult | np.ndarray | None = None,
    threads: int | None = None,
    host: bool = True,
) -> GFMDResult:
    """Equilibrium gap of an elastic half-space on the rigid surface ``heights`` at mean pressure ``sigma0``.

    Minimises the reduced energy of M3 (module docstring) until ``residual <= tol`` and
    ``load_error <= tol``. ``heights``: real square ``n x n`` array (numpy, or cupy for the GPU), units of
    ``length``. ``sigma0``, ``gamma0/rho`` and ``e_star`` are pressures in one unit; ``gamma0`` is an energy per
    area, ``rho`` a length. ``method``: "auto" (= "cg"), "cg", "lbfgs" or "fire". ``backend``: "auto" (cupy
    for a cupy array, else pyfftw when installed, else numpy), "numpy", "pyfftw" or "cupy". ``max_iter``: force
    evaluations allowed. ``initial``: an earlier result or a displacement field (any grid size: shared Fourier
    modes are carried over) to start from; default is the linear response of M4. ``threads``: FFTW threads.
    ``host=False`` leaves the fields of a cupy run on the GPU (skips three n x n device-to-host copies).
    Warns (UnderResolvedWarning) when ``rho < length/n`` (M7).
    """
    t_start = time.perf_counter()
    on_gpu = _is_cupy(heights)
    if not on_gpu:
        if isinstance(heights, (str, bytes)) or heights is None:
            raise TypeError(f"heights must be a 2-D real array, got {type(heights).__name__}")
        h_np = np.asarray(heights)
        if not (np.issubdtype(h_np.dtype, np.floating) or np.issubdtype(h_np.dtype, np.integer)):
            raise TypeError(f"heights must be a real array, got dtype {h_np.dtype}")
        shape = h_np.shape
    else:
        shape = heights.shape
    if len(shape) != 2 or shape[0] != shape[1]:
        raise ValueError(f"heights must be a square 2-D array (n x n), got shape {shape}")
    n = int(shape[0])
    if n < 2:
        raise ValueError(f"heights must be at least 2 x 2, got n={n}")
    sigma0 = chk.positive(sigma0, "sigma0")
    gamma0 = chk.positive(gamma0, "gamma0")
    rho = chk.positive(rho, "rho")
    e_star = chk.positive(e_star, "e_star")
    length = chk.positive(length, "length")
    tol = chk.positive(tol, "tol")
    if isinstance(max_iter, bool) or not isinstance(max_iter, (int, np.integer)) or max_iter < 1:
        raise ValueError(f"max_iter must be an integer >= 1, got {max_iter!r}")
    if not isinstance(method, str) or method not in ("auto", *METHODS):
        raise ValueError(f"method must be one of {', '.join(map(repr, ('auto', *METHODS)))}; got {method!r}")
    method = DEFAULT_METHOD if method == "auto" else method
    if not isinstance(backend, str) or backend not in ("auto", *BACKENDS):
        raise ValueError(f"backend must be one of {', '.join(map(repr, ('auto', *BACKENDS)))}; got {backend!r}")
    if backend == "auto":
        backend = "cupy" if on_gpu else ("pyfftw" if "pyfftw" in available_backends() else "numpy")
    fft = get_backend(backend, n, threads=threads)
    xp = fft.xp

    h = fft.asarray(heights)
    if not bool(xp.all(xp.isfinite(h))):
        raise ValueError("heights contain NaN or inf")
    dx = length / n
    if rho < dx:
        warnings.warn(
            f"rho/dx = {rho / dx:.3g} < 1 (rho={rho:g}, dx={dx:g}): the interaction range is under-resolved; "
            "the solver still converges but the mean gap carries a discretisation error (refine n)",
            UnderResolvedWarning,
            stacklevel=2,
        )
    h = h - h.mean()  # only h - <h> matters: <h> shifts g0 by a constant; report the gap of h - <h>
    h_shift = float(xp.asarray(heights, dtype=xp.float64).mean())

    if initial is None:
        Hq = fft.rfft2(h) * (1.0 / (n * n))
        k = 0.5 * e_star * _half_q(xp, n, length)
        x0 = Hq * ((sigma0 / rho) / (k + sigma0 / rho))  # linear response of M4: h~ / (1 + eta zeta)
    else:
        u0 = initial.displacement if isinstance(initial, GFMDResult) else initial
        u0 = fft.to_host(u0) if _is_cupy(u0) else np.asarray(u0, dtype=np.float64)
        if u0.ndim != 2 or u0.shape[0] != u0.shape[1] or not np.all(np.isfinite(u0)):
            raise ValueError("initial must be a GFMDResult or a finite square displacement field")
        if u0.shape[0] == n:
            x0 = xp.array(fft.rfft2(xp.asarray(u0)) * (1.0 / (n * n)))
        else:
            x0 = xp.asarray(_transfer_modes(u0, n))
    x0 = xp.array(x0, dtype=xp.complex128)

    ops = _make_ops(xp, n)
    history: list[float] = []
    # Non-finite values are caught by the status checks (residual, fields), not by numpy warnings.
    with np.errstate(all="ignore"):
        pb = _Problem(h, x0, sigma0=sigma0, rho=rho, e_star=e_star, length=length, fft=fft, ops=ops)
        status = _RUNNERS[method](pb, tol, max_iter, history)

        # Fields from the Fourier state (fresh transform, no accumulated drift between X and W).
        u = xp.array(fft.irfft2(pb.X))
        w = (h - u) * (1.0 / rho)
        e = xp.empty_like(w)
        m = float(w.max())
        S, _, _ = pb.ops.expstats(w, m, e)
        lse = m + math.log(S / (n * n)) if S > 0 else math.nan  # S >= 1 whenever m is finite
        g0 = rho * (math.log(gamma0 / (rho * sigma0)) + lse)
        p = e * (sigma0 * n * n / S) if S > 0 else e * math.nan
        gap = (g0 - h_shift) - rho * w  # g = g0 + u - h with the caller's h (mean included)
    load_error = abs(float(p.mean()) / sigma0 - 1.0)
    residual = history[-1] if history else math.inf
    fields_ok = math.isfinite(g0) and bool(xp.all(xp.isfinite(gap))) and bool(xp.all(xp.isfinite(p)))
    if not fields_ok:
        status = "non_finite"
    converged = status == "converged" and load_error <= tol and fields_ok
    if status == "converged" and not converged:
        status = "stalled"
    if host:
        gap, p, u = fft.to_host(gap), fft.to_host(p), fft.to_host(u)
    fft.synchronize()
    return GFMDResult(
        mean_gap=g0 - h_shift,
        gap=gap,
        pressure=p,
        displacement=u,
        iterations=pb.nfev,
        converged=converged,
        residual=residual,
        load_error=load_error,
        wall_time=time.perf_counter() - t_start,
        method=method,
        backend=backend,
        status=status,
        sigma0=sigma0,
        rho=rho,
        gamma0=gamma0,
        e_star=e_star,
        length=length,
        tol=tol,
        history=history,
    )
