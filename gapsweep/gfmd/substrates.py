"""Substrates other than the elastic half-space (docs/model.md M3, "Elastic layer on a rigid base").

An elastic layer of thickness ``t`` (Poisson ratio ``nu``, contact modulus ``E* = E/(1 - nu^2)``) on a rigid base,
loaded by a normal pressure on its free surface (no surface shear). Its surface stiffness for the Fourier mode
``q = |q|`` (``p~ = k(q) u~``, pressure / length) is the half-space's ``E* q / 2`` times a factor of ``x = q t``:

    bonded base (no slip, u = 0 at z = t):
        f_b(x) = [ (3 - 4 nu) cosh 2x + 2 x^2 + 5 - 12 nu + 8 nu^2 ] / [ (3 - 4 nu) sinh 2x - 2x ]
    frictionless base (free slip: u_z = 0 and no shear at z = t):
        f_s(x) = (sinh 2x + 2x) / (cosh 2x - 1)

(Carbone & Mangialardi, J. Mech. Phys. Solids 56, 684 (2008), Eq. A.30, the bonded case, as coded in
ContactMechanics' PeriodicFFTElasticHalfSpace(thickness=...); the slip case from the same plane-strain
boundary-value problem with the base's conditions exchanged; both checked against a direct solve of that problem
in tests/test_layer.py). ``f -> 1`` as ``x -> oo`` (the half-space); as ``x -> 0``
``k -> E* (1 - nu)^2 / ((1 - 2 nu) t) = E (1 - nu) / ((1 + nu)(1 - 2 nu) t)`` (bonded: the confined, oedometric
modulus over t) and ``k -> E* / t`` (slip: plane-strain uniaxial stress over t). The mean mode ``q = 0`` only
places the rigid base (the gap does not depend on it): the solvers keep ``<u> = 0`` as for the half-space, and
:func:`mean_compression` gives the layer's mean compression ``sigma0 / k(0)``.

:class:`LayerGrid` is the periodic :class:`gapsweep.gfmd._grid.Grid` whose ``q`` is the effective wavenumber
``q f(q t)``, so every minimiser that builds its operator from ``(E*/2) grid.q`` (hard wall, smooth laws) solves
the layer unchanged, on numpy or cupy arrays."""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from gapsweep.gfmd._grid import Grid

BOTTOMS = ("bonded", "slip")


def check_layer(thickness: Any, poisson: Any, bottom: Any) -> tuple[float, float, str] | None:
    """Validated ``(thickness, poisson, bottom)``, or None for the half-space (``thickness`` None or inf).
    ``thickness`` > 0 (a length, units of ``length``), ``-1 < poisson < 0.5``, ``bottom`` in :data:`BOTTOMS`."""
    if thickness is None:
        return None
    if isinstance(thickness, bool) or not isinstance(thickness, (int, float, np.integer, np.floating)):
        raise ValueError(f"thickness must be a positive number (a length) or None, got {thickness!r}")
    thickness = float(thickness)
    if math.isinf(thickness) and thickness > 0:
        return None
    if not (math.isfinite(thickness) and thickness > 0):
        raise ValueError(f"thickness must be a positive number (a length) or None, got {thickness!r}")
    if isinstance(poisson, bool) or not isinstance(poisson, (int, float, np.integer, np.floating)) \
            or not (-1.0 < float(poisson) < 0.5):
        raise ValueError(f"poisson must be a number with -1 < poisson < 0.5, got {poisson!r}")
    if bottom not in BOTTOMS:
        raise ValueError(f"bottom must be one of {', '.join(map(repr, BOTTOMS))}, got {bottom!r}")
    return thickness, float(poisson), str(bottom)


def _sinh2x_minus_2x(x: Any, xp: Any) -> Any:
    """``(sinh 2x - 2x) e^{-2x}`` without cancellation (a series below x = 0.1)."""
    y = 2.0 * x
    y2 = y * y
    series = y * y2 / 6.0 * (1.0 + y2 / 20.0 * (1.0 + y2 / 42.0 * (1.0 + y2 / 72.0 * (1.0 + y2 / 110.0))))
    e = xp.exp(-y)
    direct = -0.5 * xp.expm1(-2.0 * y) - y * e
    return xp.where(x < 0.1, series * e, direct)


