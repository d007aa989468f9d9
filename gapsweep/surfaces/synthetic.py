"""Self-affine random-phase rough surfaces (docs/model.md M2).

A surface is ``h(r) = sum_q h~(q) exp(i q.r)`` on a periodic ``n x n`` grid of side ``length`` (M1), with
``q = 2 pi (kx, ky) / length`` and the isotropic power spectrum

    C(q) = C0 (q / q_l)^(-2H-2)   for q_l <= |q| <= q_s,   zero elsewhere,

``q_l = 2 pi / lambda_l``, ``q_s = 2 pi / lambda_s``. With a roll-off wavelength ``lambda_r`` (``lambda_s <
lambda_r <= lambda_l``; the spectrum of the contact-mechanics challenge, docs/model.md "The contact-mechanics
challenge") the spectrum is constant below the roll-off instead:

    C(q) = C0   for q_l <= |q| < q_r,     C0 (q / q_r)^(-2H-2)   for q_r <= |q| <= q_s,

``q_r = 2 pi / lambda_r``; ``lambda_l`` is then the longest wavelength kept (the box side for the challenge).

Amplitudes follow M2: ``h~(q) = sqrt(C(q)/A) exp(2 pi i X_q)``
(``amplitudes="fixed"``, the paper's choice) or a complex Gaussian of the same mean square (``"gaussian"``,
Rayleigh amplitudes). Array axis 0 is x, axis 1 is y; heights carry the units of ``length``.

Resolution independence (M2): the random numbers of a mode are a counter-based hash of ``(seed, kx, ky)``, not a
draw from a sequential stream, and the mode set ``q_l <= |q| <= q_s`` does not depend on ``n``. Hence one seed
gives the same ``h~(q)`` on every grid that carries ``q_s``, and the surface at ``2n`` is the surface at ``n``
sampled twice as finely (up to rounding). Normalisation by ``rms_slope`` or ``rms_height`` is applied to that
fixed mode set, so it holds exactly (to rounding) for every discrete grid as well.
"""

from __future__ import annotations

import math
from typing import Any, Literal

import numpy as np

from gapsweep.core import checks as chk
from gapsweep.surfaces.topography import load  # height maps from files (docs/gfmd.md, "Surfaces from data")

__all__ = [
    "continuum_rms_height",
    "fourier_coefficients",
    "load",
    "mode_set",
    "rms_height",
    "rms_slope",
    "self_affine",
    "self_affine_rows",
    "spectrum",
    "wavevectors",
]

_U64 = np.uint64
_MASK = (1 << 64) - 1
# Relative slack when testing |k| against the cut-offs, so that a mode exactly on q_l or q_s is kept
# whatever the floating-point rounding of L/lambda.
_EDGE = 1e-9


def _splitmix64(x: np.ndarray) -> np.ndarray:
    """SplitMix64 finaliser (Steele, Lea & Flood 2014): a bijective 64-bit mixer, vectorised (wraps mod 2^64)."""
    x = (x + _U64(0x9E3779B97F4A7C15)) & _U64(_MASK)
    x = ((x ^ (x >> _U64(30))) * _U64(0xBF58476D1CE4E5B9)) & _U64(_MASK)
    x = ((x ^ (x >> _U64(27))) * _U64(0x94D049BB133111EB)) & _U64(_MASK)
    return x ^ (x >> _U64(31))


def _stream_key(seed: int, stream: int) -> int:
    """64-bit key of ``(seed, stream)``, injective on ``[0, 2**63) x {0, 1}``.

    Seeds below ``2**62`` keep their original key ``4 seed + stream`` (residues 0, 1 mod 4), so their surfaces
    are unchanged; larger seeds take the unused residues 2, 3 (``4 (seed - 2**62) + 2 + stream``) instead of
    wrapping onto ``seed - 2**62``.
    """
    if not (0 <= seed < 1 << 63 and stream in (0, 1)):
        raise ValueError(f"seed must be in [0, 2**63) and stream in (0, 1), got {seed!r}, {stream!r}")
    if seed < 1 << 62:
        return seed * 4 + stream
    return (seed - (1 << 62)) * 4 + 2 + stream


