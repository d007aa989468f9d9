"""Rectangular grids for the constrained and smooth minimisers (docs/gfmd.md): FFTs of normalised
coefficients, ``|q|``, Parseval sums and the elastic energy, for numpy or cupy arrays. :class:`Grid` is periodic;
:class:`FreeGrid` adds the free-boundary compliance of a finite map (docs/gfmd.md, "Periodic or free boundaries").

A field ``a`` on ``nx x ny`` points of a ``Lx x Ly`` box has the half-spectrum coefficients
``a~ = rfft2(a) / (nx ny)`` (rfft along axis 1), ``q = 2 pi (kx/Lx, ky/Ly)``. Square boxes use the planned
backends of :mod:`gapsweep.fft` (pyFFTW, cuFFT); rectangular ones the namespace's own ``fft`` module."""

from __future__ import annotations

import functools
import math
from typing import Any

import numpy as np

from gapsweep.core.fft import available_backends, get_backend
from gapsweep.core.vec import rdot

_FLAT = 1e3 * np.finfo(np.float64).eps  # rms / |mean| below which a map is flat (round-off of its mean)


def lengths(length: Any) -> tuple[float, float]:
    """``(Lx, Ly)`` from a number or a pair of numbers (validated by the caller)."""
    if isinstance(length, (tuple, list, np.ndarray)):
        lx, ly = (float(v) for v in length)
        return lx, ly
    return float(length), float(length)


