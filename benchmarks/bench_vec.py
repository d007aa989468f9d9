"""Level-1 operations of the CPU minimisers: BLAS (numpy.vdot, scipy's zaxpy; OpenBLAS threads) against
gapsweep.core.vec (rdot, axpy: single-threaded einsum / chunked numpy), side by side in one run, on an idle
machine and with ``--load K`` busy processes beside it (docs/gfmd.md "CPU threads").

    python benchmarks/bench_vec.py --load 0 2 --out benchmarks/results/vec/vec_2core.json   # ~1 minute

Times: wall and CPU (the process's, all its threads) per call, median of ``--reps``."""

from __future__ import annotations

import argparse
import json
import multiprocessing as mp
import os
import platform
import statistics
import sys
import time
from pathlib import Path

import numpy as np
from scipy.linalg.blas import zaxpy

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from gapsweep.core.vec import axpy, rdot


def _busy(stop) -> None:
    while not stop.is_set():
        pass


def _time(fn, reps: int) -> tuple[float, float]:
    fn()
    walls, cpus = [], []
    for _ in range(reps):
        w, c = time.perf_counter(), time.process_time()
        fn()
        walls.append(time.perf_counter() - w)
        cpus.append(time.process_time() - c)
    return statistics.median(walls), statistics.median(cpus)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--load", type=int, nargs="+", default=[0, 2])
    ap.add_argument("--shapes", nargs="+", default=["256x129", "1024x513", "2048x1025"])
    ap.add_argument("--reps", type=int, default=30)
    ap.add_argument("--out", type=Path, required=True)
    args = ap.parse_args()
    rows = []
    for load in args.load:
        stop = mp.Event()
        procs = [mp.Process(target=_busy, args=(stop,)) for _ in range(load)]
        for p in procs:
            p.start()
        try:
            for s in args.shapes:
                shape = tuple(int(v) for v in s.split("x"))
                rng = np.random.default_rng(0)
                a = rng.standard_normal(shape) + 1j * rng.standard_normal(shape)
                b = 1.1 * a
                ops = {"blas vdot": lambda x, y: np.vdot(x, y).real, "vec rdot": rdot,
                       "blas zaxpy": lambda x, y: zaxpy(x.ravel(), y.ravel(), a=1e-9),
                       "vec axpy": lambda x, y: axpy(1e-9, x, y)}
                for name, op in ops.items():
                    wall, cpu = _time(lambda op=op, a=a, b=b: op(a, b), args.reps)
                    rows.append({"load": load, "shape": s, "op": name, "wall_ms": 1e3 * wall, "cpu_ms": 1e3 * cpu})
                    print(f"load {load} {s:>10} {name:<11} wall {1e3 * wall:8.3f} ms  cpu {1e3 * cpu:8.3f} ms",
                          flush=True)
        finally:
            stop.set()
            for p in procs:
                p.join()
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps({"command": " ".join(sys.argv), "machine": platform.node(),
                                    "cores": os.cpu_count(), "date": time.strftime("%Y-%m-%d %H:%M %Z"),
                                    "numpy": np.__version__, "rows": rows}, indent=1))


if __name__ == "__main__":
    main()
