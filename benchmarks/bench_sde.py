"""Speed against error of the gap SDE on the CPU (docs/model.md M5): histogram L1 error against a converged
Fokker-Planck reference, as a function of step size, step sequence, scheme and realisation count.

    python benchmarks/bench_sde.py --out results/sde_cpu [--quick]

L1 = sum_i |p_i - p_ref,i| w_i over 100 bins covering the reference's 1e-5..1-1e-5 quantiles. Its Monte Carlo
floor is E L1 ~ sum_i sqrt(2 p_i (1 - p_i) / (pi n)) w_i; ``mean_bias`` is (mean - mean_ref)/sd_ref with its
standard error 1/sqrt(n), which shows step-size bias below the L1 noise floor.
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

from gapsweep import fokker_planck, sde

_sys.path.insert(0, str(_Path(__file__).resolve().parent))
import _record

# the code this benchmark measures: a result measured before a later change to it is stale
# (scripts/check_docs.py)
CODE_PATHS = ['gapsweep/gapdist']

PARAMS = {
    # paper Fig. 6 spectrum (C0/L^4 = 8e-6, h_rms = 0.0354), rho = 2e-3, sigma0 = 1e-4, C2 = 0.5
    "fig6": (dict(hurst=0.3, h_rms=0.035444, rho=2e-3, gamma0=1e-3, lambda_l=0.25, lambda_s=2.5e-3), 1e-4, 0.5),
    # M7 stiff repulsion, g_rms = 1 (h_rms = 2.34e-3), rho = 5e-4, C2 = 1, sigma0 = 1e-2
    "stiff": (dict(hurst=0.3, h_rms=2.34e-3, rho=5e-4, gamma0=1e-3, lambda_l=0.25, lambda_s=2.5e-3), 1e-2, 1.0),
}


def reference(p, s0, c2):
    t = time.perf_counter()
    ref = fokker_planck.solve(s0, c2=c2, n_steps=6400, cells_per_sd=160, cells_per_rho=10, **p)
    t_ref = time.perf_counter() - t
    ref2 = fokker_planck.solve(s0, c2=c2, n_steps=3200, cells_per_sd=80, cells_per_rho=8, **p)
    g = ref.g[-1]
    c = np.cumsum(ref.density[-1] * ref.widths)
    lo = g[np.searchsorted(c, 1e-5)]
    hi = g[min(np.searchsorted(c, 1 - 1e-5), g.size - 1)]
    edges = np.linspace(lo, hi, 101)
    pr = ref.bin_density(edges)
    self_err = float(np.sum(np.abs(ref2.bin_density(edges) - pr) * np.diff(edges)))
    return ref, edges, pr, t_ref, self_err


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", required=True, type=Path)
    ap.add_argument("--quick", action="store_true", help="fewer realisations (CI-sized smoke run)")
    args = ap.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    n_big = 20_000 if args.quick else 100_000
    configs = [  # (scheme, steps, dzeta, n)
        ("euler", "uniform", 0.1, n_big), ("euler", "uniform", 0.01, n_big),
        ("split", "uniform", 0.1, n_big), ("split", "uniform", 0.01, n_big),
        ("split", "log", 0.3, n_big), ("split", "log", 0.1, n_big), ("split", "log", 0.03, n_big),
        ("split", "log", 0.01, n_big), ("split", "log", 0.03, 10 * n_big), ("split", "log", 0.03, n_big // 10),
    ]
    rows = []
    for case, (p, s0, c2) in PARAMS.items():
        ref, edges, pr, t_ref, self_err = reference(p, s0, c2)
        w = np.diff(edges)
        m_ref, sd_ref = ref.mean(), math.sqrt(ref.variance())
        print(f"{case}: FP reference {t_ref:.2f} s, self-check L1 (3200 steps, half grid) {self_err:.1e}", flush=True)
        sde.gap_samples(s0, c2=c2, n=100, dzeta=0.5, **p)  # compile outside the timings
        sde.gap_histogram_counts(s0, c2=c2, n=100, dzeta=0.5, scheme="euler", **p)  # may fail: no raise
        for scheme, steps, dz, n in configs:
            t = time.perf_counter()
            r = sde.gap_histogram_counts(s0, c2=c2, n=n, dzeta=dz, steps=steps, scheme=scheme, bins=edges, seed=7,
                                         **p)
            wall = time.perf_counter() - t
            dens = r.counts / (n * w)
            l1 = float(np.sum(np.abs(dens - pr) * w)) + (r.below + r.above + r.nonfinite) / n
            q = pr * w
            floor = float(np.sum(np.sqrt(2 * q * (1 - q) / (math.pi * n))))
            g = sde.gap_samples(s0, c2=c2, n=min(n, 100_000), dzeta=dz, steps=steps, scheme=scheme, seed=8, **p) \
                if r.nonfinite == 0 else np.array([np.nan])
            nm = g.size
            rows.append(dict(case=case, scheme=scheme, steps=steps, dzeta=dz, n=n, n_steps=r.plan.n_steps,
                             wall_s=wall, ns_per_particle_step=1e9 * wall / (n * r.plan.n_steps), l1=l1,
                             l1_noise_floor=floor, mean_bias_sd=(float(np.mean(g)) - m_ref) / sd_ref,
                             mean_bias_se=1 / math.sqrt(nm), sd_ratio=float(np.std(g)) / sd_ref,
                             nonfinite=r.nonfinite, outside=r.below + r.above, fp_ref_s=t_ref,
                             fp_ref_self_l1=self_err))
            print(json.dumps(rows[-1]), flush=True)
    (args.out / "bench_sde.json").write_text(json.dumps(rows, indent=1))
    lines = ["| case | scheme | steps | dzeta | K | n | wall [s] | ns/particle-step | L1 | L1 noise floor | "
             "mean bias [sd] (+-SE) | sd ratio |", "| " + " --- |" * 12]
    for r in rows:
        lines.append(f"| {r['case']} | {r['scheme']} | {r['steps']} | {r['dzeta']} | {r['n_steps']} | {r['n']:.0e} | "
                     f"{r['wall_s']:.2f} | {r['ns_per_particle_step']:.1f} | {r['l1']:.2e} | "
                     f"{r['l1_noise_floor']:.2e} | {r['mean_bias_sd']:+.4f} (+-{r['mean_bias_se']:.4f}) | "
                     f"{r['sd_ratio']:.4f} |")
    (args.out / "bench_sde.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    _record.track(CODE_PATHS)
    main()
