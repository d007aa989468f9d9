"""The driver of GFMD (docs/model.md M3, docs/gfmd.md): :func:`solve` checks its input and hands the problem to
the minimiser of the interaction law's load control, periodic or with free boundaries. Re-exported as
``gapsweep.gfmd.solve``."""

from __future__ import annotations

import functools
import time
import warnings
from typing import Any

import numpy as np

from gapsweep.core import checks as chk
from gapsweep.core.fft import BACKENDS
from gapsweep.gfmd import _bounded, _constrained, _free, _smooth, _softmax
from gapsweep.gfmd._common import UnderResolvedWarning, under_resolved
from gapsweep.gfmd._ops import _is_cupy
from gapsweep.gfmd._result import GFMDResult
from gapsweep.gfmd.interactions import Interaction, resolve

# load_control of a law -> (minimiser, its methods). A new law reuses one of these; no branch per law.
_MINIMISERS: dict[str, tuple[Any, tuple[str, ...]]] = {
    "softmax": (_softmax.minimise, _softmax.METHODS),
    "multiplier": (_constrained.minimise, _constrained.METHODS),
    "variable": (_smooth.minimise, _smooth.METHODS),
    "bounded": (_bounded.minimise, _bounded.METHODS),
}
# Minimisers that take periodic=False (free boundaries), by load_control: the hard wall's own (its compliance
# swapped for the free one), every smooth law (the exponential one included) on gfmd._free.
_FREE: dict[str, tuple[Any, tuple[str, ...]]] = {
    "multiplier": (_constrained.minimise, _constrained.METHODS),
    "softmax": (_free.minimise, _free.METHODS),
    "variable": (_free.minimise, _free.METHODS),
    "bounded": (_bounded.minimise, _bounded.METHODS),  # refuses periodic=False with a clear message
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
    comm: Any = None,
    start: str = "flat",
    levels: int | None = None,
    coarse_tol: float | None = None,
    thickness: float | None = None,
    poisson: float | None = None,
    bottom: str = "bonded",
    hardness: float | None = None,
    memory: int | None = None,
) -> GFMDResult:
    """Equilibrium gap of an elastic half-space on the rigid surface ``heights`` at mean pressure ``sigma0``.

    ``interaction``: a law's name or an :class:`Interaction` object (docs/gfmd.md): "exponential" (default;
    needs ``gamma0``, an energy per area, and ``rho``, a length), "hard_wall", "adhesive" (``work``, the
    work of adhesion per area, and ``rho``, its range) or "hard_wall_adhesive" (the contact-mechanics
    challenge's hard wall with ``-work exp(-g/rho)``; ``work``, ``rho``; periodic, on one process or over ranks
    with ``comm``; docs/gfmd.md "Hard wall with adhesion"). For the exponential law the reduced energy of M3
    (module docstring) is minimised until ``residual <= tol`` and ``load_error <= tol``; the other laws'
    convergence measures are in docs/gfmd.md. ``heights``: real ``nx x ny`` array (numpy, or cupy for the
    GPU), units of ``length`` (a number, or ``(Lx, Ly)``); the exponential law's own minimiser needs a square
    grid, other grids run on the generic smooth one. ``sigma0``, ``gamma0/rho`` and ``e_star`` are pressures in
    one unit. ``method``: "auto", or "cg" (default), "lbfgs", "fire" (exponential); "mpcg" (default on the CPU;
    coarse-to-fine start), "pcg" (default on the GPU), "pk" (hard wall); "lbfgs" (adhesive);
    "plbfgs" (hard_wall_adhesive). ``backend``: "auto"
    (cupy for a cupy array, else pyfftw when installed, else numpy), "numpy", "pyfftw" or "cupy". ``max_iter``:
    force evaluations (hard wall: iterations) allowed.
    ``initial``: an earlier result or a field to start from (exponential: a displacement on any grid size,
    shared Fourier modes carried over; hard wall: a pressure; adhesive: ``(displacement, mean gap)``;
    hard_wall_adhesive: a gap field); default
    for the exponential law is the linear response of M4. ``threads``: FFTW threads. ``host``: which fields of
    a cupy run come to the host (pinned, asynchronous copies): True (all), False (none: they stay on the GPU) or
    names such as ``("gap",)``. Warns (UnderResolvedWarning) when the law's range ``rho`` is below the grid
    spacing ``max(Lx/nx, Ly/ny)`` (M7; every law with a range, every grid shape, periodic or free).

    ``periodic``: True, the map is one period of a periodic surface (docs/model.md M1); False, a finite map on
    an elastic half-space with free boundaries (docs/gfmd.md, "Periodic or free boundaries"): the Boussinesq
    response of the map's pixels on a grid padded to twice the map, pressure only on the map, ``sigma0`` the
    mean pressure over the map's own area (load = ``sigma0 Lx Ly``); every law (hard wall: its own methods;
    exponential and adhesive: "lbfgs" on ``gfmd._free``), on the CPU and the GPU (cupy).
    Default (None): a :class:`gapsweep.topography.Topography` passed as ``heights`` brings its own
    ``periodic`` flag and its ``length`` (a ``length`` given here must then be left at 1.0); arrays are periodic.

    ``comm``: an mpi4py communicator: one solve split over its ranks (docs/gfmd.md, "One solve over several
    processes"; :func:`gapsweep.gfmd.distributed.solve`): ``heights`` is then this rank's rows
    ``h[gapsweep.gfmd.slab_rows(nx, comm)]``, every rank calls ``solve`` with the same arguments, and the result
    (a ``SlabResult``) holds the global scalars on every rank and this rank's rows of the fields. Periodic only;
    ``threads`` is ignored there.

    ``start``: "flat" (default; the starts above) or "coarse": the coarse-to-fine start (docs/gfmd.md,
    "Coarse-to-fine start"; exponential and adhesive laws, hard_wall_adhesive, periodic, compressive loads): the
    problem solved first on ``levels`` grids coarser by 2, 4, ... (None: down to 64 pixels a side) to
    ``coarse_tol`` (None: 10 ``tol``), each started from the one before, the last one starting this grid. With
    ``comm`` (and on one GPU) it runs on the distributed solver's minimisers
    (:func:`gapsweep.gfmd.distributed.solve`) and returns a ``SlabResult``; without ``comm`` on the CPU on this
    function's own minimisers, methods and FFT backend (:func:`gapsweep.gfmd._coarse.solve_local`: never the
    slower engine) and returns a ``GFMDResult``. Either
    way ``diagnostics["levels"]`` lists the coarse levels and ``diagnostics["coarse_cost"]`` their cost.

    ``thickness``, ``poisson``, ``bottom``: the body is an elastic layer of thickness ``t`` (units of ``length``;
    None: the half-space) and Poisson ratio ``-1 < nu < 0.5`` on a rigid base, "bonded" (no slip; needs
    ``poisson``) or "slip" (frictionless; its stiffness does not depend on ``nu``), ``e_star`` its contact
    modulus ``E/(1 - nu^2)`` (docs/model.md, "Elastic layer on a rigid base"; :mod:`gapsweep.gfmd.substrates`).
    Periodic, one process; every law. ``hardness``: the hard wall's pressure cap ``H > sigma0`` (elastic-perfectly
    plastic contact, :mod:`gapsweep.gfmd._plastic`; ``result.plastic_area``, ``result.plastic_displacement``,
    :func:`gapsweep.gfmd.residual_surface`); periodic or free boundaries, on the half-space or a layer.

    ``memory``: L-BFGS pairs of the hard_wall_adhesive law (default 10; each pair costs two grid fields, see
    ``gapsweep.gfmd._bounded.memory_plan``) and, with ``comm``, of the distributed smooth laws (default 2).
    """
    from gapsweep.gfmd import _plastic, substrates

    layer = _checked_layer(thickness, poisson, bottom, hardness, comm, start)
    if start != "flat" and comm is None:
        if start != "coarse":
            raise ValueError(f"start must be 'flat' or 'coarse', got {start!r}")
        if periodic is False:
            raise ValueError("start='coarse' is for periodic surfaces (periodic=True)")
        if not _is_cupy(heights):  # the CPU: the plain minimisers and their FFT engine (gfmd._coarse)
            return _coarse_local(heights, sigma0=sigma0, interaction=interaction, gamma0=gamma0, rho=rho,
                                 work=work, e_star=e_star, length=length, tol=tol, method=method, backend=backend,
                                 max_iter=max_iter, initial=initial, threads=threads, host=host, levels=levels,
                                 coarse_tol=coarse_tol)
        from gapsweep.gfmd._coarse import SelfComm

        comm = SelfComm()  # one GPU: the distributed solver on one rank (its memory plan, docs/gfmd.md)
    if comm is not None:
        if periodic is False:
            raise ValueError("comm: a distributed solve is periodic (free boundaries run on one process)")
        from gapsweep.gfmd import distributed

        return distributed.solve(heights, comm=comm, sigma0=sigma0, interaction=interaction, gamma0=gamma0,
                                 rho=rho, work=work, e_star=e_star, length=length, tol=tol, method=method,
                                 backend=backend, max_iter=max_iter, initial=initial, host=host, start=start,
                                 levels=levels, coarse_tol=coarse_tol, memory=memory)
    t_start = time.perf_counter()
    heights, length, periodic = _checked_heights(heights, length, periodic)
    shape = heights.shape
    law = resolve(interaction, gamma0=gamma0, rho=rho, work=work)
    sigma0 = law.check_load(sigma0)
    e_star = chk.positive(e_star, "e_star")
    length = _checked_length(length)
    tol = chk.positive(tol, "tol")
    if isinstance(max_iter, bool) or not isinstance(max_iter, (int, np.integer)) or max_iter < 1:
        raise ValueError(f"max_iter must be an integer >= 1, got {max_iter!r}")
    minimise = _checked_minimiser(law, periodic, memory, method, backend)
    text = under_resolved(law, shape, length)
    if text is not None:  # every law with a range, every grid shape and boundary (docs/gfmd.md, "Warnings")
        warnings.warn(text, UnderResolvedWarning, stacklevel=2)
    if layer is not None or hardness is not None:
        cap = _plastic.check_hardness(hardness, sigma0)
        if cap is not None and law.name != "hard_wall":
            raise ValueError(f"hardness: the pressure cap is for interaction='hard_wall', got {law.name!r}")
        if layer is not None or cap is not None:
            r = substrates.minimise_on(heights, law, layer=layer, hardness=cap, sigma0=sigma0, e_star=e_star,
                                       length=length, tol=tol, method=method, backend=backend, max_iter=max_iter,
                                       initial=initial, threads=threads, host=host, t_start=t_start,
                                       periodic=periodic)
            r.periodic = periodic
            return r
    if periodic:
        return minimise(heights, law, sigma0=sigma0, e_star=e_star, length=length, tol=tol, method=method,
                        backend=backend, max_iter=max_iter, initial=initial, threads=threads, host=host,
                        t_start=t_start)
    r = minimise(heights, law, sigma0=sigma0, e_star=e_star, length=length, tol=tol, method=method,
                 backend=backend, max_iter=max_iter, initial=initial, threads=threads, host=host, t_start=t_start,
                 periodic=False)
    r.periodic = False
    return r


