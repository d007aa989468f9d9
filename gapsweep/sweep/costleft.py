"""The cost left in a store (``gapsweep status``; docs/running.md "The cost left").

The method plug-ins' cost models (``Method.cost``, the estimate ``gapsweep plan`` prints) give each task a
relative cost ``c_i`` [model s]. The store records the measured wall time ``w_i`` [s] of every finished row, so
the model is calibrated per method ``m`` on the rows finished so far,

    r_m = sum_{i in F_m} w_i / sum_{i in F_m} c_i        (F_m: done and not_converged rows of method m)

leaving out of ``F_m`` the rows slower than 5 times the method's median ratio: a process's first task pays its
imports and JIT compilation. Their mean excess over the calibrated model is the start-up time ``W`` of a process,
added once per process of the last run (its MPI size) while rows remain.

(the ratio over all methods where ``m`` has no finished row yet, 1 where no row has finished), and the cost left
is ``sum_{i in R} r_{m(i)} c_i`` over the remaining rows ``R``: the rows ``--resume`` runs (pending, interrupted,
timed out, damaged, incomplete) and the failed rows. Rows of tasks that need a GPU count in GPU-hours, the
others in core-hours (one core per task). The time left divides the cost left by the rate of the current run
(or of the last one): its finished rows times their mean measured wall time, over its elapsed time (for an
MPI run that rate is about the number of working ranks).

The store keeps wall time, not CPU time, per row: on a loaded machine the calibration includes the waiting.
"""

from __future__ import annotations

import datetime as _dt
import math
from pathlib import Path
from typing import Any

import numpy as np

from gapsweep.sweep import lease, storecheck
from gapsweep.sweep import methods as registry
from gapsweep.sweep import spec as specmod
from gapsweep.sweep.repair import own_spec
from gapsweep.sweep.schema import STATUS, TIMEOUT_PREFIX, StoreError
from gapsweep.sweep.store import open_read, while_written
from gapsweep.sweep.tasks import expand

__all__ = ["calibrate", "cost_left", "describe", "estimate", "eta_s", "run_rate", "summary"]

_FINISHED = (STATUS["done"], STATUS["not_converged"])
OUTLIER = 5.0  # rows slower than this many times their method's median ratio are not calibrated on


def calibrate(methods: list[str], model: np.ndarray, wall: np.ndarray, finished: np.ndarray,
              ) -> tuple[dict[str, float], float | None, float]:
    """Per-method ratios ``r_m = sum w / sum c`` over the finished rows with a measured wall time, the ratio over
    all methods (None when no row has finished) and the start-up time of a process [s]. ``model``: model cost
    per row [model s]; ``wall``: measured wall time per row [s] (NaN where none). The first task of a process also
    pays its imports and JIT compilation: rows whose own ratio ``w/c`` exceeds ``OUTLIER`` times the median ratio
    of their method are left out of ``r_m``, and their mean excess ``w - r_m c`` is the start-up time (0 when
    there is no such row)."""
    ok = finished & np.isfinite(wall) & (model > 0)
    meth = np.asarray(methods)
    keep = np.zeros_like(ok)
    for m in sorted(set(methods)):
        sel = ok & (meth == m)
        if sel.any():
            med = np.median(wall[sel] / model[sel])
            keep |= sel & (wall <= OUTLIER * med * model)
    ratios = {m: float(wall[keep & (meth == m)].sum() / model[keep & (meth == m)].sum())
              for m in sorted(set(methods)) if (keep & (meth == m)).any()}
    overall = float(wall[keep].sum() / model[keep].sum()) if keep.any() else None
    slow = np.flatnonzero(ok & ~keep)
    startup = float(np.mean([wall[i] - ratios[methods[i]] * model[i] for i in slow])) if slow.size else 0.0
    return ratios, overall, startup


def _time(text: str | None) -> _dt.datetime | None:
    try:
        return _dt.datetime.fromisoformat(text) if text else None
    except ValueError:
        return None


