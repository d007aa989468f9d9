"""Kept fields of GFMD tasks (``[methods.gfmd] keep_fields``, docs/jobs.md): which tasks keep which fields, and
the writer of one task's fields file ``<store>.fields/<task_id>.nc`` (netCDF4 through h5py, written under a
temporary name and renamed, so a crash never leaves a half-written file). Reading them back with xarray:
gapsweep.sweep.dataset.open_fields.
"""

from __future__ import annotations

import json
import math
import os
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from gapsweep.sweep.schema import FIELD_NAMES, StoreWriteError

__all__ = ["FIELD_META", "FIELD_NAMES", "field_selected", "fields_dir", "remove_fields", "remove_partial",
           "write_fields"]

_LEN = {"units": "1", "reference_unit": "L"}  # lengths in units of the spec's L
# field -> (long_name, unit attributes)
FIELD_META = {
    "gap": ("local gap g(r) = g0 + u(r) - h(r)", _LEN),
    "pressure": ("local pressure p(r) of the interaction law (file attribute interaction; docs/gfmd.md)",
                 {"units": "1", "reference_unit": "E*"}),
    "displacement": ("elastic displacement u(r), zero mean", _LEN),
    "height": ("surface height h(r), zero mean", _LEN),
}


def fields_dir(store_path: str | Path) -> Path:
    """The folder of a store's kept fields: ``<store>.fields`` beside it."""
    p = Path(store_path)
    return p.with_name(p.name + ".fields")


def field_selected(opts: Mapping[str, Any] | None, *, hurst: float, rho: float, sigma0: float, seed: int,
                   n: int) -> list[str]:
    """The fields to keep for one GFMD task under the job's ``keep_fields`` option ([] for none)."""
    if not opts:
        return []
    for key, v in (("hurst", hurst), ("rho", rho), ("sigma0", sigma0), ("seeds", seed), ("n", n)):
        want = opts.get(key)
        if want is not None and not any(math.isclose(float(v), float(w), rel_tol=1e-9) for w in want):
            return []
    return list(opts.get("fields", ()))


def write_fields(directory: str | Path, task_id: str, arrays: Mapping[str, np.ndarray], *, length: float,
                 attrs: Mapping[str, Any]) -> Path:
    """Write one task's fields as ``directory/<task_id>.nc``: netCDF4 (HDF5 with dimension scales), float64 on
    ``(x, y)`` cell centres, chunked and gzip-compressed; written under a temporary name and renamed.

    A write error (full disk, a file where the folder should be) is the store's failure, not the task's: it
    raises :class:`~gapsweep.sweep.schema.StoreWriteError`, so the run stops with the row still pending
    (docs/reliability.md) instead of recording a solved task as failed."""
    try:
        return _write_fields(directory, task_id, arrays, length=length, attrs=attrs)
    except OSError as e:
        raise StoreWriteError(f"kept fields of task {task_id} in {directory}: cannot be written ({e}); the row "
                              "stays pending: free space or fix the folder and run again with --resume") from None


def remove_partial(directory: str | Path) -> int:
    """Delete the temporary kept-field files (``.<task_id>.<pid>.tmp``) left in ``directory`` by a run that was
    killed while writing one (under MPI, ``MPI_Abort`` of another rank; issue 31). Called by a run that holds the
    store's lease, so no other run writes there. Returns the count removed."""
    d = Path(directory)
    if not d.is_dir():
        return 0
    n = 0
    for f in d.glob(".*.tmp"):
        stem = f.name[1:].split(".", 1)[0]
        if f.is_file() and len(stem) == 16 and all(c in "0123456789abcdef" for c in stem):
            f.unlink(missing_ok=True)
            n += 1
    return n


