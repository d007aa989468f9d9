"""Optional dependencies: import one, or fail with an error that names the extra to install.

The core install (numpy, scipy, h5py, pandas, matplotlib) computes the field theory, runs GFMD with numpy's FFT,
runs sweeps in one process and writes reports. Everything else is an extra of ``pip install gapsweep[...]``:

| extra | packages | brings |
| --- | --- | --- |
| ``fast`` | pyFFTW, numba | faster CPU FFTs and fused GFMD kernels |
| ``sde`` | warp-lang | the SDE ensembles (CPU and GPU) |
| ``gpu`` | cupy | GFMD on an NVIDIA GPU (``backend="cupy"``) |
| ``mpi`` | mpi4py | MPI task farms (``mpiexec -n P gapsweep run``) |
| ``distributed`` | mpi4py (+ cupy with NCCL on GPUs) | one GFMD solve over MPI ranks (``gfmd.solve(comm=...)``) |
| ``xarray`` | xarray, h5netcdf | ``store.to_dataset``, ``gapsweep export`` (netCDF4 via h5netcdf), kept fields |
| ``topography`` | SurfaceTopography | height maps in SurfaceTopography's formats; peer-code surfaces |
| ``progress`` | tqdm | a progress bar on a terminal (log lines otherwise) |
| ``flow`` | pyamg | the multigrid preconditioner of the leak-rate solve (``gapsweep.flow``; Jacobi CG otherwise) |
"""

from __future__ import annotations

import importlib
from types import ModuleType

__all__ = ["EXTRAS", "MissingExtraError", "has", "require"]

# import name -> (distribution on PyPI, extra that brings it)
EXTRAS: dict[str, tuple[str, str]] = {
    "pyfftw": ("pyFFTW", "fast"),
    "numba": ("numba", "fast"),
    "warp": ("warp-lang", "sde"),
    "cupy": ("cupy-cuda13x", "gpu"),  # the wheel the gpu extra installs (pyproject.toml)
    "cupyx": ("cupy-cuda13x", "gpu"),
    "mpi4py": ("mpi4py", "mpi"),
    "xarray": ("xarray", "xarray"),
    "h5netcdf": ("h5netcdf", "xarray"),
    "SurfaceTopography": ("SurfaceTopography", "topography"),
    "tqdm": ("tqdm", "progress"),
    "pyamg": ("pyamg", "flow"),
}


class MissingExtraError(ImportError):
    """An optional dependency is missing; the message names the extra that installs it."""


def has(module: str) -> bool:
    """Whether ``module`` can be imported (without raising)."""
    try:
        importlib.import_module(module)
    except ImportError:
        return False
    return True


def require(module: str, feature: str) -> ModuleType:
    """Import ``module`` or raise :class:`MissingExtraError` saying which ``feature`` needs which extra."""
    try:
        return importlib.import_module(module)
    except ImportError as e:
        dist, extra = EXTRAS.get(module.split(".")[0], (module, "all"))
        raise MissingExtraError(
            f"{feature} needs the optional package {dist!r}, which is not installed ({e}); "
            f"install it with: pip install 'gapsweep[{extra}]'") from e
