"""Merging shard stores of one job into one store (``gapsweep merge``, docs/running.md "Slurm").

Rows are keyed by task id; the job's canonical task list is expanded again from the spec the shards carry.
"""

from __future__ import annotations

import json
import logging
import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from gapsweep.sweep import budget, lease, outputs, provenance, storecheck, writefail
from gapsweep.sweep import methods as registry
from gapsweep.sweep import spec as specmod
from gapsweep.sweep import tasks as tasksmod
from gapsweep.sweep.schema import (
    PRESSURE_HIST,
    STATUS,
    STATUS_NAMES,
    VOLATILE,
    StoreError,
    StoreWriteError,
    results_dtype,
)
from gapsweep.sweep.store import Store, _same, empty_results, open_read, read, read_attrs, seal, upgrade_results

__all__ = ["CONFLICT_CHOICES", "merge"]

log = logging.getLogger("gapsweep.sweep.merge")


# Which of two finished rows of one task a merge keeps: a better status always wins (failed never beats done).
_RANK = {STATUS["pending"]: 0, STATUS["failed"]: 1, STATUS["not_converged"]: 2, STATUS["done"]: 3}
CONFLICT_CHOICES = ("error", "first", "last")


def _row_equal(x: np.ndarray, y: np.ndarray, hx: tuple[np.ndarray, ...], hy: tuple[np.ndarray, ...]) -> bool:
    """Whether two result rows and their histograms (gap and pressure: edges, density) are the same, wall time
    and rank aside."""
    for k in x.dtype.names:
        if k not in VOLATILE and not _same(np.asarray(x[k]), np.asarray(y[k])):
            return False
    return all(_same(a, b) for a, b in zip(hx, hy, strict=True))


def _not_own_merge(out: Path, sha: str, done: set[str]) -> str | None:
    """Why ``merge --overwrite`` must not replace ``out`` (None: it may). Only an earlier merge output (attribute
    ``merged_from``) of the same job (spec hash) that holds no done row the new merge lacks is replaced: never a
    run's store, another job's store, a plain HDF5 file or any other file (issue 31)."""
    if not outputs.is_store(out):
        return "is not a gapsweep store written by merge (another file: a plain HDF5 file, a report, ...)"
    a = outputs.hdf5_attrs(out) or {}
    if "merged_from" not in a:
        return "is a gapsweep store that a run wrote, not a merge output"
    if a.get("spec_sha256") != sha:
        return "is the merge output of another job (another spec hash)"
    try:
        old = read(out, mark_damaged=False)
    except (OSError, StoreError) as e:
        return f"is a merge output that cannot be read ({e})"
    lost = sorted(set(old.task_id[old.status == "done"]) - done)
    if lost:
        return (f"holds {len(lost)} done row(s) this merge would not have (e.g. task {lost[0]}): add the shards "
                "that hold them")
    return None


def _write(tmp: Path, out: Path, tasks: list, attrs: dict, bins: int, results: np.ndarray,
           hists: tuple[np.ndarray, ...], columns: Sequence[tuple[str, str]] = ()) -> None:
    """Write the merged store under its temporary name. A write error (full disk, file-size limit) is one line
    naming the output; the file is then not closed -- HDF5 crashes closing or releasing a file whose write failed
    (issue 31) -- and the CLI leaves with os._exit (store.write_failed)."""
    from gapsweep.sweep.store import StoreWriteError, write_failed

    try:
        st = Store.create(tmp, tasks, attrs, bins, columns=columns)
    except StoreWriteError as e:
        raise StoreWriteError(f"merge --out {out}: cannot be written ({str(e).split(' failed ', 1)[-1].strip()}); "
                              "nothing was written, the shards are untouched") from None
    try:
        if len(tasks):
            edges, dens, pedges, pdens = hists
            st.f["histograms/edges"][...] = edges
            st.f["histograms/density"][...] = dens
            st.f[PRESSURE_HIST[0]][...] = pedges
            st.f[PRESSURE_HIST[1]][...] = pdens
            # rows of a format-1/2 shard get their checksum here; format-3 rows are checked above
            st.f["results"][...] = seal(st.f["tasks"][...], results, bins, edges, dens, pedges, pdens)
        st.set_attrs({"finished": provenance.now()})
        st.f.flush()
    except (OSError, RuntimeError) as e:
        if isinstance(e, StoreError):
            raise
        raise write_failed(f"merge --out {out}: writing failed ({e}); nothing was written, the shards are "
                           "untouched") from None
    except BaseException:
        st.close()
        raise
    st.close()


