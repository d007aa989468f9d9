"""Error of the multiscale gap distribution's centring table (``closure._mean_drift``) at fewer start gaps and
paths (issue 39 item 3): against a 129 x 65536 table on the coarse grids that ``multiscale_gap_samples`` uses.

    python benchmarks/bench_multiscale_table.py --out benchmarks/results/multiscale_table.json

For each case (held-out surfaces of bench_bounds.py, three pressures) the hybrid's finest coarse grid is solved
once; for every table size the expected drift ``E[g_end | g_start] - g_start`` is evaluated at the coarse pixels'
start gaps (a random subset of 4096), and its error against the reference is given in units of the fine shells'
spread ``std(g_end - g_start)`` (the width the table shifts each pixel's samples within) and of ``rho``. CPU
seconds per table (one thread, process time).
"""

from __future__ import annotations

import argparse
import json
import math
import platform
import subprocess
import sys
import time
import warnings
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from benchmarks.bench_bounds import NEW
from gapsweep import surface
from gapsweep.theory import closure, improved
from studies.predictors_heldout import _grid

sys.path.insert(0, str(Path(__file__).resolve().parent))
import _record

# the code this benchmark measures: a result measured before a later change to it is stale
# (scripts/check_docs.py)
CODE_PATHS = ['gapsweep/theory', 'gapsweep/gfmd', 'gapsweep/surfaces']

SIZES = ((65, 4096), (65, 2048), (65, 1024), (33, 4096), (33, 1024))
REFERENCE = (129, 65536)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=Path("benchmarks/results/multiscale_table.json"))
    ap.add_argument("--cases", type=int, default=6, help="the first this many held-out surfaces")
    a = ap.parse_args(argv)
    rows = []
    for case in NEW[: a.cases]:
        hurst, lam_l, zeta_s, slope, gamma0, rr, seed = case
        n = _grid(lam_l, zeta_s)
        h = surface.self_affine(n, hurst, lambda_l=lam_l, lambda_s=lam_l / zeta_s, rms_slope=slope, seed=seed)
        rho = rr * surface.rms_height(h)
        shells = improved._Shells(h, 1.0)
        for ps in (2e-4, 0.2, 0.7):
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                hyb = improved.hybrid(ps * slope, h, zeta_c="auto", rho=rho, gamma0=gamma0, lambda_l=lam_l,
                                      tol=1e-8, finest=True, _shells=shells)
            q, pw = improved._grouped(*shells.fine(hyb.k_c), 0.04)
            if q.size == 0:
                continue
            base = math.log(rho / 2.0) - math.log(gamma0 / rho)
            start = np.asarray(hyb.result.gap, float).ravel() - hyb.shift
            start = np.random.default_rng(0).choice(start, size=min(4096, start.size), replace=False)
            ref = closure._mean_drift(start, q, pw, rho, base, np.random.default_rng(1), *REFERENCE)
            spread = float(np.sqrt(np.sum(pw)))  # rigid-limit std of the fine increment: an upper bound
            for points, paths in SIZES:
                c0 = time.process_time()
                d = closure._mean_drift(start, q, pw, rho, base, np.random.default_rng(2), points, paths)
                cpu = time.process_time() - c0
                err = float(np.max(np.abs(d - ref)))
                rows.append(dict(case="|".join(f"{v:g}" for v in case), pressure=ps, n_c=hyb.n_c, groups=int(q.size),
                                 points=points, paths=paths, max_err_over_spread=err / spread,
                                 max_err_over_rho=err / rho, cpu=cpu))
                print(rows[-1], flush=True)
    summary = {}
    for points, paths in SIZES:
        r = [x for x in rows if x["points"] == points and x["paths"] == paths]
        summary[f"{points}x{paths}"] = dict(max_err_over_spread=max(x["max_err_over_spread"] for x in r),
                                            median_err_over_spread=float(np.median([x["max_err_over_spread"]
                                                                                    for x in r])),
                                            max_err_over_rho=max(x["max_err_over_rho"] for x in r),
                                            median_cpu=float(np.median([x["cpu"] for x in r])))
    commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True,
                            cwd=Path(__file__).resolve().parents[1]).stdout.strip()
    a.out.parent.mkdir(parents=True, exist_ok=True)
    a.out.write_text(json.dumps(dict(commit=commit, command=" ".join(["python", *sys.argv]),
                                     machine=f"{platform.node()} ({platform.machine()}, one thread, shared 2-core VM)",
                                     date=time.strftime("%Y-%m-%d"), reference=list(REFERENCE), summary=summary,
                                     rows=rows), indent=1))
    print(json.dumps(summary, indent=1))
    return 0


if __name__ == "__main__":
    _record.track(CODE_PATHS)
    raise SystemExit(main())
