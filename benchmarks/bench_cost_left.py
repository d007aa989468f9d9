"""The cost left of ``gapsweep status`` against the measured remainder, on a real job (issue 28).

Runs a job (default: jobs/test_mixed.toml -- GFMD, SDE, Fokker-Planck and field theory, no test delay) in one
process, stops it with SIGTERM after ``--stop-after`` seconds (what Slurm's time-limit warning does), reads the
cost left (gapsweep.sweep.costleft) of the stopped store, finishes it with ``--resume`` and compares the estimate
with the sum of the measured wall times of the rows that were remaining (the resumed run's start-up included in
both). Writes a JSON record (``--out``) with the command, the machine and the numbers.

    python benchmarks/bench_cost_left.py [--job jobs/test_mixed.toml] [--stop-after 6] \
        [--out benchmarks/results/cost_left/cost_left.json]

The store keeps wall time per row, so on a loaded machine both the calibration and the remainder include the
waiting; the estimate is as good as the load is steady between the two runs.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import signal
import subprocess
import sys
import sys as _sys
import tempfile
import time
from pathlib import Path
from pathlib import Path as _Path

import numpy as np

from gapsweep.sweep import costleft, store

_sys.path.insert(0, str(_Path(__file__).resolve().parent))
import _record

# the code this benchmark measures: a result measured before a later change to it is stale
# (scripts/check_docs.py)
CODE_PATHS = ['gapsweep/sweep/costleft.py']

ROOT = Path(__file__).resolve().parent.parent


def _run(job: Path, path: Path, *extra: str, stop_after: float | None = None) -> tuple[int, float]:
    env = {k: v for k, v in os.environ.items() if not k.startswith("GAPSWEEP_TEST")}
    cmd = [sys.executable, "-m", "gapsweep", "run", str(job), "--store", str(path), "--mpi", "off",
           "--progress", "none", *extra]
    t0 = time.perf_counter()
    p = subprocess.Popen(cmd, env=env, stderr=subprocess.DEVNULL)
    try:
        rc = p.wait(timeout=stop_after)
    except subprocess.TimeoutExpired:
        p.send_signal(signal.SIGTERM)
        rc = p.wait()
    return rc, time.perf_counter() - t0


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--job", default=str(ROOT / "jobs" / "test_mixed.toml"))
    ap.add_argument("--stop-after", type=float, default=6.0, help="seconds before SIGTERM (the time limit)")
    ap.add_argument("--out", default=str(ROOT / "benchmarks" / "results" / "cost_left" / "cost_left.json"))
    args = ap.parse_args()
    job = Path(args.job).resolve()
    with tempfile.TemporaryDirectory() as d:
        path = Path(d) / "s.h5"
        rc1, _ = _run(job, path, stop_after=args.stop_after)
        if rc1 == 0:
            raise SystemExit(f"the job finished within {args.stop_after} s: give a smaller --stop-after")
        est = costleft.cost_left(path)
        left = np.flatnonzero(store.read(path).status.to_numpy() != "done")
        rc2, t2 = _run(job, path, "--resume")
        df = store.read(path)
        measured = float(df.wall_time.to_numpy()[left].sum())
    rec = {
        "command": " ".join([Path(sys.argv[0]).name, *sys.argv[1:]]),
        "machine": f"{platform.node()} {platform.processor() or platform.machine()}, {os.cpu_count()} cores",
        "job": str(job.relative_to(ROOT)) if job.is_relative_to(ROOT) else str(job),
        "tasks": int(est["tasks"]), "stopped_after_s": args.stop_after, "first_run_exit": rc1,
        "remaining_rows": int(len(left)), "estimate_core_s": est["core_seconds"], "estimate_gpu_s": est["gpu_seconds"],
        "estimated_eta_s": est["eta_s"], "measured_remaining_s": measured, "resume_wall_s": t2, "resume_exit": rc2,
        "relative_error": (est["core_seconds"] + est["gpu_seconds"] - measured) / measured if measured else None,
        "calibration": est["calibration"],
    }
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(rec, indent=1, sort_keys=True) + "\n")
    print(json.dumps({k: rec[k] for k in ("remaining_rows", "estimate_core_s", "measured_remaining_s",
                                           "relative_error", "estimated_eta_s", "resume_wall_s")}, indent=1))


if __name__ == "__main__":
    _record.track(CODE_PATHS)
    main()