def layer_factor(x: Any, poisson: float, bottom: str, xp: Any = np) -> Any:
    """``k(q) / (E* q / 2)`` at ``x = q t >= 0`` (module docstring), evaluated with every hyperbolic function
    scaled by ``e^{-2x}`` (no overflow at any ``x``); ``inf`` at ``x = 0``."""
    x = xp.asarray(x, dtype=xp.float64)
    e = xp.exp(-2.0 * x)
    sh = -0.5 * xp.expm1(-4.0 * x)  # sinh(2x) e^{-2x}
    ch = 0.5 * (1.0 + e * e)  # cosh(2x) e^{-2x}
    with np.errstate(divide="ignore", invalid="ignore"):
        if bottom == "bonded":
            nu = poisson
            fac = 3.0 - 4.0 * nu
            num = fac * ch + (2.0 * x * x + 5.0 - 12.0 * nu + 8.0 * nu * nu) * e
            den = (fac - 1.0) * sh + _sinh2x_minus_2x(x, xp)
        elif bottom == "slip":
            num = sh + 2.0 * x * e
            den = 0.5 * (-xp.expm1(-2.0 * x)) ** 2  # (cosh 2x - 1) e^{-2x} = 2 sinh^2 x e^{-2x}
        else:
            raise ValueError(f"bottom must be one of {BOTTOMS}, got {bottom!r}")
        return xp.where(x > 0, num / den, xp.inf)


def stiffness(q: Any, e_star: float, thickness: float, poisson: float, bottom: str, xp: Any = np) -> Any:
    """Surface stiffness ``k(q) = (E* q / 2) f(q t)`` of the layer (pressure / length; module docstring); at
    ``q = 0`` the limit ``k(0)`` (:func:`stiffness_q0`)."""
    q = xp.asarray(q, dtype=xp.float64)
    with np.errstate(invalid="ignore"):
        k = (0.5 * e_star) * q * layer_factor(q * thickness, poisson, bottom, xp)
    return xp.where(q > 0, k, stiffness_q0(e_star, thickness, poisson, bottom))


def stiffness_q0(e_star: float, thickness: float, poisson: float, bottom: str) -> float:
    """``k(q -> 0)``: ``E* (1 - nu)^2 / ((1 - 2 nu) t)`` (bonded: confined compression) or ``E* / t`` (slip)."""
    if bottom == "bonded":
        return e_star * (1.0 - poisson) ** 2 / ((1.0 - 2.0 * poisson) * thickness)
    return e_star / thickness


def mean_compression(sigma0: float, e_star: float, thickness: float, poisson: float, bottom: str) -> float:
    """The layer's mean compression ``sigma0 / k(0)`` (length): how far the rigid base lies below where the
    mean of the body's surface would be without load (not part of the gap)."""
    return sigma0 / stiffness_q0(e_star, thickness, poisson, bottom)


class LayerGrid(Grid):
    """A periodic grid on an elastic layer: :class:`Grid` with ``q`` replaced by the effective wavenumber
    ``q f(q t)`` (module docstring), 0 at ``q = 0`` (the mean mode stays eliminated)."""

    plain_periodic = True  # one whole periodic grid: the hard wall's FFTW spectral loop applies (gfmd._constrained)

    def __init__(self, shape: tuple[int, int], length: Any, backend: str, threads: int | None, on_gpu: bool,
                 *, thickness: float, poisson: float, bottom: str) -> None:
        super().__init__(shape, length, backend, threads, on_gpu)
        xp = self.xp
        self.q_geometric = self.q
        f = layer_factor(self.q * thickness, poisson, bottom, xp)
        with np.errstate(invalid="ignore"):
            self.q = xp.where(self.q > 0, self.q * f, 0.0)
        self.thickness, self.poisson, self.bottom = thickness, poisson, bottom


