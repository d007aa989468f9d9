"""Mending a store's attributes where every row survives (issue 40 item 1; ``gapsweep repair``, docs/reliability.md
"Damaged attributes").

Each row carries its own checksum over its task row, results and histograms, so a flipped bit in an attribute
never makes a row untrustworthy. Such damage is reported by every reader and mended here (and by ``--resume``):

* provenance (``created``, ``versions``, ``git_commit``, ...): rebuilt, each value saying it was lost;
* the job spec's attributes (``spec_text``, ``spec_sha256``, ``units``, ``spec_dir``): restored from the job file
  after checking that every task row of the store is one of that job's tasks, parameter for parameter
  (:func:`job_mismatch`), or -- without a job file -- from the store's own spec text where it still matches its
  hash and the task table;
* the checksum record itself (``integrity``): written again once the spec is known to be the store's.
"""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Any

from gapsweep.sweep import lease, provenance, storecheck
from gapsweep.sweep import spec as specmod
from gapsweep.sweep import tasks as tasksmod
from gapsweep.sweep.schema import StoreError
from gapsweep.sweep.store import Store, open_read, task_rows

__all__ = ["job_mismatch", "own_spec", "repair", "restore_attrs"]

log = logging.getLogger("gapsweep.sweep.repair")


def job_mismatch(f: Any, spec: specmod.JobSpec) -> str | None:
    """Why the open store ``f`` is not a store of the job ``spec`` (None: it is): every stored task row must be
    the job's task of that id, byte for byte, and the histogram bins the job's. A shard holds a subset."""
    bins = f["histograms/density"].shape[1]
    if bins != spec.histogram["bins"]:
        return f"the store has {bins} histogram bins, the job {spec.histogram['bins']}"
    n = f["tasks"].shape[0]
    if not n:
        return None
    have = f["tasks"][...]
    by_id = {t.task_id: t for t in tasksmod.expand(spec)}
    for i in range(n):
        tid = have["task_id"][i].decode("utf-8", "replace")
        t = by_id.get(tid)
        if t is None:
            return f"row {i}: task {tid} is not one of the job's tasks"
        if task_rows([t])[0].tobytes() != have[i].tobytes():
            return f"row {i}: task {tid}'s parameters differ from the job's"
    return None


def own_spec(f: Any) -> specmod.JobSpec | None:
    """The store's own spec where it can still be trusted without its checksums: the text parses, its hash is
    the attribute ``spec_sha256`` and its tasks are the task table's (:func:`job_mismatch`); else None."""
    text, sha = f.attrs.get("spec_text"), f.attrs.get("spec_sha256")
    base = f.attrs.get("spec_dir", "")
    try:
        text, sha, base = (x.decode("utf-8") if isinstance(x, bytes) else x for x in (text, sha, base))
        spec = specmod.loads(text, base=base or None)
    except (specmod.SpecError, ValueError, TypeError, AttributeError, OSError):
        return None
    if sha not in (spec.sha256, spec.text_sha256) or job_mismatch(f, spec) is not None:
        return None
    return spec


def restore_attrs(spec: specmod.JobSpec, sha: str | None = None) -> dict[str, Any]:
    """The attributes a store takes from ``spec`` (provenance.spec_attrs); ``sha``: the hash to keep (a store
    written before the canonical hash carries the text's)."""
    a = provenance.spec_attrs(spec)
    if sha:
        a["spec_sha256"] = sha
    return a


def repair(path: str | Path, job: str | Path | None = None, *, break_lease: bool = False) -> list[str]:
    """``gapsweep repair STORE [--job JOB]``: rebuild damaged provenance, restore damaged spec attributes (from
    ``job``, or from the store's own spec where it still verifies: :func:`own_spec`) and write the attribute
    checksums again, under the store's lease. Returns lines saying what was done and what is left (damaged rows
    are re-run by ``--resume``, not here). Raises StoreError where the spec cannot be restored without ``job``
    or ``job`` is not this store's."""
    p = Path(path)
    with lease.acquire(p, break_lease=break_lease, purpose="repair"):
        gone = lease.remove_leftovers(p, held=True)
        with open_read(p, check=False) as f:
            rep = storecheck.check(f, p, tolerate_tasks=True)
            if rep.tasks_damaged and rep.attrs_need_repair:
                raise StoreError(f"repair {p}: its /tasks table fails its checksum too: `gapsweep run JOB --store "
                                 f"{p} --resume` restores both from the job file; nothing was changed")
            restore = None
            if rep.spec_trusted and "job_name" in rep.provenance_damaged:  # the job's name is in its spec
                own = own_spec(f)
                restore = {"job_name": own.name} if own is not None else None
            if not rep.spec_trusted:
                if job is not None:
                    spec = specmod.load(job)
                    why = job_mismatch(f, spec)
                    if why:
                        raise StoreError(f"repair {p}: the job {job} is not this store's ({why}); nothing was "
                                         "changed")
                    restore = restore_attrs(spec)
                else:
                    spec = own_spec(f)
                    if spec is None:
                        raise StoreError(f"repair {p}: its job spec attributes are damaged "
                                         f"({', '.join(rep.spec_damaged) or 'unverifiable'}): pass --job JOB.toml "
                                         "(the job file it was run from; every task row is checked against it); "
                                         "nothing was changed")
                    sha = f.attrs.get("spec_sha256")
                    restore = restore_attrs(spec, sha.decode() if isinstance(sha, bytes) else sha)
        out = [f"removed {x}, the temporary file of a killed creation or merge" for x in gone]
        if rep.attrs_need_repair:
            Store.open(p, repair_tasks=True, restore=restore).close()
            lost = [x for x in rep.provenance_damaged if x not in (restore or {})]
            if lost:
                out.append(f"rebuilt (marked as lost): {', '.join(lost)}")
            if restore and "job_name" in rep.provenance_damaged:
                out.append("restored from the spec: job_name")
            if not rep.spec_trusted:
                out.append(f"restored from {'the job ' + str(job) if job else 'its own verified spec text'}: "
                           f"{', '.join(rep.spec_damaged) or 'the spec attributes'}"
                           + ("; attribute checksums written again" if rep.integrity_damaged else ""))
        else:
            out.append("no damaged attribute")
        if rep.runs_damaged:
            out.append(f"run records damaged ({rep.runs_damaged}): rebuilt by the next --resume")
        if rep.tasks_damaged or rep.rerun:
            out.append(f"{len(rep.rerun)} row(s) to re-run{' and a damaged /tasks table' if rep.tasks_damaged else ''}"
                       ": `gapsweep run JOB --store STORE --resume` restores them")
    return out