def run_rate(runs: list[dict[str, Any]], finished_now: int, n: int, mean_wall: float | None, now: _dt.datetime,
             held: bool) -> dict[str, Any] | None:
    """The rate of the current (or last) run in measured seconds of task time per second: rows it finished times
    the mean measured row time ``mean_wall`` [s], over its elapsed time. ``runs``: the store's run records;
    ``finished_now``: rows not pending of the ``n`` rows; ``held``: whether the store's lease is held (the last
    run, if it has not ended, is then the current one, its elapsed time up to ``now``). None without a rate."""
    if not runs or mean_wall is None:
        return None
    last = runs[-1]
    t0 = _time(last.get("started"))
    running = held and not last.get("finished") and not last.get("interrupted") and not last.get("stopped")
    if running:
        t1 = now
        rows = finished_now - (n - int(last.get("todo", n)))
    else:
        t1 = _time(last.get("finished") or last.get("interrupted_at") or last.get("stopped_at"))
        counts = last.get("counts") or {}
        rows = sum(int(v) for v in counts.values()) if counts else int(last.get("todo", 0))
    if t0 is None or t1 is None or rows <= 0:
        return None
    elapsed = (t1 - t0).total_seconds()
    if elapsed <= 0:
        return None
    return {"run": "current" if running else "last", "rows": rows, "elapsed_s": elapsed,
            "task_s_per_s": rows * mean_wall / elapsed}


def estimate(methods: list[str], model: np.ndarray, wall: np.ndarray, gpu: np.ndarray, finished: np.ndarray,
             remaining: list[int], processes: int) -> dict[str, Any]:
    """The cost left of the rows ``remaining`` (module docstring): each row's model cost times its method's
    calibrated ratio (:func:`calibrate` on the ``finished`` rows; the overall ratio for a method without one, 1
    before any row finished), summed into core-seconds (``gpu`` false) and GPU-seconds, plus the start-up time
    of ``processes`` processes in core-seconds while rows remain. Returns ``core_seconds``, ``gpu_seconds``,
    ``ratios``, ``overall`` and ``startup_s``."""
    ratios, overall, startup = calibrate(methods, model, wall, finished)
    est = np.array([model[i] * ratios.get(methods[i], overall if overall is not None else 1.0)
                    for i in remaining], dtype=float)
    g = gpu[remaining] if remaining else np.zeros(0, bool)
    start_s = startup * processes if remaining else 0.0
    return {"core_seconds": float(est[~g].sum()) + start_s, "gpu_seconds": float(est[g].sum()),
            "ratios": ratios, "overall": overall, "startup_s": startup}


def eta_s(core_seconds: float, gpu_seconds: float, rate: dict[str, Any] | None) -> float | None:
    """The time left [s]: the cost left (core- and GPU-seconds of task time) over the run's rate
    (:func:`run_rate`, task-seconds per second); None without a rate."""
    return (core_seconds + gpu_seconds) / rate["task_s_per_s"] if rate else None


def cost_left(path: str | Path, now: _dt.datetime | None = None) -> dict[str, Any]:
    """The cost left in a store as a JSON-ready dict: remaining rows by kind, core-hours and GPU-hours (the
    calibrated cost model), the calibration (ratio and rows per method) and the time left at the current rate
    (``eta_s``, None when no run has a rate yet)."""
    p = Path(path)
    with open_read(p, check=False) as f:
        rep = storecheck.check(f, p)
        own = None if rep.spec_trusted else own_spec(f)  # issue 40 item 1: damaged spec attributes
        if not rep.spec_trusted and own is None:
            what = ", ".join(rep.spec_damaged) or "unverifiable"
            raise StoreError(f"store {p}: its job spec attributes are damaged ({what}): the cost left needs the "
                             "spec (`gapsweep repair` restores it)")
        rerun = set(storecheck.incomplete_rows(f, p, rep))
        ids = [x.decode("utf-8", "replace") for x in f["tasks"].fields("task_id")[...]] if rep.n_tasks else []
        status = f["results"].fields("status")[...] if rep.n_tasks else np.zeros(0, "i1")
        wall = f["results"].fields("wall_time")[...] if rep.n_tasks else np.zeros(0)
        msg = f["results"].fields("message")[...] if rep.n_tasks else np.zeros(0, "S1")
        spec_text, spec_dir = f.attrs["spec_text"], f.attrs.get("spec_dir", "")
        runs = storecheck.run_records(f.attrs.get("runs", "[]"))
    js = own or specmod.loads(spec_text.decode() if isinstance(spec_text, bytes) else spec_text,
                              base=(spec_dir.decode() if isinstance(spec_dir, bytes) else spec_dir) or None)
    by_id = {t.task_id: t for t in expand(js)}
    tasks = [by_id.get(i) for i in ids]
    model = np.array([registry.get(t.method).cost(t) if t else 0.0 for t in tasks], dtype=float)
    gpu = np.array([bool(t and registry.get(t.method).needs_gpu(t)) for t in tasks], dtype=bool)
    methods = [t.method if t else "?" for t in tasks]
    finished = np.isin(status, _FINISHED) & ~np.isin(np.arange(len(ids)), sorted(rerun))
    failed = {i for i in np.flatnonzero(status == STATUS["failed"]).tolist()
              if not msg[i].startswith(TIMEOUT_PREFIX.encode())} - rerun
    remaining = sorted(rerun | failed)
    fin_wall = wall[finished & np.isfinite(wall)]
    mean_wall = float(fin_wall.mean()) if fin_wall.size else None
    held = bool(runs) and mean_wall is not None and lease.read(p) is not None  # the lease only where it matters
    rate = run_rate(runs, int((status != STATUS["pending"]).sum()), len(ids), mean_wall,
                    now or _dt.datetime.now(_dt.UTC), held)
    procs = int(runs[-1].get("mpi_size", 1) or 1) if runs else 1
    e = estimate(methods, model, wall.astype(float), gpu, finished, remaining, procs)
    core_s, gpu_s, ratios, overall, startup = (e[k] for k in ("core_seconds", "gpu_seconds", "ratios", "overall",
                                                               "startup_s"))
    eta = eta_s(core_s, gpu_s, rate)
    return {
        "store": str(p), "tasks": len(ids),
        "remaining": {"rows": len(remaining), "rerun_by_resume": len(rerun), "failed": len(failed)},
        "core_seconds": core_s, "gpu_seconds": gpu_s, "core_hours": core_s / 3600, "gpu_hours": gpu_s / 3600,
        "calibration": {"per_method": {m: {"ratio": r, "rows": int(np.sum(finished & (np.asarray(methods) == m)))}
                                       for m, r in ratios.items()},
                        "overall": overall, "model": "Method.cost (the estimate of gapsweep plan)",
                        "startup_s": startup, "processes": procs,
                        "calibrated": overall is not None},
        "rate": rate, "eta_s": eta,
    }


