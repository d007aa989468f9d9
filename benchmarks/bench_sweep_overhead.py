"""Per-task overhead of the sweep (docs/benchmarks.md target: <= 5 ms per task for scheduling plus storing).

Runs a job of N field-theory tasks (default 10^4) through ``gapsweep run`` and reports
``overhead = (wall time of the run - sum of the tasks' own wall times) / N``: everything the sweep adds per task
(expansion, hashing, scheduling, result conversion, the HDF5 row write and its flush, progress), measured serially
in-process and optionally under ``mpiexec -n P`` for each writer.

    python benchmarks/bench_sweep_overhead.py --out bench_out [--tasks 10000] [--mpi 2 4]

Writes ``overhead.md`` (markdown table) and ``overhead.json`` into ``--out``.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import shutil
import subprocess
import sys
import sys as _sys
import tempfile
import time
from pathlib import Path
from pathlib import Path as _Path

import numpy as np

from gapsweep import runner, store

_sys.path.insert(0, str(_Path(__file__).resolve().parent))
import _record

# the code this benchmark measures: a result measured before a later change to it is stale
# (scripts/check_docs.py)
CODE_PATHS = ['gapsweep/sweep']

SPEC = """
[job]
name = "bench-overhead"
[grid]
hurst = [0.3, 0.8]
rho = [2e-3, 1e-3]
sigma0 = {{min = 1e-5, max = 10.0, num = {num}, scale = "log"}}
[surface]
lambda_l = 0.25
lambda_s = 2.5e-3
[methods.theory]
forms = ["paper"]
"""


def _measure(path: Path, wall: float) -> dict:
    df = store.read(path)
    n = len(df)
    inside = float(np.nansum(df.wall_time))
    return {"tasks": n, "done": int((df.status == "done").sum()), "wall_s": wall, "task_time_s": inside,
            "overhead_ms_per_task": 1e3 * (wall - inside) / n, "total_ms_per_task": 1e3 * wall / n}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", required=True)
    ap.add_argument("--tasks", type=int, default=10_000, help="number of theory tasks (multiple of 4)")
    ap.add_argument("--mpi", type=int, nargs="*", default=[], help="also run under mpiexec -n P for these P")
    args = ap.parse_args()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix="gapsweep-bench-"))
    job = tmp / "job.toml"
    job.write_text(SPEC.format(num=args.tasks // 4))
    rows = []
    t0 = time.perf_counter()
    runner.run(job, tmp / "serial.h5", progress="none", mpi="off")
    rows.append({"ranks": 1, "writer": "serial", **_measure(tmp / "serial.h5", time.perf_counter() - t0)})
    import h5py

    writers = (["mpio"] if h5py.get_config().mpi else []) + ["rank0"]
    env = dict(os.environ, OMPI_ALLOW_RUN_AS_ROOT="1", OMPI_ALLOW_RUN_AS_ROOT_CONFIRM="1",
               OMPI_MCA_rmaps_base_oversubscribe="1")
    for p in args.mpi:
        if shutil.which("mpiexec") is None:
            break
        for w in writers:
            path = tmp / f"mpi{p}-{w}.h5"
            cmd = ["mpiexec", "-n", str(p), sys.executable, "-m", "gapsweep", "run", str(job), "--store", str(path),
                   "--writer", w, "--progress", "none"]
            t0 = time.perf_counter()
            subprocess.run(cmd, env=env, check=True)
            wall = time.perf_counter() - t0  # includes interpreter + MPI start-up of all ranks
            rows.append({"ranks": p, "writer": w, **_measure(path, wall)})
            assert store.diff(path, tmp / "serial.h5") == [], "stores differ"
    meta = {"python": sys.version.split()[0], "machine": platform.machine(), "cpus": os.cpu_count(),
            "host": platform.node()}
    (out / "overhead.json").write_text(json.dumps({"meta": meta, "rows": rows}, indent=2))
    lines = ["| ranks | writer | tasks | wall [s] | inside tasks [s] | overhead [ms/task] | total [ms/task] |",
             "| --- | --- | --- | --- | --- | --- | --- |"]
    for r in rows:
        lines.append(f"| {r['ranks']} | {r['writer']} | {r['tasks']} | {r['wall_s']:.2f} | {r['task_time_s']:.2f} | "
                     f"{r['overhead_ms_per_task']:.3f} | {r['total_ms_per_task']:.3f} |")
    lines.append("")
    lines.append("Overhead = (wall - sum of task wall times) / tasks; MPI rows include start-up of all ranks. "
                 f"{meta}")
    (out / "overhead.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))
    shutil.rmtree(tmp, ignore_errors=True)


if __name__ == "__main__":
    _record.track(CODE_PATHS)
    main()
