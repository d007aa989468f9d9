"""Estimates of the leak conductance from a gap distribution alone (docs/model.md, "M8 Leakage through the gap").

Both take the distribution in the store's convention: a density ``P(g)`` of the open gap (``g > 0``) that
integrates to ``1 - contact``, and the contact fraction ``contact`` (the atom at ``g = 0``, the relative contact
area). They serve GFMD's gap histogram (``edges``, ``density``, ``contact_atom`` of a store row, or
:func:`gap_density` of a gap field), Persson's/Almqvist's ``theory.persson.gap_distribution`` (points and atom) and
the SDE / Fokker-Planck densities. The local conductivity of a gap ``g`` is ``k(g) = g^3 / (12 mu)`` (Reynolds,
M8); the estimates return an effective conductance ``K`` in the same units (length^3 / (viscosity)), the leak rate
per unit width being ``K dp / L``.

* :func:`bruggeman` -- the 2-D Bruggeman effective-medium estimate (Bruggeman 1935; for seals Bottiglione,
  Carbone, Mantriota, Tribol. Int. 42, 731 (2009); Lorenz & Persson, Eur. Phys. J. E 31, 159 (2010)): ``K`` solves
  ``contact + int P(g) (K - k(g)) / (K + k(g)) dg = 0``. Contact patches are inclusions of zero conductivity;
  the estimate stops conducting at ``contact = 1/2`` (the effective-medium threshold in 2-D).
* :func:`critical_junction` -- Persson's critical-junction estimate (Persson, Albohr, Tartaglino, Volokitin,
  Tosatti, J. Phys.: Condens. Matter 17, R1 (2005); Lorenz & Persson, EPL 86, 44006 (2009)) written on the gap
  distribution (as in Bottiglione et al. 2009): the flow is limited by the narrowest constriction that an open
  path must cross; closing the gaps below ``g_c`` leaves a non-percolating open set when the closed area reaches
  the percolation threshold ``p_c`` (relative contact area 0.42 for self-affine contacts: Dapp, Lucke, Persson &
  Muser, PRL 108, 244301 (2012)), so ``contact + int_0^{g_c} P(g) dg = p_c`` and ``K = g_c^3 / (12 mu)`` (the
  conductance of one junction of unit aspect ratio; Lorenz & Persson's factor of order one is left at 1).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from scipy.optimize import brentq

__all__ = ["DAPP_THRESHOLD", "bruggeman", "critical_gap", "critical_junction", "gap_density"]

# Relative contact area at which the non-contact area stops percolating, self-affine surfaces (Dapp et al. 2012).
DAPP_THRESHOLD = 0.42


def _weights(g: Any, density: Any, contact: float) -> tuple[np.ndarray, np.ndarray, float]:
    """Points and probability weights of the open part, normalised to ``1 - contact``. ``g``: bin edges (one
    more entry than ``density``: midpoint rule) or points (as many as ``density``: trapezoid rule)."""
    g = np.asarray(g, dtype=np.float64).ravel()
    p = np.asarray(density, dtype=np.float64).ravel()
    contact = float(contact)
    if not (math.isfinite(contact) and 0.0 <= contact <= 1.0):
        raise ValueError(f"contact (the relative contact area) must be in [0, 1], got {contact!r}")
    if not (np.all(np.isfinite(g)) and np.all(np.isfinite(p))):
        raise ValueError("gap points/edges and density must be finite")
    if np.any(p < 0):
        raise ValueError("density must be >= 0")
    if g.size == p.size + 1:
        if np.any(np.diff(g) <= 0):
            raise ValueError("gap bin edges must increase")
        x, w = 0.5 * (g[1:] + g[:-1]), p * np.diff(g)
    elif g.size == p.size and g.size >= 2:
        if np.any(np.diff(g) <= 0):
            raise ValueError("gap points must increase")
        dg = np.diff(g)
        w = np.zeros_like(p)
        w[:-1] += 0.5 * dg * p[:-1]
        w[1:] += 0.5 * dg * p[1:]
        x = g
    else:
        raise ValueError(f"gap must be bin edges (len(density) + 1 = {p.size + 1}) or points (len(density) = "
                         f"{p.size} >= 2), got {g.size} values")
    if np.any(x < 0):
        raise ValueError("gaps must be >= 0")
    mass = float(w.sum())
    if contact < 1.0:
        if mass <= 0:
            raise ValueError("the density carries no open area (g > 0) but contact < 1")
        w = w * ((1.0 - contact) / mass)
    else:
        w = np.zeros_like(w)
    return x, w, contact


def gap_density(gap: Any, bins: int = 200, threshold: float = 0.0) -> tuple[np.ndarray, np.ndarray, float]:
    """Histogram of a gap field in the store's convention: ``(edges, density, contact)``, ``contact`` the fraction
    with ``gap <= threshold`` and ``density`` that of the other points (integrating to ``1 - contact``)."""
    g = np.asarray(gap.get() if hasattr(gap, "get") and not isinstance(gap, np.ndarray) else gap,
                   dtype=np.float64).ravel()
    open_ = g > threshold
    contact = 1.0 - float(open_.mean())
    go = g[open_]
    if go.size == 0:
        return np.array([0.0, 1.0]), np.zeros(1), 1.0
    lo, hi = 0.0, float(go.max())
    edges = np.linspace(lo, hi if hi > lo else lo + 1.0, int(bins) + 1)
    counts, _ = np.histogram(go, bins=edges)
    density = counts / (g.size * np.diff(edges))
    return edges, density, contact


def bruggeman(gap: Any, density: Any, contact: float, *, viscosity: float = 1.0) -> float:
    """Bruggeman's 2-D effective-medium conductance ``K`` (module docstring): the root of
    ``contact + sum_k w_k (K - k_k) / (K + k_k) = 0`` with ``k = g^3 / (12 mu)``; 0 when ``contact >= 1/2``.
    ``gap``/``density``/``contact``: the open-gap density and the contact atom (module docstring). Units of ``K``:
    length^3 / viscosity."""
    x, w, c = _weights(gap, density, contact)
    mu = float(viscosity)
    if not (math.isfinite(mu) and mu > 0):
        raise ValueError(f"viscosity must be a positive finite number, got {viscosity!r}")
    if c >= 0.5:
        return 0.0
    k = x ** 3 / (12.0 * mu)
    k, w = k[w > 0], w[w > 0]  # a point at g = 0 keeps its weight: k = 0 there acts as contact

    def f(logk: float) -> float:
        kk = math.exp(logk)
        return c + float(np.sum(w * (kk - k) / (kk + k)))

    if not np.any(k > 0):  # all open weight at g = 0
        return 0.0
    hi = math.log(float(k.max()))
    lo = math.log(float(k[k > 0].min())) - 60.0 if np.any(k > 0) else -700.0
    if f(hi) <= 0:  # round-off: every weight at the largest k
        return float(k.max())
    return math.exp(brentq(f, lo, hi, xtol=1e-12, rtol=1e-12))


def critical_gap(gap: Any, density: Any, contact: float, *, threshold: float = DAPP_THRESHOLD) -> float:
    """The critical gap ``g_c``: ``contact + int_0^{g_c} P(g) dg = threshold`` (0 when ``contact >= threshold``),
    interpolated linearly in the cumulative distribution. Units of the gap."""
    _x, _w, c = _weights(gap, density, contact)  # checks, and the normalisation of the open part
    if not (0.0 < threshold < 1.0):
        raise ValueError(f"threshold must be in (0, 1), got {threshold!r}")
    if c >= threshold:
        return 0.0
    # the cumulative distribution on the nodes (bin edges, or the points with the trapezoid rule), exact for a
    # density that is constant on each bin (edges) or linear between the points
    g = np.asarray(gap, dtype=np.float64).ravel()
    p = np.asarray(density, dtype=np.float64).ravel()
    if g.size == p.size + 1:
        cum = np.concatenate([[0.0], np.cumsum(p * np.diff(g))])
    else:
        cum = np.concatenate([[0.0], np.cumsum(0.5 * np.diff(g) * (p[1:] + p[:-1]))])
    cum = c + cum * ((1.0 - c) / cum[-1])
    i = int(np.searchsorted(cum, threshold))
    if i >= g.size:
        return float(g[-1])
    if i == 0:
        return float(g[0])
    return float(g[i - 1] + (threshold - cum[i - 1]) / (cum[i] - cum[i - 1]) * (g[i] - g[i - 1]))


def critical_junction(gap: Any, density: Any, contact: float, *, viscosity: float = 1.0,
                      threshold: float = DAPP_THRESHOLD) -> float:
    """Persson's critical-junction conductance ``K = g_c^3 / (12 mu)`` with ``g_c`` of :func:`critical_gap`
    (module docstring); 0 when ``contact >= threshold``. Units: length^3 / viscosity."""
    mu = float(viscosity)
    if not (math.isfinite(mu) and mu > 0):
        raise ValueError(f"viscosity must be a positive finite number, got {viscosity!r}")
    return critical_gap(gap, density, contact, threshold=threshold) ** 3 / (12.0 * mu)
