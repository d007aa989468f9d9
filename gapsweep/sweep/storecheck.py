"""Validation of a store on open (``docs/reliability.md``, schema in ``docs/store.md``).

Two kinds of problems:

* *structural* (a dataset missing, a wrong dtype or shape, tables of different lengths, not HDF5 at all): the
  store cannot be used; :func:`check` raises :class:`~gapsweep.store.StoreError` with one line naming the file
  and the problem.
* *row-level* (an unknown status code; a ``done`` row of a method that stores a histogram without one, or
  without a finite mean gap): such rows are reported by :func:`check` and re-run by ``--resume``.
"""

from __future__ import annotations

import json
import logging
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from gapsweep.sweep import methods as registry
from gapsweep.sweep.schema import (
    CHECKSUM,
    FORMAT,
    INTEGRITY,
    INTERRUPTED_PREFIX,
    LAYOUTS,
    MISSING_EXTRA_PREFIX,
    PLUGIN_COLUMNS,
    PRESSURE_HIST,
    PROVENANCE_ATTRS,
    SPEC_ATTRS,
    STATUS,
    TASK_DTYPE,
    TIMEOUT_PREFIX,
    Layout,
    StoreError,
    integrity_problems,
    layout_of,
    plugin_columns_of,
    row_checksum,
)

log = logging.getLogger("gapsweep.sweep.storecheck")

__all__ = ["Report", "check", "incomplete_rows", "run_records", "runs_problem"]



@dataclass
class Report:
    """What :func:`check` found: task count and the indices of rows that must be re-run, with reasons."""

    n_tasks: int
    unknown_status: list[int] = field(default_factory=list)
    done_incomplete: list[int] = field(default_factory=list)
    damaged: list[int] = field(default_factory=list)  # rows whose checksum does not match their bytes
    checksums: bool = True  # False: a store of format 1 or 2, whose rows carry no checksum
    layout: Layout | None = None  # the store's layout (gapsweep.sweep.schema.LAYOUTS)
    tasks_damaged: bool = False  # format 4, check(tolerate_tasks=True): /tasks failed its checksum
    path: str = ""
    runs_damaged: str | None = None  # why the run records (attribute runs) cannot be read; None: they can
    # format 4, issue 40 item 1: damage that leaves every row usable (each row verifies on its own checksum)
    provenance_damaged: list[str] = field(default_factory=list)  # PROVENANCE_ATTRS that fail their checksum
    spec_damaged: list[str] = field(default_factory=list)  # SPEC_ATTRS that fail their checksum
    integrity_damaged: bool = False  # the attribute checksums themselves: the attributes are unverified

    @property
    def spec_trusted(self) -> bool:
        """Whether the spec attributes verify (no damage found and the checksums that would find it intact)."""
        return not self.spec_damaged and not self.integrity_damaged

    @property
    def attrs_need_repair(self) -> bool:
        """Whether ``--resume`` / ``gapsweep repair`` has attributes to rebuild or restore."""
        return bool(self.provenance_damaged or self.spec_damaged or self.integrity_damaged)

    @property
    def rerun(self) -> list[int]:
        return sorted(set(self.unknown_status) | set(self.done_incomplete) | set(self.damaged))

    def lines(self) -> list[str]:
        out = []
        name = self.layout.name if self.layout is not None else "?"
        if self.tasks_damaged:
            out.append("table '/tasks' (task ids and parameters) fails its checksum: changed after it was "
                       "written; --resume restores it from the job (merge and export refuse the store, merge "
                       "--skip-damaged leaves out rows whose task is not the job's)")
        if self.runs_damaged:
            out.append(f"the run records (attribute 'runs') are damaged ({self.runs_damaged}): their history is "
                       "lost; --resume starts a new list, the rows are not affected")
        if self.integrity_damaged:
            out.append(f"attribute {INTEGRITY!r} (the checksums of the others) is damaged: the attributes are "
                       "unverified, the rows verify on their own checksums; `gapsweep repair STORE` rebuilds it "
                       "(with --job JOB.toml where the spec text does not match its hash)")
        if self.provenance_damaged:
            names = ", ".join(repr(x) for x in self.provenance_damaged)
            out.append(f"provenance attribute(s) {names} fail their checksum: not trusted (lost), the rows are not "
                       "affected; `gapsweep repair STORE` or --resume rebuilds them (marked as lost)")
        if self.spec_damaged:
            names = ", ".join(repr(x) for x in self.spec_damaged)
            out.append(f"job spec attribute(s) {names} fail their checksum: the rows verify on their own "
                       "checksums; `gapsweep run JOB --store STORE --resume` or `gapsweep repair STORE --job JOB` "
                       "restores them from the job file after checking every row against it")
        if not self.checksums:
            out.append(f"no row checksums this version verifies (format {name}, written before 3c): rows are "
                       "checked for completeness only, not for changed bytes")
        if self.layout is not None and not self.layout.integrity:
            out.append(f"no attribute checksums (format {name}, written before format 4): units, spec, format "
                       "version, task ids and run records are not verified")
        if self.damaged:
            out.append(f"{len(self.damaged)} damaged row(s): checksum mismatch (rows {self.damaged[:5]}"
                       f"{' ...' if len(self.damaged) > 5 else ''}): their parameters, results or histograms "
                       "changed after they were written; re-run by --resume, refused by merge and export "
                       "unless --skip-damaged")
        if self.unknown_status:
            out.append(f"{len(self.unknown_status)} row(s) with an unknown status code (rows "
                       f"{self.unknown_status[:5]}{' ...' if len(self.unknown_status) > 5 else ''}): re-run by "
                       "--resume")
        if self.done_incomplete:
            out.append(f"{len(self.done_incomplete)} 'done' row(s) without a complete result (rows "
                       f"{self.done_incomplete[:5]}{' ...' if len(self.done_incomplete) > 5 else ''}): re-run "
                       "by --resume")
        return out