def _dur(s: float) -> str:
    if s is None or not math.isfinite(s):
        return "unknown"
    h, rest = divmod(int(round(s)), 3600)
    return f"{h}h{rest // 60:02d}m{rest % 60:02d}s" if h else f"{rest // 60}m{rest % 60:02d}s"


def describe(c: dict[str, Any]) -> list[str]:
    """The lines ``gapsweep status`` prints about :func:`cost_left`."""
    r = c["remaining"]
    cal = c["calibration"]
    how = ", ".join(f"{m} x{v['ratio']:.3g} ({v['rows']} rows)" for m, v in cal["per_method"].items())
    lines = [f"cost left: {r['rows']} rows ({r['rerun_by_resume']} run by --resume, {r['failed']} failed): "
             f"{c['core_hours']:.3g} core-h, {c['gpu_hours']:.3g} GPU-h "
             + (f"(cost model calibrated by the measured rows: {how}; start-up {cal['startup_s']:.2g} s x "
                f"{cal['processes']} process(es))" if cal["calibrated"]
                else "(cost model not calibrated: no row finished yet)")]
    if c["rate"]:
        lines.append(f"time left: ~{_dur(c['eta_s'])} at the rate of the {c['rate']['run']} run "
                     f"({c['rate']['task_s_per_s']:.2f} task-s per s)")
    elif r["rows"]:
        lines.append("time left: unknown (no run with a rate yet)")
    return lines


@while_written
def summary(path: str | Path) -> dict[str, Any]:
    """``gapsweep status --json``: the job, the row counts per method and status, the lease, the last run and
    :func:`cost_left`."""
    from gapsweep.sweep.store import read, read_attrs

    gone = lease.remove_leftovers(path)  # a killed creation's or merge's temporary file (issue 40 item 7)
    # a damaged /tasks or attribute is reported (key "check"), as by `gapsweep status` (issue 40 item 9)
    attrs = read_attrs(path, tolerate_tasks=True)
    df = read(path, tolerate_tasks=True)
    with open_read(path, check=False) as f:
        report = storecheck.check(f, path, tolerate_tasks=True)
    counts = {str(m): {str(k): int(v) for k, v in g.status.value_counts().items()} for m, g in df.groupby("method")}
    runs = storecheck.run_records(attrs.get("runs", "[]"))
    held = lease.read(path)
    return {"job": attrs.get("job_name"), "shard": attrs.get("shard", ""),
            "counts": counts, "total": {str(k): int(v) for k, v in df.status.value_counts().items()},
            "lease": held, "last_run": runs[-1] if runs else None, "cost_left": _cost_or_reason(path),
            "check": report.lines(), "removed_leftovers": gone}


def _cost_or_reason(path: str | Path) -> dict[str, Any]:
    try:
        return cost_left(path)
    except (specmod.SpecError, OSError, StoreError) as e:  # the spec's height map moved, a damaged /tasks or
        # spec attribute: the counts still come
        return {"error": str(e)}