def minimise_on(heights: Any, law: Any, *, layer: tuple[float, float, str] | None, hardness: float | None,
                sigma0: float, e_star: float, length: Any, tol: float, method: str, backend: str, max_iter: int,
                initial: Any, threads: int | None, host: Any, t_start: float, periodic: bool) -> Any:
    """The solve of ``gfmd.solve`` on a layer (``layer``: validated ``(thickness, poisson, bottom)``) and/or with
    the hard wall's pressure cap ``hardness`` (gapsweep.gfmd._plastic). Free boundaries take the cap on the
    half-space; a layer is periodic only (its free-boundary Green's function is not implemented: a clear
    refusal)."""
    from gapsweep.gfmd import _constrained, _plastic, _smooth
    from gapsweep.gfmd._ops import _is_cupy

    if layer is not None and not periodic:
        raise ValueError("thickness: an elastic layer is solved with periodic boundaries only (periodic=True); "
                         "the free-boundary response of a layer is not implemented")
    on_gpu = _is_cupy(heights)

    def make_grid(shape: tuple[int, int]) -> Grid:
        assert layer is not None
        return LayerGrid(shape, length, backend, threads, on_gpu, thickness=layer[0], poisson=layer[1],
                         bottom=layer[2])

    common = dict(sigma0=sigma0, e_star=e_star, length=length, tol=tol, backend=backend, max_iter=max_iter,
                  initial=initial, threads=threads, host=host, t_start=t_start)
    if hardness is not None:
        if law.load_control != "multiplier":
            raise ValueError(f"hardness: the pressure cap is for interaction='hard_wall', got {law.name!r}")
        r = _plastic.minimise(heights, law, hardness=hardness, method=method, periodic=periodic,
                              make_grid=make_grid if layer is not None else None, **common)
    else:
        assert layer is not None
        grid = make_grid(heights.shape)
        if law.load_control == "multiplier":
            # "mpcg"'s coarse levels are half-space solves (gfmd._constrained._coarse_start): a layer takes "pcg"
            if method not in ("auto", "pk", "pcg"):
                raise ValueError(f"method must be 'auto', 'pk' or 'pcg' for the hard wall on a layer; got {method!r}")
            coarse: list[int] = []
            if method == "auto" and initial is None and min(grid.shape) >= 2 * _constrained._COARSEST \
                    and grid.shape[0] % 2 == 0 and grid.shape[1] % 2 == 0:
                # coarse-to-fine start on the layer (as the half-space's "mpcg"): the coarsened surface solved
                # on the same layer to _COARSE_TOL, recursively, its pressure copied to 2 x 2 pixels
                xp = grid.xp
                h = grid.asarray(heights)
                hc = _constrained.coarsen(h - grid.mean(h), xp)
                rc = minimise_on(hc, law, layer=layer, hardness=None, sigma0=sigma0, e_star=e_star, length=length,
                                 tol=_constrained._COARSE_TOL, method="auto", backend=backend, max_iter=2000,
                                 initial=None, threads=threads, host=False, t_start=t_start, periodic=True)
                common["initial"] = xp.repeat(xp.repeat(rc.pressure, 2, axis=0), 2, axis=1)
                coarse = [rc.iterations, *rc.diagnostics.get("coarse_iterations", [])]
            r = _constrained.minimise(heights, law, method="pcg" if method == "auto" else method, grid=grid,
                                      **common)
            r.diagnostics["coarse_iterations"] = coarse
        elif law.load_control == "softmax" and grid.xp is np and grid.shape[0] == grid.shape[1] \
                and grid.lx == grid.ly:
            # the exponential law's own minimiser with the layer's stiffness (CPU, square grids)
            from gapsweep.gfmd import _softmax

            if method not in ("auto", *_softmax.METHODS):
                raise ValueError(f"method must be one of {('auto', *_softmax.METHODS)} for interaction "
                                 f"{law.name!r} on a layer; got {method!r}")
            r = _softmax.minimise(heights, law, method=method, stiffness=np.ascontiguousarray(
                (0.5 * e_star) * grid.q), **{**common, "length": grid.lx})
        elif law.load_control == "bounded":
            raise ValueError(f"thickness: interaction {law.name!r} (a bound-constrained minimiser) is not available "
                             "on an elastic layer yet; use the half-space (no thickness)")
        else:
            # the exponential law on the GPU or a rectangular grid, the adhesive law: the generic smooth minimiser
            # (gfmd._smooth, L-BFGS; the exponential law's fused GPU kernels assume the half-space)
            if method not in ("auto", "lbfgs"):
                raise ValueError(f"method must be 'auto' or 'lbfgs' for interaction {law.name!r} on a layer; "
                                 f"got {method!r}")
            r = _smooth.minimise(heights, law, method="lbfgs", grid=grid, **common)
    if layer is not None:
        t, nu, bottom = layer
        r.substrate = {"thickness": t, "poisson": nu, "bottom": bottom,
                       "mean_compression": mean_compression(sigma0, e_star, t, nu, bottom)}
    return r