def _checked_minimiser(law: Any, periodic: bool, memory: Any, method: Any, backend: Any) -> Any:
    """The minimiser of ``law`` on this boundary (with ``memory`` L-BFGS pairs where given: the bounded
    minimiser's on one process), after checking ``memory``, ``method`` and ``backend`` (ValueError naming each)."""
    minimise, methods = _MINIMISERS[law.load_control] if periodic else _FREE[law.load_control]
    if memory is not None:
        if isinstance(memory, bool) or not isinstance(memory, (int, np.integer)) or memory < 1:
            raise ValueError(f"memory must be an integer >= 1, got {memory!r}")
        if law.load_control != "bounded":
            raise ValueError(f"memory: the L-BFGS pairs are set for interaction 'hard_wall_adhesive' (and with "
                             f"comm= for the smooth laws); interaction {law.name!r} on one process keeps its own")
        minimise = functools.partial(minimise, memory=int(memory))
    if not isinstance(method, str) or method not in ("auto", *methods):
        raise ValueError(f"method must be one of {', '.join(map(repr, ('auto', *methods)))} for interaction "
                         f"{law.name!r}{'' if periodic else ' with periodic=False'}; got {method!r}")
    if not isinstance(backend, str) or backend not in ("auto", *BACKENDS):
        raise ValueError(f"backend must be one of {', '.join(map(repr, ('auto', *BACKENDS)))}; got {backend!r}")
    return minimise


