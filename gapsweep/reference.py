"""Analytic solutions of contact mechanics that gapsweep's tests check the solvers against, for users too
(docs/gfmd.md "Reference solutions"; as ContactMechanics ships its ``ReferenceSolutions``).

Units: any consistent set. Lengths (``x``, ``a``, ``radius``, ``amplitude``, ``lam``) in one length unit,
pressures (``pbar``, ``e_star``, returned pressures) in one pressure unit, forces = pressure x length^2, the work
of adhesion ``work`` = pressure x length (energy per area). ``e_star`` is the contact modulus
``E* = E / (1 - nu^2)`` of an elastic half-space against a rigid surface (docs/model.md M1, M3).

* :func:`hertz` -- a parabolic (spherical) indenter on a half-space, hard wall (Hertz 1882; Johnson 1985,
  Contact Mechanics, Eqs. 4.22-4.23).
* :func:`westergaard` -- a 1-D sinusoidal surface pressed flat to partial contact, hard wall (Westergaard 1939;
  Johnson, Eqs. 13.11-13.12).
* :func:`johnson_wavy_adhesion` -- the same surface with adhesion in the JKR limit (Johnson, Int. J. Solids
  Struct. 32, 423, 1995).
* :func:`boussinesq_point`, :func:`boussinesq_rectangle` -- the surface displacement under a point load and under
  a uniform pressure on a rectangle (Boussinesq 1885; Love 1929; Johnson, Eqs. 3.21, 3.25): the Green's function
  of the free-boundary solver (docs/model.md M3: its Fourier transform is the compliance ``2/(E* q)``).

Every function is independent of the solvers except :func:`boussinesq_rectangle`, which is the very kernel the
free-boundary solver integrates (``gapsweep.gfmd._grid.boussinesq_pixel``; tests/test_free_boundaries.py checks it
against numerical quadrature of :func:`boussinesq_point`).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any, NamedTuple

import numpy as np

__all__ = ["Hertz", "JohnsonCurve", "boussinesq_point", "boussinesq_rectangle", "hertz", "johnson_alpha",
           "johnson_wavy_adhesion", "westergaard"]


class Hertz(NamedTuple):
    """Hertz contact of a parabolic indenter ``h(r) = -r^2 / (2 radius)`` [length, pressure, force units]."""

    a: float  #: contact radius
    force: float  #: total normal force ``F = 4 E* a^3 / (3 radius)``
    p0: float  #: peak pressure ``p0 = 3 F / (2 pi a^2) = 2 E* a / (pi radius)``
    depth: float  #: indentation ``d = a^2 / radius``

    def pressure(self, r: Any) -> Any:
        """``p(r) = p0 sqrt(1 - r^2/a^2)`` inside the contact, 0 outside (Johnson Eq. 4.23)."""
        r = np.asarray(r, dtype=float)
        return self.p0 * np.sqrt(np.clip(1.0 - (r / self.a) ** 2, 0.0, None))


def hertz(radius: float, e_star: float = 1.0, *, a: float | None = None, force: float | None = None) -> Hertz:
    """Hertz contact of a sphere of ``radius`` (its parabolic approximation) on a half-space of contact modulus
    ``e_star``, given either the contact radius ``a`` or the force ``force`` (Johnson Eq. 4.22):

        a^3 = 3 F radius / (4 E*),   p0 = 3 F / (2 pi a^2),   d = a^2 / radius.
    """
    if (a is None) == (force is None):
        raise ValueError("hertz: give exactly one of a= and force=")
    if not (radius > 0 and e_star > 0):
        raise ValueError(f"hertz: radius and e_star must be > 0, got {radius!r}, {e_star!r}")
    if a is None:
        if not force > 0:  # type: ignore[operator]
            raise ValueError(f"hertz: force must be > 0, got {force!r}")
        a = (3.0 * float(force) * radius / (4.0 * e_star)) ** (1.0 / 3.0)  # type: ignore[arg-type]
    elif not a > 0:
        raise ValueError(f"hertz: a must be > 0, got {a!r}")
    f = 4.0 * e_star * a**3 / (3.0 * radius)
    return Hertz(a=float(a), force=f, p0=3.0 * f / (2.0 * math.pi * a * a), depth=a * a / radius)


def westergaard(x: Any, pbar: float, amplitude: float, e_star: float = 1.0, lam: float = 1.0) -> tuple[float, Any]:
    """Partial contact of the wave ``h(x) = amplitude cos(2 pi x / lam)`` pressed by the mean pressure ``pbar``
    (hard wall, plane strain; Westergaard 1939, Johnson Eqs. 13.11-13.12). Returns the contact half-width ``a``,

        pbar = p* sin^2(pi a / lam),   p* = pi E* amplitude / lam   (full contact at pbar = p*),

    and the pressure at ``x`` (one period ``0 <= x < lam``, contact centred on ``x = 0``):

        p(x) = 2 pbar cos(pi x/lam) sqrt(sin^2(pi a/lam) - sin^2(pi x/lam)) / sin^2(pi a/lam)   for abs(x) < a.
    """
    pstar = math.pi * e_star * amplitude / lam
    if not 0 < pbar <= pstar:
        raise ValueError(f"westergaard: pbar must be in (0, p* = {pstar:g}], got {pbar!r}")
    s2 = pbar / pstar
    a = lam / math.pi * math.asin(math.sqrt(s2))
    x = np.asarray(x, dtype=float)
    xx = np.where(x > lam / 2, x - lam, x)
    inside = np.abs(xx) < a
    root = np.sqrt(np.clip(s2 - np.sin(np.pi * xx / lam) ** 2, 0.0, None))
    return a, np.where(inside, 2 * pbar * np.cos(np.pi * xx / lam) * root / s2, 0.0)


def johnson_alpha(work: float, amplitude: float, e_star: float = 1.0, lam: float = 1.0) -> float:
    """Johnson's adhesion parameter of the wavy surface: ``alpha^2 = 2 lam w / (pi^2 E* D^2)`` (D = amplitude)."""
    return math.sqrt(2.0 * lam * work / (math.pi**2 * e_star * amplitude**2))


