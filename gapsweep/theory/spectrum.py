"""The height spectrum a theory needs, as shells ``(q_k, v_k)``: wave number [rad/length] and the height variance
``v_k`` [length^2] the shell carries (``sum v_k = h_rms^2``, ``sum q_k^2 v_k = g_rms^2``; docs/theory.md).

Three sources, one representation, so every theory works on any of them:

``self_affine``  the continuum spectrum of docs/model.md M2, ``C(q) = C0 (q/q_l)^(-2H-2)`` on ``[q_l, q_s]``, as
                 Gauss-Legendre nodes in ``ln q`` (``v_k = w_k q_k^2 C(q_k) / (2 pi)``: with the M2 convention
                 ``h~ = sqrt(C/A)`` the variance density is ``dh^2/dq = q C(q) / (2 pi)``).
``from_heights`` the discrete spectrum of one surface: every Fourier mode of its FFT, grouped into shells of
                 equal ``|q|``; rectangular grids (``nx != ny``, ``length = (Lx, Ly)``) are allowed.
``radial``       the radially averaged PSD of a surface, binned in ``|q|`` (continuum form from data).

Conventions (M2): ``h~ = FFT[h] / (nx ny)``, the mean plane (q = 0) is excluded.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from gapsweep import _checks as chk

__all__ = ["Spectrum", "from_heights", "heights_array", "lengths", "radial", "self_affine"]

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


def _power(h: np.ndarray, length) -> tuple[np.ndarray, np.ndarray]:
    lx, ly = lengths(length)
    nx, ny = h.shape
    power = np.abs(np.fft.fft2(h) / h.size) ** 2
    qx = 2.0 * math.pi * np.fft.fftfreq(nx, d=1.0 / nx) / lx
    qy = 2.0 * math.pi * np.fft.fftfreq(ny, d=1.0 / ny) / ly
    return np.hypot(qx[:, None], qy[None, :]).ravel(), power.ravel()


def from_heights(heights: ArrayLike, length: float | tuple[float, float] = 1.0,
                 lambda_l: float | None = None) -> Spectrum:
    """Discrete spectrum of one surface: shells of equal ``|q|`` (rounded to 1e-12 relative), their summed power.

    ``lambda_l`` (default: the longest box side) only sets ``q_l``, the unit of ``zeta``.
    """
    h = heights_array(heights)
    q, power = _power(h, length)
    keep = (q > 0) & (power > 0)
    key = np.round(q[keep] / q[keep].max(), 12)
    _, inv = np.unique(key, return_inverse=True)
    v = np.bincount(inv, weights=power[keep])
    qs = np.bincount(inv, weights=q[keep]) / np.bincount(inv)
    ll = max(lengths(length)) if lambda_l is None else chk.positive(lambda_l, "lambda_l")
    return Spectrum(qs, v, 2.0 * math.pi / ll, "discrete")


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
    ring = np.rint(q / dq).astype(np.int64)
    keep = ring >= 1
    cnt = np.bincount(ring[keep])
    c = np.bincount(ring[keep], weights=power[keep]) * (lx * ly)  # sum of C = A |h~|^2
    idx = np.flatnonzero(cnt)
    c_mean = c[idx] / cnt[idx]
    # mode density of the grid: A / (2 pi)^2 modes per unit area of q-space
    qc = idx * dq
    v = c_mean / (lx * ly) * (2.0 * math.pi * qc * dq) * (lx * ly) / (2.0 * math.pi) ** 2
    ll = max(lx, ly) if lambda_l is None else chk.positive(lambda_l, "lambda_l")
    ok = v > 0
    return Spectrum(qc[ok], v[ok], 2.0 * math.pi / ll, "radial")


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
