"""``gapsweep run --reuse OTHER.h5 [--reuse-older]`` (issue 28, issue 40 item 5; docs/running.md "Reuse across
stores"): rows of the same tasks (task id: the content hash of the task's parameters) that other stores hold
``done`` are copied instead of run.

A source row is taken only when

* its checksum verifies (a store of format 1 or 2 has none: it gives nothing), and its store has this job's
  histogram bins;
* it was computed by the method's current algorithm (column ``algorithm_version`` equal to the plug-in's
  ``ALGORITHM_VERSION``; a row without one -- format 4 and older -- counts as older), unless ``--reuse-older``:
  such rows are then named in the run record (``reused_older``);
* the task keeps fields (gapsweep.sweep.fields) only together with the source's fields file, copied with it.

The first source that has a task wins; the store being written is never a source. Rank 0 alone reads the sources
(:func:`reusable_rows`, during the decision) and writes the copied rows (:func:`copy_reused`, when the store is
open), so the store equals one computed from scratch.
"""

from __future__ import annotations

import json
import logging
import os
import shutil
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from gapsweep.sweep import methods as registry
from gapsweep.sweep import storecheck
from gapsweep.sweep.fields import field_selected, fields_dir
from gapsweep.sweep.schema import PRESSURE_HIST, STATUS, Task
from gapsweep.sweep.store import Store, StoreWriteError, open_read

__all__ = ["Reused", "copy_reused", "fields_file", "reusable_rows", "reused_record", "wants_fields"]

log = logging.getLogger("gapsweep.runner")

# {row index: (source store, results row, (edges, density, pressure edges, pressure density), older version)}
Reused = dict[int, tuple[str, Any, tuple, bool]]


def fields_file(store_path: str | Path, task_id: str) -> Path:
    """The kept-fields file of task ``task_id`` beside the store ``store_path``."""
    return fields_dir(store_path) / f"{task_id}.nc"


def wants_fields(t: Task) -> bool:
    """Whether the task keeps fields (gapsweep.sweep.fields): a reused row must bring its fields file."""
    opts = t.opt("keep_fields")
    if not opts:
        return False
    return bool(field_selected(json.loads(opts), hurst=t.hurst, rho=t.rho, sigma0=t.sigma0, seed=t.seed, n=t.n))


def _candidates(sp: Path, want: dict[str, int], out: Reused, bins: int,
                ) -> tuple[list[int], list[str], Any, list[Any]] | None:
    """The rows of source ``sp`` that could be taken: done, checksum verified, of a wanted task not taken yet
    (row indices into the source, its task ids, its results and histograms); None: the source gives nothing."""
    with open_read(sp, check=False) as f:
        rep = storecheck.check(f, sp)
        if not rep.checksums:
            log.warning("--reuse %s: a store without row checksums (format 1 or 2): its rows cannot be "
                        "verified, none reused", sp)
            return None
        if f["histograms/density"].shape[1] != bins:
            log.warning("--reuse %s: %d histogram bins, this job %d: none reused", sp,
                        f["histograms/density"].shape[1], bins)
            return None
        n = f["tasks"].shape[0]
        ids = [x.decode("utf-8", "replace") for x in f["tasks"].fields("task_id")[...]] if n else []
        status = f["results"].fields("status")[...] if n else []
        bad = set(rep.rerun)
        take = [j for j, tid in enumerate(ids) if tid in want and want[tid] not in out and j not in bad
                and int(status[j]) == STATUS["done"]]
        if not take:
            return None
        res = f["results"][...]
        h = [f[k][...] for k in ("histograms/edges", "histograms/density", *PRESSURE_HIST)]
    return take, ids, res, h


def _older(res: Any, take: list[int], methods: list[str], current: dict[str, int]) -> set[int]:
    """The rows of ``take`` computed by another algorithm version than their method's current one (a row without
    the column counts as version -1: older)."""
    vers = res["algorithm_version"] if "algorithm_version" in (res.dtype.names or ()) else None
    return {j for j, m in zip(take, methods, strict=True) if (-1 if vers is None else int(vers[j])) != current[m]}


def reusable_rows(sources: Sequence[str | Path], path: Path, tasks: list[Task], todo: list[int], bins: int,
                  older: bool = False) -> Reused:
    """Rows of ``todo`` that the stores ``sources`` hold ``done`` for the same task, as :data:`Reused` (module
    docstring: which rows are taken). Raises ValueError when a source is the store being written (``path``)."""
    want = {tasks[i].task_id: i for i in todo}
    out: Reused = {}
    current = {name: registry.get(name).algorithm_version for name in {tasks[i].method for i in todo}}
    for src in sources:
        sp = Path(src)
        if sp.resolve() == path.resolve():
            raise ValueError(f"--reuse {src}: that is the store being written")
        found = _candidates(sp, want, out, bins)
        if found is None:
            continue
        take, ids, res, h = found
        stale = _older(res, take, [tasks[want[ids[j]]].method for j in take], current)
        if stale and not older:
            log.warning("--reuse %s: %d row(s) computed by another (older or unknown) algorithm version of their "
                        "method are run again (--reuse-older copies them)", sp, len(stale))
            take = [j for j in take if j not in stale]
        nofields = {j for j in take if wants_fields(tasks[want[ids[j]]]) and not fields_file(sp, ids[j]).is_file()}
        if nofields:
            log.warning("--reuse %s: %d row(s) keep fields that the source lacks: run again", sp, len(nofields))
            take = [j for j in take if j not in nofields]
        for j in take:
            out[want[ids[j]]] = (str(sp.absolute()), res[j], tuple(a[j] for a in h), j in stale)
        log.info("--reuse %s: %d row(s) copied instead of run", sp, len(take))
    return out


def reused_record(reused: Reused | None) -> dict[str, Any]:
    """The run record's ``reused`` entry: rows copied per source store (nothing when none was), and
    ``reused_older``: those of them computed by another algorithm version (``--reuse-older``)."""
    if not reused:
        return {}
    srcs = sorted({v[0] for v in reused.values()})
    out: dict[str, Any] = {"reused": {s: sum(1 for v in reused.values() if v[0] == s) for s in srcs}}
    old = {s: sum(1 for v in reused.values() if v[0] == s and v[3]) for s in srcs}
    if any(old.values()):
        out["reused_older"] = {s: k for s, k in old.items() if k}
    return out


def _copy_fields(st: Store, src: str, tid: str) -> None:
    """The kept-fields file of task ``tid`` from the source store ``src`` (if it has one) beside ``st``, copied
    under a temporary name first (a failed copy leaves no partial file)."""
    f = fields_file(src, tid)
    if not f.is_file():
        return
    d = fields_dir(st.path)
    d.mkdir(parents=True, exist_ok=True)
    tmp = d / f".{tid}.{os.getpid()}.tmp"
    try:
        shutil.copyfile(f, tmp)
        os.replace(tmp, d / f"{tid}.nc")
    except OSError as e:
        tmp.unlink(missing_ok=True)
        raise StoreWriteError(f"store {st.path}: copying the kept fields of task {tid} from {src} failed "
                              f"({e.strerror or e})") from None


def copy_reused(st: Store, reused: Reused | None, tasks: list[Task] | None = None) -> None:
    """Write the rows taken from other stores (rank 0, which alone has them), each with its kept fields file when
    ``tasks`` is given (issue 40 item 5: the store then equals one computed from scratch)."""
    for i, (src, row, hists, _older) in sorted((reused or {}).items()):
        if tasks is not None:
            _copy_fields(st, src, tasks[i].task_id)
        st.copy_row(i, row, hists)