def remove_fields(directory: str | Path) -> int:
    """Delete the kept-field files that runs wrote into ``directory`` (``<task_id>.nc`` with a 16-hex-digit task
    id, and their temporary files) and the folder if it is then empty; anything else is left. Returns the count
    of files removed. Used by ``run --overwrite``: the fields of the replaced store must not outlive it."""
    d = Path(directory)
    if not d.is_dir():
        return 0
    n = 0
    for f in d.iterdir():
        stem = f.name[1:].split(".", 1)[0] if f.name.startswith(".") else f.stem
        if f.is_file() and len(stem) == 16 and all(c in "0123456789abcdef" for c in stem) and (
                f.suffix == ".nc" or f.name.endswith(".tmp")):
            f.unlink()
            n += 1
    try:
        d.rmdir()
    except OSError:
        pass  # something else lives there: leave the folder
    return n


# a spec's length unit -> its UDUNITS (CF) string: "A" would read as ampere there
CF_UNITS = {"A": "angstrom"}


def cf_unit(u: str | None) -> str | None:
    """The CF/UDUNITS spelling of a job's unit (``"A"`` -> ``"angstrom"``; the others are UDUNITS already)."""
    return None if u is None else " ".join(CF_UNITS.get(w, w) for w in str(u).split())


def _length_units(attrs: Mapping[str, Any]) -> dict[str, str]:
    u = attrs.get("length_unit")
    return {"units": str(cf_unit(u))} if u else dict(_LEN)


def _pressure_units(attrs: Mapping[str, Any]) -> dict[str, str]:
    u = attrs.get("pressure_unit")
    return {"units": str(u)} if u else {"units": "1", "reference_unit": "E*"}


def _write_fields(directory: str | Path, task_id: str, arrays: Mapping[str, np.ndarray], *, length: float,
                  attrs: Mapping[str, Any]) -> Path:
    import h5py

    d = Path(directory)
    d.mkdir(parents=True, exist_ok=True)
    final = d / f"{task_id}.nc"
    tmp = d / f".{task_id}.{os.getpid()}.tmp"
    nx, ny = next(iter(arrays.values())).shape
    lx, ly = (length, length) if np.isscalar(length) else length
    axes = {"x": (np.arange(nx) + 0.5) * (lx / nx), "y": (np.arange(ny) + 0.5) * (ly / ny)}
    chunk = (min(nx, 256), min(ny, 256))
    f: Any = None
    hdf5 = True  # an error before the file is closed comes from HDF5
    try:
        f = h5py.File(tmp, "w", track_order=True)  # closed below, not by a with-block: see the except
        for name, x in axes.items():
            ds = f.create_dataset(name, data=x)
            ds.make_scale(name)
            ds.attrs.update({"long_name": f"{name} position of the cell centre", **_length_units(attrs)})
        for name, a in arrays.items():
            long_name, units = FIELD_META[name]
            units = _length_units(attrs) if units is _LEN else _pressure_units(attrs)
            ds = f.create_dataset(name, data=np.asarray(a, dtype=np.float64), chunks=chunk, compression="gzip",
                                  compression_opts=4, shuffle=True)
            ds.dims[0].attach_scale(f["x"])
            ds.dims[1].attach_scale(f["y"])
            ds.attrs.update({"long_name": long_name, **units})
        f.attrs.update({"Conventions": "CF-1.10", "title": f"gapsweep kept fields of task {task_id}",
                        "task_id": task_id})
        for k, v in attrs.items():
            f.attrs[k] = v if isinstance(v, (int, float, str, np.integer, np.floating)) else json.dumps(v)
        f.close()
        hdf5 = False
        os.replace(tmp, final)
    except (OSError, RuntimeError) as e:
        if not hdf5:
            raise
        # HDF5 crashes when a file whose write failed is closed or released (issue 31: a run keeping fields
        # segfaulted on a full disk): the file is kept open to the end of the process, which leaves by os._exit
        from gapsweep.sweep.writefail import write_failed

        raise write_failed(f"kept fields of task {task_id} in {d}: cannot be written ({e}); the row stays "
                           "pending: free space or fix the folder and run again with --resume") from None
    finally:
        if tmp.exists():
            tmp.unlink()
    return final
