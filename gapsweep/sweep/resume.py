"""What a run does with its store (docs/running.md "Resume and re-runs", docs/reliability.md): create it, resume
it, or nothing (``noop``).

:func:`decide` is rank 0's decision before anything opens the store for writing (the runner holds the store's
lease by then):

* no store at the path, or ``--overwrite``: ``create``, every task to run, once the free disk and the file-size
  limit allow the store's estimated size (:func:`check_room`);
* a store of this job and shard (its spec hash, or the same tasks in another axis order: ``reordered``): its rows
  are validated (``storecheck``); pending rows, rows of unknown status and done rows without a complete result
  are the rows to run; with ``--resume`` that is ``resume`` (``noop`` when none is left and nothing needs
  repair), without it a :class:`RunError` that says so;
* anything else (another job's or shard's store, a file that is not a store) is a :class:`RunError`.

A store written from the same spec with an axis's values in another order, or another ``job.description``, is
resumed in its own row order (:func:`stored_order`, :func:`store_order`; issue 31). Everything here reads the
store; nothing writes it.
"""

from __future__ import annotations

import json
import logging
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from gapsweep.sweep import budget, storecheck
from gapsweep.sweep import methods as registry
from gapsweep.sweep import spec as specmod
from gapsweep.sweep.repair import job_mismatch
from gapsweep.sweep.schema import STATUS, StoreError, Task, Unit
from gapsweep.sweep.store import open_read

__all__ = ["RunError", "check_room", "decide", "moved_rows", "store_order", "stored_order", "task_key"]

log = logging.getLogger("gapsweep.runner")


class RunError(RuntimeError):
    """The run cannot start as asked (store exists, belongs to another job, writer unavailable)."""


def check_room(path: Path, spec: specmod.JobSpec, n_tasks: int) -> None:
    """Refuse (RunError) a new store at ``path`` that the free disk or the file-size limit (``ulimit -f``) would
    not hold: its estimated size (gapsweep.sweep.budget.store_bytes) is compared with the free space, and the
    file's growth is probed (a limit would otherwise fail inside the collective creation under mpio)."""
    size = budget.store_bytes(n_tasks, spec.histogram["bins"], len(spec.text), len(registry.job_columns(spec)))
    free = budget.disk_free(path.parent)
    if size > free:
        raise RunError(f"store {path}: needs ~{budget.human(size)}, only {budget.human(free)} free there")
    try:
        budget.probe_growth(path, min(size, budget.PROBE_BYTES), size=size)
    except OSError as e:
        raise RunError(f"store {path}: cannot be created ({e.strerror}: full disk or file-size limit, "
                       f"~{budget.human(size)} needed); nothing was written") from None


@dataclass
class Seen:
    """What :func:`look` read in an existing store: its spec hash and shard, the validation report, why it is not
    this job's (None: it is; only where its spec attributes fail their checksum), the rows to run again, the
    task rows that differ from the job's (``moved``; None: the task table cannot be this job's) and those of them
    kept done (``kept``), whether its run records are damaged, and the failed rows not run again."""

    sha: Any
    shard: Any
    report: storecheck.Report
    not_job: str | None
    todo: list[int]
    moved: set[int] | None
    kept: set[int] = field(default_factory=set)
    runs_bad: bool = False
    failed: set[int] = field(default_factory=set)


def look(path: Path, spec: specmod.JobSpec, tasks: list[Task], resume: bool) -> Seen:
    """Read and validate the store at ``path`` once (it reads and checksums every row); a file that cannot be
    read as a store is a RunError (with ``--overwrite`` as the way out only where it is a gapsweep store)."""
    try:
        with open_read(path, check=False) as f:
            report = storecheck.check(f, path, tolerate_tasks=resume)
            # issue 40 item 1: spec attributes that fail their checksum are not compared; the job is this store's
            # when every task row is the job's (the rows verify on their own checksums)
            not_job = None if report.spec_trusted else job_mismatch(f, spec)
            todo = storecheck.incomplete_rows(f, path, report)
            moved, kept = moved_rows(f, tasks, set(report.damaged), set(todo))
            failed = set(np.flatnonzero(f["results"].fields("status")[...] == STATUS["failed"]).tolist()
                         if report.n_tasks else []) - set(todo)
            seen = Seen(f.attrs.get("spec_sha256"), f.attrs.get("shard"), report, not_job, todo, moved, kept,
                        report.runs_damaged is not None, failed)
    except (OSError, StoreError) as e:
        from gapsweep.sweep.outputs import is_store

        if not is_store(path):  # --overwrite would be refused too (the output rule): not ours to replace
            raise RunError(f"{e}; it is not a gapsweep store: choose another --store") from None
        raise RunError(f"{e}; pass --overwrite to replace it") from None
    if isinstance(seen.sha, bytes):
        seen.sha = seen.sha.decode()
    return seen


