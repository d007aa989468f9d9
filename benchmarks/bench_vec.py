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
import sys as _sys
from pathlib import Path as _Path

from gapsweep.core.vec import axpy, rdot

_sys.path.insert(0, str(_Path(__file__).resolve().parent))
import _record

# the code this benchmark measures: a result measured before a later change to it is stale
# (scripts/check_docs.py)
CODE_PATHS = ['gapsweep/core/vec.py', 'gapsweep/gfmd']


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


def _blas_rdot(a, b) -> float:
    return float(np.vdot(a.ravel(), b.ravel()).real) if a.flags.c_contiguous else float(np.vdot(a, b).real)


def _blas_axpy(a, x, y) -> None:
    zaxpy(x.ravel(), y.ravel(), a=a)


def solves(load: int) -> list[dict]:
    """Whole numpy solves (256^2 periodic, a 128 x 160 free map) with the minimisers' level-1 operations as
    shipped (gapsweep.core.vec) and as before (BLAS vdot / zaxpy patched in their place), side by side."""
    from gapsweep import gfmd
    from gapsweep.gfmd import _free, _grid, _ops
    from gapsweep.surfaces.synthetic import self_affine

    h = self_affine(256, 0.8, lambda_l=0.25, lambda_s=1 / 64, seed=3)
    laws = [dict(interaction="exponential", gamma0=1e-3, rho=4e-3), dict(interaction="adhesive", work=2e-4, rho=4e-3),
            dict(interaction="hard_wall")]
    gfmd.solve(h, sigma0=1e-2, backend="numpy", **laws[0])  # JIT and plans outside the timings
    rows = []
    for variant in ("vec", "blas"):
        patch = variant == "blas"
        _grid.rdot, _ops.rdot = (_blas_rdot, _blas_rdot) if patch else (rdot, rdot)
        _free.axpy = _blas_axpy if patch else axpy
        for law in laws:
            for periodic in (True, False):
                hh = h if periodic else h[:128, :160]
                w, c = time.perf_counter(), time.process_time()
                r = gfmd.solve(hh, sigma0=1e-2, backend="numpy", periodic=periodic, tol=1e-8, **law)
                rows.append({"load": load, "variant": variant, "law": law["interaction"], "periodic": periodic,
                             "status": r.status, "iterations": r.iterations, "wall_s": time.perf_counter() - w,
                             "cpu_s": time.process_time() - c})
                print(f"load {load} solve {variant:<4} {law['interaction']:<11} periodic={periodic!s:<5} "
                      f"{r.status} {r.iterations} it, wall {rows[-1]['wall_s']:.3f} s", flush=True)
    _grid.rdot, _ops.rdot, _free.axpy = rdot, rdot, axpy
    return rows


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
            rows += solves(load)
        finally:
            stop.set()
            for p in procs:
                p.join()
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps({"command": " ".join(sys.argv), "machine": platform.node(),
                                    "cores": os.cpu_count(), "date": time.strftime("%Y-%m-%d %H:%M %Z"),
                                    "numpy": np.__version__, "rows": rows}, indent=1))


if __name__ == "__main__":
    _record.track(CODE_PATHS)
    main()