def runs_problem(value: Any) -> str | None:
    """Why an attribute ``runs`` is not a JSON list of run records (objects), or None where it is one."""
    if isinstance(value, bytes):
        try:
            value = value.decode("utf-8")
        except UnicodeDecodeError:
            return "not UTF-8"
    try:
        runs = json.loads(value)
    except (ValueError, TypeError, RecursionError) as e:
        return f"not JSON: {str(e)[:80]}"
    if not isinstance(runs, list) or not all(isinstance(r, dict) for r in runs):
        return "not a list of run records"
    return None


def run_records(value: Any) -> list[dict[str, Any]]:
    """The run records of an attribute ``runs``; [] where it is damaged (issue 31: a damaged one blocked status,
    resume and merge; the rows do not depend on it). :func:`runs_problem` says why."""
    if runs_problem(value) is not None:
        return []
    return json.loads(value.decode("utf-8") if isinstance(value, bytes) else value)


def _fail(path: Any, what: str) -> None:
    raise StoreError(f"store {path}: {what}")


def _attributes(f: Any) -> dict[str, Any]:
    """Every attribute but the checksums' own, an unreadable one (e.g. a string no longer UTF-8) as its error."""
    out: dict[str, Any] = {}
    for k in f.attrs.keys():
        if k != INTEGRITY:
            try:
                out[k] = f.attrs[k]
            except Exception as e:
                out[k] = e
    return out


_TASKS_PROBLEM = "table '/tasks'"


_warned: set[tuple[str, str]] = set()


def _warn_once(path: Any, problem: str) -> None:
    """A damaged attribute is logged once per store and process (status reads a store several times)."""
    key = (str(path), problem)
    if key not in _warned:
        _warned.add(key)
        log.warning("store %s: %s", path, problem)