def check_job(path: Path, spec: specmod.JobSpec, shard_text: str, seen: Seen, resume: bool,
              reordered: bool) -> None:
    """Refuse (RunError) a store that is not this job's and shard's. Where its spec attributes fail their
    checksum, the job is compared row by row (``seen.not_job``) and only ``--resume`` restores them."""
    if not seen.report.spec_trusted:
        what = ", ".join(seen.report.spec_damaged) or "the attribute checksums"
        if seen.not_job is not None or seen.shard != shard_text:
            raise RunError(f"store {path}: its job spec attributes are damaged ({what}) and this job is not the "
                           f"store's ({seen.not_job or 'another shard'}): resume it with the job file it was run "
                           "from; its rows verify on their own checksums")
        if not resume:
            raise RunError(f"store {path}: its job spec attributes are damaged ({what}); its rows verify on their "
                           "own checksums: pass --resume to restore them from this job file (checked against every "
                           f"task row), or run `gapsweep repair {path} --job JOB`")
    elif ((seen.sha not in (spec.sha256, spec.text_sha256) and not reordered) or seen.shard != shard_text
          or seen.moved is None):
        raise RunError(f"store {path} was written for another job spec or shard; pass --overwrite to replace "
                       "it or choose another --store")


def needs_repair(seen: Seen) -> bool:
    """Whether ``--resume`` has something to rebuild beyond rows: damaged run records, provenance or spec
    attributes."""
    return seen.runs_bad or seen.report.attrs_need_repair


def check_resume(path: Path, todo: list[int], moved: set[int], n_tasks: int, resume: bool) -> None:
    """Refuse (RunError) a store with work left when ``--resume`` was not given (saying what is left), or one
    that cannot grow by a new run record (full disk, file-size limit)."""
    if not resume and not todo:
        raise RunError(f"store {path}: {len(moved)} damaged task row(s) (rows {sorted(moved)[:5]}): pass --resume to "
                       "restore them from the job spec (every done row is kept)")
    if not resume:
        raise RunError(f"store {path} exists with {len(todo)} of {n_tasks} tasks pending: pass --resume to "
                       "finish it or --overwrite to start again")
    try:
        budget.probe_growth(path)
    except OSError as e:
        raise RunError(f"store {path}: no room to record a new run ({e.strerror}: full disk or file-size "
                       "limit); nothing was changed: free space and run again") from None


def decide(path: Path, spec: specmod.JobSpec, tasks: list[Task], shard_text: str, resume: bool,
           overwrite: bool, *, reordered: bool = False) -> tuple[str, list[int], int]:
    """``(mode, task indices to run, failed rows not run again)``, mode ``create`` | ``resume`` | ``noop``.
    Raises RunError when the store cannot be used. On resume the store is validated (docs/reliability.md):
    pending rows, rows of unknown status and done rows without a complete result are run again; done rows whose
    task row alone is damaged are kept (their task rows are restored)."""
    if not path.exists() or overwrite:
        check_room(path, spec, len(tasks))
        return "create", list(range(len(tasks))), 0
    seen = look(path, spec, tasks, resume)
    check_job(path, spec, shard_text, seen, resume, reordered)
    todo = seen.todo
    if seen.kept:  # done rows whose results verify against the spec's task row: only their task row is restored
        log.warning("store %s: %d done row(s) with a damaged task row verify against the job spec's: kept, their "
                    "task rows are restored (rows %s)", path, len(seen.kept), sorted(seen.kept)[:5])
        todo = [i for i in todo if i not in seen.kept]
    if not todo and not seen.moved and not (resume and needs_repair(seen)):
        return "noop", [], len(seen.failed)
    check_resume(path, todo, seen.moved or set(), len(tasks), resume)
    return "resume", todo, len(seen.failed)


