"""Cost of free boundaries: ``gfmd.solve(..., periodic=False)`` against the periodic solve of the same map, side
by side in one process (docs/gfmd.md, "Periodic or free boundaries"). Also prints how much the boundary
condition changes the answer (mean gap, contact area).

Each case: one warm-up solve per mode (numba compilation, FFT plans, the Green's function), then ``--repeats``
timed solves per mode, alternating, the minimum reported; ``ratio = free / periodic`` (wall time) and
``cpu_ratio`` (process time, every thread: steadier on a shared machine). CPU, one thread (set
``OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1`` too: the spectral dot products call BLAS), the default method of
each law ("auto"). ``--only exponential`` runs the cases whose name contains the word.

    PYTHONPATH=$PWD nice python benchmarks/bench_free.py [--repeats 3] [--json out.json] [--only exponential]
        [--cases heldout]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
import sys as _sys
import time
from pathlib import Path
from pathlib import Path as _Path

import numpy as np

from gapsweep.gfmd import solve
from gapsweep.surface import self_affine
from gapsweep.topography import load

_sys.path.insert(0, str(_Path(__file__).resolve().parent))
import _record

# the code this benchmark measures: a result measured before a later change to it is stale
# (scripts/check_docs.py)
CODE_PATHS = ['gapsweep/gfmd', 'gapsweep/surfaces']

ROOT = Path(__file__).resolve().parent.parent


def cases() -> list[tuple[str, np.ndarray, tuple[float, float], dict]]:
    ex = load(ROOT / "jobs/data/measured_tilted_192x128.npz", unit="um", pixel_size=0.5, detrend="plane")
    p = self_affine(512, 0.8, lambda_l=0.5, lambda_s=8 / 512, seed=5, rms_slope=1.0)
    hw = dict(interaction="hard_wall", tol=1e-8)
    return [
        ("example 192x128 um, hard wall", ex.heights, ex.length, dict(sigma0=5e-3, **hw)),
        ("crop 256x256, hard wall", p[:256, :256], (0.5, 0.5), dict(sigma0=0.05, **hw)),
        ("crop 512x384, hard wall", p[:, 64:448], (1.0, 0.75), dict(sigma0=0.05, **hw)),
        ("crop 256x192, exponential", p[:256, :192], (0.5, 0.375),
         dict(sigma0=0.05, gamma0=1e-4, rho=1e-3, tol=1e-8)),
        ("crop 320x448, exponential", p[:320, 32:480], (0.625, 0.875),
         dict(sigma0=0.05, gamma0=1e-4, rho=1e-3, tol=1e-8)),
    ]


def heldout_cases() -> list[tuple[str, np.ndarray, tuple[float, float], dict]]:
    """Maps and parameters nobody tuned the free minimiser on (issue 36, item 7): square maps (the periodic
    exponential solve then runs the softmax CG, the rectangular ones the generic L-BFGS), other seeds and Hurst
    exponents, and the measured example map in um / MPa with the exponential law."""
    ex = load(ROOT / "jobs/data/measured_tilted_192x128.npz", unit="um", pixel_size=0.5, detrend="plane")
    sq = self_affine(256, 0.3, lambda_l=0.25, lambda_s=4 / 256, seed=9, rms_slope=1.0)
    big = self_affine(512, 0.5, lambda_l=0.5, lambda_s=8 / 512, seed=21, rms_slope=1.0)
    sq2 = self_affine(192, 0.7, lambda_l=0.5, lambda_s=6 / 192, seed=33, rms_slope=0.5)
    ex_exp = dict(sigma0=20.0, e_star=1000.0, gamma0=50.0, rho=0.5, tol=1e-8)
    exp = dict(gamma0=1e-4, rho=4e-3, tol=1e-8)
    hw = dict(interaction="hard_wall", tol=1e-8)
    return [
        ("held-out example 192x128 um, exponential", ex.heights, ex.length, ex_exp),
        ("held-out square 256 H0.3 s9, exponential", sq, (1.0, 1.0), dict(sigma0=0.02, **exp)),
        ("held-out square 192 H0.7 s33, exponential", sq2, (1.0, 1.0), dict(sigma0=0.01, gamma0=1e-4, rho=6e-3,
                                                                             tol=1e-8)),
        ("held-out crop 384x256 H0.5 s21, exponential", big[:384, 100:356], (0.375, 0.25),
         dict(sigma0=0.05, gamma0=1e-4, rho=1e-3, tol=1e-8)),
        ("held-out square 256 H0.3 s9, hard wall", sq, (1.0, 1.0), dict(sigma0=0.02, **hw)),
        ("held-out crop 384x256 H0.5 s21, hard wall", big[:384, 100:356], (0.375, 0.25), dict(sigma0=0.05, **hw)),
    ]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--json", type=Path, default=None)
    ap.add_argument("--only", default="", help="run the cases whose name contains this")
    ap.add_argument("--cases", choices=("tuned", "heldout"), default="tuned",
                    help="the original cases (tuned on) or the held-out ones (heldout_cases)")
    args = ap.parse_args()
    rows = []
    print(f"{'case':32s} {'periodic s':>10s} {'free s':>9s} {'ratio':>6s} {'its p/f':>9s} "
          f"{'gap free/per':>12s} {'area free/per':>13s}")
    for name, h, length, kw in (cases() if args.cases == "tuned" else heldout_cases()):
        if args.only not in name:
            continue
        res, best, cpu = {}, {True: np.inf, False: np.inf}, {True: np.inf, False: np.inf}
        for per in (True, False):
            res[per] = solve(h, length=length, periodic=per, **kw)  # warm-up
        for _ in range(args.repeats):
            for per in (True, False):
                t, c = time.perf_counter(), time.process_time()
                res[per] = solve(h, length=length, periodic=per, **kw)
                best[per] = min(best[per], time.perf_counter() - t)
                cpu[per] = min(cpu[per], time.process_time() - c)
        a, b = res[True], res[False]
        assert a.converged and b.converged, (a.status, b.status)
        row = dict(case=name, law=kw.get("interaction", "exponential"),
                   grid="square" if h.shape[0] == h.shape[1] and length[0] == length[1] else "rectangular",
                   periodic_s=best[True], free_s=best[False], ratio=best[False] / best[True],
                   iterations_periodic=a.iterations, iterations_free=b.iterations,
                   mean_gap_ratio=b.mean_gap / a.mean_gap,
                   area_ratio=b.contact_area / a.contact_area if a.contact_area else float("nan"),
                   periodic_cpu_s=cpu[True], free_cpu_s=cpu[False], cpu_ratio=cpu[False] / cpu[True])
        rows.append(row)
        print(f"{name:32s} {best[True]:10.3f} {best[False]:9.3f} {row['ratio']:6.2f} "
              f"{a.iterations:4d}/{b.iterations:<4d} {row['mean_gap_ratio']:12.3f} {row['area_ratio']:13.3f}"
              f"  CPU s {cpu[True]:.3f}/{cpu[False]:.3f} = {row['cpu_ratio']:.2f}", flush=True)
    commit = subprocess.run(["git", "rev-parse", "HEAD"], cwd=ROOT, capture_output=True, text=True).stdout.strip()
    meta = dict(machine=platform.processor() or platform.machine(), cpus=os.cpu_count(),
                load=os.getloadavg()[0], python=platform.python_version(), repeats=args.repeats, commit=commit,
                command="python " + " ".join(sys.argv), date=time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
                threads={k: os.environ.get(k) for k in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS")})
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(dict(meta=meta, rows=rows), indent=1))


if __name__ == "__main__":
    _record.track(CODE_PATHS, header=True)
    main()