def _uniform(seed: int, stream: int, kx: np.ndarray, ky: np.ndarray) -> np.ndarray:
    """Uniform numbers in [0, 1) keyed by (seed, stream, kx, ky): independent of grid size and ordering."""
    off = _U64(1 << 31)
    with np.errstate(over="ignore"):
        x = _splitmix64(np.full(kx.shape, _stream_key(seed, stream), dtype=_U64))
        x = _splitmix64(x ^ (kx.astype(np.int64) + np.int64(1 << 31)).astype(_U64))
        x = _splitmix64(x ^ ((ky.astype(np.int64) + np.int64(1 << 31)).astype(_U64) * off))
    return (x >> _U64(11)).astype(np.float64) * (1.0 / 9007199254740992.0)


def wavevectors(n: int, length: float = 1.0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Full-grid wavevectors ``(qx, qy, |q|)`` in numpy FFT order, shape ``(n, n)``, units rad/length (M1, M2)."""
    n = chk.count(n, "n", minimum=2)
    length = chk.positive(length, "length")
    k = np.fft.fftfreq(n, d=1.0 / n)
    qx, qy = np.meshgrid(2 * np.pi * k / length, 2 * np.pi * k / length, indexing="ij")
    return qx, qy, np.hypot(qx, qy)


def mode_set(
    hurst: float, *, lambda_l: float, lambda_s: float, length: float = 1.0, lambda_r: float | None = None
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Integer wave numbers ``(kx, ky)`` of the canonical half plane (``ky > 0`` or ``ky == 0, kx > 0``) with
    ``q_l <= |q| <= q_s`` and the spectral shape ``(q/q_l)^(-2H-2)`` at each (M2); with ``lambda_r`` the shape
    ``min(1, (q/q_r)^(-2H-2))`` (constant below the roll-off). Independent of the grid."""
    kl, ks = length / lambda_l, length / lambda_s
    kmax = int(math.floor(ks * (1 + _EDGE)))
    k = np.arange(-kmax, kmax + 1)
    kx, ky = np.meshgrid(k, np.arange(0, kmax + 1), indexing="ij")
    kx, ky = kx.ravel(), ky.ravel()
    k2 = (kx * kx + ky * ky).astype(np.float64)
    keep = (k2 >= (kl * kl) * (1 - _EDGE)) & (k2 <= (ks * ks) * (1 + _EDGE)) & ((ky > 0) | (kx > 0))
    kx, ky, k2 = kx[keep], ky[keep], k2[keep]
    if lambda_r is None:
        shape = (np.sqrt(k2) / kl) ** (-2.0 * hurst - 2.0)
    else:
        shape = np.minimum((np.sqrt(k2) / (length / lambda_r)) ** (-2.0 * hurst - 2.0), 1.0)
    return kx, ky, shape


def self_affine(
    n: int,
    hurst: float,
    *,
    lambda_l: float,
    lambda_s: float,
    length: float = 1.0,
    rms_slope: float | None = None,
    rms_height: float | None = None,
    c0: float | None = None,
    amplitudes: Literal["fixed", "gaussian"] = "fixed",
    seed: int = 0,
    backend: Literal["numpy", "cupy"] = "numpy",
    lambda_r: float | None = None,
) -> np.ndarray:
    """Random-phase self-affine surface ``h`` of shape ``(n, n)`` (M2), zero mean, real, units of ``length``.
    ``lambda_r``: roll-off wavelength (module docstring): the spectrum is constant between ``q_l`` and ``q_r``.

    Exactly one of ``rms_slope`` (``g_rms``, dimensionless), ``rms_height`` (``h_rms``, length) or ``c0``
    (``C0``, length^4, with ``h~(q) = sqrt(C(q)/A) exp(i phase)``) fixes the spectrum; none given means
    ``rms_slope=1`` (the paper's default). The grid must carry ``q_s``: ``n > 2 length / lambda_s``.

    ``backend="cupy"`` builds the surface on the GPU and returns a cupy array: the mode set and its
    coefficients (independent of ``n``, a few MB) are computed on the host exactly as for numpy, only the
    ``n x n`` half spectrum and its inverse FFT (cuFFT) live on the GPU, so the result equals the numpy surface
    of the same seed to FFT round-off (~1e-15 relative) and grids too large for host memory work. GPU memory:
    the half spectrum, cuFFT's copy of it and the surface, about 3 grid-sized float64 arrays at the peak.
    """
    n, kx, ky, coeff = _coefficients(n, hurst, lambda_l=lambda_l, lambda_s=lambda_s, length=length,
                                     rms_slope=rms_slope, rms_height=rms_height, c0=c0, amplitudes=amplitudes,
                                     seed=seed, lambda_r=lambda_r)
    if backend not in ("numpy", "cupy"):
        raise ValueError(f"backend must be 'numpy' or 'cupy', got {backend!r}")
    # Half-spectrum layout of irfft2 (axis 1 holds ky >= 0). The ky = 0 column needs both kx and -kx.
    if backend == "cupy":
        return _irfft2_modes_gpu(n, kx, ky, coeff)
    half = np.zeros((n, n // 2 + 1), dtype=np.complex128)
    half[kx % n, ky] = coeff
    on_axis = ky == 0
    half[(-kx[on_axis]) % n, 0] = np.conj(coeff[on_axis])
    return np.fft.irfft2(half, s=(n, n)) * (n * n)


def _coefficients(n: int, hurst: float, *, lambda_l: float, lambda_s: float, length: float,
                  rms_slope: float | None, rms_height: float | None, c0: float | None, amplitudes: str,
                  seed: int, lambda_r: float | None = None) -> tuple[int, np.ndarray, np.ndarray, np.ndarray]:
    """Validated ``n`` and the canonical half plane's modes ``(kx, ky)`` with their coefficients ``h~`` (M2)."""
    n = chk.count(n, "n", minimum=2)
    hurst = chk.hurst(hurst)
    length = chk.positive(length, "length")
    lambda_l = chk.positive(lambda_l, "lambda_l")
    lambda_s = chk.positive(lambda_s, "lambda_s")
    if lambda_s >= lambda_l:
        raise ValueError(f"lambda_s must be < lambda_l, got lambda_s={lambda_s!r} >= lambda_l={lambda_l!r}")
    if lambda_l > length * (1 + _EDGE):
        raise ValueError(f"lambda_l must be <= length={length!r} (periodic box), got {lambda_l!r}")
    if lambda_r is not None:
        lambda_r = chk.positive(lambda_r, "lambda_r")
        if not lambda_s < lambda_r <= lambda_l * (1 + _EDGE):
            raise ValueError(f"lambda_r (roll-off) must lie in (lambda_s, lambda_l] = ({lambda_s!r}, {lambda_l!r}], "
                             f"got {lambda_r!r}")
    given = {k: v for k, v in (("rms_slope", rms_slope), ("rms_height", rms_height), ("c0", c0)) if v is not None}
    if len(given) > 1:
        raise ValueError(f"give exactly one of rms_slope, rms_height, c0; got {sorted(given)}")
    if not given:
        given = {"rms_slope": 1.0}
    (norm_name, norm_value), = given.items()
    norm_value = chk.positive(norm_value, norm_name)
    if amplitudes not in ("fixed", "gaussian"):
        raise ValueError(f"amplitudes must be 'fixed' or 'gaussian', got {amplitudes!r}")
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or not 0 <= int(seed) < 2**63:
        raise ValueError(f"seed must be an integer in [0, 2**63), got {seed!r}")
    seed = int(seed)
    kmax = int(math.floor(length / lambda_s * (1 + _EDGE)))
    if n <= 2 * kmax:
        raise ValueError(
            f"n={n} is too small to carry lambda_s={lambda_s!r}: the Nyquist condition needs "
            f"n > 2 length/lambda_s = {2 * length / lambda_s:g}, i.e. n >= {2 * kmax + 1}"
        )

    kx, ky, shape = mode_set(hurst, lambda_l=lambda_l, lambda_s=lambda_s, length=length, lambda_r=lambda_r)
    if kx.size == 0:
        raise ValueError("no wavevector lies in [q_l, q_s]: widen lambda_l/lambda_s")
    area = length * length
    phase = np.exp(2j * np.pi * _uniform(seed, 0, kx, ky))
    amp = np.sqrt(shape / area)  # sqrt(C/A) for C0 = 1
    if amplitudes == "gaussian":
        # Complex Gaussian with <|z|^2> = 1: Rayleigh modulus sqrt(-ln U), U in (0, 1].
        amp = amp * np.sqrt(-np.log1p(-_uniform(seed, 1, kx, ky)))
    coeff = amp * phase
    q2 = (2 * np.pi / length) ** 2 * (kx * kx + ky * ky)
    # Both q and -q carry |h~|^2: the factor 2 counts the conjugate half plane.
    if norm_name == "c0":
        coeff *= math.sqrt(norm_value)
    elif norm_name == "rms_height":
        coeff *= norm_value / math.sqrt(2.0 * np.sum(np.abs(coeff) ** 2))
    else:
        coeff *= norm_value / math.sqrt(2.0 * np.sum(q2 * np.abs(coeff) ** 2))
    return n, kx, ky, coeff


def self_affine_rows(
    n: int,
    hurst: float,
    *,
    comm: Any,
    lambda_l: float,
    lambda_s: float,
    length: float = 1.0,
    rms_slope: float | None = None,
    rms_height: float | None = None,
    c0: float | None = None,
    amplitudes: Literal["fixed", "gaussian"] = "fixed",
    seed: int = 0,
    backend: Literal["numpy", "cupy"] = "numpy",
    lambda_r: float | None = None,
) -> Any:
    """This rank's rows ``h[slab_rows(n, comm)]`` of :func:`self_affine` with the same arguments, made in place
    (docs/gfmd.md, "One solve over several processes"): no rank forms the whole surface. Collective.

    The mode coefficients depend on ``(seed, kx, ky)`` only (M2: a counter-based hash, no sequential random
    stream), so each rank writes the modes of its own half-spectrum columns; the whole mode set (a few MB,
    ``kx, ky <= length/lambda_s``) is computed on every rank, the ``n x n`` spectrum never. The inverse transform
    is :class:`gapsweep.core.slab.SlabFFT`'s with ``norm="backward"``: on the CPU the same 1-D pocketfft calls as
    ``numpy.fft.irfft2``, so the rows equal :func:`self_affine`'s bit for bit (tests/mpi/test_distributed.py);
    ``backend="cupy"`` (one GPU per rank) runs 1-D cuFFT transforms and equals the single-GPU surface to FFT
    round-off (~1e-15 relative; cuFFT's 2-D plan orders the arithmetic differently). Memory per rank: the rank's
    spectrum columns (complex) and the transform's buffers, about 4 arrays of the rank's rows."""
    from gapsweep.core.slab import SlabFFT

    n, kx, ky, coeff = _coefficients(n, hurst, lambda_l=lambda_l, lambda_s=lambda_s, length=length,
                                     rms_slope=rms_slope, rms_height=rms_height, c0=c0, amplitudes=amplitudes,
                                     seed=seed, lambda_r=lambda_r)
    if backend not in ("numpy", "cupy"):
        raise ValueError(f"backend must be 'numpy' or 'cupy', got {backend!r}")
    fft = SlabFFT((n, n), comm, backend=backend)
    xp = fft.xp
    c = fft.col
    on_axis = ky == 0
    rows = np.concatenate([ky, np.zeros(int(on_axis.sum()), dtype=ky.dtype)])  # ky: rows of the [ky, kx] layout
    cols = np.concatenate([kx % n, (-kx[on_axis]) % n])
    vals = np.concatenate([coeff, np.conj(coeff[on_axis])])
    mine = (rows >= c.start) & (rows < c.stop)
    spec = xp.zeros(fft.spec_shape, dtype=xp.complex128)
    # the mirrors last, as in self_affine, so a mode written twice keeps the same value
    spec[xp.asarray(rows[mine] - c.start), xp.asarray(cols[mine])] = xp.asarray(vals[mine])
    return fft.irfft2(spec, norm="backward") * (n * n)


def _irfft2_modes_gpu(n: int, kx: np.ndarray, ky: np.ndarray, coeff: np.ndarray):
    """``irfft2`` of the half spectrum holding ``coeff`` at ``(kx, ky)`` (and the ky = 0 mirrors), times ``n^2``,
    on the GPU (cupy): the same layout as the numpy branch of :func:`self_affine`."""
    from gapsweep.core import extras as _extras

    cupy = _extras.require("cupy", 'GPU surfaces (backend="cupy")')
    from cupyx.scipy.fft import get_fft_plan

    half = cupy.zeros((n, n // 2 + 1), dtype=cupy.complex128)
    on_axis = ky == 0
    rows = np.concatenate([kx % n, (-kx[on_axis]) % n])
    cols = np.concatenate([ky, np.zeros(int(on_axis.sum()), dtype=ky.dtype)])
    vals = np.concatenate([coeff, np.conj(coeff[on_axis])])
    # Same write order as the numpy branch (the mirrors last), so a mode written twice keeps the same value.
    half[cupy.asarray(rows), cupy.asarray(cols)] = cupy.asarray(vals)
    # A plan of its own, used once and dropped: cupy's plan cache would keep its work area on the GPU.
    plan = get_fft_plan(half, shape=(n, n), axes=(0, 1), value_type="C2R")
    with plan:
        h = cupy.fft.irfft2(half, s=(n, n), norm="forward")  # norm="forward": the unscaled sum, = irfft2 n^2
    del half, plan
    return h


def fourier_coefficients(heights: np.ndarray) -> np.ndarray:
    """``h~(q) = FFT[h] / n^2`` so that ``h(r) = sum_q h~(q) exp(i q.r)`` (M2); full (n, n) array, FFT order."""
    h = chk.square_heights(heights)
    return np.fft.fft2(h) / h.size


def rms_height(heights: np.ndarray) -> float:
    """``h_rms = sqrt(<(h - <h>)^2>)`` over the grid (M2), units of length."""
    h = chk.square_heights(heights)
    return float(np.sqrt(np.mean((h - h.mean()) ** 2)))


def rms_slope(heights: np.ndarray, length: float = 1.0) -> float:
    """Spectral rms gradient ``g_rms = sqrt(sum_q q^2 |h~(q)|^2)`` (M2): exact for a band-limited periodic
    surface (finite differences would underestimate it near Nyquist). Dimensionless."""
    h = chk.square_heights(heights)
    length = chk.positive(length, "length")
    n = h.shape[0]
    # Half spectrum (rfft2, half the work of fft2): the columns 0 < ky < n/2 stand for their conjugate mirrors too.
    kx = np.fft.fftfreq(n, d=1.0 / n)
    ky = np.fft.rfftfreq(n, d=1.0 / n)
    q2 = (2 * np.pi / length) ** 2 * (kx[:, None] ** 2 + ky[None, :] ** 2)
    w = np.full(ky.size, 2.0)
    w[0] = 1.0
    if n % 2 == 0:
        w[-1] = 1.0
    hq = np.fft.rfft2(h) / h.size
    return float(np.sqrt(np.sum(q2 * w[None, :] * (hq.real ** 2 + hq.imag ** 2))))


def spectrum(heights: np.ndarray, length: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    """Isotropic discrete spectrum ``C(q) = A <|h~(q)|^2>`` averaged over shells of integer ``|k|`` (M2).

    Returns ``(q, C)`` for the non-empty shells with ``|k| >= 1`` (units rad/length and length^4).
    """
    h = chk.square_heights(heights)
    n = h.shape[0]
    length = chk.positive(length, "length")
    power = np.abs(fourier_coefficients(h)) ** 2 * length * length
    k = np.fft.fftfreq(n, d=1.0 / n)
    kabs = np.hypot(*np.meshgrid(k, k, indexing="ij"))
    shell = np.rint(kabs).astype(np.int64).ravel()
    counts = np.bincount(shell)
    sums = np.bincount(shell, weights=power.ravel())
    kq = np.bincount(shell, weights=kabs.ravel())
    ok = (counts > 0) & (np.arange(counts.size) >= 1)
    return 2 * np.pi * kq[ok] / counts[ok] / length, sums[ok] / counts[ok]


def continuum_rms_height(
    hurst: float, *, lambda_l: float, lambda_s: float, rms_slope: float = 1.0, lambda_r: float | None = None
) -> float:
    """Continuum ``h_rms`` of the M2 spectrum normalised to ``g_rms = rms_slope``:
    ``h_rms^2 / g_rms^2 = int C q dq / int C q^3 dq`` over ``[q_l, q_s]`` (``C ~ q^(-2H-2)``; with ``lambda_r``
    constant below ``q_r``). Units of length."""
    ql, qs = 2 * np.pi / chk.positive(lambda_l, "lambda_l"), 2 * np.pi / chk.positive(lambda_s, "lambda_s")
    hurst = chk.hurst(hurst)
    if lambda_r is None:
        m0 = (ql ** (-2 * hurst) - qs ** (-2 * hurst)) / (2 * hurst)
        m2 = (qs ** (2 - 2 * hurst) - ql ** (2 - 2 * hurst)) / (2 - 2 * hurst)
        return float(rms_slope * math.sqrt(m0 / m2))
    qr = 2 * np.pi / chk.positive(lambda_r, "lambda_r")
    # C = (q/q_r)^(-2H-2) above q_r, 1 below: int C q dq and int C q^3 dq in closed form
    m0 = qr ** (2 * hurst + 2) * (qr ** (-2 * hurst) - qs ** (-2 * hurst)) / (2 * hurst) + (qr**2 - ql**2) / 2
    m2 = qr ** (2 * hurst + 2) * (qs ** (2 - 2 * hurst) - qr ** (2 - 2 * hurst)) / (2 - 2 * hurst) \
        + (qr**4 - ql**4) / 4
    return float(rms_slope * math.sqrt(m0 / m2))
