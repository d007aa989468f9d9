"""The sweep store: one HDF5 file per job (or per shard), schema in ``docs/store.md``.

Layout (all datasets preallocated for every task of the job when the file is created, so that rows can be
written independently, in any order, by any rank; under ``driver="mpio"`` the creation is collective):

* ``/tasks``          compound ``(n_tasks,)``: task_id, method, chain, hurst, rho, sigma0, seed, n, lambda_l,
  lambda_s, length, gamma0, e_star, c1, c2 (parameters, written once at creation).
* ``/results``        compound ``(n_tasks,)``: status (int8, see ``STATUS``), message, the float results of
  ``tasks.FLOAT_RESULTS`` (NaN where not computed) and the integer results ``tasks.INT_RESULTS`` (-1).
* ``/histograms/edges`` ``(n_tasks, bins + 1)``, ``/histograms/density`` ``(n_tasks, bins)`` (NaN if none).
* ``/histograms/pressure_edges``, ``/histograms/pressure_density`` (format 2): the local pressure's histogram of
  GFMD rows (its atom at ``p = 0`` in the ``pressure_atom`` column).

Format 1 stores (before the issue-12 columns contact_area, elastic_energy, contact_atom, pressure_atom,
mean_gap_persson, flags and the pressure histograms) still open, read (missing columns as NaN, ``flags`` -1),
resume (the new columns are not written into them), merge and diff.
* file attributes: format, spec text and hash, job name, shard, provenance (versions, git commit), runs.

The default (earliest) HDF5 file format is used on purpose: it has no "file open for write" superblock flag,
so a file whose writer was killed with ``kill -9`` stays readable without ``h5clear`` (docs/store.md). Storage is
allocated at creation (a row write never grows the file); each row is written payload first, status last, and
flushed (serial writer); under ``mpio`` raw data goes straight to MPI-IO (no sieve buffer), and all metadata is
written and flushed at creation. Reliability (leases, validation, write errors): docs/reliability.md.
"""

from __future__ import annotations

import json
import logging
import math
import os
import sys
import threading
from collections.abc import Iterable, Sequence
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import h5py
import numpy as np

from gapsweep.sweep import lease, storecheck
from gapsweep.sweep.schema import (  # noqa: F401 - the store's layout, re-exported as in version 0.1
    CHECKSUM,
    FLOAT_RESULTS,
    FORMAT,
    FORMAT_VERSION,
    INT_RESULTS,
    INTEGRITY,
    MESSAGE_LEN,
    NEW_IN_V2,
    PLUGIN_COLUMNS,
    PRESSURE_HIST,
    RESULT_DTYPE,
    RESULT_DTYPE_V1,
    RESULT_DTYPES,
    STATUS,
    STATUS_NAMES,
    TASK_DTYPE,
    VOLATILE,
    StoreError,
    StoreWriteError,
    Task,
    TaskResult,
    integrity_record,
    plugin_columns_of,
    results_dtype,
    row_checksum,
)
from gapsweep.sweep.writefail import KEEP_TYPES, io_failed, one_line, write_failed  # noqa: F401 - re-exported

ALGO_COLUMN = "algorithm_version"  # format 5 (issue 40 item 5)

log = logging.getLogger("gapsweep.store")

__all__ = [
    "FORMAT",
    "Store",
    "StoreError",
    "StoreWriteError",
    "diff",
    "io_failed",
    "open_read",
    "read",
    "read_attrs",
    "read_histograms",
    "read_pressure_histograms",
    "status",
]

@contextmanager
def _quiet_dealloc():
    """After a failed write HDF5 reports each object it cannot release through ``sys.unraisablehook`` (a
    traceback per object); the error raised to the caller says it once, so those are logged at debug level."""
    import sys

    old = sys.unraisablehook

    def hook(u: Any) -> None:
        if "h5py" in repr(getattr(u, "object", "")) or "ObjectID" in repr(getattr(u, "object", "")):
            log.debug("HDF5 release after a failed write: %s", u.exc_value)
        else:
            old(u)

    import io

    sys.unraisablehook = hook
    err, sys.stderr = sys.stderr, io.StringIO()  # h5py prints some of those tracebacks itself
    try:
        yield
    finally:
        sys.unraisablehook = old
        caught, sys.stderr = sys.stderr.getvalue(), err
        if caught:
            log.debug("HDF5 release after a failed write: %s", caught)


def _failed(msg: str) -> StoreWriteError:
    """:func:`gapsweep.sweep.writefail.write_failed` (called inside the ``except`` of a failed write)."""
    return write_failed(msg)


def _early() -> Any:
    # Allocate every dataset's storage at creation: a row write then only overwrites bytes the file already
    # has, so a disk that fills up (or a file-size limit) during the run cannot hit a row write.
    dcpl = h5py.h5p.create(h5py.h5p.DATASET_CREATE)
    dcpl.set_alloc_time(h5py.h5d.ALLOC_TIME_EARLY)
    return dcpl


def _nan_or(v: Any) -> float:
    return math.nan if v is None else float(v)


def _lx(length: Any) -> float:
    """The ``/tasks`` length column: the box side ``L``, or ``Lx`` of a rectangular box (``[Lx, Ly]`` in the
    spec text, attribute ``spec_text``)."""
    return float(length[0]) if isinstance(length, (list, tuple)) else float(length)


