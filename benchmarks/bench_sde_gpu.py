"""GPU benchmark of the gap SDE (docs/model.md M5): 10^7 realisations, zeta 1 -> 100, dzeta = 0.01 (9,900 steps).

Times are warm (the first call, which compiles the kernel, is excluded) and include everything a user call
does: the host-side step plan, coefficient upload, the kernel, binning on the device and the copy of the counts.
The paper: 10^7 realisations in about 20 s on an RTX 4090D.

    python benchmarks/bench_sde_gpu.py --out results/sde_gpu            # on the GPU machine
    python benchmarks/bench_sde_gpu.py --device cpu --n 20000 --out /tmp/x   # smoke test on the CPU
"""

from __future__ import annotations

import argparse
import json
import math
import statistics
import time
from pathlib import Path

import numpy as np

from gapsweep import sde

PAPER_SECONDS = 20.0


def fig6_h_rms(c0: float = 8e-6, hurst: float = 0.3, lambda_l: float = 0.25, lambda_s: float = 2.5e-3) -> float:
    """h_rms of the paper's Fig. 6 spectrum (C0/L^4 = 8e-6), continuum form of M2."""
    ql = 2 * math.pi / lambda_l
    zs = lambda_l / lambda_s
    return math.sqrt(c0 * ql**2 / (2 * math.pi) * (1 - zs ** (-2 * hurst)) / (2 * hurst))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", required=True, type=Path)
    ap.add_argument("--device", default="cuda:0")
    ap.add_argument("--n", type=int, default=10**7)
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--bins", type=int, default=200)
    args = ap.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)

    import warp as wp

    wp.config.log_level = 30
    wp.init()
    dev = wp.get_device(args.device)
    name = dev.name
    fig6 = dict(hurst=0.3, h_rms=fig6_h_rms(), rho=2e-3, gamma0=1e-3, lambda_l=0.25, lambda_s=2.5e-3)
    stiff = dict(hurst=0.3, h_rms=2.34e-3, rho=5e-4, gamma0=1e-3, lambda_l=0.25, lambda_s=2.5e-3)
    cases = [
        ("fig6 s0=1e-4 C2=0.5, uniform dz=0.01, float32 (headline)", fig6, 1e-4, 0.5, 0.01, "uniform", "float32",
         "split"),
        ("fig6 s0=1e-4 C2=0, uniform dz=0.01, float32", fig6, 1e-4, 0.0, 0.01, "uniform", "float32", "split"),
        ("fig6 s0=1e-4 C2=0.5, uniform dz=0.01, float64", fig6, 1e-4, 0.5, 0.01, "uniform", "float64", "split"),
        ("fig6 s0=1e-4 C2=0.5, log dz=0.01 (463 steps), float32", fig6, 1e-4, 0.5, 0.01, "log", "float32",
         "split"),
        ("fig6 s0=1e-4 C2=0.5, paper's Euler-Maruyama, uniform dz=0.01, float32", fig6, 1e-4, 0.5, 0.01,
         "uniform", "float32", "euler"),
        ("M7 stiff rho=5e-4 C2=1 s0=1e-2, uniform dz=0.01, float32", stiff, 1e-2, 1.0, 0.01, "uniform",
         "float32", "split"),
    ]
    rows = []
    for label, p, s0, c2, dz, steps, dtype, scheme in cases:
        kw = dict(p, c2=c2, dzeta=dz, steps=steps, dtype=dtype, scheme=scheme, n=args.n, device=args.device,
                  bins=args.bins, seed=1)
        t = time.perf_counter()
        sde.gap_histogram_counts(s0, **kw)  # compile + first run
        first = time.perf_counter() - t
        times, kernel_times = [], []
        for rep in range(args.repeat):
            wp.synchronize_device(args.device)
            t = time.perf_counter()
            r = sde.gap_histogram_counts(s0, **{**kw, "seed": 2 + rep})
            times.append(time.perf_counter() - t)
            kernel_times.append(r.wall_time)
        steps_n = r.plan.n_steps
        best = min(times)
        rows.append(dict(case=label, device=name, n=args.n, n_steps=steps_n, dtype=dtype, steps=steps, scheme=scheme,
                         first_call_s=first, best_s=best, median_s=statistics.median(times),
                         launch_and_copy_best_s=min(kernel_times),
                         particle_steps_per_s=args.n * steps_n / best,
                         speedup_vs_paper_20s=PAPER_SECONDS * (steps_n / 9900) / best if steps == "uniform" else
                         PAPER_SECONDS / best,
                         nonfinite=r.nonfinite, outside=r.below + r.above,
                         mean=float(np.sum(0.5 * (r.edges[1:] + r.edges[:-1]) * r.counts) / max(r.counts.sum(), 1))))
        print(json.dumps(rows[-1]), flush=True)
    (args.out / "bench_sde_gpu.json").write_text(json.dumps(rows, indent=1))
    lines = [f"# SDE GPU benchmark on {name} (n = {args.n:.0e}, warm, best of {args.repeat})", "",
             "| case | steps | time best [s] | median [s] | particle-steps/s | speed-up vs paper 20 s |",
             "| --- | --- | --- | --- | --- | --- |"]
    for r in rows:
        lines.append(f"| {r['case']} | {r['n_steps']} | {r['best_s']:.3f} | {r['median_s']:.3f} | "
                     f"{r['particle_steps_per_s']:.2e} | {r['speedup_vs_paper_20s']:.0f}x |")
    (args.out / "bench_sde_gpu.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