def _checked_layer(thickness: Any, poisson: Any, bottom: str, hardness: Any, comm: Any, start: str) -> Any:
    """The elastic layer of ``thickness``, ``poisson``, ``bottom`` (gfmd.substrates; None: the half-space);
    a layer or a pressure cap only on one process from the flat start."""
    from gapsweep.gfmd import substrates

    if bottom == "slip" and poisson is None:
        poisson = 0.0  # the slip layer's stiffness in E* does not depend on nu
    if thickness is not None and poisson is None:
        raise ValueError("poisson is needed with thickness and bottom='bonded' (-1 < poisson < 0.5)")
    layer = substrates.check_layer(thickness, poisson, bottom)
    if (layer is not None or hardness is not None) and (comm is not None or start != "flat"):
        raise ValueError("thickness / hardness: solved on one process from the flat start (comm=None, "
                         "start='flat')")
    return layer


def _checked_heights(heights: Any, length: Any, periodic: Any) -> tuple[Any, Any, bool]:
    """``(heights array, length, periodic)`` of a one-process solve: a Topography's own map, length and boundary
    taken over; the array checked (2-D, real, at least 2 x 2; numpy or cupy)."""
    from gapsweep.surfaces.topography import Topography

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
    return heights, length, periodic


def _checked_length(length: Any) -> Any:
    """``length``: a positive number or a pair ``(Lx, Ly)`` of them."""
    if isinstance(length, (tuple, list, np.ndarray)):
        if len(length) != 2:
            raise ValueError(f"length must be a number or a pair (Lx, Ly), got {length!r}")
        length = (chk.positive(length[0], "length[0]"), chk.positive(length[1], "length[1]"))
    else:
        length = chk.positive(length, "length")
    return length


