"""Real 2-D FFT backends for the GFMD solver (docs/model.md M3): pyFFTW, numpy and cupy (cuFFT).

Every backend exposes the same two *unnormalised* transforms of a real ``n x n`` field, in the half-spectrum
layout of ``numpy.fft.rfft2`` (shape ``(n, n // 2 + 1)``):

    rfft2(a)[k]  = sum_r a(r) exp(-i q_k.r)          (forward, no 1/n^2)
    irfft2(A)(r) = sum_k A[k] exp(+i q_k.r)           (inverse, no 1/n^2; conjugate half implied)

so that with ``u~ = rfft2(u) / n^2`` (the coefficients of M2) ``u = irfft2(u~)``. The solver folds the ``1/n^2``
into scalars it already multiplies with. Both calls may return an internal buffer that the next call of the
same transform overwrites: consume (or copy) the result first.

pyFFTW plans are made once per ``(n, threads, effort)`` and kept for the process; FFTW wisdom is cached on disk
(``$GAPSWEEP_CACHE`` or ``~/.cache/gapsweep``), one file per thread count because wisdom is per thread count.
The thread count defaults to ``$GAPSWEEP_FFT_THREADS`` or 1 (sweeps run one rank per core).
"""

from __future__ import annotations

import logging
import os
import pickle
import tempfile
import threading
from pathlib import Path
from typing import Any

import numpy as np

from gapsweep.core.extras import require

log = logging.getLogger(__name__)

__all__ = ["BACKENDS", "FFTBackend", "available_backends", "cache_dir", "get_backend"]

BACKENDS = ("numpy", "pyfftw", "cupy")  # the names get_backend accepts

_PLANS: dict[tuple, FFTBackend] = {}
_LOCK = threading.Lock()
_WISDOM_LOADED: set[int] = set()


def cache_dir() -> Path:
    """Directory for FFTW wisdom: ``$GAPSWEEP_CACHE`` or ``~/.cache/gapsweep``."""
    env = os.environ.get("GAPSWEEP_CACHE")
    return Path(env) if env else Path.home() / ".cache" / "gapsweep"


def default_threads() -> int:
    """FFT thread count: ``$GAPSWEEP_FFT_THREADS`` or 1."""
    try:
        return max(1, int(os.environ.get("GAPSWEEP_FFT_THREADS", "1")))
    except ValueError:
        return 1


class FFTBackend:
    """Unnormalised rfft2/irfft2 pair on one square grid (see module docstring)."""

    name: str = "numpy"

    def __init__(self, n: int) -> None:
        self.n = n
        self.xp: Any = np

    def rfft2(self, a):
        return np.fft.rfft2(a)

    def irfft2(self, a):
        # norm="forward" puts 1/n^2 on the forward transform: the inverse is the plain sum.
        return np.fft.irfft2(a, s=(self.n, self.n), norm="forward")

    def convolve(self, a, mult, out=None):
        """``irfft2(rfft2(a) * mult)`` (a Fourier multiplier, unnormalised as above) into ``out``, or a new
        array when ``out`` is None (never an internal buffer)."""
        r = self.irfft2(self.rfft2(a) * mult)
        if out is None:
            return self.xp.array(r)
        self.xp.copyto(out, r)
        return out

    def asarray(self, a):
        return self.xp.asarray(a, dtype=self.xp.float64)

    def to_host(self, a) -> np.ndarray:
        return np.asarray(a)

    def to_host_many(self, arrays: dict[str, Any]) -> dict[str, np.ndarray]:
        """``{name: host copy}`` of several arrays (the GPU backend overlaps them; see there)."""
        return {k: self.to_host(a) for k, a in arrays.items()}

    def synchronize(self) -> None:
        pass