def _integrity(f: Any, path: Any, tolerate_tasks: bool, rep: Report) -> bool:
    """Format 4: every attribute and the ``/tasks`` table against their checksums (schema.integrity_record).
    Damage the rows survive is recorded in ``rep`` and logged (issue 40 item 1: run records, provenance, the
    spec's attributes, the checksum record itself; ``/tasks`` with ``tolerate_tasks``); any other (format,
    format_version, shard) is named in one line and refuses the store. Returns whether ``/tasks`` failed."""
    try:
        record = f.attrs[INTEGRITY]
    except Exception:
        record = None

    def tasks() -> Any:
        if "tasks" not in f or not hasattr(f["tasks"], "dtype"):
            return None  # named by the structural check
        try:
            return f["tasks"][...]
        except (OSError, ValueError, KeyError, TypeError) as exc:
            _fail(path, f"cannot read /tasks ({exc}): damaged store")

    tasks_bad = False
    for key, problem in integrity_problems(record, _attributes(f), tasks):
        name = key[5:] if key.startswith("attr:") else key
        if key == INTEGRITY:
            rep.integrity_damaged = True
        elif name == "runs":  # the rows do not depend on the run records (issue 31 item 5): --resume rebuilds them
            rep.runs_damaged = rep.runs_damaged or "fails its checksum: changed after it was written"
        elif key.startswith("attr:") and name in PROVENANCE_ATTRS:
            rep.provenance_damaged.append(name)
        elif key.startswith("attr:") and name in SPEC_ATTRS:
            rep.spec_damaged.append(name)
        elif key == "table:/tasks" and tolerate_tasks:
            tasks_bad = True
        else:
            _fail(path, problem + " (changed after it was written: a damaged store)")
        _warn_once(path, problem)
    return tasks_bad


def _layout(f: Any, path: Any, r: Any, integrity: bool) -> Layout:
    version = f.attrs.get("format_version")
    lay = layout_of(version, r.dtype, "checksums" in f, integrity)
    if lay is None:
        same = [x.name for x in LAYOUTS if x.results == r.dtype and x.integrity == integrity]
        shown = version.item() if hasattr(version, "item") else version
        _fail(path, f"format_version {shown!r} with a /results table of format {'/'.join(same)}: no layout "
              "ever written (a damaged attribute, or a store of a newer gapsweep)")
    return lay


def check(f: Any, path: str | Path, *, tolerate_tasks: bool = False) -> Report:
    """:func:`_check`; an error of the HDF5 library while reading damaged metadata (a flipped byte in an object
    header: KeyError "Unable to open object", OSError, ValueError, TypeError) is a one-line StoreError naming the
    store (issue 40 item 3: such errors reached the user as tracebacks)."""
    try:
        return _check(f, path, tolerate_tasks=tolerate_tasks)
    except StoreError:
        raise
    except (KeyError, OSError, ValueError, TypeError, IndexError, AttributeError, RuntimeError) as e:
        msg = str(e.args[0]) if isinstance(e, KeyError) and e.args else str(e)
        _fail(path, f"damaged HDF5 structure ({type(e).__name__}: {msg})")
        raise  # pragma: no cover - _fail raises


def _plugin_columns(f: Any, path: Any, r: Any) -> None:
    """The ``/results`` dtype is a gapsweep results table whose plug-in columns (after format 5's) are the ones
    its attribute ``PLUGIN_COLUMNS`` declares."""
    plugin = plugin_columns_of(r.dtype)  # [] for every layout ever written; plug-in columns after format 5's
    if plugin is None:
        _fail(path, f"/results has dtype {r.dtype}, expected the gapsweep results table")
    if plugin:
        declared = f.attrs.get(PLUGIN_COLUMNS)
        try:
            ok = [tuple(x) for x in json.loads(declared)] == plugin
        except (TypeError, ValueError):
            ok = False
        if not ok:
            _fail(path, f"/results has plug-in columns {[k for k, _ in plugin]} that its attribute "
                  f"{PLUGIN_COLUMNS!r} does not declare (damaged store)")


def _histograms(f: Any, path: Any, r: Any, e: Any, d: Any) -> bool:
    """The histogram datasets: 2-d float edges and density, the pressure histograms (format 2 on) both present
    and of the gap histograms' shape. Returns whether the pressure histograms are there."""
    if e.dtype.kind != "f" or d.dtype.kind != "f" or e.ndim != 2 or d.ndim != 2:
        _fail(path, "/histograms/edges or /density is not a 2-d float array")
    has_p = [name in f for name in PRESSURE_HIST]
    if any(has_p) and not all(has_p):
        _fail(path, f"only one of /{PRESSURE_HIST[0]}, /{PRESSURE_HIST[1]} present (damaged or partial store)")
    if all(has_p):  # format 2: the pressure histograms match the gap histograms' shape
        pe, pdn = f[PRESSURE_HIST[0]], f[PRESSURE_HIST[1]]
        if pe.dtype.kind != "f" or pdn.dtype.kind != "f" or pe.shape != e.shape or pdn.shape != d.shape:
            _fail(path, "/histograms/pressure_edges or /pressure_density does not match the gap histograms' shape")
    elif r.dtype.names is not None and "contact_area" in r.dtype.names:
        _fail(path, f"dataset /{PRESSURE_HIST[0]} missing (damaged or partial store)")
    return all(has_p)


