"""The GPU tests' one way to get cupy: the module, or a skip naming why (no cupy, no device, or a driver that
cannot run a kernel)."""

from __future__ import annotations

from typing import Any

import pytest


def cupy_or_skip() -> Any:
    try:
        import cupy

        if cupy.cuda.runtime.getDeviceCount() < 1:
            raise RuntimeError("no CUDA device")
        cupy.zeros(1).sum()  # a driver that cannot run a kernel fails here
    except Exception as exc:
        pytest.skip(f"no CUDA GPU for cupy ({type(exc).__name__}: {exc})")
    return cupy
