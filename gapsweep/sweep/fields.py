"""Kept fields of GFMD tasks (``[methods.gfmd] keep_fields``, docs/jobs.md): which tasks keep which fields, and
the writer of one task's fields file ``<store>.fields/<task_id>.nc`` (netCDF4 through h5py, written under a
temporary name and renamed, so a crash never leaves a half-written file). Reading them back with xarray:
gapsweep.sweep.dataset.open_fields.
"""

from __future__ import annotations

import json
import math
import os
from collections.abc import Iterator, Mapping
from pathlib import Path
from typing import Any

import numpy as np

from gapsweep.core.slab import block, slab_rows
from gapsweep.sweep import writefail
from gapsweep.sweep.schema import FIELD_NAMES, StoreWriteError

__all__ = ["FIELD_META", "FIELD_NAMES", "field_selected", "fields_dir", "remove_fields", "remove_partial",
           "write_field_rows", "write_fields"]

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


def _create(f: Any, task_id: str, shape: tuple[int, int], names: list[str], *, length: Any,
            attrs: Mapping[str, Any]) -> dict[str, Any]:
    """The file's structure (written identically by every rank under ``mpio``): the cell-centre axes as dimension
    scales, one float64 ``(x, y)`` dataset per field (chunked, gzip-compressed, not yet written) and the
    attributes. Returns the field datasets by name."""
    nx, ny = shape
    lx, ly = (length, length) if np.isscalar(length) else length
    axes = {"x": (np.arange(nx) + 0.5) * (lx / nx), "y": (np.arange(ny) + 0.5) * (ly / ny)}
    chunk = (min(nx, 256), min(ny, 256))
    for name, x in axes.items():
        ds = f.create_dataset(name, data=x)
        ds.make_scale(name)
        ds.attrs.update({"long_name": f"{name} position of the cell centre", **_length_units(attrs)})
    out = {}
    for name in names:
        long_name, units = FIELD_META[name]
        units = _length_units(attrs) if units is _LEN else _pressure_units(attrs)
        ds = f.create_dataset(name, shape=(nx, ny), dtype=np.float64, chunks=chunk, compression="gzip",
                              compression_opts=4, shuffle=True)
        ds.dims[0].attach_scale(f["x"])
        ds.dims[1].attach_scale(f["y"])
        ds.attrs.update({"long_name": long_name, **units})
        out[name] = ds
    f.attrs.update({"Conventions": "CF-1.10", "title": f"gapsweep kept fields of task {task_id}",
                    "task_id": task_id})
    for k, v in attrs.items():
        f.attrs[k] = v if isinstance(v, (int, float, str, np.integer, np.floating)) else json.dumps(v)
    return out


def _write_fields(directory: str | Path, task_id: str, arrays: Mapping[str, np.ndarray], *, length: float,
                  attrs: Mapping[str, Any]) -> Path:
    import h5py

    d = Path(directory)
    d.mkdir(parents=True, exist_ok=True)
    final = d / f"{task_id}.nc"
    tmp = d / f".{task_id}.{os.getpid()}.tmp"
    shape = next(iter(arrays.values())).shape
    f: Any = None
    hdf5 = True  # an error before the file is closed comes from HDF5
    try:
        f = h5py.File(tmp, "w", track_order=True)  # closed below, not by a with-block: see the except
        out = _create(f, task_id, shape, list(arrays), length=length, attrs=attrs)
        for name, a in arrays.items():
            out[name][...] = np.asarray(a, dtype=np.float64)
        f.close()
        hdf5 = False
        os.replace(tmp, final)
    except (OSError, RuntimeError) as e:
        if not hdf5:
            raise
        _failed(task_id, d, e)
    finally:
        if tmp.exists():
            tmp.unlink()
    return final


def _failed(task_id: str, d: Path, e: BaseException) -> None:
    """Raise the error of a failed HDF5 write of a fields file (inside its ``except``). HDF5 crashes when a file
    whose write failed is closed or released (issue 31: a run keeping fields segfaulted on a full disk): the file
    is kept open to the end of the process, which leaves by os._exit."""
    from gapsweep.sweep.writefail import write_failed

    raise write_failed(f"kept fields of task {task_id} in {d}: cannot be written ({e}); the row stays "
                       "pending: free space or fix the folder and run again with --resume") from None


# ---------------------------------------------------------------------------------------------- by rows
def write_field_rows(directory: str | Path, task_id: str, rows: Mapping[str, np.ndarray], *,
                     shape: tuple[int, int], comm: Any, writer: str, length: Any,
                     attrs: Mapping[str, Any]) -> Path | None:
    """:func:`write_fields` of fields split in row slabs over the ranks of ``comm`` (a GFMD solve over every
    rank, gapsweep.sweep.collective): ``rows`` holds this rank's rows (``gapsweep.core.slab.slab_rows`` of the
    global ``shape``) of each field, the same names on every rank. The file is the one a single process writes
    of the whole fields (same datasets, chunks, compression, attributes; the same values bit for bit). Collective.

    ``writer = "mpio"`` (h5py with MPI): every rank opens the temporary file (``driver="mpio"``), the structure is
    made collectively and each rank writes its rows as a hyperslab (collective I/O, which HDF5 needs for
    compressed datasets). Otherwise (``"rank0"``): rank 0 alone writes; the other ranks send their rows to it in
    chunks of at most ``gapsweep.sweep.slabs.CHUNK_BYTES`` (rank 0 holds one chunk, never a whole field). Either
    way the file is written under a temporary name and renamed by rank 0 once closed; any error raises
    :class:`StoreWriteError` (never a failed row: the ranks would part ways; the runner ends the MPI job, the row
    stays pending, the temporary file is removed by a ``--resume``, :func:`remove_partial`). Returns the file's
    path on rank 0, else None."""
    try:
        if writer == "mpio":
            return _write_rows_mpio(directory, task_id, rows, shape, comm, length, attrs)
        return _write_rows_rank0(directory, task_id, rows, shape, comm, length, attrs)
    except StoreWriteError:
        raise
    except Exception as e:  # an OSError, or anything else on some ranks only: the runner ends the MPI job
        what = str(e) if isinstance(e, OSError) else f"{type(e).__name__}: {e}"
        raise StoreWriteError(f"kept fields of task {task_id} in {directory}: cannot be written ({what}); the row "
                              "stays pending: free space or fix the folder and run again with --resume") from None


