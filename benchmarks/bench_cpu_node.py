"""CPU node: memory-bandwidth probe beside the GFMD sweep's throughput (issue 14, item 5), in one run.

Each layout runs ``P`` worker processes with ``T`` threads each (``--layouts 1x1 16x1 4x4``); after their
warm-up they wait for each other (a file barrier) and are timed inside the worker:

* triad: STREAM-like ``a = b + s c`` (numba, one fused loop, threads = T), counted as 24 bytes per element
  (STREAM convention); ``--triad-mb`` per array: 256 MB (DRAM) and 8 MB (the size of one N = 1024 field).
* gfmd: force evaluations of the CG solver at ``--n`` (irfft2 of a direction, the fused softmax pass with its
  moments, rfft2, the gradient pass: what a sweep task repeats), FFT backend ``--backend``.

The node's bound for the sweep: if a force evaluation is limited by memory traffic, its throughput over P
processes can grow at most as the triad's does, so ``fraction = (gfmd scaling) / (triad scaling)`` at the same
layout. Reports GB/s, evaluations/s and the ratios.

    python benchmarks/bench_cpu_node.py --out OUT                       # defaults: 1x1 16x1 4x4, n = 1024
    python benchmarks/bench_cpu_node.py --out /tmp/x --layouts 1x1 2x1 --n 256 --evals 5   # smoke test
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
import time
from pathlib import Path
from pathlib import Path as _Path

_sys.path.insert(0, str(_Path(__file__).resolve().parent))
import _record

# the code this benchmark measures: a result measured before a later change to it is stale
# (scripts/check_docs.py)
CODE_PATHS = ['gapsweep/gfmd', 'gapsweep/core']

ROOT = Path(__file__).resolve().parents[1]


def _wait(barrier: str) -> None:
    """Start together: announce readiness in the barrier folder, then wait until every worker has."""
    folder, procs = barrier.rsplit(":", 1)
    Path(folder, str(os.getpid())).touch()
    while len(os.listdir(folder)) < int(procs):
        time.sleep(0.002)


def worker_triad(mb: float, repeat: int, barrier: str) -> dict:
    import numba
    import numpy as np

    @numba.njit(parallel=True, fastmath=True, cache=False)
    def triad(a, b, c, s):
        for i in numba.prange(a.size):
            a[i] = b[i] + s * c[i]

    n = int(mb * 1e6 / 8)
    a, b, c = np.empty(n), np.random.default_rng(0).random(n), np.random.default_rng(1).random(n)
    triad(a, b, c, 3.0)  # compile + first touch
    _wait(barrier)
    t = time.perf_counter()
    for _ in range(repeat):
        triad(a, b, c, 3.0)
    dt = time.perf_counter() - t
    return {"seconds": dt, "bytes": 24.0 * n * repeat, "check": float(a[1] - b[1] - 3.0 * c[1])}


def worker_gfmd(n: int, evals: int, backend: str, threads: int, barrier: str) -> dict:
    import numpy as np

    sys.path.insert(0, str(ROOT))
    from gapsweep import gfmd
    from gapsweep.core.fft import get_backend
    from gapsweep.surface import self_affine

    h = self_affine(n, 0.3, lambda_l=0.25, lambda_s=4.0 / n, rms_slope=1.0, seed=1)
    fb = get_backend(backend, n, threads=threads)
    rng = np.random.default_rng(0)
    X = fb.rfft2(rng.standard_normal((n, n))) * (1e-6 / n**2)
    pb = gfmd._Problem(h, X.copy(), sigma0=1e-2, rho=2e-3, e_star=1.0, length=1.0, fft=fb,
                       ops=gfmd._make_ops(np, n))

    def force():
        d = fb.irfft2(X)
        m = pb.ops.trial(pb.W, d, -1e-3, pb.Wt)
        S, _, _ = pb.ops.expstats(pb.Wt, m, pb.et, d)
        E = fb.rfft2(pb.et)
        pb.ops.grad_step(pb.X, X, 0.0, E, 1e-2 / S, pb.k, pb.G)

    force()
    force()
    _wait(barrier)
    t = time.perf_counter()
    for _ in range(evals):
        force()
    return {"seconds": time.perf_counter() - t, "evals": evals}


def run_layout(kind: str, procs: int, threads: int, args) -> dict:
    env = dict(os.environ, OMP_NUM_THREADS=str(threads), NUMBA_NUM_THREADS=str(threads),
               GAPSWEEP_FFT_THREADS=str(threads), MKL_NUM_THREADS=str(threads), OPENBLAS_NUM_THREADS=str(threads))
    import tempfile

    folder = tempfile.mkdtemp(prefix="bench_cpu_node_")
    cmd = [sys.executable, __file__, "--worker", kind, "--barrier", f"{folder}:{procs}", "--threads", str(threads),
           "--n", str(args.n), "--evals", str(args.evals), "--backend", args.backend,
           "--triad-mb", str(args.triad_mb_one), "--repeat", str(args.repeat)]
    ps = [subprocess.Popen(cmd, env=env, stdout=subprocess.PIPE, text=True) for _ in range(procs)]
    outs = [json.loads(p.communicate()[0].strip().splitlines()[-1]) for p in ps]
    shutil.rmtree(folder, ignore_errors=True)
    if any(p.returncode for p in ps):
        raise RuntimeError(f"a {kind} worker failed")
    slowest = max(o["seconds"] for o in outs)
    if kind == "triad":
        return {"GB/s": sum(o["bytes"] for o in outs) / slowest / 1e9, "slowest_s": slowest}
    total = sum(o["evals"] for o in outs)
    return {"evals/s": total / slowest, "ms/eval per process": 1e3 * slowest / outs[0]["evals"]}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", type=Path)
    ap.add_argument("--layouts", nargs="+", default=["1x1", "16x1", "4x4"], help="PROCESSESxTHREADS")
    ap.add_argument("--n", type=int, default=1024)
    ap.add_argument("--evals", type=int, default=40)
    ap.add_argument("--backend", default="pyfftw")
    ap.add_argument("--triad-mb", type=float, nargs="+", default=[256.0, 8.0])
    ap.add_argument("--repeat", type=int, default=20)
    ap.add_argument("--worker", choices=["triad", "gfmd"])
    ap.add_argument("--barrier", help="(worker) FOLDER:PROCESSES")
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--triad-mb-one", type=float, default=256.0)
    args = ap.parse_args()
    if args.worker == "triad":
        print(json.dumps(worker_triad(args.triad_mb_one, args.repeat, args.barrier)))
        return
    if args.worker == "gfmd":
        print(json.dumps(worker_gfmd(args.n, args.evals, args.backend, args.threads, args.barrier)))
        return
    if args.out is None:
        ap.error("--out is required")
    args.out.mkdir(parents=True, exist_ok=True)
    rows = []
    for lay in args.layouts:
        procs, threads = (int(x) for x in lay.split("x"))
        row = {"layout": lay, "processes": procs, "threads": threads}
        for mb in args.triad_mb:
            args.triad_mb_one = mb
            r = run_layout("triad", procs, threads, args)
            row[f"triad {mb:g} MB GB/s"] = r["GB/s"]
        r = run_layout("gfmd", procs, threads, args)
        row["gfmd evals/s"] = r["evals/s"]
        row["gfmd ms/eval per process"] = r["ms/eval per process"]
        rows.append(row)
        print(json.dumps(row), flush=True)
    base = rows[0]
    for r in rows:
        for mb in args.triad_mb:
            r[f"triad {mb:g} MB scaling"] = r[f"triad {mb:g} MB GB/s"] / base[f"triad {mb:g} MB GB/s"]
        r["gfmd scaling"] = r["gfmd evals/s"] / base["gfmd evals/s"]
        r["fraction of DRAM bound"] = r["gfmd scaling"] / r[f"triad {args.triad_mb[0]:g} MB scaling"]
    meta = {"host": platform.node(), "cpus": os.cpu_count(), "command": " ".join(sys.argv), "n": args.n,
            "backend": args.backend}
    (args.out / "cpu_node.json").write_text(json.dumps({"meta": meta, "rows": rows}, indent=1))
    keys = list(rows[0])
    lines = [f"### CPU node ({os.cpu_count()} CPUs): triad bandwidth beside GFMD force evaluations "
             f"(n = {args.n}, {args.backend})", "", f"`{meta['command']}`", "",
             "| " + " | ".join(keys) + " |", "|" + " --- |" * len(keys)]
    for r in rows:
        lines.append("| " + " | ".join(f"{r[k]:.3g}" if isinstance(r[k], float) else str(r[k]) for k in keys) + " |")
    (args.out / "cpu_node.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    _record.track(CODE_PATHS)
    main()
