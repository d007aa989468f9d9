"""The sweep store: one HDF5 file per job (or per shard), schema in ``docs/store.md``.

Layout (all datasets preallocated for every task of the job when the file is created, so that rows can be
written independently, in any order, by any rank; under ``driver="mpio"`` the creation is collective):

* ``/tasks``          compound ``(n_tasks,)``: task_id, method, chain, hurst, rho, sigma0, seed, n, lambda_l,
  lambda_s, length, gamma0, e_star, c1, c2 (parameters, written once at creation).
* ``/results``        compound ``(n_tasks,)``: status (int8, see ``STATUS``), message, the float results of
  ``tasks.FLOAT_RESULTS`` (NaN where not computed) and the integer results ``tasks.INT_RESULTS`` (-1).
* ``/histograms/edges`` ``(n_tasks, bins + 1)``, ``/histograms/density`` ``(n_tasks, bins)`` (NaN if none).
* file attributes: format, spec text and hash, job name, shard, provenance (versions, git commit), runs.

The default (earliest) HDF5 file format is used on purpose: it has no "file open for write" superblock flag,
so a file whose writer was killed with ``kill -9`` stays readable without ``h5clear`` (docs/store.md). Each row is
flushed as it is written (serial writer); under ``mpio`` raw data goes straight to MPI-IO (no sieve buffer),
and all metadata is written and flushed at creation.
"""

from __future__ import annotations

import json
import math
import os
from collections.abc import Iterable, Sequence
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import h5py
import numpy as np

from gapsweep.tasks import FLOAT_RESULTS, INT_RESULTS, STATUS, Task, TaskResult

__all__ = [
    "FORMAT",
    "Store",
    "StoreError",
    "diff",
    "merge",
    "open_read",
    "read",
    "read_attrs",
    "read_histograms",
    "status",
]

FORMAT = "gapsweep-store"
FORMAT_VERSION = 1
MESSAGE_LEN = 240
STATUS_NAMES = {v: k for k, v in STATUS.items()}

TASK_DTYPE = np.dtype([
    ("task_id", "S16"), ("method", "S16"), ("chain", "S16"), ("hurst", "f8"), ("rho", "f8"), ("sigma0", "f8"),
    ("seed", "i8"), ("n", "i8"), ("lambda_l", "f8"), ("lambda_s", "f8"), ("length", "f8"), ("gamma0", "f8"),
    ("e_star", "f8"), ("c1", "f8"), ("c2", "f8"),
])
RESULT_DTYPE = np.dtype(
    [("status", "i1"), ("message", f"S{MESSAGE_LEN}")]
    + [(k, "f8") for k in FLOAT_RESULTS]
    + [(k, "i8") for k in INT_RESULTS]
)
# Columns that differ between two runs of the same job by nature (compare stores without them).
VOLATILE = ("wall_time", "rank")


class StoreError(RuntimeError):
    """A store cannot be used as asked (wrong spec, wrong format, conflicting merge)."""


def _nan_or(v: Any) -> float:
    return math.nan if v is None else float(v)


def task_rows(tasks: Sequence[Task]) -> np.ndarray:
    rows = np.zeros(len(tasks), dtype=TASK_DTYPE)
    for i, t in enumerate(tasks):
        rows[i] = (t.task_id.encode(), t.method.encode(), t.chain.encode(), t.hurst, t.rho, t.sigma0, t.seed, t.n,
                   t.opt("surface.lambda_l"), t.opt("surface.lambda_s"), t.opt("surface.length"), t.opt("gamma0"),
                   t.opt("e_star"), _nan_or(t.opt("c1")), _nan_or(t.opt("c2")))
    return rows


def empty_results(n: int) -> np.ndarray:
    r = np.zeros(n, dtype=RESULT_DTYPE)
    for k in FLOAT_RESULTS:
        r[k] = np.nan
    for k in INT_RESULTS:
        r[k] = -1
    return r


def result_row(res: TaskResult) -> np.ndarray:
    row = empty_results(1)
    row["status"] = STATUS[res.status]
    row["message"] = res.message.encode("utf-8", "replace")[:MESSAGE_LEN]
    for k, v in res.values.items():
        if k in FLOAT_RESULTS:
            row[k] = float(v)
        elif k in INT_RESULTS:
            row[k] = int(v)
    if res.hist is not None:
        row["count"] = int(res.hist[2])
    return row