class Grid:
    """FFT pair and spectral helpers on one periodic grid (see module docstring)."""

    def __init__(self, shape: tuple[int, int], length: Any, backend: str, threads: int | None,
                 on_gpu: bool) -> None:
        nx, ny = (int(v) for v in shape)
        self.shape = (nx, ny)
        self.size = nx * ny
        self.lx, self.ly = lengths(length)
        if backend == "auto":
            backend = "cupy" if on_gpu else ("pyfftw" if "pyfftw" in available_backends() else "numpy")
        square = nx == ny and self.lx == self.ly
        self.backend = backend
        self._fft = get_backend(backend, nx, threads=threads) if square else None
        if self._fft is not None:
            self.xp = self._fft.xp
        elif backend == "cupy":
            import cupy

            self.xp = cupy
        else:
            self.xp = np
        xp = self.xp
        kx = xp.fft.fftfreq(nx, d=1.0 / nx) * (2 * math.pi / self.lx)
        ky = xp.fft.rfftfreq(ny, d=1.0 / ny) * (2 * math.pi / self.ly)
        self.q = xp.sqrt(kx[:, None] ** 2 + ky[None, :] ** 2)
        self._edge_weights = True  # w is 2 but for the columns ky = 0 and Nyquist (Grid.dot's BLAS path relies on it)

    @functools.cached_property
    def _w(self) -> Any:
        """The Parseval weights of the half spectrum, made on first use (a hard-wall solve on the GPU needs them
        only for its result: half a grid array less at its peak, gfmd._cuda.solve_memory)."""
        nx, ny = self.shape
        w = self.xp.full((nx, ny // 2 + 1), 2.0)
        w[:, 0] = 1.0
        if ny % 2 == 0:
            w[:, -1] = 1.0
        return w

    def asarray(self, a: Any) -> Any:
        return self.xp.asarray(a, dtype=self.xp.float64)

    def fwd(self, a: Any) -> Any:
        """``a~ = rfft2(a) / (nx ny)`` (a new array)."""
        if self._fft is not None:
            return self._fft.rfft2(a) * (1.0 / self.size)
        return self.xp.fft.rfft2(a) * (1.0 / self.size)

    def inv(self, a: Any) -> Any:
        """The real field of the coefficients ``a~`` (a new array)."""
        if self._fft is not None:
            return self.xp.array(self._fft.irfft2(a))
        return self.xp.fft.irfft2(a, s=self.shape) * float(self.size)

    def multiplier(self, m: Any) -> Any:
        """The Fourier multiplier ``m`` (on the coefficients ``a~``) prepared for :meth:`convolve`."""
        return m * (1.0 / self.size) if self._fft is not None else m

    def convolve(self, a: Any, m: Any, out: Any = None) -> Any:
        """The real field of ``m a~`` for ``m`` from :meth:`multiplier`, into ``out`` (or a new array)."""
        if self._fft is not None:
            return self._fft.convolve(a, m, out)
        r = self.inv(self.fwd(a) * m)
        if out is None:
            return r
        self.xp.copyto(out, r)
        return out

    def dot(self, a: Any, b: Any) -> float:
        """``<A B>`` (grid mean of the product of the two real fields) by Parseval: ``sum w Re(conj(a) b)`` with
        the half spectrum's weights ``w`` (2, but 1 on the columns ky = 0 and Nyquist). On numpy one
        single-threaded pass over the whole array less the two edge columns (gapsweep.core.vec.rdot), no
        temporaries (the L-BFGS two-loop recursion
        spends most of its time here on large grids)."""
        if getattr(self, "_edge_weights", False) and self.xp is np and a.dtype == np.complex128 \
                and b.dtype == np.complex128 and a.shape == b.shape == self._w.shape \
                and a.flags.c_contiguous and b.flags.c_contiguous:
            s = 2.0 * rdot(a, b) - rdot(a[:, 0], b[:, 0])
            if self.shape[1] % 2 == 0:
                s -= rdot(a[:, -1], b[:, -1])
            return float(s)
        return float(self.xp.sum(self._w * (a.real * b.real + a.imag * b.imag)))

    def elastic_energy(self, u_hat: Any, e_star: float) -> float:
        """``(E*/4) sum_q q |u~(q)|^2``: elastic energy per nominal area of the displacement ``u`` (M3)."""
        return 0.5 * self.dot(u_hat, (0.5 * e_star) * self.q * u_hat)

    # Reductions over the whole grid. A distributed grid (gapsweep.gfmd.distributed.SlabGrid) holds a slab of
    # rows (real space) and of half-spectrum columns (Fourier space) per rank and combines them over the ranks;
    # the minimisers call these instead of the array methods, so one algorithm serves both.
    @property
    def real_shape(self) -> tuple[int, int]:
        """Shape of the real fields this process holds (the whole grid here)."""
        return self.shape

    def spectrum_zeros(self) -> Any:
        """Zero half-spectrum coefficients of the fields this process holds."""
        return self.xp.zeros((self.shape[0], self.shape[1] // 2 + 1), dtype=self.xp.complex128)

    def mean(self, a: Any) -> float:
        """Grid mean of the real field ``a``."""
        return float(self.xp.mean(a))

    def total(self, a: Any) -> float:
        return float(self.xp.sum(a))

    def amin(self, a: Any) -> float:
        return float(a.min())

    def amax(self, a: Any) -> float:
        return float(a.max())

    def count(self, mask: Any) -> int:
        return int(self.xp.count_nonzero(mask))

    def agree(self, flag: bool) -> bool:
        """Whether ``flag`` holds on every process (here: the one)."""
        return bool(flag)

    def all_finite(self, a: Any) -> bool:
        return self.agree(bool(self.xp.all(self.xp.isfinite(a))))

    def centred(self, heights: Any) -> tuple[Any, float, float]:
        """``(h - <h>, h_rms, g_ref)`` of a height map on this grid, refusing NaN/inf: ``g_ref``, the length
        the hard-wall solvers measure their gap residual in, is ``h_rms``, or the pixel size for a flat map (its rms
        no more than the round-off of removing its mean, which depends on the units' digits: a constant free map
        would converge at one length unit, not at another). Units: those of ``heights``."""
        h = self.asarray(heights)
        if not self.all_finite(h):
            raise ValueError("heights contain NaN or inf")
        h_shift = self.mean(h)
        h = h - h_shift
        h_rms = math.sqrt(self.mean(h * h))
        flat = not h_rms > _FLAT * abs(h_shift)
        g_ref = min(self.lx / self.shape[0], self.ly / self.shape[1]) if flat else h_rms
        return h, h_rms, g_ref

    def mode0(self, a: Any) -> complex:
        """The ``q = 0`` coefficient of the half spectrum ``a``."""
        return complex(a[0, 0])

    def set_mode0(self, a: Any, value: complex) -> None:
        a[0, 0] = value

    def reduce_ops(self, ops: Any) -> Any:
        """The hard-wall passes (gfmd._constrained_ops) with their scalars combined over the grid: as they are."""
        return ops

    def to_host(self, a: Any) -> np.ndarray:
        return a.get() if self.xp is not np else a

    def to_host_many(self, arrays: dict[str, Any]) -> dict[str, np.ndarray]:
        """``{name: host copy}``: through the FFT backend's pinned, asynchronous copies where it has one."""
        if self._fft is not None:
            return self._fft.to_host_many(arrays)
        return {k: self.to_host(a) for k, a in arrays.items()}

    def synchronize(self) -> None:
        if self.xp is not np:
            self.xp.cuda.get_current_stream().synchronize()


def boussinesq_pixel(x: Any, y: Any, a: float, b: float, e_star: float, xp: Any = np) -> Any:
    """Surface displacement at ``(x, y)`` of an elastic half-space (contact modulus ``E*``) under a unit uniform
    pressure on the rectangle ``|x'| <= a, |y'| <= b`` (Love 1929; Johnson, Contact Mechanics, Eq. 3.25), units
    length / pressure:

        u = 1/(pi E*) [ (x+a) ln((y+b + r_pp)/(y-b + r_mp)) + (y+b) ln((x+a + r_pp)/(x-a + r_pm))
                      + (x-a) ln((y-b + r_mm)/(y+b + r_pm)) + (y-b) ln((x-a + r_mm)/(x+a + r_mp)) ],

    ``r_pp = |(x+a, y+b)|``, ``r_pm = |(x-a, y+b)|``, ``r_mp = |(x+a, y-b)|``, ``r_mm = |(x-a, y-b)|``. Far from
    the pixel it tends to Boussinesq's point load ``4ab/(pi E* r)`` (docs/model.md M3: the Fourier transform of
    ``1/(pi E* r)`` is the compliance ``2/(E* q)`` of the periodic solver). ``s + r`` with ``s < 0`` is written
    ``t^2/(r - s)`` (``r = |(s, t)|``) so that no digits cancel far from the pixel."""

    def plus(s: Any, t: Any) -> Any:  # s + sqrt(s^2 + t^2), without cancellation for s < 0
        r = xp.sqrt(s * s + t * t)
        with np.errstate(divide="ignore", invalid="ignore"):
            return xp.where(s >= 0, s + r, (t * t) / (r - s))

    def term(c: Any, num: Any, den: Any) -> Any:  # c ln(num/den), 0 where c = 0 (the limit c ln c -> 0)
        with np.errstate(divide="ignore", invalid="ignore"):
            v = c * xp.log(num / den)
        return xp.where(c == 0, 0.0, v)

    xa, xm, yb, ym = x + a, x - a, y + b, y - b
    u = (term(xa, plus(yb, xa), plus(ym, xa)) + term(yb, plus(xa, yb), plus(xm, yb))
         + term(xm, plus(ym, xm), plus(yb, xm)) + term(ym, plus(xm, ym), plus(xa, ym)))
    return u / (math.pi * e_star)


_GREEN: dict[tuple, np.ndarray] = {}  # (shape, Lx, Ly, E*) -> spectrum of G; host arrays only, oldest dropped


class FreeGrid(Grid):
    """A finite, non-periodic map on an elastic half-space (free boundaries; docs/gfmd.md, "Periodic or free
    boundaries"). The map's own grid (``nx x ny``, box ``Lx x Ly``) keeps every method of :class:`Grid` (its
    periodic ``|q|`` serves the preconditioner); :meth:`compliance` is the exact discrete free-surface response
    ``u(r_i) = sum_j G(r_i - r_j) p(r_j)`` over the map's pixels, ``G`` from :func:`boussinesq_pixel`, evaluated
    as a circular convolution on the ``2nx x 2ny`` grid with the pressure zero outside the map (Hockney's
    method: every distance between two pixels of the map, ``|dx| <= nx - 1``, appears once on the doubled
    grid, so no periodic image enters; the same construction as ContactMechanics' FreeFFTElasticHalfSpace).
    The displacement has no zero-mean constraint: the mean pressure (taken over the map's area) sets it."""

    periodic = False

    def __init__(self, shape: tuple[int, int], length: Any, backend: str, threads: int | None,
                 on_gpu: bool) -> None:
        super().__init__(shape, length, backend, threads, on_gpu)
        self._plans = _staged_fftw(self.shape, threads) if self.backend == "pyfftw" else None
        if self.xp is np:  # scipy's pocketfft: about twice numpy's speed on these sizes
            import scipy.fft

            self._f, self._kw, self._ow = scipy.fft, {"workers": threads or 1}, {"overwrite_x": True}
        else:  # cupy.fft (cuFFT): the same calls without scipy's keywords
            self._f, self._kw, self._ow = self.xp.fft, {}, {}
        self._green: dict[float, Any] = {}
        self._pad: Any = None  # the GPU's 2-D plans of the doubled grid (gfmd._cuda._PadFFT), made on first use

    def _padfft(self) -> Any:
        """cuFFT plans of the doubled grid (GPU only; None on the CPU)."""
        if self.xp is np:
            return None
        if self._pad is None:
            from gapsweep.gfmd._cuda import _PadFFT

            self._pad = _PadFFT(self.xp, self.shape)
        return self._pad

    def green(self, e_star: float) -> Any:
        """Spectrum of ``G`` on the doubled grid (distances wrapped to ``[-n, n]`` pixels), shape
        ``(2nx, ny + 1)``, unnormalised (``rfft2`` of ``G``): real, as ``G`` is even. Made once per ``E*``."""
        key = (self.shape, self.lx, self.ly, float(e_star))
        if e_star not in self._green and self.xp is np and key in _GREEN:  # a later solve of the same grid
            self._green[e_star] = _GREEN[key]
        if e_star not in self._green:
            xp, (nx, ny) = self.xp, self.shape
            dx, dy = self.lx / nx, self.ly / ny
            ix = xp.arange(2 * nx)
            iy = xp.arange(2 * ny)
            x = xp.where(ix <= nx, ix, ix - 2 * nx) * dx
            y = xp.where(iy <= ny, iy, iy - 2 * ny) * dy
            g = boussinesq_pixel(x[:, None], y[None, :], 0.5 * dx, 0.5 * dy, e_star, xp)
            self._green[e_star] = xp.ascontiguousarray(xp.fft.rfft2(g).real)
            if xp is np:  # host arrays are kept for the process (a few grids: a sweep solves one map many times)
                if len(_GREEN) >= 16:
                    _GREEN.pop(next(iter(_GREEN)))
                _GREEN[key] = self._green[e_star]
        return self._green[e_star]

    def pad_fwd(self, a: Any) -> Any:
        """Unnormalised ``rfft2`` (shape ``(2nx, ny + 1)``) of the map field ``a`` zero-padded to the doubled
        grid. The padding is never formed: the transform runs axis by axis, the first one over the map's ``nx``
        rows only (about a quarter of the doubled grid's FFT work saved)."""
        nx, ny = self.shape
        if self._plans is not None:  # FFTW plans (pyFFTW backend); returns a plan buffer
            return self._plans.fwd(a)
        if self.xp is not np:  # cuFFT: one 2-D plan over the padded buffer (gfmd._cuda._PadFFT)
            return self._padfft().fwd(a)
        b = self._f.rfft(a, n=2 * ny, axis=1, **self._kw)  # rows of the map, zero padded to 2 ny
        return self._f.fft(b, n=2 * nx, axis=0, **self._ow, **self._kw)  # rows nx .. 2nx - 1 are zero

    def pad_inv(self, b: Any) -> Any:
        """The map block (``nx x ny``) of the real field whose unnormalised ``rfft2`` on the doubled grid is
        ``b`` (the inverse of :meth:`pad_fwd` restricted to the map; only the map's rows are transformed back).
        ``b`` is overwritten on the CPU."""
        nx, ny = self.shape
        if self._plans is not None:
            return self._plans.inv(b)
        if self.xp is not np:
            pad = self._padfft()
            return self.xp.ascontiguousarray(pad.inv_sum(b, pad.scale))
        c = self._f.ifft(b, axis=0, **self._ow, **self._kw)[:nx]
        return self._f.irfft(c, n=2 * ny, axis=1, **self._kw)[:, :ny]

    def pad_sum(self, b: Any) -> Any:
        """The map block of the unnormalised inverse (the plain sum over modes) of the doubled grid's half
        spectrum ``b``: ``pad_inv(b * 4 nx ny)``. On the GPU a view of a plan buffer, valid until the next
        transform (use it at once), and ``b`` is kept; on the CPU a new array, and ``b`` may be overwritten."""
        if self.xp is not np:
            return self._padfft().inv_sum(b)
        return self.pad_inv(b * float(4 * self.shape[0] * self.shape[1]))

    def compliance(self, e_star: float) -> Any:
        """``K(p, out=None)``: the map's displacement (length) under the pressure ``p`` on the map (docstring of
        :class:`FreeGrid`): :meth:`pad_fwd`, times the Green's function's spectrum, :meth:`pad_inv`."""
        m = self.green(e_star)
        pad = self._padfft()
        if pad is not None:  # GPU: the two plans, the product in the C2R input, the normalisation in m
            m_inv = m * pad.scale

            def apply_gpu(a: Any, out: Any = None) -> Any:
                return pad.convolve(a, m_inv, out)

            return apply_gpu

        def apply(a: Any, out: Any = None) -> Any:
            b = self.pad_fwd(a)
            b *= m
            u = self.pad_inv(b)
            if out is None:
                return self.xp.ascontiguousarray(u)
            out[...] = u
            return out

        return apply

    def elastic_energy_pu(self, p: Any, u: Any) -> float:
        """Elastic energy per map area ``<p u> / 2`` (pressure x length) of the equilibrium ``u = K p``."""
        return 0.5 * float(self.xp.mean(p * u))


class _StagedFFTW:
    """FFTW plans of :meth:`FreeGrid.pad_fwd` and :meth:`FreeGrid.pad_inv` for one map shape: r2c along y of the
    map's rows (zero padded to ``2ny``), c2c along x (zero rows ``nx .. 2nx-1``), and back; the zero parts of
    the input buffers are written once and never touched again. About 1.8x scipy's speed at 256 x 256."""

    def __init__(self, shape: tuple[int, int], threads: int | None) -> None:
        import pyfftw

        nx, ny = shape
        self.nx, self.ny, self.scale = nx, ny, 1.0 / (4 * nx * ny)
        t = threads or 1
        flags = ("FFTW_MEASURE",)
        e = pyfftw.empty_aligned
        self.r_in = e((nx, 2 * ny), dtype="float64")
        self.r_in[...] = 0.0
        self.r_out = e((nx, ny + 1), dtype="complex128")
        self.c_in = e((2 * nx, ny + 1), dtype="complex128")
        self.c_in[...] = 0.0
        self.c_out = e((2 * nx, ny + 1), dtype="complex128")
        self.c_back = e((2 * nx, ny + 1), dtype="complex128")
        self.i_in = e((nx, ny + 1), dtype="complex128")
        self.i_out = e((nx, 2 * ny), dtype="float64")
        self.p1 = pyfftw.FFTW(self.r_in, self.r_out, axes=(1,), flags=flags, threads=t)
        self.p2 = pyfftw.FFTW(self.c_in, self.c_out, axes=(0,), flags=flags, threads=t)
        self.p3 = pyfftw.FFTW(self.c_out, self.c_back, axes=(0,), direction="FFTW_BACKWARD", flags=flags,
                              threads=t)
        self.p4 = pyfftw.FFTW(self.i_in, self.i_out, axes=(1,), direction="FFTW_BACKWARD",
                              flags=(*flags, "FFTW_DESTROY_INPUT"), threads=t)
        self.c_in[...] = 0.0  # planning with FFTW_MEASURE may scribble on the buffers
        self.r_in[...] = 0.0

    def fwd(self, a: np.ndarray) -> np.ndarray:
        """Unnormalised rfft2 of ``a`` zero-padded; the returned array is a plan buffer (consume it first)."""
        self.r_in[:, : self.ny] = a
        self.p1.execute()
        self.c_in[: self.nx] = self.r_out
        self.p2.execute()
        return self.c_out

    def inv(self, b: np.ndarray) -> np.ndarray:
        """The map block of the normalised inverse (a new array)."""
        if b is not self.c_out:
            self.c_out[...] = b
        self.p3.execute()
        self.i_in[...] = self.c_back[: self.nx]
        self.p4.execute()
        return self.i_out[:, : self.ny] * self.scale


_STAGED: dict[tuple[int, int, int], _StagedFFTW] = {}


def _staged_fftw(shape: tuple[int, int], threads: int | None) -> _StagedFFTW:
    """Plans made once per ``(nx, ny, threads)`` for the process (planning measures: tens of ms)."""
    key = (int(shape[0]), int(shape[1]), int(threads or 1))
    if key not in _STAGED:
        _STAGED[key] = _StagedFFTW(shape, threads)
    return _STAGED[key]
