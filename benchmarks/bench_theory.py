"""Speed of the field-theory mean gap (docs/theory.md "Speed"): 10^5 pressures at figure-2 parameters
(H = 0.3, rho = 2e-3, gamma0 = 1e-3, lambda_l = 0.25, lambda_s = 2.5e-3, so zeta_s = 100), one call vectorised
over the pressures, with one zeta for all and with a zeta per pressure. Best and median of ``--repeat`` warm
calls, wall and CPU seconds, one thread.

    OMP_NUM_THREADS=1 python benchmarks/bench_theory.py --out benchmarks/results/theory/speed_vm.json
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import sys
import sys as _sys
import time
from pathlib import Path
from pathlib import Path as _Path

import numpy as np

from gapsweep import theory

_sys.path.insert(0, str(_Path(__file__).resolve().parent))
import _record

# the code this benchmark measures: a result measured before a later change to it is stale
# (scripts/check_docs.py)
CODE_PATHS = ['gapsweep/theory']

P = dict(hurst=0.3, h_rms=None, rho=2e-3, gamma0=1e-3, lambda_l=0.25, lambda_s=2.5e-3)


def _time(f, repeat: int) -> dict[str, float]:
    f()  # warm
    wall, cpu = [], []
    for _ in range(repeat):
        t0, c0 = time.perf_counter(), time.process_time()
        f()
        wall.append(time.perf_counter() - t0)
        cpu.append(time.process_time() - c0)
    return {"wall_best_s": min(wall), "wall_median_s": statistics.median(wall), "cpu_best_s": min(cpu),
            "cpu_median_s": statistics.median(cpu)}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, required=True, help="JSON file to write")
    ap.add_argument("--n", type=int, default=100_000, help="number of pressures (default 1e5)")
    ap.add_argument("--repeat", type=int, default=7, help="timed calls per case (default 7)")
    a = ap.parse_args(argv)
    s = np.geomspace(1e-4, 1.0, a.n)
    kw = {k: v for k, v in P.items() if v is not None}
    kw["h_rms"] = 0.0354
    zetas = np.geomspace(10.0, 100.0, a.n)
    rows = [
        {"case": "one zeta", "n": a.n, **_time(lambda: theory.mean_gap(s, **kw), a.repeat)},
        {"case": "zeta per pressure", "n": a.n, **_time(lambda: theory.mean_gap(s, zeta=zetas, **kw), a.repeat)},
    ]
    meta = {"host": platform.node(), "machine": platform.machine(), "python": platform.python_version(),
            "cpus": os.cpu_count(), "omp_threads": os.environ.get("OMP_NUM_THREADS", ""),
            "command": "python benchmarks/bench_theory.py " + " ".join(sys.argv[1:] if argv is None else argv),
            "date": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime())}
    a.out.parent.mkdir(parents=True, exist_ok=True)
    a.out.write_text(json.dumps({"meta": meta, "rows": rows}, indent=1))
    for r in rows:
        print(f"{r['case']:<18} n = {r['n']}: wall best {r['wall_best_s']:.4f} s, median {r['wall_median_s']:.4f} s; "
              f"cpu best {r['cpu_best_s']:.4f} s")
    return 0


if __name__ == "__main__":
    _record.track(CODE_PATHS)
    raise SystemExit(main())
