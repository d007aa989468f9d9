"""The height spectrum a theory needs, as shells ``(q_k, v_k)``: wave number [rad/length] and the height variance
``v_k`` [length^2] the shell carries (``sum v_k = h_rms^2``, ``sum q_k^2 v_k = g_rms^2``; docs/theory.md).

Three sources, one representation, so every theory works on any of them:

``self_affine``  the continuum spectrum of docs/model.md M2, ``C(q) = C0 (q/q_l)^(-2H-2)`` on ``[q_l, q_s]``, as
                 Gauss-Legendre nodes in ``ln q`` (``v_k = w_k q_k^2 C(q_k) / (2 pi)``: with the M2 convention
                 ``h~ = sqrt(C/A)`` the variance density is ``dh^2/dq = q C(q) / (2 pi)``).
``from_heights`` the discrete spectrum of one surface: every Fourier mode of its FFT, grouped into shells of
                 equal ``|q|``; rectangular grids (``nx != ny``, ``length = (Lx, Ly)``) are allowed.
``radial``       the radially averaged PSD of a surface, binned in ``|q|`` (continuum form from data).

``map_spectrum`` is the one entry for a measured map (periodic or not): it picks the estimator that fits the
data (module section "Maps that are not periodic" below), reports the rms height, slope and curvature it used,
and warns when a non-periodic map is asked for a periodic spectrum. Every theory that takes a map's own
spectrum should go through it.

Conventions (M2): ``h~ = FFT[h] / (nx ny)``, the mean plane (q = 0) is excluded.

Maps that are not periodic (docs/gfmd.md, "Spectra of measured maps"). The FFT treats a map as one period, so
the jump between opposite edges (and any tilt) counts as roughness: a step of the order of ``h_rms`` along two
lines of the map, whose power falls only as ``q^-2`` and so inflates the rms slope (measured: a crop of a
surface of rms slope 1.00 gives 1.56 by the plain FFT). ``map_spectrum`` therefore differentiates inside the map
(forward differences ``Dx h``, ``Dy h`` on the ``(nx-1) x (ny-1)`` pixels that have both neighbours: no edge
jump, and the tilt becomes the excluded q = 0 mode), transforms the two slope fields, and divides their summed
power by the differences' own symbol ``|D(q)|^2 = (2 sin(qx dx/2)/dx)^2 + (2 sin(qy dy/2)/dy)^2``, so that
``v(q) = (|Dx h~|^2 + |Dy h~|^2) / |D(q)|^2``: for a periodic map this is exactly ``|h~(q)|^2`` (the difference
operator is diagonal in Fourier space), so the finite-difference error at high ``q`` is undone rather than
inherited. A window (SurfaceTopography's choice: detrend, then Hann) was measured and rejected: it weights the
map's centre, and for slopes carried by the longest wavelengths (``H > 0.5``) that is a large statistical error
(+19 % and +9 % in the rms slope on two of three crops, against +1.8 % and +1.7 % by the differences).
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from gapsweep.core import checks as chk
from gapsweep.surfaces.topography import EDGE_RATIO_LIMIT, edge_ratio

__all__ = ["EDGE_RATIO_LIMIT", "MapSpectrum", "Spectrum", "edge_ratio", "from_heights", "heights_array", "lengths",
           "map_spectrum", "radial", "self_affine"]

log = logging.getLogger("gapsweep.theory")
#: A map whose edge ratio (:func:`edge_ratio`) exceeds this is taken as not periodic. For a periodic map the
#: wrap-around neighbours are neighbours like any other (ratio about 1; one row's worth of samples, so
#: fluctuations of tens of per cent); a crop has a jump of order ``h_rms`` there (ratio ``h_rms/(g_rms dx)``,
#: typically 5 .. 100).

_GL_ORDER = 20
_PANEL = 0.5  # longest Gauss-Legendre panel in ln q


@dataclass(frozen=True)
class Spectrum:
    """Shells ``q`` (ascending, rad/length) and their height variances ``v`` (length^2); ``q_l`` sets ``zeta``."""

    q: np.ndarray
    v: np.ndarray
    q_l: float
    kind: str  # "continuum", "discrete" or "radial"
    q_s: float | None = None  # upper cut-off of a continuum spectrum
    hurst: float | None = None  # Hurst exponent of a self-affine continuum spectrum

    @property
    def h_rms(self) -> float:
        return float(math.sqrt(np.sum(self.v)))

    @property
    def g_rms(self) -> float:
        return float(math.sqrt(np.sum(self.q**2 * self.v)))

    def cumulative_slope2(self) -> np.ndarray:
        """``g_rms^2`` of the shells up to and including each shell (the ``zeta``-resolved slope variance)."""
        return np.cumsum(self.q**2 * self.v)


def lengths(length: float | tuple[float, float]) -> tuple[float, float]:
    """``length`` as ``(Lx, Ly)``: a number means a square box."""
    if np.ndim(length) == 0:
        lx = chk.positive(length, "length")  # type: ignore[arg-type]
        return lx, lx
    if len(length) != 2:  # type: ignore[arg-type]
        raise ValueError(f"length must be a number or a pair (Lx, Ly), got {length!r}")
    return chk.positive(length[0], "length[0]"), chk.positive(length[1], "length[1]")  # type: ignore[index]


def heights_array(heights: ArrayLike, name: str = "heights") -> np.ndarray:
    """A finite real 2-D height map with at least 2 points along each axis (``nx != ny`` allowed)."""
    h = chk.finite_array(heights, name)
    if h.ndim != 2 or min(h.shape) < 2:
        raise ValueError(f"{name} must be a 2-D array with at least 2 points per axis, got shape {h.shape}")
    return h


def _group_discrete(q: np.ndarray, power: np.ndarray, q_l: float, k2: np.ndarray | None = None) -> Spectrum:
    """Shells of equal ``|q|`` (rounded to 1e-12 relative) with their summed power. ``k2``: the integer
    ``kx^2 + ky^2`` of every mode where the box is square (then ``|q|`` is a function of it): shells by a
    bincount, O(modes), instead of the sort of ``np.unique`` (the same shells: distinct ``k2`` up to 2^40 differ by
    more than 1e-12 in ``|q|``, and equal ``k2`` merge exactly rather than after rounding)."""
    keep = (q > 0) & (power > 0)
    if k2 is not None:
        kk = k2[keep]
        cnt = np.bincount(kk)
        occupied = np.flatnonzero(cnt)
        inv = np.searchsorted(occupied, kk)
        v = np.bincount(inv, weights=power[keep])
        qs = np.bincount(inv, weights=q[keep]) / cnt[occupied]
        return Spectrum(qs, v, q_l, "discrete")
    key = np.round(q[keep] / q[keep].max(), 12)
    _, inv = np.unique(key, return_inverse=True)
    v = np.bincount(inv, weights=power[keep])
    qs = np.bincount(inv, weights=q[keep]) / np.bincount(inv)
    return Spectrum(qs, v, q_l, "discrete")


def _group_radial(q: np.ndarray, power: np.ndarray, lx: float, ly: float, dq: float, q_l: float) -> Spectrum:
    """Rings of width ``dq``: the mean ``C = A |h~|^2`` of each ring times its area in q-space."""
    ring = np.rint(q / dq).astype(np.int64)
    keep = ring >= 1
    cnt = np.bincount(ring[keep])
    c = np.bincount(ring[keep], weights=power[keep]) * (lx * ly)  # sum of C = A |h~|^2
    idx = np.flatnonzero(cnt)
    c_mean = c[idx] / cnt[idx]
    # mode density of the grid: A / (2 pi)^2 modes per unit area of q-space
    qc = idx * dq
    v = c_mean / (lx * ly) * (2.0 * math.pi * qc * dq) * (lx * ly) / (2.0 * math.pi) ** 2
    ok = v > 0
    return Spectrum(qc[ok], v[ok], q_l, "radial")


def _power(h: np.ndarray, length) -> tuple[np.ndarray, np.ndarray]:
    q, power, _ = _power_k2(h, length)
    return q, power


def _power_k2(h: np.ndarray, length) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """``(|q|, |h~|^2, k2)`` of every mode; ``k2 = kx^2 + ky^2`` (integers) where ``Lx = Ly``, else None."""
    lx, ly = lengths(length)
    nx, ny = h.shape
    power = np.abs(np.fft.fft2(h) / h.size) ** 2
    kx = np.fft.fftfreq(nx, d=1.0 / nx)
    ky = np.fft.fftfreq(ny, d=1.0 / ny)
    q = np.hypot(2.0 * math.pi * kx[:, None] / lx, 2.0 * math.pi * ky[None, :] / ly).ravel()
    k2 = None
    if lx == ly:
        ki, kj = kx.astype(np.int64), ky.astype(np.int64)
        k2 = (ki[:, None] ** 2 + kj[None, :] ** 2).ravel()
    return q, power.ravel(), k2


def from_heights(heights: ArrayLike, length: float | tuple[float, float] = 1.0,
                 lambda_l: float | None = None) -> Spectrum:
    """Discrete spectrum of one surface: shells of equal ``|q|`` (rounded to 1e-12 relative), their summed power.

    ``lambda_l`` (default: the longest box side) only sets ``q_l``, the unit of ``zeta``.
    """
    h = heights_array(heights)
    q, power, k2 = _power_k2(h, length)
    ll = max(lengths(length)) if lambda_l is None else chk.positive(lambda_l, "lambda_l")
    return _group_discrete(q, power, 2.0 * math.pi / ll, k2)


def radial(heights: ArrayLike, length: float | tuple[float, float] = 1.0, lambda_l: float | None = None,
           bin_width: float | None = None) -> Spectrum:
    """Radially averaged PSD of one surface as a continuum spectrum: ``C(q)`` averaged in rings of width
    ``dq`` (default ``2 pi / max(Lx, Ly)``), each ring carrying ``v = q C(q) dq / (2 pi)`` at its centre.

    This is the continuum form from data: the shells' discreteness and anisotropy are averaged out, the total
    variance is kept to the quadrature error of the ring sum.
    """
    h = heights_array(heights)
    lx, ly = lengths(length)
    q, power = _power(h, length)
    dq = 2.0 * math.pi / max(lx, ly) if bin_width is None else chk.positive(bin_width, "bin_width")
    ll = max(lx, ly) if lambda_l is None else chk.positive(lambda_l, "lambda_l")
    return _group_radial(q, power, lx, ly, dq, 2.0 * math.pi / ll)


def self_affine(
    hurst: float,
    *,
    lambda_l: float,
    lambda_s: float,
    rms_slope: float | None = None,
    rms_height: float | None = None,
    c0: float | None = None,
    length: float = 1.0,
) -> Spectrum:
    """Continuum M2 spectrum on ``[q_l, q_s]`` as quadrature shells (relative accuracy ~1e-15 for smooth integrands
    in ``ln q``). Exactly one of ``rms_slope``, ``rms_height``, ``c0`` (length^4, M2 convention; ``length`` is
    the box side it refers to, ``h~ = sqrt(C/A)``) fixes the amplitude; none means ``rms_slope=1``."""
    hurst = chk.hurst(hurst)
    lambda_l = chk.positive(lambda_l, "lambda_l")
    lambda_s = chk.positive(lambda_s, "lambda_s")
    if not lambda_s < lambda_l:
        raise ValueError(f"lambda_s must be < lambda_l, got lambda_s={lambda_s!r}, lambda_l={lambda_l!r}")
    given = {k: v for k, v in (("rms_slope", rms_slope), ("rms_height", rms_height), ("c0", c0)) if v is not None}
    if len(given) > 1:
        raise ValueError(f"give at most one of rms_slope, rms_height, c0; got {sorted(given)}")
    ql, qs = 2.0 * math.pi / lambda_l, 2.0 * math.pi / lambda_s
    span = math.log(qs / ql)
    panels = max(1, math.ceil(span / _PANEL))
    x, w = np.polynomial.legendre.leggauss(_GL_ORDER)
    j = np.arange(panels)[:, None]
    t = ((j + 0.5 * (x[None, :] + 1.0)) / panels).ravel() * span
    wt = np.broadcast_to(0.5 * w[None, :] / panels, (panels, _GL_ORDER)).ravel() * span
    q = ql * np.exp(t)
    # dh^2 = q C(q)/(2 pi) dq = q^2 C(q)/(2 pi) d ln q, with C0 = 1 first
    v = wt * q**2 * (q / ql) ** (-2.0 * hurst - 2.0) / (2.0 * math.pi)
    if "c0" in given:
        v = v * chk.positive(c0, "c0")  # type: ignore[arg-type]
    elif "rms_height" in given:
        v = v * (chk.positive(rms_height, "rms_height") ** 2 / np.sum(v))  # type: ignore[arg-type]
    else:
        g = chk.positive(given.get("rms_slope", 1.0), "rms_slope")
        v = v * (g * g / np.sum(q * q * v))
    return Spectrum(q, v, ql, "continuum", q_s=qs, hurst=hurst)


# --------------------------------------------------------------------------------------------------------------
# measured maps
# --------------------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class MapSpectrum:
    """The spectrum of a height map as :func:`map_spectrum` estimated it, with what it used.

    ``spectrum``: the shells (pass to any theory). ``h_rms`` [length], ``g_rms`` (rms slope, dimensionless) and
    ``curvature_rms`` [1/length] (rms mean curvature ``sqrt(sum q^4 v)/2``, ``<(lap h)^2>^(1/2)/2``) of those
    shells. ``periodic``: the treatment used; ``method``: "fft" (plain FFT of the map, periodic) or
    "differences" (slopes inside the map, non-periodic; module docstring). ``edge_ratio``: :func:`edge_ratio`
    of the map; ``looks_periodic``: ``edge_ratio <= EDGE_RATIO_LIMIT``. ``periodic_mismatch``: True when a
    periodic spectrum was asked for a map that does not look periodic (logged as a warning): its slope is then
    inflated by the edge jump."""

    spectrum: Spectrum
    h_rms: float
    g_rms: float
    curvature_rms: float
    periodic: bool
    method: str
    edge_ratio: float
    looks_periodic: bool
    periodic_mismatch: bool


def _difference_power(h: np.ndarray, lx: float, ly: float) -> tuple[np.ndarray, np.ndarray, float, float]:
    """``(|q|, v)`` of every mode on the ``(nx-1) x (ny-1)`` pixels with both forward neighbours (module
    docstring): ``v = (|Dx h~|^2 + |Dy h~|^2)/|D(q)|^2``; and that sub-box's sides."""
    nx, ny = h.shape
    dx, dy = lx / nx, ly / ny
    gx = (h[1:, :-1] - h[:-1, :-1]) / dx
    gy = (h[:-1, 1:] - h[:-1, :-1]) / dy
    mx, my = nx - 1, ny - 1
    power = (np.abs(np.fft.fft2(gx)) ** 2 + np.abs(np.fft.fft2(gy)) ** 2) / float(mx * my) ** 2
    qx = 2.0 * math.pi * np.fft.fftfreq(mx, d=1.0 / mx) / (mx * dx)
    qy = 2.0 * math.pi * np.fft.fftfreq(my, d=1.0 / my) / (my * dy)
    d2 = (2.0 * np.sin(0.5 * qx * dx) / dx)[:, None] ** 2 + (2.0 * np.sin(0.5 * qy * dy) / dy)[None, :] ** 2
    with np.errstate(divide="ignore", invalid="ignore"):
        v = np.where(d2 > 0, power / d2, 0.0)  # q = 0: the mean slope (tilt), excluded like the mean plane
    q = np.hypot(qx[:, None], qy[None, :])
    return q.ravel(), v.ravel(), mx * dx, my * dy