class _Rows:
    """The merged rows so far, one per task of the job (pending until a shard gives one): results, histograms
    (gap and pressure: edges, density), the shard each came from, the conflicts met and the damaged rows
    skipped."""

    def __init__(self, n: int, bins: int, rdtype: np.dtype) -> None:
        self.results = empty_results(n, rdtype)
        self.edges = np.full((n, bins + 1), np.nan)
        self.dens = np.full((n, bins), np.nan)
        self.pedges = np.full((n, bins + 1), np.nan)
        self.pdens = np.full((n, bins), np.nan)
        self.source = [""] * n
        self.conflicts: list[str] = []
        self.damaged = 0

    def hists(self) -> tuple[np.ndarray, ...]:
        return self.edges, self.dens, self.pedges, self.pdens

    def offer(self, i: int, tid: str, s: str | Path, row: Any, h: tuple[np.ndarray, ...], on_conflict: str) -> None:
        """Shard ``s``'s finished row of task ``tid`` (index ``i``): kept when its status is better than the row
        held, or equal with other content and ``on_conflict="last"`` (a conflict, recorded either way)."""
        new, old = _RANK[int(row["status"])], _RANK[int(self.results["status"][i])]
        if new < old:
            return
        if new == old:
            if _row_equal(self.results[i], row, (self.edges[i], self.dens[i], self.pedges[i], self.pdens[i]), h):
                return
            self.conflicts.append(f"task {tid}: {self.source[i]} and {s} both have a "
                                  f"{STATUS_NAMES[int(row['status'])]!r} row with different results")
            if on_conflict != "last":
                return
        self.results[i] = row
        self.edges[i], self.dens[i], self.pedges[i], self.pdens[i] = h
        self.source[i] = str(s)


def _read_shard(s: str | Path, js: specmod.JobSpec, rdtype: np.dtype, map_rms: dict[str, tuple[float, ...]],
                skip_damaged: bool) -> tuple[Any, list[str], np.ndarray, tuple[np.ndarray, ...]] | None:
    """A shard's check report, task ids, results (in this job's results dtype; a file map's rms values of a
    layout before 5 in format 5's meaning) and histograms (NaN pressure histograms for a format-1 shard); None
    for a shard without rows. Raises StoreError for a shard of other histogram bins."""
    bins = js.histogram["bins"]
    with open_read(s, tolerate_tasks=skip_damaged) as f:
        rep = storecheck.check(f, s, tolerate_tasks=skip_damaged)
        if f["tasks"].shape[0] == 0:
            return None
        if f["histograms/density"].shape[1] != bins:
            raise StoreError(f"merge: {s} has {f['histograms/density'].shape[1]} histogram bins, the job {bins}")
        ids = [x.decode("utf-8", "replace") for x in f["tasks"].fields("task_id")[...]]
        old_rms = "h_rms_spectrum" not in f["results"].dtype.names
        r = upgrade_results(f["results"][...], rdtype)  # a format-1 shard: by column name
        if old_rms and js.surface.get("kind") == "file":
            r = _map_rms_to_format5(r, js.surface, map_rms)
        e, d = f["histograms/edges"][...], f["histograms/density"][...]
        if PRESSURE_HIST[0] in f:
            pe, pd_ = f[PRESSURE_HIST[0]][...], f[PRESSURE_HIST[1]][...]
        else:
            pe, pd_ = np.full(e.shape, np.nan), np.full(d.shape, np.nan)
    return rep, ids, r, (e, d, pe, pd_)


def _add_shard(rows: _Rows, s: str | Path, index: dict[str, int], js: specmod.JobSpec, rdtype: np.dtype,
               map_rms: dict[str, tuple[float, ...]], on_conflict: str, skip_damaged: bool) -> None:
    """Offer every finished, undamaged row of shard ``s`` to ``rows``. A damaged row refuses the merge unless
    ``skip_damaged`` (then it counts as pending, as a row whose task id is not the job's from a damaged
    ``/tasks``); a task id that is not the job's otherwise refuses it."""
    got = _read_shard(s, js, rdtype, map_rms, skip_damaged)
    if got is None:
        return
    rep, ids, r, h = got
    if rep.damaged and not skip_damaged:
        raise StoreError(f"merge: {s} has {len(rep.damaged)} damaged row(s) (checksum mismatch, rows "
                         f"{rep.damaged[:5]}{' ...' if len(rep.damaged) > 5 else ''}); re-run them with "
                         "--resume, or pass --skip-damaged to merge without them; nothing was written")
    rows.damaged += len(rep.damaged)
    bad = set(rep.rerun)
    for j, tid in enumerate(ids):
        if j in bad or r["status"][j] == STATUS["pending"]:
            continue  # (a damaged task id of such a row is restored by --resume of its shard)
        if tid not in index and rep.tasks_damaged:  # --skip-damaged: a task id changed since it was written
            log.warning("merge: %s row %d: task id %r is not the job's (damaged /tasks): left out", s, j, tid)
            rows.damaged += 1
            continue
        if tid not in index:
            raise StoreError(f"merge: task {tid} of {s} is not in the job")
        rows.offer(index[tid], tid, s, r[j], tuple(x[j] for x in h), on_conflict)


