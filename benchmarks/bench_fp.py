"""Speed against error of the Fokker-Planck solver (docs/model.md M5): L1 error of the density against a much finer
solve (C2 = 0: the exact Gaussian), on the same 100 bins as benchmarks/bench_sde.py (the reference's 1e-5 ..
1 - 1e-5 quantiles), as a function of zeta steps and grid resolution, with wall time.

    python benchmarks/bench_fp.py --out results/fp_cpu
"""

from __future__ import annotations

import argparse
import json
import math
import sys as _sys
import time
from pathlib import Path
from pathlib import Path as _Path

import numpy as np
from scipy.stats import norm

from gapsweep import fokker_planck, sde

_sys.path.insert(0, str(_Path(__file__).resolve().parent))
import _record

# the code this benchmark measures: a result measured before a later change to it is stale
# (scripts/check_docs.py)
CODE_PATHS = ['gapsweep/gapdist']

PARAMS = {
    "fig6": (dict(hurst=0.3, h_rms=0.035444, rho=2e-3, gamma0=1e-3, lambda_l=0.25, lambda_s=2.5e-3), 1e-4, 0.5),
    "stiff": (dict(hurst=0.3, h_rms=2.34e-3, rho=5e-4, gamma0=1e-3, lambda_l=0.25, lambda_s=2.5e-3), 1e-2, 1.0),
    "gauss_c2_0": (dict(hurst=0.3, h_rms=2.34e-3, rho=2e-3, gamma0=1e-3, lambda_l=0.25, lambda_s=2.5e-3), 1e-3, 0.0),
}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", required=True, type=Path)
    args = ap.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    rows = []
    for case, (p, s0, c2) in PARAMS.items():
        if c2 == 0.0:
            pl = sde.plan_steps(s0, **p)
            m, sd = pl.g0_end, math.sqrt(pl.variance)
            edges = m + sd * np.linspace(-4.4, 4.4, 101)  # 1e-5 .. 1 - 1e-5 quantiles, 100 bins
            exact = np.diff(norm.cdf(edges, m, sd)) / np.diff(edges)
        else:
            ref = fokker_planck.solve(s0, c2=c2, n_steps=12800, cells_per_sd=200, cells_per_rho=16, **p)
            g = ref.g[-1]
            c = np.cumsum(ref.density[-1] * ref.widths)
            edges = np.linspace(g[np.searchsorted(c, 1e-5)], g[min(np.searchsorted(c, 1 - 1e-5), g.size - 1)], 101)
            exact = ref.bin_density(edges)
        for n_steps in (50, 100, 200, 400, 800, 1600, 3200):
            for cps, cpr in ((20, 2), (40, 4), (80, 8)):
                t = time.perf_counter()
                r = fokker_planck.solve(s0, c2=c2, n_steps=n_steps, cells_per_sd=cps, cells_per_rho=cpr, **p)
                wall = time.perf_counter() - t
                l1 = float(np.sum(np.abs(r.bin_density(edges) - exact) * np.diff(edges)))
                rows.append(dict(case=case, n_steps=n_steps, cells_per_sd=cps, cells_per_rho=cpr,
                                 n_cells=int(r.y.size), wall_s=wall, l1=l1, status=r.status,
                                 mass_error=r.mass_error))
                print(json.dumps(rows[-1]), flush=True)
    (args.out / "bench_fp.json").write_text(json.dumps(rows, indent=1))
    lines = ["| case | zeta steps | cells/sd | cells/rho | cells | wall [s] | L1 vs reference |",
             "| --- | --- | --- | --- | --- | --- | --- |"]
    for r in rows:
        lines.append(f"| {r['case']} | {r['n_steps']} | {r['cells_per_sd']} | {r['cells_per_rho']} | "
                     f"{r['n_cells']} | {r['wall_s']:.3f} | {r['l1']:.2e} |")
    (args.out / "bench_fp.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    _record.track(CODE_PATHS)
    main()