def task_key(spec: specmod.JobSpec) -> str:
    """The spec's canonical JSON with the values of every axis list sorted (grid axes and method overrides) and
    without its description: equal for two specs that differ only in the order of axis values (docs/jobs.md: the
    order does not enter) or in their free-text ``job.description``, which enters no task (a corrected
    description must not strand a half-finished store)."""
    d = json.loads(spec.canonical())
    d.pop("description", None)

    def norm(x: Any) -> Any:
        if isinstance(x, dict):
            return {k: norm(v) for k, v in x.items()}
        if isinstance(x, list) and all(isinstance(v, (int, float, str)) and not isinstance(v, bool) for v in x):
            return sorted(x, key=lambda v: (isinstance(v, str), v))
        return x

    return json.dumps({**d, "grid": norm(d["grid"]), "methods": norm(d["methods"])}, sort_keys=True)


def stored_order(path: Path, spec: specmod.JobSpec, tasks: list[Task], shard_text: str,
                 overwrite: bool) -> list[int] | None:
    """Issue 31: a store written from the same spec with the values of an axis in another order, or another
    ``job.description`` (its hash differs, its tasks are the same: :func:`task_key`), is resumed in its own row
    order: the permutation (store row -> index into ``tasks``), or None where the spec is the store's or
    another job's."""
    if overwrite or not path.is_file():
        return None
    try:
        with open_read(path, check=False) as f:
            sha, text, shard = (f.attrs.get(k) for k in ("spec_sha256", "spec_text", "shard"))
            ids = [x.decode("utf-8", "replace") for x in f["tasks"].fields("task_id")[...]] \
                if f["tasks"].shape[0] else []
    except (OSError, StoreError, KeyError):
        return None  # decide says what is wrong with it
    sha, text = (x.decode("utf-8", "replace") if isinstance(x, bytes) else x for x in (sha, text))
    if sha in (spec.sha256, spec.text_sha256) or shard != shard_text or not isinstance(text, str):
        return None
    try:
        if task_key(specmod.loads(text, base=spec.base_dir or None)) != task_key(spec):
            return None
    except (specmod.SpecError, ValueError, AttributeError):
        return None
    index = {t.task_id: i for i, t in enumerate(tasks)}
    if sorted(ids) != sorted(index):
        return None
    log.info("store %s: the job spec differs from the store's only in the order of axis values or in its "
             "description; resumed in the store's row order", path)
    return [index[x] for x in ids]


def store_order(tasks: list[Task], units: list[Unit], order: list[int] | None) -> tuple[list[Task], list[Unit]]:
    """``tasks`` (and their ``units``) in the store's row order (:func:`stored_order`); unchanged for None."""
    if order is None:
        return tasks, units
    new = {old: k for k, old in enumerate(order)}
    return [tasks[i] for i in order], [u.remap(new) for u in units]


def moved_rows(f: Any, tasks: list[Task], damaged: set[int], todo: set[int],
               ) -> tuple[set[int] | None, set[int]]:
    """Rows whose stored task row differs from the job's (a damaged task id or parameter, issue 31) and, of those,
    the done rows whose stored checksum verifies against the job's task row (their results are intact: only the
    task row is restored, the row stays done). None when the task table cannot be this job's: another length, or
    a differing row that is neither damaged (checksum) nor to be run again (pending)."""
    from gapsweep.sweep.schema import CHECKSUM, PRESSURE_HIST, row_checksum
    from gapsweep.sweep.store import task_rows

    have = f["tasks"][...] if f["tasks"].shape[0] else np.zeros(0)
    if len(have) != len(tasks):
        return None, set()
    want = task_rows(tasks)
    moved = {i for i in range(len(want)) if have[i].tobytes() != want[i].tobytes()}
    if not moved <= damaged | todo:
        return None, set()
    kept = set()
    r = f["results"]
    if CHECKSUM in (r.dtype.names or ()):
        g = (f["histograms/edges"], f["histograms/density"], f[PRESSURE_HIST[0]], f[PRESSURE_HIST[1]])
        for i in sorted(moved & damaged):
            row = r[i]
            if int(row["status"]) != STATUS["pending"] and \
                    int(row[CHECKSUM]) == row_checksum(want[i], row, tuple(x[i] for x in g)):
                kept.add(i)
    return moved, kept
