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

# Package layout: interactions/ (the laws), _solve (the driver: solve), _softmax (the exponential law's
# minimiser), _constrained (hard wall), _smooth (other laws), _free (free boundaries), _ops (array operations,
# numba CPU kernels), _cuda (cupy GPU kernels, kernels.cu), _solvers (cg, lbfgs, fire), _common (helpers),
# _result (GFMDResult), _path (load paths), batched (batches). This file only re-exports: no module of the
# package imports it back. Benchmarks use gfmd._Problem and gfmd._make_ops.
from gapsweep.core.slab import slab_rows
from gapsweep.gfmd import _softmax
from gapsweep.gfmd._common import STATUSES, UnderResolvedWarning, _make_ops, _transfer_modes  # noqa: F401
from gapsweep.gfmd._ops import _have_numba, _is_cupy  # noqa: F401
from gapsweep.gfmd._path import LoadPath, solve_path
from gapsweep.gfmd._plastic import residual_surface
from gapsweep.gfmd._result import GFMDResult
from gapsweep.gfmd._solve import _FREE, _MINIMISERS, solve  # noqa: F401
from gapsweep.gfmd._solvers import _half_q, _Problem  # noqa: F401 - used by benchmarks (gfmd._Problem)
from gapsweep.gfmd.batched import Problem as BatchProblem
from gapsweep.gfmd.batched import solve_batch
from gapsweep.gfmd.interactions import INTERACTIONS, Interaction, resolve  # noqa: F401

__all__ = ["INTERACTIONS", "METHODS", "BatchProblem", "GFMDResult", "Interaction", "LoadPath",
           "UnderResolvedWarning", "residual_surface", "slab_rows", "solve", "solve_batch", "solve_path"]

METHODS = _softmax.METHODS  # methods of the exponential law (the job-spec validator uses this list)
DEFAULT_METHOD = _softmax.DEFAULT_METHOD