def task_rows(tasks: Sequence[Task]) -> np.ndarray:
    rows = np.zeros(len(tasks), dtype=TASK_DTYPE)
    for i, t in enumerate(tasks):
        rows[i] = (t.task_id.encode(), t.method.encode(), t.chain.encode(), t.hurst, t.rho, t.sigma0, t.seed, t.n,
                   _nan_or(t.opt("surface.lambda_l")), _nan_or(t.opt("surface.lambda_s")), _lx(t.opt("surface.length")),
                   _nan_or(t.opt("gamma0")),
                   t.opt("e_star"), _nan_or(t.opt("c1")), _nan_or(t.opt("c2")))
    return rows


def empty_results(n: int, dtype: np.dtype = RESULT_DTYPE) -> np.ndarray:
    """``n`` pending rows of the table ``dtype``: float results NaN, integer results -1 (plug-in columns too)."""
    r = np.zeros(n, dtype=dtype)
    for k in FLOAT_RESULTS:
        if k in dtype.names:
            r[k] = np.nan
    for k in INT_RESULTS:
        if k in dtype.names:
            r[k] = -1
    for k, kind in plugin_columns_of(dtype) or ():
        r[k] = np.nan if kind == "float" else -1
    return r


def upgrade_results(r: np.ndarray, dtype: np.dtype = RESULT_DTYPE) -> np.ndarray:
    """Results rows of any format as rows of the table ``dtype`` (default: the current one without plug-in
    columns; copied by column name; new columns NaN / -1)."""
    if r.dtype == dtype:
        return r
    out = empty_results(r.shape[0], dtype)
    for k in r.dtype.names:
        if k in dtype.names:
            out[k] = r[k]
    return out


def result_row(res: TaskResult, dtype: np.dtype = RESULT_DTYPE) -> np.ndarray:
    """The results row of ``res`` in the table ``dtype`` (a format-1 store drops the columns it lacks)."""
    row = empty_results(1, dtype)
    row["status"] = STATUS[res.status]
    row["message"] = res.message.encode("utf-8", "replace")[:MESSAGE_LEN]
    values = dict(res.values)
    if "h_rms_spectrum" not in dtype.names:
        # a store of a layout before 5 (resumed): its h_rms, g_rms of a file map are the spectrum's, so its new rows
        # keep that meaning (one column, one quantity within a store; docs/store.md "Formats")
        for k in ("h_rms", "g_rms"):
            spec = values.get(f"{k}_spectrum")
            if spec is not None and math.isfinite(float(spec)):
                values[k] = spec
    for k, v in values.items():
        if k not in dtype.names:
            continue
        if k in FLOAT_RESULTS:
            row[k] = float(v)
        elif k in INT_RESULTS:
            row[k] = int(v)
        elif dtype.fields[k][0].kind in "fi":  # a plug-in column (docs/store.md "Plug-in columns")
            row[k] = float(v) if dtype.fields[k][0].kind == "f" else int(v)
    if res.hist is not None:
        row["count"] = int(res.hist[2])
    return row


def seal(tasks: np.ndarray, results: np.ndarray, bins: int, edges: np.ndarray | None = None,
         density: np.ndarray | None = None, pedges: np.ndarray | None = None,
         pdensity: np.ndarray | None = None) -> np.ndarray:
    """``results`` (format 3) with every row's ``checksum`` set (:func:`gapsweep.sweep.schema.row_checksum`);
    histograms not given are the all-NaN rows of a store's creation. Modifies and returns ``results``."""
    nan_e, nan_d = np.full(bins + 1, np.nan), np.full(bins, np.nan)
    for i in range(len(tasks)):
        results[CHECKSUM][i] = row_checksum(tasks[i], results[i], (
            nan_e if edges is None else edges[i], nan_d if density is None else density[i],
            nan_e if pedges is None else pedges[i], nan_d if pdensity is None else pdensity[i]))
    return results


def reseal(f: h5py.File) -> None:
    """Recompute the checksums of every row of an open format-3 store from its bytes (tests and tools that
    rewrite rows on purpose, e.g. a shard with other results; never used on a store whose damage must show)."""
    g = f["histograms"]
    r = f["results"][...]
    f["results"][...] = seal(f["tasks"][...], r, g["density"].shape[1], g["edges"][...], g["density"][...],
                             g["pressure_edges"][...], g["pressure_density"][...])


def seal_attrs(f: h5py.File, tasks: np.ndarray | None = None) -> None:
    """Write the format-4 checksums of every attribute and of ``/tasks`` (``tasks``: the table, if the caller
    has it) from what the file holds now (schema.integrity_record). Called by every writer of attributes; tests
    and tools that change an attribute on purpose call it too (never on a store whose damage must show)."""
    attrs = storecheck._attributes(f)
    f.attrs[INTEGRITY] = integrity_record(attrs, f["tasks"][...] if tasks is None else tasks)


def _locking_kw() -> dict[str, Any]:
    # A reader of a running store must not take (or wait for) HDF5's file lock.
    return {"locking": False} if h5py.version.hdf5_version_tuple >= (1, 10, 7) else {}


def _writer_file(path: str | Path, mode: str, comm: Any) -> h5py.File:
    """Open a store for writing. Serial: with HDF5's own file lock where the file system supports it
    (``locking="best-effort"``; ``HDF5_USE_FILE_LOCKING=FALSE`` still switches it off) -- beside the lease's lock
    on the file (gapsweep.sweep.lease.FileLock), which is what excludes a second gapsweep writer. Where HDF5's lock
    is refused although the lease is held (NFS emulates ``flock`` by the same byte-range locks), the file is
    opened without it. ``mpio`` takes no file lock (HDF5 does not support one there)."""
    if comm is not None:
        return h5py.File(path, mode, driver="mpio", comm=comm)
    if h5py.version.version_tuple[:2] < (3, 5):
        return h5py.File(path, mode)
    try:
        return h5py.File(path, mode, locking="best-effort")
    except OSError as e:
        if "lock" not in str(e).lower():
            raise
        log.debug("store %s: HDF5's file lock refused (%s); opened under the lease's lock", path, e)
        return h5py.File(path, mode, locking=False)


