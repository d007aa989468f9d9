"""gapsweep: mean gap, gap distribution and contact of an elastic body on a randomly rough surface.

The package is laid out as its data path (docs/architecture.md):

* physics, free of I/O, MPI and the sweep (docs/model.md M1-M7):
  ``core`` (input checks, optional extras, FFT backends), ``surfaces`` (synthetic self-affine surfaces, measured
  height maps), ``gfmd`` (the exact solver with its interaction laws), ``theory`` (field theory, Persson's theory,
  improved predictors), ``gapdist`` (gap distributions: the SDE in magnification, the Fokker-Planck solver,
  calibration);
* ``sweep``: job spec -> tasks -> method plug-ins (``sweep.methods``) -> result record -> HDF5 store, the MPI
  farm, xarray/netCDF views;
* thin drivers: ``cli`` and ``demo``; and ``analysis`` (aggregation, figures, the report of ``gapsweep report``), a
  consumer of stores that physics never imports.

The flat names of version 0.1 (``gapsweep.surface``, ``gapsweep.store``, ``gapsweep.sde``, ...) still import: they
are alias files gathered in ``gapsweep/_compat/`` (on this package's ``__path__``, :mod:`gapsweep._compat`), and
importing one gives the module it now lives in (the table :data:`STABLE_NAMES`), the same module object, so
attributes, monkeypatching, pickling and ``importlib.reload`` behave as before. Those in :data:`DEPRECATED_NAMES`
warn and go in 0.4 (docs/architecture.md, "The 0.1 names").
Importing gapsweep changes no process-wide state (no environment variable; numba's cache folder is set for
gapsweep's own kernels only, :mod:`gapsweep.core.numba_cache`).
"""

from __future__ import annotations

import os as _os
from typing import TYPE_CHECKING

__version__ = "0.2.0"

# the 0.1 names' alias files: found by the ordinary path finder after the package's own modules
__path__.append(_os.path.join(_os.path.dirname(__file__), "_compat"))

if TYPE_CHECKING:  # type checkers do not follow __path__: `from gapsweep import store` names the real modules
    from gapsweep.gapdist import calibrate, fokker_planck, sde  # noqa: F401
    from gapsweep.gfmd import resolution  # noqa: F401
    from gapsweep.surfaces import synthetic as surface  # noqa: F401
    from gapsweep.surfaces import topography  # noqa: F401
    from gapsweep.sweep import api as store  # noqa: F401
    from gapsweep.sweep import dataset, runner, spec  # noqa: F401

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

#: the 0.1 names of internals: importing one warns (DeprecationWarning); they go in gapsweep 0.4
DEPRECATED_NAMES: frozenset[str] = frozenset({
    "gapsweep._checks", "gapsweep._extras", "gapsweep.fft", "gapsweep._sde_kernels", "gapsweep._sde_cuda",
    *(f"gapsweep.{m}" for m in ("tasks", "storecheck", "lease", "budget", "limits", "provenance", "batching",
                                "gpus")),
})