def _structure(f: Any, path: Any) -> bool:
    """The store's structure (format attribute, spec attributes, datasets, their dtypes, shapes and lengths),
    each problem a StoreError naming it. Returns whether the pressure histograms are there."""
    if f.attrs.get("format") != FORMAT:
        _fail(path, f"not a gapsweep store (format attribute {f.attrs.get('format')!r})")
    for name in ("spec_text", "spec_sha256"):
        if name not in f.attrs:
            _fail(path, f"attribute {name!r} missing (damaged or partial store)")
    for name in ("tasks", "results", "histograms/edges", "histograms/density"):
        if name not in f:
            _fail(path, f"dataset /{name} missing (damaged or partial store)")
        if not hasattr(f[name], "dtype"):
            _fail(path, f"/{name} is a group, not a dataset (damaged store)")
    t, r, e, d = f["tasks"], f["results"], f["histograms/edges"], f["histograms/density"]
    if t.dtype != TASK_DTYPE:
        _fail(path, f"/tasks has dtype {t.dtype}, expected the gapsweep task table")
    _plugin_columns(f, path, r)
    has_p = _histograms(f, path, r, e, d)
    lens = {"tasks": t.shape[0], "results": r.shape[0], "histograms/edges": e.shape[0],
            "histograms/density": d.shape[0]}
    if len(set(lens.values())) != 1:
        _fail(path, "tables of different lengths (" + ", ".join(f"{k} {v}" for k, v in lens.items())
              + "): damaged or partial store")
    if e.shape[1] != d.shape[1] + 1:
        _fail(path, f"histogram edges ({e.shape[1]}) and density ({d.shape[1]}) columns do not match")
    return has_p


def _rows(f: Any, path: Any, rep: Report) -> None:
    """Rows of unknown status and done rows without a complete result (no finite mean gap, or -- for methods
    whose rows carry a gap histogram -- no finite, non-empty histogram), into ``rep``."""
    t, r, e, d = f["tasks"], f["results"], f["histograms/edges"], f["histograms/density"]
    try:
        status = r.fields("status")[...]
        mean_gap = r.fields("mean_gap")[...]
        methods = t.fields("method")[...]
        dens = d[...]
    except (OSError, ValueError) as exc:
        _fail(path, f"cannot read the tables ({exc}): damaged store")
    known = np.isin(status, list(STATUS.values()))
    rep.unknown_status = np.flatnonzero(~known).tolist()
    done = status == STATUS["done"]
    # methods whose rows carry a gap histogram (the plug-in says; theory rows have none)
    hist_methods = [m.name.encode() for m in registry.all_methods().values() if m.histogram]
    needs_hist = np.isin(methods, hist_methods)
    hist_ok = np.all(np.isfinite(dens), axis=1) & np.any(dens > 0, axis=1)
    if "contact_atom" in r.dtype.names:  # hard wall in full contact: every point is in the atom at g = 0
        atom = r.fields("contact_atom")[...]
        hist_ok |= np.all(np.isfinite(dens), axis=1) & (atom >= 1.0)
    edges_ok = np.all(np.isfinite(e[...]), axis=1)
    bad = done & (~np.isfinite(mean_gap) | (needs_hist & ~(hist_ok & edges_ok)))
    rep.done_incomplete = np.flatnonzero(bad).tolist()