class Store:
    """An open store for writing. Create with :meth:`create` (collective under mpio) or :meth:`open`."""

    def __init__(self, f: h5py.File, comm: Any = None) -> None:
        self.f = f
        self.path = f.filename  # kept: a file whose close failed must not be asked again
        self.comm = comm
        self._res = f["results"]
        self._edges = f["histograms/edges"]
        self._density = f["histograms/density"]
        # format 2: the pressure histograms (absent in format-1 stores, whose rows then keep the old columns)
        self._pedges = f[PRESSURE_HIST[0]] if PRESSURE_HIST[0] in f else None
        self._pdensity = f[PRESSURE_HIST[1]] if PRESSURE_HIST[1] in f else None
        self._rdtype = self._res.dtype
        # format 3: each row carries its checksum (over its task row, itself and its histograms); which rows hold
        # histograms now, so that a row without one writes none (its NaN rows are already what is stored)
        self._ck = CHECKSUM in (self._rdtype.names or ())
        self._versions = ALGO_COLUMN in (self._rdtype.names or ()) and self._ck
        n = self._res.shape[0]
        self._task_rows = f["tasks"][...] if self._ck and n else None
        self._has_hist = (np.isfinite(self._edges[:, 0]) if n else np.zeros(0, bool)) if self._ck else None
        self._has_phist = (np.isfinite(self._pedges[:, 0]) if n else np.zeros(0, bool)) \
            if self._ck and self._pedges is not None else None
        self._deferred: dict[str, Any] = {}  # attribute fixes waiting for repair_tasks (Store.open)
        self._integrity = INTEGRITY in f.attrs  # format 4: attribute writes keep the checksums current
        # ... of the task table as this process knows it (the same on every rank: read once, or the job's)
        self._tasks_now = f["tasks"][...] if self._integrity else None
        self.parallel = comm is not None
        self.n_tasks = self._res.shape[0]
        self.bins = self._density.shape[1]
        self._nan_rows = (np.full(self.bins + 1, np.nan), np.full(self.bins, np.nan))  # a row without histogram
        # rows that are pending now: a row that is not (run again: timed out, damaged, incomplete) is first marked
        # pending, so that no reader sees its old status beside its new payload (issue 31: false "damaged")
        self._fresh = self.statuses() == STATUS["pending"]

    @classmethod
    def create(cls, path: str | Path, tasks: Sequence[Task], attrs: dict[str, Any], bins: int, *,
               comm: Any = None, columns: Sequence[tuple[str, str]] = ()) -> Store:
        """Create the file with every dataset preallocated. With ``comm`` (mpio) all ranks must call this with
        the same arguments; rank 0 then writes the task table and the initial (pending) rows. ``columns``: the
        job's plug-in columns ``(name, kind)`` (docs/store.md "Plug-in columns"; ``methods.job_columns``)."""
        with _quiet_dealloc():
            return cls._create(path, tasks, attrs, bins, comm, columns)

    @classmethod
    def _create(cls, path: str | Path, tasks: Sequence[Task], attrs: dict[str, Any], bins: int,
                comm: Any, columns: Sequence[tuple[str, str]] = ()) -> Store:
        n = len(tasks)
        if columns:  # plug-in columns: declared in an attribute (covered by the attribute checksums)
            attrs = {**attrs, PLUGIN_COLUMNS: json.dumps([list(c) for c in columns])}
        try:
            f = _writer_file(path, "w", comm)
        except (OSError, RuntimeError) as e:
            raise _failed(f"store {path}: cannot create ({e})") from None
        try:
            for k, v in attrs.items():
                f.attrs[k] = v
            dt = f.create_dataset("tasks", shape=(n,), dtype=TASK_DTYPE, dcpl=_early())
            rdtype = results_dtype(columns)
            dr = f.create_dataset("results", shape=(n,), dtype=rdtype, dcpl=_early())
            g = f.create_group("histograms")
            g.create_dataset("edges", shape=(n, bins + 1), dtype="f8", fillvalue=np.nan, dcpl=_early())
            g.create_dataset("density", shape=(n, bins), dtype="f8", fillvalue=np.nan, dcpl=_early())
            g.create_dataset("pressure_edges", shape=(n, bins + 1), dtype="f8", fillvalue=np.nan, dcpl=_early())
            g.create_dataset("pressure_density", shape=(n, bins), dtype="f8", fillvalue=np.nan, dcpl=_early())
            rows = task_rows(tasks)
            if comm is None or comm.rank == 0:
                if n:
                    dt[...] = rows
                    dr[...] = seal(rows, empty_results(n, rdtype), bins)
            seal_attrs(f, rows)  # every rank the same (collective under mpio)
            f.flush()
            if comm is not None:
                comm.Barrier()
        except (OSError, RuntimeError) as e:
            if isinstance(e, StoreError):
                f.close()
                raise
            raise _failed(f"store {path}: creating the datasets failed ({e})") from None  # not closed: see _failed
        except BaseException:
            f.close()
            raise
        return cls(f, comm)

    @classmethod
    def open(cls, path: str | Path, *, comm: Any = None, repair_tasks: bool = False,
             restore: dict[str, Any] | None = None) -> Store:
        """Open an existing store for writing (validated; ``repair_tasks``: a ``/tasks`` table that fails its
        checksum is accepted, for :meth:`repair_tasks` to restore from the job).

        Attributes that fail their checksum while the rows verify (issue 40 item 1, storecheck.Report) are
        mended first: damaged provenance is rebuilt, marked as lost (provenance.rebuilt); the job spec's
        attributes (or all of them, when the checksum record itself is damaged) are set to ``restore`` -- the
        caller's, checked against every row (``--resume`` with the job file, ``gapsweep repair``) -- and the
        checksums written again. Without ``restore`` such a store is refused in one line naming the remedy."""
        try:
            f = _writer_file(path, "r+", comm)
        except OSError as e:
            raise StoreError(f"store {path}: cannot open for writing ({e})") from None
        try:
            rep = storecheck.check(f, path, tolerate_tasks=repair_tasks)
            fixes: dict[str, Any] = {}
            if rep.attrs_need_repair:
                if not rep.spec_trusted and restore is None:
                    raise StoreError(f"store {path}: {rep.lines()[0]}")
                from gapsweep.sweep.provenance import rebuilt

                fixes = rebuilt(rep.provenance_damaged)
                fixes.update({k: v for k, v in (restore or {}).items() if k in rep.provenance_damaged})
                if not rep.spec_trusted:
                    fixes.update(restore or {})
                if comm is not None:  # every rank writes the same values (collective)
                    fixes = comm.bcast(fixes, root=0)
        except BaseException:
            f.close()
            raise
        st = cls(f, comm)
        if fixes and rep.tasks_damaged:  # sealed now, the damaged /tasks would verify: after repair_tasks
            st._deferred = fixes
        elif fixes:
            st._fix_attrs(fixes)
        return st

    def _fix_attrs(self, fixes: dict[str, Any]) -> None:
        self.set_attrs(fixes, flush=True)
        log.warning("store %s: attribute(s) %s rebuilt or restored, their checksums written again", self.path,
                    ", ".join(sorted(fixes)))

    def repair_tasks(self, tasks: Sequence[Task], *, write: bool = True) -> list[int]:
        """Rewrite the ``/tasks`` rows that differ from the job's (rows found damaged by their checksums;
        ``write``: this rank writes, the others only update what they compute checksums from). Returns the rows."""
        if not self.n_tasks:
            return []
        want = task_rows(tasks)
        have = self.f["tasks"][...]
        bad = [i for i in range(self.n_tasks) if have[i].tobytes() != want[i].tobytes()]
        try:
            if write:
                for i in bad:
                    self.f["tasks"][i] = want[i]
        except (OSError, RuntimeError) as e:
            raise _failed(f"store {self.path}: restoring task rows failed ({e})") from None
        if self._task_rows is not None:
            self._task_rows = want
        if self._integrity:
            self._tasks_now = want
        if self._deferred:
            fixes, self._deferred = self._deferred, {}
            self._fix_attrs(fixes)
        return bad

    def force_histograms(self, rows: Iterable[int]) -> None:
        """Make the next write of each of ``rows`` write its histograms even when it has none (NaN rows): a row
        run again on --resume may hold damaged bytes where its histograms should be NaN (issue 31: a theory,
        SDE or Fokker-Planck row whose NaN histogram or pressure histogram was damaged stayed damaged)."""
        if self._has_hist is None:
            return
        for i in rows:
            self._has_hist[i] = True
            if self._has_phist is not None:
                self._has_phist[i] = True

    def statuses(self) -> np.ndarray:
        return self._res.fields("status")[...] if self.n_tasks else np.zeros(0, dtype="i1")

    def task_ids(self) -> list[str]:
        return [x.decode("utf-8", "replace") for x in self.f["tasks"].fields("task_id")[...]] if self.n_tasks else []

    def write(self, i: int, res: TaskResult, *, flush: bool = True) -> None:
        """Write row ``i`` (independent I/O under mpio): payload first (histogram), status row last, so that a
        row whose status says ``done`` is complete. The serial writer flushes after the payload and after the
        status, so that a ``kill -9`` loses at most the row in flight. An I/O error raises
        :class:`StoreWriteError`."""
        if res.hist is not None and (len(res.hist[1]) != self.bins or len(res.hist[0]) != self.bins + 1):
            raise StoreError(f"histogram of task {i} has {len(res.hist[1])} bins, the store has {self.bins}")
        if res.phist is not None and (len(res.phist[1]) != self.bins or len(res.phist[0]) != self.bins + 1):
            raise StoreError(f"pressure histogram of task {i} has {len(res.phist[1])} bins, the store has {self.bins}")
        with _quiet_dealloc():
            self._write(i, res, flush)

    def _write(self, i: int, res: TaskResult, flush: bool) -> None:
        ck = self._ck
        nan_e, nan_d = self._nan_rows
        hist = (np.asarray(res.hist[0], dtype=np.float64), np.asarray(res.hist[1], dtype=np.float64)) \
            if res.hist is not None else (nan_e, nan_d)
        phist = (np.asarray(res.phist[0], dtype=np.float64), np.asarray(res.phist[1], dtype=np.float64)) \
            if res.phist is not None else (nan_e, nan_d)
        try:
            self._mark_pending(i, flush)
            # A checksummed row's histograms on disk must be what its checksum covers: a row without one writes
            # NaN rows only where an earlier run of it left a histogram (else the creation's NaN rows are there).
            wrote = False
            if res.hist is not None or (ck and self._has_hist[i]):
                self._edges[i], self._density[i] = hist
                wrote = True
            if self._pedges is not None and (res.phist is not None or (ck and self._has_phist[i])):
                self._pedges[i], self._pdensity[i] = phist
                wrote = True
            if flush and not self.parallel and wrote:
                self.f.flush()
            self._inject()
            row = result_row(res, self._rdtype)[0]
            if self._versions:  # format 5: the algorithm that computed the row (issue 40 item 5; every path)
                row[ALGO_COLUMN] = self._algorithm_version(i)
            if ck:  # the checksum travels in the row's own write, after the payload
                row[CHECKSUM] = row_checksum(self._task_rows[i], row, (*hist, *phist))
                self._has_hist[i] = res.hist is not None
                if self._has_phist is not None:
                    self._has_phist[i] = res.phist is not None
            self._res[i] = row
            if flush and not self.parallel:
                self.f.flush()
        except (OSError, RuntimeError) as e:
            raise _failed(f"store {self.path}: writing row {i} failed ({e})") from None

    def _algorithm_version(self, i: int) -> int:
        """ALGORITHM_VERSION of the method plug-in of row ``i`` (docs/store.md "Algorithm versions")."""
        from gapsweep.sweep import methods as registry

        return int(registry.get(self._task_rows[i]["method"].decode()).algorithm_version)

    def _mark_pending(self, i: int, flush: bool) -> None:
        """A row that is not pending in the file (run again: timed out, damaged, incomplete) is first written back
        to pending, so that no reader (and no kill) meets its old status beside its new payload (issue 31)."""
        if self._fresh[i]:
            return
        self._res[i] = empty_results(1, self._rdtype)[0]  # status pending (0): no checksum to match
        if flush and not self.parallel:
            self.f.flush()
        self._fresh[i] = True

    def copy_row(self, i: int, row: np.void, hists: tuple[np.ndarray, ...]) -> None:
        """Write row ``i`` as a finished row taken from another store (``gapsweep run --reuse``): its results row
        (copied by column name) and histograms (gap and pressure: edges, density), payload first, with the
        checksum of this store's row; flushed like :meth:`write`."""
        e, d, pe, pd = (np.asarray(a, dtype=np.float64) for a in hists)
        r = empty_results(1, self._rdtype)[0]
        for k in self._rdtype.names:
            if k in (row.dtype.names or ()) and k != CHECKSUM:
                r[k] = row[k]
        with _quiet_dealloc():
            try:
                self._mark_pending(i, True)
                self._edges[i], self._density[i] = e, d
                if self._pedges is not None:
                    self._pedges[i], self._pdensity[i] = pe, pd
                if not self.parallel:
                    self.f.flush()
                if self._ck:
                    r[CHECKSUM] = row_checksum(self._task_rows[i], r, (e, d, pe, pd))
                    self._has_hist[i] = bool(np.isfinite(e[0]))
                    if self._has_phist is not None:
                        self._has_phist[i] = bool(np.isfinite(pe[0]))
                self._res[i] = r
                if not self.parallel:
                    self.f.flush()
            except (OSError, RuntimeError) as exc:
                raise _failed(f"store {self.path}: writing row {i} failed ({exc})") from None

    def _inject(self) -> None:
        """Fault-injection seam between a row's payload and its status: does nothing here. The fault suite
        replaces it from outside the package (a full disk, a kill -9 at that point; tests/hooks)."""

    def set_attrs(self, attrs: dict[str, Any], *, flush: bool = False) -> None:
        """Set file attributes (collective under mpio: every rank passes the same values)."""
        try:
            with _quiet_dealloc():
                for k, v in attrs.items():
                    self.f.attrs[k] = v
                if self._integrity:
                    seal_attrs(self.f, self._tasks_now)
                if flush:
                    self.f.flush()
        except (OSError, RuntimeError) as e:
            raise _failed(f"store {self.path}: writing attributes failed ({e})") from None

    def close(self) -> None:
        try:
            with _quiet_dealloc():
                self.f.close()
        except (OSError, RuntimeError) as e:
            raise _failed(f"store {self.path}: closing failed ({e})") from None