def _write_rows_mpio(directory: str | Path, task_id: str, rows: Mapping[str, np.ndarray], shape: tuple[int, int],
                     comm: Any, length: Any, attrs: Mapping[str, Any]) -> Path | None:
    import h5py

    d = Path(directory)
    d.mkdir(parents=True, exist_ok=True)
    final = d / f"{task_id}.nc"
    tmp = d / f".{task_id}.{comm.bcast(os.getpid(), root=0)}.tmp"  # one name: rank 0's process id
    mine = slab_rows(int(shape[0]), comm)
    # An MPI-IO write that fails (full disk, file-size limit) is reported by the MPI library but not returned by
    # HDF5's collective calls, which then wait forever: rank 0 first reserves the file's largest size (the raw
    # fields, compression can only shrink them but by its few bytes per chunk), and every rank raises its error.
    need = int(1.02 * 8 * shape[0] * shape[1] * len(rows)) + 8 * (shape[0] + shape[1]) + (64 << 10)
    err = writefail.reserve(tmp, need) if comm.Get_rank() == 0 else None
    err = comm.bcast(err, root=0)
    if err is not None:
        raise OSError(err)
    f: Any = None
    try:
        f = h5py.File(tmp, "w", driver="mpio", comm=comm, track_order=True)
        out = _create(f, task_id, tuple(shape), list(rows), length=length, attrs=attrs)
        for name, a in rows.items():
            with out[name].collective:
                out[name][mine.start:mine.stop] = np.asarray(a, dtype=np.float64)
        f.close()
    except (OSError, RuntimeError) as e:  # another rank may wait in a collective call: the runner aborts
        _failed(task_id, d, e)
    if comm.Get_rank() != 0:
        comm.bcast(None, root=0)
        return None
    err = None
    try:
        os.replace(tmp, final)
    except OSError as e:
        err = str(e)
    if comm.bcast(err, root=0) is not None:
        raise OSError(err)
    return final


def _write_rows_rank0(directory: str | Path, task_id: str, rows: Mapping[str, np.ndarray], shape: tuple[int, int],
                      comm: Any, length: Any, attrs: Mapping[str, Any]) -> Path | None:
    from gapsweep.sweep.slabs import TAG_ROWS, row_chunks

    size, rank = comm.Get_size(), comm.Get_rank()
    if rank != 0:
        if not comm.bcast(None, root=0):  # rank 0 could not create the file: it raises, the runner aborts
            raise StoreWriteError(f"kept fields of task {task_id}: rank 0 could not create the file")
        mine = slab_rows(int(shape[0]), comm)
        for name in rows:
            a = np.ascontiguousarray(rows[name], dtype=np.float64)
            for c in row_chunks(mine, int(shape[1])):
                comm.Send(a[c.start - mine.start:c.stop - mine.start], dest=0, tag=TAG_ROWS)
        return None

    def receive(name: str) -> Iterator[tuple[slice, np.ndarray]]:
        yield slab_rows(int(shape[0]), comm), np.asarray(rows[name], dtype=np.float64)
        for r in range(1, size):
            for c in row_chunks(block(int(shape[0]), size, r), int(shape[1])):
                buf = np.empty((c.stop - c.start, int(shape[1])), dtype=np.float64)
                comm.Recv(buf, source=r, tag=TAG_ROWS)
                yield c, buf

    return _write_rank0_file(directory, task_id, list(rows), receive, tuple(shape), comm, length, attrs)


def _write_rank0_file(directory: str | Path, task_id: str, names: list[str], receive: Any,
                      shape: tuple[int, int], comm: Any, length: Any, attrs: Mapping[str, Any]) -> Path:
    """Rank 0's part of :func:`_write_rows_rank0`: create the file (telling the other ranks whether it could), then
    write each field's row blocks as ``receive(name)`` yields them, close and rename."""
    import h5py

    d = Path(directory)
    final = d / f"{task_id}.nc"
    tmp = d / f".{task_id}.{os.getpid()}.tmp"
    f: Any = None
    hdf5 = True
    told = False
    try:
        d.mkdir(parents=True, exist_ok=True)
        f = h5py.File(tmp, "w", track_order=True)
        out = _create(f, task_id, shape, names, length=length, attrs=attrs)
        comm.bcast(True, root=0)
        told = True
        for name in names:
            for c, block_rows in receive(name):
                out[name][c.start:c.stop] = block_rows
        f.close()
        hdf5 = False
        os.replace(tmp, final)
    except (OSError, RuntimeError) as e:
        if not told:
            comm.bcast(False, root=0)
        if not hdf5 or f is None:
            raise
        _failed(task_id, d, e)
    except BaseException:
        if not told:  # the other ranks wait for the word: they raise too
            comm.bcast(False, root=0)
        raise
    finally:
        if tmp.exists():
            tmp.unlink()
    return final