def _locking_kw() -> dict[str, Any]:
    # A reader of a running store must not take (or wait for) HDF5's file lock.
    return {"locking": False} if h5py.version.hdf5_version_tuple >= (1, 10, 7) else {}


class Store:
    """An open store for writing. Create with :meth:`create` (collective under mpio) or :meth:`open`."""

    def __init__(self, f: h5py.File, comm: Any = None) -> None:
        self.f = f
        self.comm = comm
        self._res = f["results"]
        self._edges = f["histograms/edges"]
        self._density = f["histograms/density"]
        self.parallel = comm is not None
        self.n_tasks = self._res.shape[0]
        self.bins = self._density.shape[1]

    @classmethod
    def create(cls, path: str | Path, tasks: Sequence[Task], attrs: dict[str, Any], bins: int, *,
               comm: Any = None) -> Store:
        """Create the file with every dataset preallocated. With ``comm`` (mpio) all ranks must call this with
        the same arguments; rank 0 then writes the task table and the initial (pending) rows."""
        n = len(tasks)
        if comm is not None:
            f = h5py.File(path, "w", driver="mpio", comm=comm)
        else:
            f = h5py.File(path, "w")
        try:
            for k, v in attrs.items():
                f.attrs[k] = v
            dt = f.create_dataset("tasks", shape=(n,), dtype=TASK_DTYPE)
            dr = f.create_dataset("results", shape=(n,), dtype=RESULT_DTYPE)
            g = f.create_group("histograms")
            g.create_dataset("edges", shape=(n, bins + 1), dtype="f8", fillvalue=np.nan)
            g.create_dataset("density", shape=(n, bins), dtype="f8", fillvalue=np.nan)
            if comm is None or comm.rank == 0:
                if n:
                    dt[...] = task_rows(tasks)
                    dr[...] = empty_results(n)
            f.flush()
            if comm is not None:
                comm.Barrier()
        except BaseException:
            f.close()
            raise
        return cls(f, comm)

    @classmethod
    def open(cls, path: str | Path, *, comm: Any = None) -> Store:
        f = h5py.File(path, "r+", driver="mpio", comm=comm) if comm is not None else h5py.File(path, "r+")
        if f.attrs.get("format") != FORMAT:
            f.close()
            raise StoreError(f"{path}: not a gapsweep store")
        return cls(f, comm)

    def statuses(self) -> np.ndarray:
        return self._res.fields("status")[...] if self.n_tasks else np.zeros(0, dtype="i1")

    def task_ids(self) -> list[str]:
        return [x.decode() for x in self.f["tasks"].fields("task_id")[...]] if self.n_tasks else []

    def write(self, i: int, res: TaskResult, *, flush: bool = True) -> None:
        """Write row ``i`` (independent I/O under mpio). The serial writer flushes each row so that a
        ``kill -9`` loses at most the rows in flight."""
        if res.hist is not None and (len(res.hist[1]) != self.bins or len(res.hist[0]) != self.bins + 1):
            raise StoreError(f"histogram of task {i} has {len(res.hist[1])} bins, the store has {self.bins}")
        self._res[i] = result_row(res)[0]
        if res.hist is not None:
            edges, density, _ = res.hist
            self._edges[i] = edges
            self._density[i] = density
        if flush and not self.parallel:
            self.f.flush()

    def set_attrs(self, attrs: dict[str, Any]) -> None:
        """Set file attributes (collective under mpio: every rank passes the same values)."""
        for k, v in attrs.items():
            self.f.attrs[k] = v

    def close(self) -> None:
        self.f.close()


# ---------------------------------------------------------------------------------------------------------
# reading


@contextmanager
def open_read(path: str | Path):
    """Open a store read-only without taking HDF5's file lock (it may be running)."""
    p = Path(path)
    if not p.is_file():
        raise FileNotFoundError(f"store {str(p)!r}: no such file")
    try:
        f = h5py.File(p, "r", **_locking_kw())
    except OSError as e:
        # Already open in this process (HDF5 shares the file) with other locking flags: open it as it is.
        if "locking flag" not in str(e):
            raise
        f = h5py.File(p, "r")
    with f:
        if f.attrs.get("format") != FORMAT:
            raise StoreError(f"{p}: not a gapsweep store (format attribute {f.attrs.get('format')!r})")
        yield f