def _coarse_local(heights: Any, *, sigma0: float, interaction: Any, gamma0: Any, rho: Any, work: Any, e_star: float,
                  length: Any, tol: float, method: str, backend: str, max_iter: int, initial: Any,
                  threads: int | None, host: Any, levels: Any, coarse_tol: Any) -> GFMDResult:
    """``start="coarse"`` on one CPU process (docs/gfmd.md, "Coarse-to-fine start"): checked as the distributed
    start, then :func:`gapsweep.gfmd._coarse.solve_local` on this module's plain solve (the same minimisers,
    methods and FFT backend as ``start="flat"``)."""
    from gapsweep.gfmd import _coarse
    from gapsweep.gfmd._lean import SINK_RANGES
    from gapsweep.gfmd.distributed import _check_coarse
    from gapsweep.surfaces.topography import Topography

    if isinstance(heights, Topography):
        if length != 1.0 and tuple(np.broadcast_to(length, 2)) != tuple(heights.length):
            raise ValueError(f"length={length!r} contradicts the Topography's own length {heights.length}; "
                             "leave length out when passing a Topography")
        if not heights.periodic:
            raise ValueError("start='coarse' is for periodic surfaces (periodic=True)")
        length, heights = tuple(heights.length), heights.heights
    h = np.asarray(heights)
    if not (np.issubdtype(h.dtype, np.floating) or np.issubdtype(h.dtype, np.integer)):
        raise TypeError(f"heights must be a real array, got dtype {h.dtype}")
    if h.ndim != 2 or min(h.shape) < 2:
        raise ValueError(f"heights must be a 2-D array of at least 2 x 2, got shape {h.shape}")
    h = np.asarray(h, dtype=np.float64)
    if not np.all(np.isfinite(h)):
        raise ValueError("heights contain NaN or inf")
    law = resolve(interaction, gamma0=gamma0, rho=rho, work=work)
    sigma0 = law.check_load(sigma0)
    tol = chk.positive(tol, "tol")
    lx, ly = (chk.positive(v, "length") for v in np.broadcast_to(np.asarray(length, dtype=float), 2))
    n_levels, ctol = _check_coarse(law, law.load_control, sigma0, initial, levels, coarse_tol, tol, h.shape, 1)
    smooth = law.load_control != "softmax" or h.shape[0] != h.shape[1] or lx != ly
    common = dict(sigma0=sigma0, interaction=law, e_star=e_star, length=length, method=method, backend=backend,
                  max_iter=max_iter, threads=threads, periodic=True)

    def plain(hl: Any, init: Any, kw: dict) -> GFMDResult:
        if law.load_control == "bounded" and isinstance(init, tuple):  # (u, <g>) of the body surface: its gap
            u, g0 = init
            init = u + g0 - (hl - float(np.mean(hl)))
        return solve(hl, initial=init, **common, **kw)

    return _coarse.solve_local(h, plain, length=(lx, ly), backend=backend, threads=threads, levels=n_levels,
                               smooth=smooth, sink=SINK_RANGES * (law.range() or 0.0),
                               level_kw=dict(tol=ctol, host=True), fine_kw=dict(tol=tol, host=host))