# ---------------------------------------------------------------------------------------------------------
# reading


# Readers of a store that a live process is writing (issue 40 item 8: under mpio 78 of 4,241 polling reads were
# told "truncated or damaged" while metadata was being written): the read is tried again after these pauses (s),
# then reported as "being written" rather than damaged.
RETRY_DELAYS = (0.02, 0.05, 0.1, 0.2, 0.4, 0.8)
_retrying = threading.local()


def _being_written(path: str | Path) -> dict[str, Any] | None:
    """The lease of ``path`` where another live process (or one on another host, which cannot be checked) holds
    it; a lease of this process (a merge reading its own output) does not count: its errors are its own."""
    import socket

    try:
        held = lease.read(path)
    except OSError:
        return None
    if held is None or held.get("alive") is False:
        return None
    if held.get("host") == socket.gethostname() and held.get("pid") == os.getpid():
        return None
    return held


def while_written(fn: Any) -> Any:
    """Decorate a reader ``fn(path, ...)``: a StoreError (or OSError other than a missing file) raised while a
    live writer holds the store's lease is retried after :data:`RETRY_DELAYS`; if it persists, it is raised as
    "being written by <holder>" with the reader's own message, not as damage. Nested readers retry once."""
    import functools
    import time

    @functools.wraps(fn)
    def wrapper(path: str | Path, *a: Any, **kw: Any) -> Any:
        if getattr(_retrying, "on", False):
            return fn(path, *a, **kw)
        _retrying.on = True
        try:
            for delay in (*RETRY_DELAYS, None):
                try:
                    return fn(path, *a, **kw)
                except FileNotFoundError:
                    raise
                except (StoreError, OSError) as e:
                    held = _being_written(path)
                    if held is None or isinstance(e, StoreWriteError):
                        raise
                    if delay is None:
                        log.debug("store %s: the last read while being written: %s", path, e)
                        raise StoreError(f"store {path}: being written by {lease.describe(held)}; the reads met "
                                         "parts still being written: read again in a moment or when it finishes "
                                         "(`gapsweep status` once the lease is gone tells whether it is damaged)"
                                         ) from None
                    log.debug("store %s: read while being written failed (%s); trying again", path, e)
                    time.sleep(delay)
        finally:
            _retrying.on = False
        raise AssertionError("unreachable")  # pragma: no cover

    return wrapper


