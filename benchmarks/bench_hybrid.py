"""Cost of the multiscale hybrid mean gap (gapsweep.theory.improved.hybrid) against full GFMD, side by side.

    python benchmarks/bench_hybrid.py --stores DIR [--threads 1] [--out benchmarks/results/hybrid.csv]

For a few figure 2/3 points (seed 0) it times, cold-started in one process: full GFMD (``gfmd.solve``) at
N = 1024 (the smallest power of two carrying lambda_s = L/400), the hybrid at zeta_c = 4, 8, 16, 32 and its
local-pressure variant at zeta_c = 8, 16, and
reports the mean gap of each against the stored GFMD result at N = 2048 (``DIR/fig2.h5``, ``fig3.h5``).
"""

from __future__ import annotations

import argparse
import platform
import sys as _sys
import time
import warnings
from pathlib import Path
from pathlib import Path as _Path

import pandas as pd

from gapsweep import gfmd, store, surface
from gapsweep.theory import improved

_sys.path.insert(0, str(_Path(__file__).resolve().parent))
import _record

# the code this benchmark measures: a result measured before a later change to it is stale
# (scripts/check_docs.py)
CODE_PATHS = ['gapsweep/theory', 'gapsweep/gfmd']

POINTS = [("fig3", 0.8, 2e-3, 1e-3), ("fig3", 0.8, 1e-3, 1e-2), ("fig2", 0.3, 5e-4, 1e-3)]


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--stores", type=Path, required=True)
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--out", type=Path, default=Path("benchmarks/results/hybrid.csv"))
    a = ap.parse_args(argv)
    rows = []
    for job, hurst, rho, s0 in POINTS:
        t = store.read(a.stores / f"{job}.h5")
        ref = t[(t.method == "gfmd") & (t.n == 2048) & (t.seed == 0) & (abs(t.rho / rho - 1) < 1e-9)
                & (abs(t.sigma0 / s0 - 1) < 1e-6)].iloc[0]
        h = surface.self_affine(1024, hurst, lambda_l=0.25, lambda_s=2.5e-3, rms_slope=1.0, seed=0)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            t0 = time.perf_counter()
            full = gfmd.solve(h, sigma0=s0, gamma0=1e-3, rho=rho, threads=a.threads)
            t_full = time.perf_counter() - t0
            rows.append(dict(job=job, hurst=hurst, rho=rho, sigma0=s0, method="gfmd_N1024", seconds=t_full,
                             mean_gap=full.mean_gap, rel_err=full.mean_gap / ref.mean_gap - 1, speedup=1.0))
            for zc, local in ((4, False), (8, False), (16, False), (32, False), (8, True), (16, True)):
                t0 = time.perf_counter()
                g0, _ = improved.hybrid(s0, h, zeta_c=zc, rho=rho, gamma0=1e-3, lambda_l=0.25, local=local)
                dt = time.perf_counter() - t0
                name = f"hybrid_local_{zc}" if local else f"hybrid_{zc}"
                rows.append(dict(job=job, hurst=hurst, rho=rho, sigma0=s0, method=name, seconds=dt,
                                 mean_gap=g0, rel_err=g0 / ref.mean_gap - 1, speedup=t_full / dt))
        print(pd.DataFrame(rows[-7:]).to_string(index=False), flush=True)
    df = pd.DataFrame(rows)
    df["machine"] = f"{platform.node()} {platform.processor() or platform.machine()}"
    a.out.parent.mkdir(parents=True, exist_ok=True)
    df.to_csv(a.out, index=False)
    return 0


if __name__ == "__main__":
    _record.track(CODE_PATHS)
    raise SystemExit(main())