def _job(shards: Sequence[str | Path], metas: list[dict[str, Any]], skip_damaged: bool,
         ) -> tuple[specmod.JobSpec, str]:
    """The job the shards share (its spec from a shard whose spec attributes can be trusted) and its hash;
    StoreError for shards of different jobs or a spec that is not valid (naming the shard)."""
    specs = _trusted_specs(shards, metas, skip_damaged)
    shas = {m["spec_sha256"] for m, _ in specs}
    if len(shas) != 1:
        raise StoreError(f"merge: shards come from different job specs ({len(shas)} spec hashes)")
    first, s0 = specs[0]
    try:
        return specmod.loads(first["spec_text"], base=first.get("spec_dir") or None), first["spec_sha256"]
    except specmod.SpecError as e:  # name the shard whose spec it is (issue 19)
        raise StoreError(f"merge: shard {s0}: its job spec is not valid: {e}") from None


def _check_args(shards: Sequence[str | Path], outp: Path, on_conflict: str) -> None:
    if not shards:
        raise StoreError("merge: no shard stores given")
    if on_conflict not in CONFLICT_CHOICES:
        raise ValueError(f"merge: on_conflict must be one of {', '.join(CONFLICT_CHOICES)}, got {on_conflict!r}")
    if any(outputs.same_file(x, outp) or Path(x).resolve() == outp.resolve() for x in shards):
        raise StoreError(f"merge: the output {outp} is also a shard (the same file, by device and inode); choose "
                         "another --out")


def _write_out(outp: Path, shards: Sequence[str | Path], overwrite: bool, break_lease: bool, sha: str,
               js: specmod.JobSpec, tasks: list, attrs: dict[str, Any], rows: _Rows,
               columns: Sequence[tuple[str, str]]) -> None:
    """Write the merged store to ``outp`` holding its lease: under a temporary name, with its whole size reserved
    first, renamed into place; ``--overwrite`` replaces only an earlier merge of the same job
    (:func:`_not_own_merge`)."""
    bins = js.histogram["bins"]
    done = {t.task_id for t, s in zip(tasks, rows.results["status"], strict=True) if s == STATUS["done"]}
    with lease.acquire(outp, break_lease=break_lease, purpose="merge"):  # a live writer is named first
        lease.remove_leftovers(outp, held=True)  # of a killed creation or merge (issue 40 item 7)
        _guard(outp, shards, overwrite, lambda o: _not_own_merge(o, sha, done))
        tmp = outp.with_name(f".{outp.name}.tmp-{os.getpid()}")
        # room first (issue 40 item 3): a merge whose HDF5 writes failed on a full disk or under a file-size limit
        # segfaulted (exit 139); the whole store is reserved before HDF5 writes a byte (writefail.reserve)
        need = budget.store_bytes(len(tasks), bins, len(js.text) + len(attrs.get("runs", "")))
        err = writefail.reserve(tmp, int(1.5 * need) + (1 << 20))
        if err is not None:
            raise StoreWriteError(f"merge --out {outp}: cannot be written ({err}); nothing was written, the "
                                  "shards are untouched")
        try:
            _write(tmp, outp, tasks, attrs, bins, rows.results, rows.hists(), columns)
            os.replace(tmp, outp)
        except BaseException:
            tmp.unlink(missing_ok=True)
            raise