def crash_probe(path: str | Path) -> None:
    """Read the store's metadata, attributes and tables (storecheck.check) in a forked child first, and raise a
    one-line StoreError where that crashed the HDF5 library (issue 40 item 3: a flipped byte in an object header
    or the global heap made HDF5 segfault, which no ``except`` catches). A Python error in the child is left to
    the command itself, which meets it again and reports it. For the CLI's reading commands (not under MPI)."""
    import signal

    p = Path(path)
    if not p.is_file() or not hasattr(os, "fork"):
        return
    sys.stdout.flush()
    sys.stderr.flush()
    pid = os.fork()
    if pid == 0:  # the child: quiet, no exit handlers, only the exit status (or the signal) tells
        try:
            import faulthandler

            faulthandler.disable()
            devnull = os.open(os.devnull, os.O_WRONLY)
            os.dup2(devnull, 1)
            os.dup2(devnull, 2)
            logging.disable(logging.CRITICAL)
            # the readers' own path (the check every command starts with), then every table: a crash of HDF5 on
            # damaged metadata is undefined behaviour, most faithfully met by the same calls in the same (forked)
            # memory as the command's; costs one more check of the store
            with open_read(p, check=False) as f:
                try:
                    storecheck.check(f, p, tolerate_tasks=True)
                except StoreError:
                    pass
                for k in ("tasks", "results", "histograms/edges", "histograms/density", *PRESSURE_HIST):
                    if k in f:
                        f[k][...]
        except BaseException:
            pass
        finally:
            os._exit(0)
    _, st = os.waitpid(pid, 0)
    if os.WIFSIGNALED(st):
        sig = os.WTERMSIG(st)
        name = signal.Signals(sig).name if sig in signal.Signals._value2member_map_ else str(sig)
        raise StoreError(f"store {p}: its HDF5 metadata is damaged (reading it crashed the HDF5 library with "
                         f"{name}): not readable; nothing was written")


