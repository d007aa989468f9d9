"""gapsweep: mean gap, gap distribution and contact of an elastic body on a randomly rough surface.

The package is laid out as its data path (docs/architecture.md):

* physics, free of I/O, MPI and the sweep (docs/model.md M1-M7):
  ``core`` (input checks, optional extras, FFT backends), ``surfaces`` (synthetic self-affine surfaces, measured
  height maps), ``gfmd`` (the exact solver with its interaction laws), ``theory`` (field theory, Persson's theory,
  improved predictors), ``gapdist`` (gap distributions: the SDE in magnification, the Fokker-Planck solver,
  calibration);
* ``sweep``: job spec -> tasks -> method plug-ins (``sweep.methods``) -> result record -> HDF5 store, the MPI
  farm, xarray/netCDF views;
* thin drivers: ``cli`` and ``demo``; the report lives in the top-level ``analysis`` package.

The flat names of version 0.1 (``gapsweep.surface``, ``gapsweep.store``, ``gapsweep.sde``, ...) stay the stable
public face: importing one gives the module it now lives in (the table :data:`STABLE_NAMES`), the same module
object, so attributes, monkeypatching and pickling behave as before.
"""

from __future__ import annotations

import importlib
import importlib.abc
import importlib.machinery
import os
import sys

__version__ = "0.2.0"


def _numba_cache_dir() -> None:
    """Point numba's on-disk cache (the GFMD CPU kernels are ``cache=True``) at a per-user folder before numba is
    imported: ``$NUMBA_CACHE_DIR`` if set, else ``$XDG_CACHE_HOME/gapsweep/numba`` (``~/.cache/gapsweep/numba``),
    else ``<tmp>/gapsweep-numba-<uid>``. Without it numba writes ``*.nbi``/``*.nbc`` into the source tree's
    ``__pycache__`` (issue 19): a read-only or shared install, and another user's files in a checkout."""
    if os.environ.get("NUMBA_CACHE_DIR"):
        return
    import tempfile

    home = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    uid = os.getuid() if hasattr(os, "getuid") else 0
    for d in (os.path.join(home, "gapsweep", "numba"),
              os.path.join(tempfile.gettempdir(), f"gapsweep-numba-{uid}")):
        try:
            os.makedirs(d, exist_ok=True)
        except OSError:
            continue
        if os.access(d, os.W_OK | os.X_OK):
            os.environ["NUMBA_CACHE_DIR"] = d
            if "numba" in sys.modules:  # imported before gapsweep: its config has read the environment already
                sys.modules["numba"].config.CACHE_DIR = d
            return


_numba_cache_dir()

# stable public name -> the module it lives in
STABLE_NAMES: dict[str, str] = {
    "gapsweep._checks": "gapsweep.core.checks",
    "gapsweep._extras": "gapsweep.core.extras",
    "gapsweep.fft": "gapsweep.core.fft",
    "gapsweep.surface": "gapsweep.surfaces.synthetic",
    "gapsweep.topography": "gapsweep.surfaces.topography",
    "gapsweep.sde": "gapsweep.gapdist.sde",
    "gapsweep._sde_kernels": "gapsweep.gapdist._sde_kernels",
    "gapsweep._sde_cuda": "gapsweep.gapdist._sde_cuda",
    "gapsweep.fokker_planck": "gapsweep.gapdist.fokker_planck",
    "gapsweep.calibrate": "gapsweep.gapdist.calibrate",
    "gapsweep.resolution": "gapsweep.gfmd.resolution",
    "gapsweep.store": "gapsweep.sweep.api",
    **{f"gapsweep.{m}": f"gapsweep.sweep.{m}" for m in (
        "spec", "tasks", "runner", "storecheck", "lease", "budget", "limits", "provenance", "batching", "gpus",
        "dataset")},
}


class _StableNames(importlib.abc.MetaPathFinder, importlib.abc.Loader):
    """Import finder that answers a stable name with the module it now lives in (no copy, no warning)."""

    def find_spec(self, name: str, path: object = None, target: object = None):
        if name in STABLE_NAMES:
            return importlib.machinery.ModuleSpec(name, self)
        return None

    def create_module(self, spec: importlib.machinery.ModuleSpec):
        return importlib.import_module(STABLE_NAMES[spec.name])

    def exec_module(self, module: object) -> None:  # the target module is already executed
        return None


if not any(isinstance(f, _StableNames) for f in sys.meta_path):
    sys.meta_path.append(_StableNames())
