"""Persson's contact area for an elastic layer on a rigid base (docs/model.md, "Elastic layer on a rigid base";
docs/theory.md, "Persson's theory").

The layer's stiffness ``k(q) = (E* q/2) f(q t)`` (gapsweep.gfmd.substrates) enters Persson's theory through
``E* -> E* f(q t)`` inside the integral over the roughness (Carbone, Lorenz, Persson & Wohlers, Eur. Phys. J. E
29, 275 (2009); Persson, J. Phys.: Condens. Matter 24, 095008 (2012)): the full-contact pressure variance is

    V_c = (E*^2 / 4) sum_shells q^2 v(q) f(q t)^2          (pressure^2; the half-space: f = 1, V_c = E*^2 g^2/4),

and the contact area follows from it exactly as for the half-space (``gapsweep.theory.persson.contact_area``,
its three variants). ``f -> 1`` for ``q t >> 1`` (the half-space's answer); for ``q t << 1`` on every shell the
variance tends to ``k(0)^2 h_rms^2``, that of a Winkler foundation.

Persson's mean separation (Persson, Phys. Rev. Lett. 99 (2007); Yang & Persson, J. Phys.: Condens.
Matter 20 (2008): ``u(p) = int_p^inf dp'/(A0 p') dU_el/dp'``) with the layer's elastic energy
``U_el / A0 = (1/2) sum_shells k(q) v(q) W(q, p)`` (the half-space's ``(E*/4) sum q v W`` with ``E* -> E* f(q t)``,
Persson 2012) and ``P(q, p)`` from the layer's pressure variance above: with ``s(q)^2 = sum_{q' <= q} q'^2
f(q' t)^2 v(q')`` the same steps as for the half-space give

    u(sigma0) = sqrt(2/pi) sum_shells (q f(q t))^(-1) int_{s_{k-1}}^{s_k} F(sqrt(2) sigma0 / (E* s)) ds,

the half-space's formula (gapsweep.theory.persson.mean_separation) with every wavenumber replaced by the layer's
effective ``q f(q t)`` -- as GFMD's ``LayerGrid`` does. Checked: ``t -> oo`` gives the half-space's value, and
against GFMD on layers of three thicknesses, both bottoms (tests/test_layer.py). The gap distribution with a
layer is not implemented.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike
from scipy.special import erf

from gapsweep.core import checks as chk
from gapsweep.gfmd.substrates import check_layer, layer_factor
from gapsweep.theory import persson
from gapsweep.theory.spectrum import Spectrum

__all__ = ["contact_area", "full_contact_variance", "mean_separation"]


def full_contact_variance(sp, e_star: float, thickness: float, poisson: float, bottom: str) -> float:
    """``V_c`` of the module docstring for the spectrum ``sp`` (gapsweep.theory.spectrum.Spectrum)."""
    f = layer_factor(np.asarray(sp.q, dtype=float) * thickness, poisson, bottom)
    return float(e_star**2 / 4.0 * np.sum(sp.q**2 * sp.v * f**2))


def _layer_inputs(sigma0: ArrayLike, thickness: float, poisson: float | None, bottom: str,
                  e_star: float) -> tuple[tuple[float, float, str], np.ndarray, float]:
    """The checked layer ``(thickness, poisson, bottom)`` (``poisson`` 0 by default with "slip"), ``sigma0`` and
    ``e_star`` shared by :func:`contact_area` and :func:`mean_separation`; a clear error naming the field."""
    if bottom == "slip" and poisson is None:
        poisson = 0.0
    if poisson is None:
        raise ValueError("poisson is needed with bottom='bonded' (-1 < poisson < 0.5)")
    layer = check_layer(thickness, poisson, bottom)
    if layer is None:
        raise ValueError(f"thickness must be a positive, finite number (a length), got {thickness!r}")
    return layer, chk.positive_array(sigma0, "sigma0"), chk.positive(e_star, "e_star")


def contact_area(sigma0: ArrayLike, *, thickness: float, poisson: float | None = None, bottom: str = "bonded",
                 hurst: float | None = None, lambda_l: float | None = None, lambda_s: float | None = None,
                 e_star: float = 1.0, rms_slope: float | None = None, rms_height: float | None = None,
                 c0: float | None = None, length: float | tuple[float, float] = 1.0, variant: str = "persson2001",
                 gamma: float | None = None, heights: ArrayLike | None = None,
                 periodic: bool | None = None) -> float | np.ndarray:
    """Relative contact area ``A/A0`` at mean pressure ``sigma0`` (units of ``e_star``) of a layer of thickness
    ``thickness`` (units of length), Poisson ratio ``poisson`` (needed for "bonded"), ``bottom`` "bonded" or
    "slip"; the spectrum's keywords and ``variant`` as :func:`gapsweep.theory.persson.contact_area`."""
    layer, s, e_star = _layer_inputs(sigma0, thickness, poisson, bottom, e_star)
    gam = persson._gamma(variant, gamma)
    sp = persson._spectrum(hurst, lambda_l, lambda_s, rms_slope, rms_height, c0, length, heights, periodic)
    v_c = full_contact_variance(sp, e_star, *layer)
    v = persson._pressure_variance(s, v_c, variant, gam)
    a = erf(s / np.sqrt(2.0 * v))
    return float(a) if a.ndim == 0 else a


def mean_separation(sigma0: ArrayLike, *, thickness: float, poisson: float | None = None, bottom: str = "bonded",
                    hurst: float | None = None, lambda_l: float | None = None, lambda_s: float | None = None,
                    e_star: float = 1.0, rms_slope: float | None = None, rms_height: float | None = None,
                    c0: float | None = None, length: float | tuple[float, float] = 1.0,
                    gamma: float = persson.GAMMA_YP, heights: ArrayLike | None = None,
                    periodic: bool | None = None) -> float | np.ndarray:
    """Mean interfacial separation ``u(sigma0)`` [length] of a hard-wall contact on a layer of thickness
    ``thickness`` (units of length), Poisson ratio ``poisson`` (needed for "bonded"), ``bottom`` "bonded" or
    "slip" (module docstring; docs/theory.md "Persson's theory"): ``sigma0`` in units of ``e_star``, ``gamma`` the
    elastic-energy factor (0.42, Yang & Persson), the spectrum's keywords as
    :func:`gapsweep.theory.persson.mean_separation`. Vectorised over ``sigma0``."""
    layer, s, e_star = _layer_inputs(sigma0, thickness, poisson, bottom, e_star)
    gam = chk.real(gamma, "gamma")
    if not 0.0 < gam <= 1.5:
        raise ValueError(f"gamma must be in (0, 1.5], got {gamma!r}")
    sp = persson._spectrum(hurst, lambda_l, lambda_s, rms_slope, rms_height, c0, length, heights, periodic)
    f = layer_factor(np.asarray(sp.q, dtype=float) * layer[0], layer[1], layer[2])
    # the layer as a half-space of effective wavenumbers q f(q t), shell by shell (a continuum spectrum on its
    # quadrature shells: the half-space's closed form in q does not hold for q f(q t))
    eff = Spectrum(np.asarray(sp.q, dtype=float) * f, np.asarray(sp.v, dtype=float), float(sp.q_l), "discrete")
    out = persson._u_shells(np.sqrt(2.0) * s.ravel() / e_star, eff, gam).reshape(s.shape)
    return float(out) if out.ndim == 0 else out