@contextmanager
def open_read(path: str | Path, *, check: bool = True, tolerate_tasks: bool = False):
    """Open a store read-only without taking HDF5's file lock (it may be running). With ``check`` the
    structure is validated (:mod:`gapsweep.storecheck`): a damaged store raises :class:`StoreError` naming the
    file and the problem."""
    p = Path(path)
    if not p.is_file():
        raise FileNotFoundError(f"store {str(p)!r}: no such file")
    if p.stat().st_size == 0:
        raise StoreError(f"store {p}: empty file (0 bytes): not a gapsweep store")
    try:
        try:
            f = h5py.File(p, "r", **_locking_kw())
        except OSError as e:
            # Already open in this process (HDF5 shares the file) with other locking flags: open it as it is.
            if "locking flag" not in str(e):
                raise
            f = h5py.File(p, "r")
    except OSError as e:
        raise StoreError(f"store {p}: not a readable HDF5 file ({e}): truncated or damaged") from None
    with f:
        if check:
            storecheck.check(f, p, tolerate_tasks=tolerate_tasks)
        elif f.attrs.get("format") != FORMAT:
            if INTEGRITY in f.attrs:  # format 4: a changed format attribute is named as such
                storecheck.check(f, p)
            raise StoreError(f"store {p}: not a gapsweep store (format attribute {f.attrs.get('format')!r})")
        try:
            yield f
        except (KeyError, IndexError, ValueError) as e:
            raise StoreError(f"store {p}: damaged ({type(e).__name__}: {e})") from None
        except OSError as e:
            raise StoreError(f"store {p}: read error ({e}): damaged store") from None


@while_written
def read_attrs(path: str | Path, *, tolerate_tasks: bool = False) -> dict[str, Any]:
    """File attributes as Python values (strings decoded). ``tolerate_tasks``: see :func:`storecheck.check`."""
    with open_read(path, tolerate_tasks=tolerate_tasks) as f:
        return {k: (v.decode("utf-8", "replace") if isinstance(v, bytes) else v) for k, v in f.attrs.items()}


