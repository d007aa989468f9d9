"""CUDA engine of the gap SDE's split scheme (docs/model.md M5): the kernels of ``sde_kernels.cu`` (package data)
through cupy/NVRTC, built with -use_fast_math. Same scheme and same Philox stream as the warp kernels of
:mod:`gapsweep._sde_kernels`, so a realisation's numbers do not depend on the engine; used by
:mod:`gapsweep.sde` for ``device="cuda[:N]"`` when cupy is installed (``GAPSWEEP_SDE_ENGINE=warp`` turns it off).
"""

from __future__ import annotations

import functools
import importlib.util
import os
import sys
from pathlib import Path
from typing import Any

import numpy as np

_SRC = Path(__file__).with_name("sde_kernels.cu")
_BLOCK = 256
_SHARED_SLOTS = 12_000  # a per-block histogram in shared memory up to 48 KB
# Extra slots after the bins in a histogram count array: below, above, non-finite (both engines).
N_EXTRA = 3


def enabled(device: str, scheme: str) -> bool:
    """Whether ``device``/``scheme`` run on this engine: CUDA devices, the split scheme, cupy installed and
    ``GAPSWEEP_SDE_ENGINE`` not "warp"."""
    if not device.startswith("cuda") or scheme != "split":
        return False
    if os.environ.get("GAPSWEEP_SDE_ENGINE", "auto") == "warp":
        return False
    # whether cupy is installed, without importing it: a process that runs no GPU task (the farm's coordinator
    # writing the run record) must not load the CUDA libraries
    return "cupy" in sys.modules or importlib.util.find_spec("cupy") is not None


def _device_index(device: str) -> int:
    return int(device.split(":", 1)[1]) if ":" in device else 0


def device_name(device: str) -> str:
    """``"cuda:N"`` for ``"cuda"`` (cupy's current device) or ``"cuda:N"``, checked against cupy's device count
    (ValueError naming the device when absent)."""
    import cupy

    try:
        count = cupy.cuda.runtime.getDeviceCount()
        index = int(device.split(":", 1)[1]) if ":" in device else cupy.cuda.runtime.getDevice()
    except Exception as exc:  # no driver / no device: cupy raises its CUDA runtime error
        raise ValueError(f"device {device!r} is not available ({exc})") from None
    if not 0 <= index < count:
        raise ValueError(f"device {device!r} is not available ({count} CUDA device(s))")
    return f"cuda:{index}"


@functools.cache
def _module(device_index: int) -> Any:
    import cupy

    with cupy.cuda.Device(device_index):
        return cupy.RawModule(code=_SRC.read_text(encoding="utf-8"), options=("-use_fast_math", "--std=c++14"))


class Engine:
    """Coefficients of one plan on one device, and the launches (all on the device's current stream)."""

    def __init__(self, device: str, dtype: str, s: np.ndarray, b: np.ndarray, rb: np.ndarray, rho: float,
                 repulse: int, n_steps: int) -> None:
        import cupy

        self.cp = cupy
        self.index = _device_index(device)
        self.dev = cupy.cuda.Device(self.index)
        self.np_real = np.dtype(dtype).type
        self.suffix = "f32" if dtype == "float32" else "f64"
        with self.dev:
            self.mod = _module(self.index)
            self.s, self.b, self.rb = (cupy.asarray(np.asarray(a, dtype=dtype)) for a in (s, b, rb))
        self.rho, self.inv_rho = self.np_real(rho), self.np_real(1.0 / rho)
        self.repulse, self.n_steps = np.int32(repulse), np.int32(n_steps)

    def _common(self, first: int, k0: int, k1: int, m: int) -> tuple:
        return (np.int64(m), np.uint64(first), np.uint32(k0), np.uint32(k1), self.n_steps, self.s, self.b,
                self.rb, self.rho, self.inv_rho, self.repulse)

    def samples(self, first: int, k0: int, k1: int, m: int) -> Any:
        """Final ``y`` of realisations ``first .. first+m-1`` (a device array, not yet synchronised)."""
        with self.dev:
            out = self.cp.empty(m, dtype=self.np_real)
            fn = self.mod.get_function("sde_samples_" + self.suffix)
            fn(((m + _BLOCK - 1) // _BLOCK,), (_BLOCK,), (*self._common(first, k0, k1, m), out))
        return out

    def histogram_state(self, y_edges: np.ndarray) -> tuple:
        with self.dev:
            nb = y_edges.size - 1
            counts = self.cp.zeros(nb + N_EXTRA, dtype=self.cp.uint64)
            return self.cp.asarray(y_edges.astype(self.np_real)), counts

    def histogram(self, first: int, k0: int, k1: int, m: int, edges: Any, lo: float, inv_w: float,
                  is_uniform: int, counts: Any) -> None:
        """Add the binned final ``y`` of ``m`` realisations to ``counts`` (nb bins, below, above, non-finite)."""
        nb = int(edges.size - 1)
        shared = nb + N_EXTRA <= _SHARED_SLOTS
        with self.dev:
            fn = self.mod.get_function("sde_histogram_" + self.suffix)
            fn(((m + _BLOCK - 1) // _BLOCK,), (_BLOCK,),
               (*self._common(first, k0, k1, m), edges, np.int32(nb), self.np_real(lo), self.np_real(inv_w),
                np.int32(is_uniform), np.int32(shared), counts), shared_mem=4 * (nb + N_EXTRA) if shared else 0)

    def to_host(self, a: Any) -> np.ndarray:
        with self.dev:
            return self.cp.asnumpy(a)
