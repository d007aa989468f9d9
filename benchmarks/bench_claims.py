"""Measurements behind three statements in the docs (issue 9.6), small enough for a CPU:

1. GFMD solver error against tol, per method: ``|dg0| / (rho tol)`` with ``dg0`` the mean-gap difference from a
   tol = 1e-11 CG reference on the same surface (claimed: ``<= 0.1`` for every method).
2. FIRE's cost relative to CG: ratios of force evaluations and of wall time, same surface, tol, start.
3. SDE bias at few log steps: mean and sd of ``n`` realisations with ``steps="log"``, ``n_steps`` = 18 ... 463,
   against the Fokker-Planck solution (tol 1e-3), in units of the sd (M7 stiff and figure-6 parameters).

    python benchmarks/bench_claims.py --out OUT            # n = 256, lambda_s = L/64, 1e6 SDE paths: ~5 min

Surfaces: ``self_affine(n, H, lambda_l=0.25, lambda_s=1/64, seed=1)`` (the paper's lambda_s = L/400 needs n > 800).
"""

from __future__ import annotations

import argparse
import json
import math
import platform
import sys as _sys
import time
import warnings
from pathlib import Path
from pathlib import Path as _Path

import numpy as np

from gapsweep import fokker_planck, gfmd, sde
from gapsweep.surface import self_affine

_sys.path.insert(0, str(_Path(__file__).resolve().parent))
import _record

# the code this benchmark measures: a result measured before a later change to it is stale
# (scripts/check_docs.py)
CODE_PATHS = ['gapsweep/gfmd', 'gapsweep/gapdist', 'gapsweep/surfaces']

GAMMA0 = 1e-3
CASES = [(0.3, 2e-3), (0.3, 1e-3), (0.3, 5e-4), (0.8, 5e-3), (0.8, 2e-3), (0.8, 1e-3)]
SIGMA0 = [1e-4, 1e-2, 1.0]
SDE_CASES = {
    "stiff": dict(hurst=0.3, h_rms=2.34e-3, rho=5e-4, gamma0=1e-3, lambda_l=0.25, lambda_s=2.5e-3, c2=1.0),
    "fig6": dict(hurst=0.3, h_rms=0.035444, rho=2e-3, gamma0=1e-3, lambda_l=0.25, lambda_s=2.5e-3, c2=0.5),
}


def gfmd_rows(n: int, tols: list[float]) -> list[dict]:
    warnings.simplefilter("ignore", gfmd.UnderResolvedWarning)
    rows = []
    for hurst, rho in CASES:
        h = self_affine(n, hurst, lambda_l=0.25, lambda_s=1 / 64, seed=1)
        for s0 in SIGMA0:
            kw = dict(sigma0=s0, gamma0=GAMMA0, rho=rho, threads=1, max_iter=20000)
            ref = gfmd.solve(h, tol=1e-11, method="cg", **kw)
            for tol in tols:
                for method in ("cg", "fire"):
                    r = gfmd.solve(h, tol=tol, method=method, **kw)
                    rows.append(dict(H=hurst, rho=rho, sigma0=s0, tol=tol, method=method, evals=r.iterations,
                                     wall_s=r.wall_time, status=r.status,
                                     err_over_rho_tol=abs(r.mean_gap - ref.mean_gap) / (rho * tol)))
                    print(json.dumps(rows[-1]), flush=True)
    return rows


def sde_rows(n: int) -> list[dict]:
    rows = []
    for name, p in SDE_CASES.items():
        for s0 in ([1e-4, 1e-2, 1.0, 10.0] if name == "stiff" else [1e-4]):
            ref = fokker_planck.solve(s0, tol=1e-3, max_steps=51200, **p)
            m, sd = ref.mean(), math.sqrt(ref.variance())
            for k in (18, 49, 150, 463):
                g = sde.gap_samples(s0, n=n, steps="log", n_steps=k, seed=3, **p)
                rows.append(dict(case=name, sigma0=s0, n_steps=k, n=n, fp_status=ref.status, fp_error=ref.error,
                                 mean_bias_sd=(float(g.mean()) - m) / sd, se_sd=float(g.std()) / sd / math.sqrt(n),
                                 sd_ratio=float(g.std()) / sd))
                print(json.dumps(rows[-1]), flush=True)
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", required=True, type=Path)
    ap.add_argument("--n", type=int, default=256, help="GFMD grid")
    ap.add_argument("--tols", type=float, nargs="+", default=[1e-4, 1e-6])
    ap.add_argument("--paths", type=int, default=10**6, help="SDE realisations")
    ap.add_argument("--skip-gfmd", action="store_true")
    args = ap.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    g = [] if args.skip_gfmd else gfmd_rows(args.n, args.tols)
    s = sde_rows(args.paths)
    meta = {"host": platform.node(), "seconds": time.perf_counter() - t0, "n": args.n, "paths": args.paths}
    (args.out / "bench_claims.json").write_text(json.dumps({"meta": meta, "gfmd": g, "sde": s}, indent=1))
    lines = []
    if g:
        by = {(r["H"], r["rho"], r["sigma0"], r["tol"], r["method"]): r for r in g}
        fire = [r for r in g if r["method"] == "fire"]
        ev = [r["evals"] / by[(r["H"], r["rho"], r["sigma0"], r["tol"], "cg")]["evals"] for r in fire]
        wt = [r["wall_s"] / by[(r["H"], r["rho"], r["sigma0"], r["tol"], "cg")]["wall_s"] for r in fire]
        for m in ("cg", "fire"):
            e = [r["err_over_rho_tol"] for r in g if r["method"] == m]
            lines.append(f"{m}: |dg0|/(rho tol) median {np.median(e):.3g}, max {max(e):.3g} over {len(e)} solves")
        lines.append(f"fire/cg evaluations {min(ev):.2g} .. {max(ev):.2g} (median {np.median(ev):.2g}); "
                     f"wall time {min(wt):.2g} .. {max(wt):.2g} (median {np.median(wt):.2g})")
    for r in s:
        lines.append(f"sde {r['case']} sigma0={r['sigma0']:g} K={r['n_steps']}: mean bias {r['mean_bias_sd']:+.4f} "
                     f"sd (+- {r['se_sd']:.4f}), sd ratio {r['sd_ratio']:.4f} (FP {r['fp_status']}, "
                     f"err {r['fp_error']:.1g})")
    (args.out / "bench_claims.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    _record.track(CODE_PATHS)
    main()
