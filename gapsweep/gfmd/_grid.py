"""Periodic rectangular grids for the constrained and smooth minimisers (docs/gfmd.md): FFTs of normalised
coefficients, ``|q|``, Parseval sums and the elastic energy, for numpy or cupy arrays.

A field ``a`` on ``nx x ny`` points of a ``Lx x Ly`` box has the half-spectrum coefficients
``a~ = rfft2(a) / (nx ny)`` (rfft along axis 1), ``q = 2 pi (kx/Lx, ky/Ly)``. Square boxes use the planned
backends of :mod:`gapsweep.fft` (pyFFTW, cuFFT); rectangular ones the namespace's own ``fft`` module."""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from gapsweep.fft import available_backends, get_backend


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
        nyh = ny // 2 + 1
        w = xp.full((nx, nyh), 2.0)
        w[:, 0] = 1.0
        if ny % 2 == 0:
            w[:, -1] = 1.0
        self._w = w  # Parseval weights of the half spectrum

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
        """``<A B>`` (grid mean of the product of the two real fields) by Parseval."""
        return float(self.xp.sum(self._w * (a.real * b.real + a.imag * b.imag)))

    def elastic_energy(self, u_hat: Any, e_star: float) -> float:
        """``(E*/4) sum_q q |u~(q)|^2``: elastic energy per nominal area of the displacement ``u`` (M3)."""
        return 0.5 * self.dot(u_hat, (0.5 * e_star) * self.q * u_hat)

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
