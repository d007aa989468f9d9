"""Strong scaling of the MPI task farm on a GFMD sweep (docs/benchmarks.md target:
parallel efficiency >= 85 % at 16 ranks).

The job: GFMD at N = ``--n`` (default 1024) on H = 0.3 and 0.8, rho = 2e-3, 8 pressures 1e-4..1, ``--seeds``
surfaces; independent tasks (no warm-start chains) unless ``--warm-start``. CPU only: the FFT backend is forced
(``--backend``, default pyfftw, else numpy) and every rank runs one FFT thread, so a GPU on the machine is not used.
For each rank count P it runs ``mpiexec -n P gapsweep run`` (1 rank: plain ``gapsweep run``) and reports

* wall efficiency ``E(P) = T(1) / (P T(P))`` from the command's wall time (start-up of the ranks included);
* steady efficiency: the same after subtracting the start-up time of P ranks (measured on a P-task theory job);
* whether the store equals the 1-rank store (content, see ``gapsweep.store.diff``).

    python benchmarks/bench_sweep_scaling.py --out bench_scaling --ranks 1 2 4 8 16 [--seeds 16]

Writes ``scaling.md`` and ``scaling.json`` into ``--out``. Environment: ``MPIEXEC`` (default ``mpiexec``),
``MPIEXEC_ARGS`` (default ``--bind-to core``; add ``--oversubscribe`` for more ranks than cores).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import shlex
import shutil
import subprocess
import sys
import sys as _sys
import tempfile
import time
from pathlib import Path
from pathlib import Path as _Path

import numpy as np

from gapsweep import store

_sys.path.insert(0, str(_Path(__file__).resolve().parent))
import _record

# the code this benchmark measures: a result measured before a later change to it is stale
# (scripts/check_docs.py)
CODE_PATHS = ['gapsweep/sweep']

SPEC = """
[job]
name = "bench-scaling"
[grid]
hurst = [0.3, 0.8]
rho = [2e-3]
sigma0 = {{min = 1e-4, max = 1.0, num = 8, scale = "log"}}
seeds = {{start = 0, count = {seeds}}}
[surface]
lambda_l = 0.25
lambda_s = {lambda_s}
[methods.gfmd]
n = {n}
tol = 1e-6
backend = "{backend}"
warm_start = {warm}
"""

STARTUP = """
[job]
name = "bench-startup"
[grid]
hurst = [0.3]
rho = [2e-3]
sigma0 = {{min = 1e-4, max = 1.0, num = {num}, scale = "log"}}
[surface]
lambda_s = {lambda_s}
[methods.theory]
forms = ["discrete"]
n = {n}
"""


def _cmd(p: int, job: Path, path: Path, extra: list[str]) -> list[str]:
    base = [sys.executable, "-m", "gapsweep", "run", str(job), "--store", str(path), "--progress", "none", *extra]
    if p == 1:
        return [*base, "--mpi", "off"]
    mpiexec = shlex.split(os.environ.get("MPIEXEC", "mpiexec"))
    args = shlex.split(os.environ.get("MPIEXEC_ARGS", "--bind-to core"))
    return [*mpiexec, "-n", str(p), *args, *base]


def _timed(cmd: list[str], env: dict) -> float:
    t0 = time.perf_counter()
    subprocess.run(cmd, env=env, check=True)
    return time.perf_counter() - t0


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", required=True)
    ap.add_argument("--ranks", type=int, nargs="+", default=[1, 2, 4, 8, 16])
    ap.add_argument("--n", type=int, default=1024)
    ap.add_argument("--seeds", type=int, default=16)
    ap.add_argument("--backend", default=None, help="GFMD FFT backend (default: pyfftw if importable, else numpy)")
    ap.add_argument("--warm-start", action="store_true", help="pressure chains with warm starts (coarser units)")
    ap.add_argument("--writer", default="auto", choices=("auto", "mpio", "rank0"))
    ap.add_argument("--coordinator-works", default="auto", choices=("auto", "yes", "no"))
    args = ap.parse_args()
    backend = args.backend
    if backend is None:
        try:
            import pyfftw  # noqa: F401

            backend = "pyfftw"
        except ImportError:
            backend = "numpy"
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix="gapsweep-scaling-"))
    lambda_s = 2.5e-3 if args.n >= 802 else 4.0 / args.n  # M6 when the grid carries it
    job = tmp / "job.toml"
    job.write_text(SPEC.format(seeds=args.seeds, n=args.n, backend=backend, lambda_s=lambda_s,
                               warm="true" if args.warm_start else "false"))
    env = dict(os.environ, OMP_NUM_THREADS="1", OPENBLAS_NUM_THREADS="1", GAPSWEEP_FFT_THREADS="1",
               NUMBA_NUM_THREADS="1", OMPI_ALLOW_RUN_AS_ROOT="1", OMPI_ALLOW_RUN_AS_ROOT_CONFIRM="1",
               HDF5_USE_FILE_LOCKING="FALSE")
    # Warm-up: one small serial run plans the FFTs (FFTW wisdom is cached on disk for all ranks).
    warm = tmp / "warm.toml"
    warm.write_text(job.read_text().replace(f"count = {args.seeds}", "count = 1").replace("num = 8", "num = 1"))
    _timed(_cmd(1, warm, tmp / "warm.h5", []), env)
    extra = ["--writer", args.writer, "--coordinator-works", args.coordinator_works]
    rows, ref = [], None
    for p in args.ranks:
        path = tmp / f"p{p}.h5"
        wall = _timed(_cmd(p, job, path, extra if p > 1 else []), env)
        sj = tmp / f"startup{p}.toml"
        sj.write_text(STARTUP.format(num=max(p, 2), n=args.n, lambda_s=lambda_s))
        startup = _timed(_cmd(p, sj, tmp / f"startup{p}.h5", extra if p > 1 else []), env)
        df = store.read(path)
        attrs = store.read_attrs(path)
        writer = json.loads(attrs["runs"])[-1]["writer"]
        same = None
        if ref is None:
            ref = path
        else:
            same = store.diff(path, ref) == []
        rows.append({"ranks": p, "wall_s": wall, "startup_s": startup, "task_time_s": float(np.nansum(df.wall_time)),
                     "tasks": len(df), "done": int((df.status == "done").sum()), "writer": writer,
                     "identical_to_first": same})
        print(rows[-1], flush=True)
    t1 = next((r for r in rows if r["ranks"] == 1), None)
    for r in rows:
        if t1 is not None:
            r["speedup"] = t1["wall_s"] / r["wall_s"]
            r["efficiency_wall"] = r["speedup"] / r["ranks"]
            r["efficiency_steady"] = (t1["wall_s"] - t1["startup_s"]) / (r["ranks"] * max(r["wall_s"] - r["startup_s"],
                                                                                        1e-9))
    meta = {"n": args.n, "seeds": args.seeds, "backend": backend, "warm_start": args.warm_start,
            "python": sys.version.split()[0], "cpus": os.cpu_count(), "host": platform.node(),
            "mpiexec": os.environ.get("MPIEXEC", "mpiexec"), "mpiexec_args": os.environ.get("MPIEXEC_ARGS",
                                                                                           "--bind-to core")}
    (out / "scaling.json").write_text(json.dumps({"meta": meta, "rows": rows}, indent=2))
    lines = ["| ranks | writer | tasks | wall [s] | start-up [s] | sum of task times [s] | speed-up | "
             "efficiency (wall) | efficiency (steady) | same store |", "| --- " * 10 + "|"]
    for r in rows:
        lines.append(f"| {r['ranks']} | {r['writer']} | {r['tasks']} | {r['wall_s']:.1f} | {r['startup_s']:.1f} | "
                     f"{r['task_time_s']:.1f} | {r.get('speedup', float('nan')):.2f} | "
                     f"{100 * r.get('efficiency_wall', float('nan')):.0f} % | "
                     f"{100 * r.get('efficiency_steady', float('nan')):.0f} % | {r['identical_to_first']} |")
    lines += ["", f"GFMD N = {args.n}, {meta}"]
    (out / "scaling.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))
    shutil.rmtree(tmp, ignore_errors=True)


if __name__ == "__main__":
    _record.track(CODE_PATHS)
    main()