@while_written
def read(path: str | Path, *, mark_damaged: bool = True, tolerate_tasks: bool = False):
    """One row per task: parameters, status (string), message and results (``docs/store.md``).

    Returns a ``pandas.DataFrame`` with columns task_id, method, chain, hurst, rho, sigma0, seed, n, lambda_l,
    lambda_s, length, gamma0, e_star, c1, c2, status, message, the float results (NaN where not computed) and
    iterations, count, rank (-1 where not computed). A row whose checksum does not match its bytes has the status
    ``"damaged"`` (and a warning is logged): analysis that keeps ``done`` rows leaves it out; ``mark_damaged =
    False`` gives the stored status (a comparison of contents, :func:`diff`)."""
    import pandas as pd

    with open_read(path, check=False) as f:
        report = storecheck.check(f, path, tolerate_tasks=tolerate_tasks)
        t = f["tasks"][...]
        r = f["results"][...]
    if not mark_damaged:
        report.damaged = []
    if report.damaged:
        log.warning("store %s: %d damaged row(s) (checksum mismatch), read with status 'damaged': %s", path,
                    len(report.damaged), report.damaged[:5])
    cols: dict[str, Any] = {}
    for k in TASK_DTYPE.names:
        cols[k] = [x.decode("utf-8", "replace") for x in t[k]] if TASK_DTYPE[k].kind == "S" else t[k]
    cols["status"] = [STATUS_NAMES.get(int(s), "unknown") for s in r["status"]]
    for i in report.damaged:
        cols["status"][i] = "damaged"
    cols["message"] = [x.decode("utf-8", "replace") for x in r["message"]]
    for k in FLOAT_RESULTS + INT_RESULTS:  # a format-1 store lacks the newer columns: NaN (floats), -1 (flags)
        cols[k] = r[k] if k in r.dtype.names else np.full(len(r), np.nan if k in FLOAT_RESULTS else -1)
    for k, _ in plugin_columns_of(r.dtype) or ():  # the plug-in columns of the job, after the others
        cols[k] = r[k]
    return pd.DataFrame(cols)


@while_written
def read_pressure_histograms(path: str | Path, task_ids: Iterable[str] | None = None,
                             ) -> dict[str, tuple[np.ndarray, np.ndarray, float]]:
    """``{task_id: (edges, density, atom)}`` of the local pressure for GFMD rows that have one (format-2
    stores): ``atom`` is the fraction at exactly ``p = 0`` (hard wall: the free surface), ``density`` that of the
    other points, integrating to ``1 - atom``. Empty for format-1 stores."""
    with open_read(path) as f:
        if PRESSURE_HIST[0] not in f or not f["tasks"].shape[0]:
            return {}
        ids = [x.decode("utf-8", "replace") for x in f["tasks"].fields("task_id")[...]]
        atom = f["results"].fields("pressure_atom")[...]
        e_all, d_all = f[PRESSURE_HIST[0]][...], f[PRESSURE_HIST[1]][...]
    want = set(task_ids) if task_ids is not None else None
    out = {}
    for i, tid in enumerate(ids):
        if (want is None or tid in want) and np.all(np.isfinite(e_all[i])):
            out[tid] = (e_all[i], d_all[i], float(atom[i]))
    return out


@while_written
def read_histograms(path: str | Path, task_ids: Iterable[str] | None = None,
                    ) -> dict[str, tuple[np.ndarray, np.ndarray, int]]:
    """``{task_id: (edges, density, count)}`` for tasks that have a histogram (density integrates to 1 over
    the bins; count = samples or pixels binned). ``task_ids`` restricts the selection."""
    with open_read(path) as f:
        ids = [x.decode("utf-8", "replace") for x in f["tasks"].fields("task_id")[...]] if f["tasks"].shape[0] else []
        count = f["results"].fields("count")[...] if ids else np.zeros(0, dtype="i8")
        want = set(task_ids) if task_ids is not None else None
        out = {}
        edges_ds, dens_ds = f["histograms/edges"], f["histograms/density"]
        for i, tid in enumerate(ids):
            if want is not None and tid not in want:
                continue
            e = edges_ds[i]
            if not np.all(np.isfinite(e)):
                continue
            out[tid] = (e, dens_ds[i], int(count[i]))
    return out


@while_written
def status(path: str | Path) -> str:
    """A short text summary of a running or finished store (counts per method and status, runs, failures).
    Temporary files of a killed creation or merge of this store are removed first and named (issue 40 item 7)."""
    gone = lease.remove_leftovers(path)
    attrs = read_attrs(path, tolerate_tasks=True)  # a damaged /tasks is a line of the summary, not its end
    df = read(path, tolerate_tasks=True)
    with open_read(path, check=False) as f:
        report = storecheck.check(f, path, tolerate_tasks=True)
    lines = [f"store {path}: job {attrs.get('job_name')!r}, {len(df)} tasks"
             + (f", shard {attrs['shard']}" if attrs.get("shard") else "")]
    held = lease.read(path)
    if held is not None:
        lines.append(f"lease: held by {lease.describe(held)}")
    lines.extend(f"removed: {x}, the temporary file of a killed creation, merge or export of this store"
                 for x in gone)
    lines.extend(f"check: {x}" for x in report.lines())
    if len(df):
        tab = df.groupby(["method", "status"]).size().unstack(fill_value=0)
        cols = [*STATUS, *(x for x in ("unknown", "damaged") if x in tab.columns)]
        for s in cols:
            if s not in tab.columns:
                tab[s] = 0
        tab = tab[cols]
        tab.loc["total"] = tab.sum()
        lines.append(tab.to_string())
        done = df[(df.status != "pending") & df.wall_time.notna()]
        if len(done):
            lines.append(f"wall time of finished tasks: {np.nansum(done.wall_time):.1f} s "
                         f"(max {np.nanmax(done.wall_time):.2f} s)")
    runs = storecheck.run_records(attrs.get("runs", "[]"))
    for r in runs:
        end = r.get("finished") or "(running or killed)"
        if r.get("interrupted"):
            end = f"{r.get('interrupted_at')} (interrupted by {r['interrupted']}, {r.get('counts')})"
        elif r.get("stopped"):
            end = f"{r.get('stopped_at')} (stopped: {r['stopped']})"
        lines.append(f"run: started {r.get('started')} finished {end} "
                     f"ranks {r.get('mpi_size')} writer {r.get('writer')} hosts {','.join(r.get('hosts', []))}")
        if r.get("reused_older"):
            lines.append(f"  --reuse-older: rows of another algorithm version copied from {r['reused_older']}")
    lines.extend(_versions(df))
    bad = df[df.status.isin(["failed", "not_converged"])]
    for _, row in bad.head(10).iterrows():
        lines.append(f"  {row.status}: {row.task_id} {row.method} H={row.hurst:g} rho={row.rho:g} "
                     f"sigma0={row.sigma0:g} seed={row.seed}: {row.message}")
    if len(bad) > 10:
        lines.append(f"  ... and {len(bad) - 10} more")
    lines.extend(_unfinished(path, df))
    return "\n".join(lines)