class _CupyBackend(FFTBackend):
    """cuFFT through two plans made once per grid (cached with the backend) and run straight into
    preallocated outputs: no plan-cache look-up, no allocation, no normalisation pass per call. C2R destroys
    its input, so irfft2 copies it into a work buffer first (as cupy.fft does). Falls back to cupy.fft where
    the plan API is not available."""

    name = "cupy"

    def __init__(self, n: int) -> None:
        cupy = require("cupy", 'the GPU FFT backend (backend="cupy")')

        self.n = n
        self.xp = cupy
        self._plans = None
        try:
            from cupy.cuda import cufft
            from cupyx.scipy.fft import get_fft_plan

            rin = cupy.empty((n, n), dtype=cupy.float64)
            cin = cupy.empty((n, n // 2 + 1), dtype=cupy.complex128)
            fwd = get_fft_plan(rin, axes=(0, 1), value_type="R2C")
            inv = get_fft_plan(cin, shape=(n, n), axes=(0, 1), value_type="C2R")
            self._plans = (fwd, inv, cufft.CUFFT_FORWARD, cufft.CUFFT_INVERSE)
            self._cin = cin
            del rin
        except Exception:  # old cupy or no N-D plan for this shape: the generic path below
            self._plans = None
        # rfft2's and irfft2's output buffers, made on their first call: convolve needs neither (the hard wall's
        # memory plan, gfmd._cuda.solve_memory)
        self._cout_buf = self._rout_buf = None

    @property
    def _cout(self):
        if self._cout_buf is None:
            self._cout_buf = self.xp.empty_like(self._cin)
        return self._cout_buf

    @property
    def _rout(self):
        if self._rout_buf is None:
            self._rout_buf = self.xp.empty((self.n, self.n), dtype=self.xp.float64)
        return self._rout_buf

    def rfft2(self, a):
        if self._plans is None or a.dtype != self.xp.float64 or a.shape != (self.n, self.n):
            return self.xp.fft.rfft2(a)
        a = self.xp.ascontiguousarray(a)
        self._plans[0].fft(a, self._cout, self._plans[2])
        return self._cout

    def irfft2(self, a):
        if self._plans is None or a.shape != self._cin.shape:
            return self.xp.fft.irfft2(a, s=(self.n, self.n), norm="forward")
        self.xp.copyto(self._cin, a)
        self._plans[1].fft(self._cin, self._rout, self._plans[3])
        return self._rout

    def convolve(self, a, mult, out=None):
        """As :meth:`FFTBackend.convolve` with one buffer: R2C into the C2R input buffer, the product in place,
        C2R straight into ``out`` (no temporary spectrum, no output buffer, no copy)."""
        xp = self.xp
        if self._plans is None or a.dtype != xp.float64 or a.shape != (self.n, self.n) \
                or getattr(mult, "shape", None) != self._cin.shape:
            return super().convolve(a, mult, out)
        self._plans[0].fft(xp.ascontiguousarray(a), self._cin, self._plans[2])
        self._cin *= mult
        if out is None or out.dtype != xp.float64 or out.shape != (self.n, self.n) or not out.flags.c_contiguous:
            res = xp.empty((self.n, self.n), dtype=xp.float64)
        else:
            res = out
        self._plans[1].fft(self._cin, res, self._plans[3])  # C2R straight into the caller's array
        if out is not None and res is not out:
            xp.copyto(out, res)
            return out
        return res

    def to_host(self, a) -> np.ndarray:
        return self.to_host_many({"a": a})["a"]

    def to_host_many(self, arrays: dict[str, Any]) -> dict[str, np.ndarray]:
        """Device-to-host copies into page-locked (pinned) host memory, all queued asynchronously on the current
        stream and waited for once: the copy engine runs at link speed (a pageable copy stages through a
        driver buffer at a fraction of it). The pinned blocks come from cupy's pinned-memory pool, so repeated
        solves reuse them; they return to the pool when the arrays are freed."""
        import cupyx

        stream = self.xp.cuda.get_current_stream()
        out = {}
        for k, a in arrays.items():
            a = self.xp.ascontiguousarray(a)
            host = cupyx.empty_pinned(a.shape, dtype=a.dtype)
            a.get(stream=stream, out=host, blocking=False)
            out[k] = host
        stream.synchronize()
        return out

    def synchronize(self) -> None:
        self.xp.cuda.get_current_stream().synchronize()


def _wisdom_path(threads: int) -> Path:
    return cache_dir() / f"fftw_wisdom_t{threads}.pkl"


def _load_wisdom(threads: int) -> None:
    import pyfftw

    if threads in _WISDOM_LOADED:
        return
    _WISDOM_LOADED.add(threads)
    path = _wisdom_path(threads)
    try:
        with open(path, "rb") as f:
            pyfftw.import_wisdom(pickle.load(f))
    except (OSError, pickle.PickleError, EOFError, TypeError, ValueError) as e:
        log.debug("no usable FFTW wisdom at %s (%s): planning from scratch", path, e)


def _save_wisdom(threads: int) -> None:
    import pyfftw

    path = _wisdom_path(threads)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        # Atomic replace: several ranks may plan at once; a reader never sees half a file.
        fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=".wisdom")
        with os.fdopen(fd, "wb") as f:
            pickle.dump(pyfftw.export_wisdom(), f)
        os.replace(tmp, path)
    except OSError as e:
        log.debug("FFTW wisdom not saved to %s (%s): only costs planning time", path, e)


class _PyFFTWBackend(FFTBackend):
    name = "pyfftw"

    def __init__(self, n: int, threads: int, effort: str) -> None:
        pyfftw = require("pyfftw", 'the FFTW backend (backend="pyfftw")')

        self.n = n
        self.xp = np
        self.threads = threads
        _load_wisdom(threads)
        shape_r, shape_c = (n, n), (n, n // 2 + 1)
        self._rin = pyfftw.empty_aligned(shape_r, dtype="float64")
        self._cout = pyfftw.empty_aligned(shape_c, dtype="complex128")
        self._cin = pyfftw.empty_aligned(shape_c, dtype="complex128")
        self._rout = pyfftw.empty_aligned(shape_r, dtype="float64")
        flags = (effort,)
        self._fwd = pyfftw.FFTW(self._rin, self._cout, axes=(0, 1), direction="FFTW_FORWARD",
                                flags=flags, threads=threads)
        # c2r destroys its input: the solver always copies into _cin first, so that is harmless.
        self._inv = pyfftw.FFTW(self._cin, self._rout, axes=(0, 1), direction="FFTW_BACKWARD",
                                flags=(*flags, "FFTW_DESTROY_INPUT"), threads=threads)
        _save_wisdom(threads)

    def rfft2(self, a):
        self._rin[...] = a
        self._fwd.execute()
        return self._cout

    def irfft2(self, a):
        self._cin[...] = a
        self._inv.execute()
        return self._rout

    def convolve(self, a, mult, out=None):
        # Straight through the plan buffers: no temporary spectrum, one copy in and one out.
        self._rin[...] = a
        self._fwd.execute()
        np.multiply(self._cout, mult, out=self._cin)
        self._inv.execute()
        if out is None:
            return self._rout.copy()
        np.copyto(out, self._rout)
        return out


def available_backends() -> list[str]:
    """Names of the backends importable here (``cupy`` only with a visible GPU)."""
    names = ["numpy"]
    try:
        import pyfftw  # noqa: F401

        names.insert(0, "pyfftw")
    except ImportError:
        pass
    try:
        import cupy

        if cupy.cuda.runtime.getDeviceCount() > 0:
            names.append("cupy")
    except Exception:  # ImportError, or a CUDA runtime error without a driver
        pass
    return names


def _current_device() -> int:
    """The id of cupy's current CUDA device (the key of every per-device cache); without cupy, the missing-extra
    error that names the gpu extra."""
    cupy = require("cupy", 'the GPU FFT backend (backend="cupy")')

    return int(cupy.cuda.Device().id)


def get_backend(name: str, n: int, *, threads: int | None = None, effort: str | None = None) -> FFTBackend:
    """Return the (cached) backend ``name`` in {"numpy", "pyfftw", "cupy"} for an ``n x n`` grid; a cupy backend
    is cached per CUDA device (the current one), since its cuFFT plans and buffers live on one device.

    ``threads``: FFTW threads (default ``$GAPSWEEP_FFT_THREADS`` or 1). ``effort``: FFTW planner flag
    (default ``$GAPSWEEP_FFTW_EFFORT`` or ``FFTW_MEASURE``).
    """
    if name not in BACKENDS:
        raise ValueError(f"backend must be one of {', '.join(map(repr, ('auto', *BACKENDS)))}; got {name!r}")
    threads = default_threads() if threads is None else int(threads)
    if threads < 1:
        raise ValueError(f"threads must be >= 1, got {threads}")
    effort = effort or os.environ.get("GAPSWEEP_FFTW_EFFORT", "FFTW_MEASURE")
    if effort not in ("FFTW_ESTIMATE", "FFTW_MEASURE", "FFTW_PATIENT", "FFTW_EXHAUSTIVE"):
        raise ValueError(f"effort must be an FFTW planner flag such as 'FFTW_MEASURE', got {effort!r}")
    # cuFFT plans and their buffers belong to the device current when they were made: a plan of device 0 run on
    # device 1 fails with CUFFT_EXEC_FAILED (issue 36), so a cupy backend is cached per device.
    device = _current_device() if name == "cupy" else -1
    key = (name, n, threads if name == "pyfftw" else 0, effort if name == "pyfftw" else "", device)
    with _LOCK:
        backend = _PLANS.get(key)
        if backend is None:
            if name == "pyfftw":
                backend = _PyFFTWBackend(n, threads, effort)
            elif name == "cupy":
                backend = _CupyBackend(n)
            else:
                backend = FFTBackend(n)
            _PLANS[key] = backend
    return backend