def read_attrs(path: str | Path) -> dict[str, Any]:
    """File attributes as Python values (strings decoded)."""
    with open_read(path) as f:
        return {k: (v.decode() if isinstance(v, bytes) else v) for k, v in f.attrs.items()}


def read(path: str | Path):
    """One row per task: parameters, status (string), message and results (``docs/store.md``).

    Returns a ``pandas.DataFrame`` with columns task_id, method, chain, hurst, rho, sigma0, seed, n, lambda_l,
    lambda_s, length, gamma0, e_star, c1, c2, status, message, the float results (NaN where not computed) and
    iterations, count, rank (-1 where not computed)."""
    import pandas as pd

    with open_read(path) as f:
        t = f["tasks"][...]
        r = f["results"][...]
    cols: dict[str, Any] = {}
    for k in TASK_DTYPE.names:
        cols[k] = [x.decode() for x in t[k]] if TASK_DTYPE[k].kind == "S" else t[k]
    cols["status"] = [STATUS_NAMES.get(int(s), "unknown") for s in r["status"]]
    cols["message"] = [x.decode("utf-8", "replace") for x in r["message"]]
    for k in FLOAT_RESULTS + INT_RESULTS:
        cols[k] = r[k]
    return pd.DataFrame(cols)


def read_histograms(path: str | Path, task_ids: Iterable[str] | None = None,
                    ) -> dict[str, tuple[np.ndarray, np.ndarray, int]]:
    """``{task_id: (edges, density, count)}`` for tasks that have a histogram (density integrates to 1 over
    the bins; count = samples or pixels binned). ``task_ids`` restricts the selection."""
    with open_read(path) as f:
        ids = [x.decode() for x in f["tasks"].fields("task_id")[...]] if f["tasks"].shape[0] else []
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


def status(path: str | Path) -> str:
    """A short text summary of a running or finished store (counts per method and status, runs, failures)."""
    attrs = read_attrs(path)
    df = read(path)
    lines = [f"store {path}: job {attrs.get('job_name')!r}, {len(df)} tasks"
             + (f", shard {attrs['shard']}" if attrs.get("shard") else "")]
    if len(df):
        tab = df.groupby(["method", "status"]).size().unstack(fill_value=0)
        for s in STATUS:
            if s not in tab.columns:
                tab[s] = 0
        tab = tab[list(STATUS)]
        tab.loc["total"] = tab.sum()
        lines.append(tab.to_string())
        done = df[(df.status != "pending") & df.wall_time.notna()]
        if len(done):
            lines.append(f"wall time of finished tasks: {np.nansum(done.wall_time):.1f} s "
                         f"(max {np.nanmax(done.wall_time):.2f} s)")
    runs = json.loads(attrs.get("runs", "[]"))
    for r in runs:
        lines.append(f"run: started {r.get('started')} finished {r.get('finished') or '(running or killed)'} "
                     f"ranks {r.get('mpi_size')} writer {r.get('writer')} hosts {','.join(r.get('hosts', []))}")
    bad = df[df.status.isin(["failed", "not_converged"])]
    for _, row in bad.head(10).iterrows():
        lines.append(f"  {row.status}: {row.task_id} {row.method} H={row.hurst:g} rho={row.rho:g} "
                     f"sigma0={row.sigma0:g} seed={row.seed}: {row.message}")
    if len(bad) > 10:
        lines.append(f"  ... and {len(bad) - 10} more")
    return "\n".join(lines)


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
        for k in RESULT_DTYPE.names:
            if k not in ignore and not _same(ra[k], rb[k]):
                rows = np.flatnonzero(~_eq(ra[k], rb[k]))
                out.append(f"results.{k} differs in {rows.size} rows (first: {rows[:5].tolist()})")
        for k in ("edges", "density"):
            if not _same(fa["histograms"][k][...], fb["histograms"][k][...]):
                out.append(f"histograms.{k} differs")
    return out