class JohnsonCurve(NamedTuple):
    """Johnson's load-contact curve of the adhesive wave (see :func:`johnson_wavy_adhesion`)."""

    f: Callable[[float], float]  #: ``pbar / p*`` as a function of ``psi = pi a / lam``
    psi_c: float  #: start of the stable (rising) branch: ``f(psi_c)`` is the pull-off pressure under load control
    psi_top: float  #: end of the stable branch (where the contact jumps to full contact)

    @property
    def pull_off(self) -> float:
        """The pull-off mean pressure in units of ``p*`` (negative: tensile)."""
        return self.f(self.psi_c)

    def half_width(self, pbar_over_pstar: float) -> float:
        """``psi = pi a / lam`` on the stable branch at the mean pressure ``pbar / p*``."""
        from scipy.optimize import brentq

        return float(brentq(lambda s: self.f(s) - pbar_over_pstar, self.psi_c, self.psi_top))


def johnson_wavy_adhesion(alpha: float) -> JohnsonCurve:
    """Adhesive contact of the wave ``amplitude cos(2 pi x / lam)`` in the JKR limit (Johnson 1995): with
    ``psi = pi a / lam`` and ``p* = pi E* amplitude / lam``,

        pbar / p* = sin^2 psi - alpha sqrt(tan psi),     alpha = :func:`johnson_alpha`,

    Westergaard's pressure plus the periodic flat-punch term whose stress intensity factor meets Griffith's
    ``K^2 = 2 E* w``. ``alpha = 0`` is :func:`westergaard`. Returns the curve and the ends of its stable branch."""
    from scipy.optimize import brentq

    if not alpha >= 0:
        raise ValueError(f"johnson_wavy_adhesion: alpha must be >= 0, got {alpha!r}")

    def f(psi: float) -> float:
        return math.sin(psi) ** 2 - alpha * math.sqrt(math.tan(psi))

    def fp(psi: float) -> float:
        return math.sin(2 * psi) - alpha / (2 * math.sqrt(math.tan(psi)) * math.cos(psi) ** 2)

    ps = np.linspace(1e-4, 1.5, 20001)
    v = np.array([fp(p) for p in ps])
    if not (v > 0).any():
        raise ValueError(f"johnson_wavy_adhesion: no stable branch for alpha = {alpha!r}")
    i, j = int(np.argmax(v > 0)), len(v) - 1 - int(np.argmax(v[::-1] > 0))
    psi_c = float(brentq(fp, ps[i - 1], ps[i])) if i > 0 else float(ps[0])
    psi_top = float(brentq(fp, ps[j], ps[j + 1])) if j < len(ps) - 1 else float(ps[-1])
    return JohnsonCurve(f, psi_c, psi_top)


def boussinesq_point(r: Any, force: float = 1.0, e_star: float = 1.0) -> Any:
    """Surface displacement at distance ``r`` from a normal point ``force`` on a half-space (Boussinesq 1885;
    Johnson Eq. 3.21 with ``E* = E/(1 - nu^2)``): ``u(r) = force / (pi E* r)``."""
    return force / (math.pi * e_star * np.asarray(r, dtype=float))


def boussinesq_rectangle(x: Any, y: Any, a: float, b: float, e_star: float = 1.0) -> Any:
    """Surface displacement at ``(x, y)`` under a unit uniform pressure on the rectangle ``|x'| <= a, |y'| <= b``
    (Love 1929; Johnson Eq. 3.25), in length per pressure: the integral of :func:`boussinesq_point` over the
    rectangle, in closed form (the free-boundary solver's kernel, ``gapsweep.gfmd._grid.boussinesq_pixel``, whose
    docstring gives the formula). Far from the rectangle it tends to ``4 a b / (pi E* r)``."""
    from gapsweep.gfmd._grid import boussinesq_pixel

    return boussinesq_pixel(np.asarray(x, dtype=float), np.asarray(y, dtype=float), a, b, e_star)