def _versions(df: Any) -> list[str]:
    """Status lines about finished rows not computed by the current algorithm version of their method (column
    algorithm_version: another version, or -1 unknown -- a store written before format 5, or a row copied from one
    by ``--reuse-older``); issue 40 item 5."""
    from gapsweep.sweep import methods as registry

    out = []
    fin = df[df.status.isin(["done", "failed", "not_converged"])]
    for m, g in fin.groupby("method"):
        try:
            cur = registry.get(str(m)).algorithm_version
        except (KeyError, ValueError):
            continue
        v = g.algorithm_version.astype(int)
        unknown, other = int((v < 0).sum()), g[(v >= 0) & (v != cur)]
        if len(other):
            out.append(f"algorithm: {len(other)} {m} row(s) computed by version(s) "
                       f"{sorted(set(other.algorithm_version.astype(int)))} (current {cur})")
        if unknown:
            out.append(f"algorithm: {unknown} {m} row(s) of unknown algorithm version (written before format 5, "
                       "or copied from such a store by --reuse-older)")
    return out


def _unfinished(path: str | Path, df: Any) -> list[str]:
    """The status lines about rows a run left pending (which ones, and that ``--resume`` runs them) and about
    failed rows (finished: ``--resume`` runs only the timed-out ones again)."""
    out = []
    pend = df[df.status == "pending"]
    if len(pend):
        ids = ", ".join(f"{r.task_id} ({r.method})" for r in pend.head(10).itertuples())
        out.append(f"pending: {len(pend)} row(s) not run yet: {ids}" + (" ..." if len(pend) > 10 else ""))
        out.append(f"  `gapsweep run JOB --store {path} --resume` runs them (JOB: this store's spec, attribute "
                   "spec_text); nothing else is run again")
    failed = int((df.status == "failed").sum())
    if failed:
        out.append(f"failed: {failed} row(s) (listed above); --resume runs the timed-out ones again, the others "
                   "are finished (--overwrite starts the store again)")
    return out


def diff(a: str | Path, b: str | Path, *, ignore: Sequence[str] = VOLATILE) -> list[str]:
    """Differences in content between two stores (empty list: identical). Compares the spec hash, the task
    table, every result column except ``ignore`` (wall time and rank by default) and the histograms, bit for
    bit (NaN equals NaN). Provenance attributes (times, hosts, MPI size, writer) are not content."""
    out: list[str] = []
    with open_read(a) as fa, open_read(b) as fb:
        if fa.attrs["spec_sha256"] != fb.attrs["spec_sha256"]:
            out.append("spec_sha256 differs")
        ta, tb = fa["tasks"][...], fb["tasks"][...]
        if ta.shape != tb.shape:
            return [*out, f"task count {ta.shape[0]} != {tb.shape[0]}"]
        for k in TASK_DTYPE.names:
            if not _same(ta[k], tb[k]):
                out.append(f"tasks.{k} differs")
        ra, rb = fa["results"][...], fb["results"][...]
        for k in dict.fromkeys((*RESULT_DTYPE.names, *ra.dtype.names, *rb.dtype.names)):
            if k in ignore:
                continue
            if (k in ra.dtype.names) != (k in rb.dtype.names):
                out.append(f"results.{k} only in {'the first' if k in ra.dtype.names else 'the second'} store "
                           "(format 1 vs 2)")
            elif k in ra.dtype.names and not _same(ra[k], rb[k]):
                rows = np.flatnonzero(~_eq(ra[k], rb[k]))
                out.append(f"results.{k} differs in {rows.size} rows (first: {rows[:5].tolist()})")
        for k in ("edges", "density", "pressure_edges", "pressure_density"):
            if k in fa["histograms"] and k in fb["histograms"] and not _same(fa["histograms"][k][...],
                                                                              fb["histograms"][k][...]):
                out.append(f"histograms.{k} differs")
    return out


def _eq(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    if x.dtype.kind == "f":
        return (x == y) | (np.isnan(x) & np.isnan(y))
    return x == y


def _same(x: np.ndarray, y: np.ndarray) -> bool:
    return x.shape == y.shape and bool(np.all(_eq(x, y)))


KEEP_TYPES.append(Store)  # a Store holds an h5py.File: kept alive after a failed write as well (writefail)
