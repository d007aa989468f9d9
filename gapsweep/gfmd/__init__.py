"""Green's function molecular dynamics (GFMD) at fixed mean pressure (docs/model.md M3).

Interaction laws (``interaction=`` of :func:`solve`, one file each in :mod:`gapsweep.gfmd.interactions`, interface
in :mod:`gapsweep.gfmd.interactions.base`, equations and units in docs/gfmd.md): "exponential" (the default,
below), and further laws that plug into the same solver through their ``load_control``. The rest of this
docstring describes the exponential law's minimiser (``gfmd._softmax``).

An elastic half-space (contact modulus ``E*``) is pressed with mean pressure ``sigma0`` onto a rigid periodic
rough surface ``h`` (``n x n`` grid, side ``length``); the surfaces repel with ``p(g) = (gamma0/rho) exp(-g/rho)``.
A finite, non-periodic map (``solve(..., periodic=False)``) is solved with free boundaries instead: the
half-space's Boussinesq response on a grid padded to twice the map (``gfmd._grid.FreeGrid``; hard wall on its own
minimiser, smooth laws on ``gfmd._free``; docs/gfmd.md, "Periodic or free boundaries").

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

import os
import time
from typing import Any

import numpy as np

# Package layout: interactions/ (the laws), _softmax (the exponential law's minimiser), _ops (array operations,
# numba CPU kernels), _cuda (cupy GPU kernels, kernels.cu), _solvers (cg, lbfgs, fire), _result (GFMDResult).
# _make_ops looks up _have_numba here (tests monkeypatch gfmd._have_numba); benchmarks use gfmd._Problem, _make_ops.
from gapsweep import _checks as chk
from gapsweep.fft import BACKENDS
from gapsweep.gfmd import _constrained, _free, _smooth, _softmax
from gapsweep.gfmd._cuda import _CupyOps
from gapsweep.gfmd._ops import _have_numba, _is_cupy, _NumbaOps, _Ops
from gapsweep.gfmd._path import LoadPath, solve_path
from gapsweep.gfmd._result import GFMDResult
from gapsweep.gfmd._solvers import _half_q, _Problem  # noqa: F401 - used by benchmarks (gfmd._Problem)
from gapsweep.gfmd.interactions import INTERACTIONS, Interaction, resolve

__all__ = ["INTERACTIONS", "METHODS", "BatchProblem", "GFMDResult", "Interaction", "LoadPath",
           "UnderResolvedWarning", "solve", "solve_batch", "solve_path"]

METHODS = _softmax.METHODS  # methods of the exponential law (the job-spec validator uses this list)
DEFAULT_METHOD = _softmax.DEFAULT_METHOD
STATUSES = ("converged", "max_iter", "non_finite", "stalled", "detached")


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


# load_control of a law -> (minimiser, its methods). A new law reuses one of these; no branch per law.
_MINIMISERS: dict[str, tuple[Any, tuple[str, ...]]] = {
    "softmax": (_softmax.minimise, _softmax.METHODS),
    "multiplier": (_constrained.minimise, _constrained.METHODS),
    "variable": (_smooth.minimise, _smooth.METHODS),
}
# Minimisers that take periodic=False (free boundaries), by load_control: the hard wall's own (its compliance
# swapped for the free one), every smooth law (the exponential one included) on gfmd._free.
_FREE: dict[str, tuple[Any, tuple[str, ...]]] = {
    "multiplier": (_constrained.minimise, _constrained.METHODS),
    "softmax": (_free.minimise, _free.METHODS),
    "variable": (_free.minimise, _free.METHODS),
}


def solve(
    heights: Any,
    *,
    sigma0: float,
    interaction: str | Interaction = "exponential",
    gamma0: float | None = None,
    rho: float | None = None,
    work: float | None = None,
    e_star: float = 1.0,
    length: float = 1.0,
    tol: float = 1e-6,
    method: str = "auto",
    backend: str = "auto",
    max_iter: int = 5000,
    initial: GFMDResult | np.ndarray | None = None,
    threads: int | None = None,
    host: bool | tuple[str, ...] = True,
    periodic: bool | None = None,
) -> GFMDResult:
    """Equilibrium gap of an elastic half-space on the rigid surface ``heights`` at mean pressure ``sigma0``.

    ``interaction``: a law's name or an :class:`Interaction` object (docs/gfmd.md): "exponential" (default;
    needs ``gamma0``, an energy per area, and ``rho``, a length), "hard_wall", or "adhesive" (``work``, the
    work of adhesion per area, and ``rho``, its range). For the exponential law the reduced energy of M3
    (module docstring) is minimised until ``residual <= tol`` and ``load_error <= tol``; the other laws'
    convergence measures are in docs/gfmd.md. ``heights``: real ``nx x ny`` array (numpy, or cupy for the
    GPU), units of ``length`` (a number, or ``(Lx, Ly)``); the exponential law's own minimiser needs a square
    grid, other grids run on the generic smooth one. ``sigma0``, ``gamma0/rho`` and ``e_star`` are pressures in
    one unit. ``method``: "auto", or "cg" (default), "lbfgs", "fire" (exponential); "mpcg" (default on the CPU;
    coarse-to-fine start), "pcg" (default on the GPU), "pk" (hard wall); "lbfgs" (adhesive). ``backend``: "auto"
    (cupy for a cupy array, else pyfftw when installed, else numpy), "numpy", "pyfftw" or "cupy". ``max_iter``:
    force evaluations (hard wall: iterations) allowed.
    ``initial``: an earlier result or a field to start from (exponential: a displacement on any grid size,
    shared Fourier modes carried over; hard wall: a pressure; adhesive: ``(displacement, mean gap)``); default
    for the exponential law is the linear response of M4. ``threads``: FFTW threads. ``host``: which fields of
    a cupy run come to the host (pinned, asynchronous copies): True (all), False (none: they stay on the GPU) or
    names such as ``("gap",)``. Warns (UnderResolvedWarning) when ``rho < length/n`` (M7, exponential law).

    ``periodic``: True, the map is one period of a periodic surface (docs/model.md M1); False, a finite map on
    an elastic half-space with free boundaries (docs/gfmd.md, "Periodic or free boundaries"): the Boussinesq
    response of the map's pixels on a grid padded to twice the map, pressure only on the map, ``sigma0`` the
    mean pressure over the map's own area (load = ``sigma0 Lx Ly``); every law (hard wall: its own methods;
    exponential and adhesive: "lbfgs" on ``gfmd._free``), on the CPU and the GPU (cupy).
    Default (None): a :class:`gapsweep.topography.Topography` passed as ``heights`` brings its own
    ``periodic`` flag and its ``length`` (a ``length`` given here must then be left at 1.0); arrays are periodic.
    """
    t_start = time.perf_counter()
    from gapsweep.topography import Topography

    if isinstance(heights, Topography):
        if length != 1.0 and tuple(np.broadcast_to(length, 2)) != tuple(heights.length):
            raise ValueError(f"length={length!r} contradicts the Topography's own length {heights.length}; "
                             "leave length out when passing a Topography")
        length = tuple(heights.length)
        periodic = heights.periodic if periodic is None else periodic
        heights = heights.heights
    if periodic is None:
        periodic = True
    if not isinstance(periodic, (bool, np.bool_)):
        raise ValueError(f"periodic must be True or False, got {periodic!r}")
    periodic = bool(periodic)
    if not _is_cupy(heights):
        if isinstance(heights, (str, bytes)) or heights is None:
            raise TypeError(f"heights must be a 2-D real array, got {type(heights).__name__}")
        heights = np.asarray(heights)
        if not (np.issubdtype(heights.dtype, np.floating) or np.issubdtype(heights.dtype, np.integer)):
            raise TypeError(f"heights must be a real array, got dtype {heights.dtype}")
    shape = heights.shape
    if len(shape) != 2:
        raise ValueError(f"heights must be a 2-D array (nx x ny), got shape {shape}")
    if min(shape) < 2:
        raise ValueError(f"heights must be at least 2 x 2, got shape {shape}")
    law = resolve(interaction, gamma0=gamma0, rho=rho, work=work)
    sigma0 = law.check_load(sigma0)
    e_star = chk.positive(e_star, "e_star")
    if isinstance(length, (tuple, list, np.ndarray)):
        if len(length) != 2:
            raise ValueError(f"length must be a number or a pair (Lx, Ly), got {length!r}")
        length = (chk.positive(length[0], "length[0]"), chk.positive(length[1], "length[1]"))
    else:
        length = chk.positive(length, "length")
    tol = chk.positive(tol, "tol")
    if isinstance(max_iter, bool) or not isinstance(max_iter, (int, np.integer)) or max_iter < 1:
        raise ValueError(f"max_iter must be an integer >= 1, got {max_iter!r}")
    minimise, methods = _MINIMISERS[law.load_control] if periodic else _FREE[law.load_control]
    if not isinstance(method, str) or method not in ("auto", *methods):
        raise ValueError(f"method must be one of {', '.join(map(repr, ('auto', *methods)))} for interaction "
                         f"{law.name!r}{'' if periodic else ' with periodic=False'}; got {method!r}")
    if not isinstance(backend, str) or backend not in ("auto", *BACKENDS):
        raise ValueError(f"backend must be one of {', '.join(map(repr, ('auto', *BACKENDS)))}; got {backend!r}")
    if periodic:
        return minimise(heights, law, sigma0=sigma0, e_star=e_star, length=length, tol=tol, method=method,
                        backend=backend, max_iter=max_iter, initial=initial, threads=threads, host=host,
                        t_start=t_start)
    r = minimise(heights, law, sigma0=sigma0, e_star=e_star, length=length, tol=tol, method=method,
                 backend=backend, max_iter=max_iter, initial=initial, threads=threads, host=host, t_start=t_start,
                 periodic=False)
    r.periodic = False
    return r


# Batches of problems of one grid size (gfmd/batched.py): imported last, it builds on solve and _MINIMISERS.
from gapsweep.gfmd.batched import Problem as BatchProblem  # noqa: E402
from gapsweep.gfmd.batched import solve_batch  # noqa: E402