def map_spectrum(heights: Any, length: float | tuple[float, float] | None = None, *, periodic: bool | None = None,
                 lambda_l: float | None = None, form: str = "discrete") -> MapSpectrum:
    """Spectrum of a measured height map, right for the data (module docstring, "Maps that are not periodic";
    docs/gfmd.md, "Spectra of measured maps"; docs/model.md M2 conventions).

    ``heights``: a 2-D array (``nx x ny``, units of ``length``) or a :class:`gapsweep.topography.Topography`
    (its ``length`` and ``periodic`` flag are used unless given here). ``length``: ``Lx`` or ``(Lx, Ly)``
    (default 1 for arrays). ``periodic``: True, the map is one period (plain FFT, every mode exact); False,
    a finite map (slopes by differences inside the map, then FFT; no edge jump, tilt removed); None (default):
    the Topography's flag, else decided by :func:`edge_ratio` ``<= EDGE_RATIO_LIMIT``. Asking for a periodic
    spectrum of a map that does not look periodic logs a warning and sets ``periodic_mismatch``.
    ``form``: "discrete" (shells of equal ``|q|``, as :func:`from_heights`) or "radial" (rings of width
    ``2 pi/max(Lx, Ly)``, as :func:`radial`). ``lambda_l``: sets ``q_l`` only (default the longest side)."""
    from gapsweep.surfaces.topography import Topography  # the loader module imports nothing from here

    topo_periodic = None
    if isinstance(heights, Topography):
        if length is None:
            length = heights.length
        topo_periodic = heights.periodic
        heights = heights.heights
    if form not in ("discrete", "radial"):
        raise ValueError(f"form must be 'discrete' or 'radial', got {form!r}")
    if periodic is not None and not isinstance(periodic, (bool, np.bool_)):
        raise ValueError(f"periodic must be True, False or None, got {periodic!r}")
    h = heights_array(heights)
    lx, ly = lengths(1.0 if length is None else length)
    ratio = edge_ratio(h)
    looks = ratio <= EDGE_RATIO_LIMIT
    asked = periodic if periodic is not None else topo_periodic
    use = bool(asked) if asked is not None else looks
    mismatch = use and not looks
    if mismatch:
        log.warning("map_spectrum: a periodic spectrum was asked for a map that does not look periodic (edge "
                    "ratio %.3g > %.3g): the jump between its edges counts as roughness and inflates the rms "
                    "slope; pass periodic=False", ratio, EDGE_RATIO_LIMIT)
    ll = max(lx, ly) if lambda_l is None else chk.positive(lambda_l, "lambda_l")
    q_l = 2.0 * math.pi / ll
    k2 = None
    if use:
        q, v, k2 = _power_k2(h, (lx, ly))
        bx, by, method = lx, ly, "fft"
    else:
        if min(h.shape) < 3:
            raise ValueError(f"heights: a non-periodic map needs at least 3 points per axis, got {h.shape}")
        q, v, bx, by = _difference_power(h - h.mean(), lx, ly)
        method = "differences"
    if form == "discrete":
        sp = _group_discrete(q, v, q_l, k2)
    else:
        sp = _group_radial(q, v, bx, by, 2.0 * math.pi / max(bx, by), q_l)
    curv = 0.5 * float(math.sqrt(np.sum(sp.q**4 * sp.v)))
    log.debug("map_spectrum: %s, h_rms %.4g, g_rms %.4g, edge ratio %.3g", method, sp.h_rms, sp.g_rms, ratio)
    return MapSpectrum(sp, sp.h_rms, sp.g_rms, curv, use, method, ratio, looks, mismatch)