def merge(shards: Sequence[str | Path], out: str | Path, *, overwrite: bool = False,
          on_conflict: str = "error", break_lease: bool = False, skip_damaged: bool = False) -> dict[str, int]:
    """Merge shard stores of one job into ``out`` (rows in the job's canonical task order, keyed by task id).

    All shards must carry the same spec (hash). When a task has a finished row in several shards, the better
    status wins (done > not_converged > failed; a failed row never replaces a done one). Rows of equal status
    and different content (wall time and rank aside) are a conflict: ``on_conflict="error"`` (default) refuses
    the merge naming the task, ``"first"`` / ``"last"`` keep the row of the first / last shard named. Rows
    that a check finds incomplete (unknown status, done without result) count as pending. The merged store
    lists every task of the job (missing ones stay pending); it is written under a temporary name and renamed
    into place, holding ``out``'s lease. A shard row whose checksum does not match its bytes (docs/store.md,
    "Checksums") refuses the merge, naming the shard and the rows, unless ``skip_damaged`` (then it counts as
    pending). Returns counts per status (and ``conflicts`` resolved, ``damaged`` rows skipped)."""
    outp = Path(out)
    _check_args(shards, outp, on_conflict)
    _guard(outp, shards, overwrite, lambda o: None)  # exists, folder
    metas = [read_attrs(s, tolerate_tasks=skip_damaged) for s in shards]
    js, sha = _job(shards, metas, skip_damaged)
    tasks = tasksmod.expand(js)
    index = {t.task_id: i for i, t in enumerate(tasks)}
    runs = []
    for m in metas:
        runs.extend(storecheck.run_records(m.get("runs", "[]")))  # a damaged list: those records are lost
    attrs = provenance.store_attrs(js, shard="", extra={"merged_from": json.dumps([str(s) for s in shards]),
                                                        "runs": json.dumps(runs)})
    attrs["spec_sha256"] = sha
    columns = registry.job_columns(js)  # the job's plug-in columns (docs/store.md "Plug-in columns")
    rdtype = results_dtype(columns)
    rows = _Rows(len(tasks), js.histogram["bins"], rdtype)
    map_rms: dict[str, tuple[float, ...]] = {}  # a file map's rms values, computed once (_map_rms_to_format5)
    for s in shards:
        _add_shard(rows, s, index, js, rdtype, map_rms, on_conflict, skip_damaged)
    if rows.conflicts and on_conflict == "error":
        raise StoreError(f"merge: {len(rows.conflicts)} conflicting row(s), e.g. {rows.conflicts[0]}; pass "
                         "--on-conflict first|last to choose, nothing was written")
    for c in rows.conflicts:
        log.warning("merge: %s (kept the %s)", c, on_conflict)
    _write_out(outp, shards, overwrite, break_lease, sha, js, tasks, attrs, rows, columns)
    counts = {name: int(np.sum(rows.results["status"] == code)) for name, code in STATUS.items()}
    counts["conflicts"] = len(rows.conflicts)
    counts["damaged"] = rows.damaged
    return counts


def _trusted_specs(shards: Sequence[str | Path], metas: list[dict[str, Any]], skip_damaged: bool,
                   ) -> list[tuple[dict[str, Any], str | Path]]:
    """The attributes of the shards whose job spec can be trusted, with the shard (issue 40 item 1): its spec
    attributes verify, or its spec text still matches its hash and its task table (repair.own_spec). A shard whose
    spec attributes are damaged is merged under another shard's spec: its rows verify on their own checksums and
    each of its task ids must be one of that job's (checked row by row below). Raises where no shard's spec is
    trusted."""
    from gapsweep.sweep.repair import own_spec

    out, bad = [], []
    for s, m in zip(shards, metas, strict=True):
        with open_read(s, check=False) as f:
            rep = storecheck.check(f, s, tolerate_tasks=skip_damaged)
            if rep.spec_trusted or own_spec(f) is not None:
                out.append((m, s))
            else:
                bad.append(f"{s} ({', '.join(rep.spec_damaged) or 'unverifiable'})")
    for b in bad:
        log.warning("merge: shard %s: its job spec attributes are damaged; merged under another shard's spec", b)
    if not out:
        raise StoreError(f"merge: the job spec attributes of every shard are damaged ({'; '.join(bad)}): "
                         "`gapsweep repair SHARD --job JOB.toml` restores them from the job file (the rows verify "
                         "on their own checksums); nothing was written")
    return out


def _guard(outp: Path, shards: Sequence[str | Path], overwrite: bool, own: Any) -> None:
    """The output rule (gapsweep.sweep.outputs) for ``merge --out``, raised as the merge's own StoreError."""
    try:
        outputs.guard_output(outp, shards, "merge --out", overwrite=overwrite, own=own)
    except FileExistsError as e:
        raise StoreError(str(e)) from None


def _map_rms_to_format5(r: np.ndarray, surface: dict[str, Any], cache: dict[str, tuple[float, ...]]) -> np.ndarray:
    """Rows of a file-map shard of a layout before 5 in format 5's meaning: the values its ``h_rms``, ``g_rms``
    held (the map's spectral moments) move to ``h_rms_spectrum``, ``g_rms_spectrum``, and ``h_rms``, ``g_rms``
    become those of the heights solved, computed from the map the spec names (docs/store.md "Formats")."""
    from gapsweep.sweep.context import _rms_and_spectrum
    from gapsweep.sweep.filesurface import file_surface_heights

    if "v" not in cache:
        cache["v"] = _rms_and_spectrum(file_surface_heights(surface), surface)
    h, g = cache["v"][:2]
    has = np.isfinite(r["h_rms"])
    for k, new in (("h_rms", h), ("g_rms", g)):
        r[f"{k}_spectrum"][has] = r[k][has]
        r[k][has] = new
    return r