def _eq(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    if x.dtype.kind == "f":
        return (x == y) | (np.isnan(x) & np.isnan(y))
    return x == y


def _same(x: np.ndarray, y: np.ndarray) -> bool:
    return x.shape == y.shape and bool(np.all(_eq(x, y)))


# ---------------------------------------------------------------------------------------------------------
# merge


def merge(shards: Sequence[str | Path], out: str | Path, *, overwrite: bool = False) -> dict[str, int]:
    """Merge shard stores of one job into ``out`` (rows in the job's canonical task order, keyed by task id).

    All shards must carry the same spec (hash). A task found done in two shards keeps the first; the merged
    store lists every task of the job (missing ones stay pending). Returns counts per status."""
    from gapsweep import provenance
    from gapsweep import spec as specmod
    from gapsweep import tasks as tasksmod

    if not shards:
        raise StoreError("merge: no shard stores given")
    outp = Path(out)
    if outp.exists() and not overwrite:
        raise StoreError(f"merge: {outp} exists (pass --overwrite to replace it)")
    metas = [read_attrs(s) for s in shards]
    shas = {m["spec_sha256"] for m in metas}
    if len(shas) != 1:
        raise StoreError(f"merge: shards come from different job specs ({len(shas)} spec hashes)")
    js = specmod.loads(metas[0]["spec_text"])
    tasks = tasksmod.expand(js)
    index = {t.task_id: i for i, t in enumerate(tasks)}
    runs = []
    for m in metas:
        runs.extend(json.loads(m.get("runs", "[]")))
    attrs = provenance.store_attrs(js, shard="", extra={"merged_from": json.dumps([str(s) for s in shards]),
                                                        "runs": json.dumps(runs)})
    tmp = outp.with_name(outp.name + ".tmp")
    st = Store.create(tmp, tasks, attrs, js.histogram["bins"])
    try:
        results = empty_results(len(tasks))
        edges = np.full((len(tasks), st.bins + 1), np.nan)
        dens = np.full((len(tasks), st.bins), np.nan)
        for s in shards:
            with open_read(s) as f:
                if f["tasks"].shape[0] == 0:
                    continue
                ids = [x.decode() for x in f["tasks"].fields("task_id")[...]]
                r = f["results"][...]
                e, d = f["histograms/edges"][...], f["histograms/density"][...]
            for j, tid in enumerate(ids):
                if tid not in index:
                    raise StoreError(f"merge: task {tid} of {s} is not in the job")
                i = index[tid]
                if r["status"][j] == STATUS["pending"] or results["status"][i] != STATUS["pending"]:
                    continue
                results[i] = r[j]
                edges[i], dens[i] = e[j], d[j]
        if len(tasks):
            st.f["results"][...] = results
            st.f["histograms/edges"][...] = edges
            st.f["histograms/density"][...] = dens
        st.f.attrs["finished"] = provenance.now()
    finally:
        st.close()
    os.replace(tmp, outp)
    return {name: int(np.sum(results["status"] == code)) for name, code in STATUS.items()}


# ---------------------------------------------------------------------------------------------------------
# standard data views (gapsweep.dataset): xarray, netCDF4, a tolerant diff, kept fields

__all__ += ["export_netcdf", "open_fields", "to_dataset"]
_exact_diff = diff


def diff(a: str | Path, b: str | Path, *, rtol: float = 0.0, atol: float = 0.0,
         ignore: Sequence[str] = VOLATILE) -> list[str]:
    """Differences in content between two stores (empty list: equal). With ``rtol = atol = 0`` (default) bit
    for bit, as before; otherwise float results and histograms may differ by ``atol + rtol |b|`` (e.g. a merge of
    shards that summed in another order), see :func:`gapsweep.dataset.diff`."""
    if rtol == 0 and atol == 0:
        return _exact_diff(a, b, ignore=ignore)
    from gapsweep import dataset

    return dataset.diff(a, b, rtol=rtol, atol=atol, ignore=ignore)


def to_dataset(path: str | Path, *, n: int | None = None, c2: float | None = None):
    """The store at ``path`` as an ``xarray.Dataset`` (CF attributes, provenance), see
    :func:`gapsweep.dataset.to_dataset`."""
    from gapsweep import dataset

    return dataset.to_dataset(path, n=n, c2=c2)


def export_netcdf(path: str | Path, out: str | Path, *, overwrite: bool = False) -> Path:
    """Write the store as netCDF4 (``gapsweep export``): :func:`gapsweep.dataset.export_netcdf`."""
    from gapsweep import dataset

    return dataset.export_netcdf(path, out, overwrite=overwrite)


def open_fields(path: str | Path, task_ids: Iterable[str] | None = None) -> dict:
    """Kept fields of chosen GFMD tasks as xarray Datasets: :func:`gapsweep.dataset.open_fields`."""
    from gapsweep import dataset

    return dataset.open_fields(path, task_ids)