def _check(f: Any, path: str | Path, *, tolerate_tasks: bool = False) -> Report:
    """Validate an open store ``f`` (h5py.File); raise StoreError on a structural problem (a format-4 store's
    attributes and task table first: one that fails its checksum is named). ``tolerate_tasks`` (``--resume``,
    which restores task rows from the job; ``status``; ``merge --skip-damaged``): a ``/tasks`` table that
    fails its checksum is reported (``Report.tasks_damaged``) instead."""
    integrity = INTEGRITY in f.attrs
    found = Report(0)
    tasks_damaged = _integrity(f, path, tolerate_tasks, found) if integrity else False
    has_p = _structure(f, path)
    n = f["tasks"].shape[0]
    rep = Report(n, layout=_layout(f, path, f["results"], integrity), tasks_damaged=tasks_damaged,
                 provenance_damaged=found.provenance_damaged, spec_damaged=found.spec_damaged,
                 integrity_damaged=found.integrity_damaged)
    rep.checksums = rep.layout.row_checksums == "column"
    rep.runs_damaged = runs_problem(f.attrs.get("runs", "[]")) or found.runs_damaged
    if not n:
        return rep
    _rows(f, path, rep)
    if rep.checksums and not has_p:
        _fail(path, "row checksums present without the pressure histograms they cover (damaged or partial store)")
    if rep.checksums:
        rep.damaged = _damaged(f, path, n)
    return rep


def _damaged(f: Any, path: Any, n: int) -> list[int]:
    """Finished rows whose stored checksum does not match the checksum of their bytes (a changed value,
    parameter, histogram or status byte, swapped rows)."""
    try:
        t, r = f["tasks"][...], f["results"][...]
        e, d = f["histograms/edges"][...], f["histograms/density"][...]
        pe, pd = f[PRESSURE_HIST[0]][...], f[PRESSURE_HIST[1]][...]
    except (OSError, ValueError, KeyError) as exc:
        _fail(path, f"cannot read the tables ({exc}): damaged store")
    # A pending row is work still to do (a write that failed or was killed between a row's payload and its status
    # leaves one with a stale checksum): it runs again anyway and is not reported; every other row must match.
    pending = STATUS["pending"]
    bad = [i for i in range(n) if int(r[i]["status"]) != pending
           and int(r[i][CHECKSUM]) != row_checksum(t[i], r[i], (e[i], d[i], pe[i], pd[i]))]
    return [i for i in bad if not _settles(f, i)]


def _settles(f: Any, i: int, tries: int = 4) -> bool:
    """Whether a row that did not match its checksum does on reading it again (issue 31): a reader of a store
    being written under mpio may see part of a row write (its tables are read one after the other, and a compound
    row is not written atomically). The row is damaged only when two reads in a row give the same bytes and they
    still do not match."""
    prev = None
    for _ in range(tries):
        try:
            t, r = f["tasks"][i], f["results"][i]
            h = tuple(f[k][i] for k in ("histograms/edges", "histograms/density", *PRESSURE_HIST))
        except (OSError, ValueError, KeyError):
            return False
        if int(r["status"]) == STATUS["pending"] or int(r[CHECKSUM]) == row_checksum(t, r, h):
            return True
        key = (t.tobytes(), r.tobytes(), *(x.tobytes() for x in h))
        if key == prev:
            return False
        prev = key
    return False


def incomplete_rows(f: Any, path: str | Path, rep: Report | None = None) -> list[int]:
    """Rows that ``--resume`` must (re)run: pending, unknown status, done without a complete result, damaged, or
    timed out. ``rep``: this file's :func:`check`, if the caller has it (the check reads every table)."""
    rep = check(f, path) if rep is None else rep
    if not rep.n_tasks:
        return []
    status = f["results"].fields("status")[...]
    msg = f["results"].fields("message")[...]
    # a row that timed out (--task-timeout) is run again: the limit may have been a slow node's or a cold cache's
    # ... and so is one cut by a signal (issue 31: inside JIT compilation), or one whose method's optional package
    # was missing (issue 40: installed since, or it fails again at once)
    timed_out = [i for i in np.flatnonzero(status == STATUS["failed"]).tolist()
                 if msg[i].startswith((TIMEOUT_PREFIX.encode(), INTERRUPTED_PREFIX.encode(),
                                       MISSING_EXTRA_PREFIX.encode(), b"MissingExtraError:"))]  # (its form before)
    if timed_out:
        log.info("store %s: %d timed-out row(s) are run again", path, len(timed_out))
    return sorted(set(np.flatnonzero(status == STATUS["pending"]).tolist()) | set(rep.rerun) | set(timed_out))
