"""Cost of the body options of issue 43 against the elastic half-space solve of the same map, side by side in one
process: an elastic layer (``gfmd.solve(..., thickness=t, poisson=nu, bottom=...)``; docs/model.md "Elastic layer
on a rigid base") and the hard wall's pressure cap (``hardness=H``; docs/gfmd.md "Plastic contact (pressure
cap)"). Also prints how much the option changes the answer (mean gap, contact area, plastic area).

Each case: one warm-up solve per variant (numba compilation, FFT plans), then ``--repeats`` timed solves per
variant, alternating, the minimum reported; ``ratio = option / half-space`` (wall time), ``cpu_ratio`` (process
time). CPU, one thread (``OMP_NUM_THREADS=1 NUMBA_NUM_THREADS=1``), the default method of each variant ("auto").

    PYTHONPATH=$PWD OMP_NUM_THREADS=1 NUMBA_NUM_THREADS=1 nice python benchmarks/bench_body.py \\
        [--n 512] [--repeats 3] [--json out.json] [--only layer]
"""

from __future__ import annotations

import argparse
import datetime
import json
import platform
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from gapsweep.gfmd import solve
from gapsweep.surface import self_affine

ROOT = Path(__file__).resolve().parent.parent



import sys as _sys  # noqa: E402
from pathlib import Path as _Path  # noqa: E402

_sys.path.insert(0, str(_Path(__file__).resolve().parent))
import _record  # noqa: E402

# the code this benchmark measures: a result measured before a later change to it is stale
# (scripts/check_docs.py)
CODE_PATHS = ['gapsweep/gfmd/substrates.py', 'gapsweep/gfmd/_plastic.py', 'gapsweep/gfmd/_plastic_ops.py',
              'gapsweep/gfmd/_constrained.py', 'gapsweep/gfmd/_constrained_ops.py', 'gapsweep/gfmd/_softmax.py',
              'gapsweep/gfmd/_solvers.py', 'gapsweep/gfmd/_smooth.py', 'gapsweep/core']

def cases(n: int) -> list[tuple[str, np.ndarray, dict, dict]]:
    """(name, heights, the half-space solve's keywords, the option's extra keywords)."""
    h = self_affine(n, 0.8, lambda_l=0.5, lambda_s=8 / n, seed=5, rms_slope=0.5)
    hw = dict(interaction="hard_wall", tol=1e-8, sigma0=0.02)
    ex = dict(sigma0=0.02, gamma0=1e-4, rho=1e-3, tol=1e-8)
    el = solve(h, **hw)
    pmax = float(el.pressure.max())
    return [
        ("hard wall, bonded layer t = 0.05 L", h, hw, dict(thickness=0.05, poisson=0.3, bottom="bonded")),
        ("hard wall, slip layer t = 0.01 L", h, hw, dict(thickness=0.01, bottom="slip")),
        ("hard wall, bonded layer t = 1 L", h, hw, dict(thickness=1.0, poisson=0.45)),
        ("exponential, bonded layer t = 0.05 L", h, ex, dict(thickness=0.05, poisson=0.3)),
        ("hard wall, cap H = 0.5 p_max", h, hw, dict(hardness=0.5 * pmax)),
        ("hard wall, cap H = 0.2 p_max", h, hw, dict(hardness=0.2 * pmax)),
        ("hard wall, cap H = 0.2 p_max, layer t = 0.05 L", h, hw,
         dict(hardness=0.2 * pmax, thickness=0.05, poisson=0.3)),
    ]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=512)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--json", type=Path, default=None)
    ap.add_argument("--only", default="", help="run the cases whose name contains this")
    args = ap.parse_args()
    rows = []
    print(f"{'case':48s} {'half s':>8s} {'option s':>9s} {'ratio':>6s} {'cpu r':>6s} {'its h/o':>9s} "
          f"{'gap o/h':>8s} {'area o/h':>8s} {'plastic':>8s}")
    for name, h, kw, opt in cases(args.n):
        if args.only not in name:
            continue
        res = {"half": solve(h, **kw), "opt": solve(h, **kw, **opt)}  # warm-up
        best = {"half": np.inf, "opt": np.inf}
        cpu = {"half": np.inf, "opt": np.inf}
        for _ in range(args.repeats):
            for key, more in (("half", {}), ("opt", opt)):
                t0, c0 = time.perf_counter(), time.process_time()
                res[key] = solve(h, **kw, **more)
                best[key] = min(best[key], time.perf_counter() - t0)
                cpu[key] = min(cpu[key], time.process_time() - c0)
        a, b = res["half"], res["opt"]
        if not (a.converged and b.converged):
            raise SystemExit(f"{name}: not converged ({a.status}, {b.status})")
        row = {"case": name, "n": args.n, "half_space_s": best["half"], "option_s": best["opt"],
               "ratio": best["opt"] / best["half"], "cpu_ratio": cpu["opt"] / cpu["half"],
               "iterations_half_space": a.iterations, "iterations_option": b.iterations,
               "method_half_space": a.method, "method_option": b.method,
               "mean_gap_ratio": b.mean_gap / a.mean_gap, "area_ratio": b.contact_area / a.contact_area,
               "plastic_area": float(b.plastic_area) if np.isfinite(b.plastic_area) else None}
        rows.append(row)
        print(f"{name:48s} {row['half_space_s']:8.3f} {row['option_s']:9.3f} {row['ratio']:6.2f} "
              f"{row['cpu_ratio']:6.2f} {a.iterations:4d}/{b.iterations:<4d} {row['mean_gap_ratio']:8.3f} "
              f"{row['area_ratio']:8.3f} {row['plastic_area'] or 0:8.4f}", flush=True)
    if args.json:
        commit = subprocess.run(["git", "-C", str(ROOT), "rev-parse", "--short", "HEAD"], capture_output=True,
                                text=True).stdout.strip()
        meta = {"commit": commit, "command": " ".join(["python", *sys.argv]), "machine": platform.machine(),
                "node": "2-core shared VM (x86_64), one thread", "python": platform.python_version(),
                "date": datetime.datetime.now(datetime.UTC).strftime("%Y-%m-%d %H:%M UTC"),
                "repeats": args.repeats}
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps({"meta": meta, "rows": rows}, indent=1))


if __name__ == "__main__":
    _record.track(CODE_PATHS)
    main()
