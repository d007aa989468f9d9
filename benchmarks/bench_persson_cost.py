"""CPU cost of Persson's mean separation and gap distribution from a height map against one hard-wall GFMD solve
of the same map (issue 39 item 3), and their values against the earlier per-shell kernel evaluation.

    python benchmarks/bench_persson_cost.py --out benchmarks/results/persson_cost.json

Maps: self-affine, N = 640, 768, 1024 (non-powers of two included), other seeds and Hurst exponents than the
tests; pressures sigma0/(E* g_rms) = 1e-3, 1e-2, 0.1. Per point: process CPU seconds (one thread) of
``persson.mean_separation(sigma0, heights=h)``, ``persson.gap_distribution(u, sigma0, heights=h)`` (100 gaps),
and ``gfmd.solve(h, sigma0, interaction="hard_wall", tol=1e-8)``; and the relative difference of the mean
separation and (pointwise, where positive) of the gap density from the earlier evaluation (every shell's kernels
by Gauss-Legendre, ``persson._hk_exact``), which the new one replaces by a spline table (``persson._hk``).
"""

from __future__ import annotations

import argparse
import json
import platform
import subprocess
import sys
import time
from pathlib import Path
from unittest import mock

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from gapsweep import gfmd, surface
from gapsweep.theory import persson

sys.path.insert(0, str(Path(__file__).resolve().parent))
import _record

# the code this benchmark measures: a result measured before a later change to it is stale
# (scripts/check_docs.py)
CODE_PATHS = ['gapsweep/theory', 'gapsweep/gfmd', 'gapsweep/surfaces']

MAPS = ((640, 0.75, 0.5, 100, 201), (768, 0.45, 0.5, 150, 202), (1024, 0.3, 0.25, 100, 203))
PRESSURES = (1e-3, 1e-2, 0.1)


def _cpu(f, *a, **k):
    c0 = time.process_time()
    r = f(*a, **k)
    return r, time.process_time() - c0


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=Path("benchmarks/results/persson_cost.json"))
    a = ap.parse_args(argv)
    rows = []
    for n, hurst, lam_l, zeta_s, seed in MAPS:
        h = surface.self_affine(n, hurst, lambda_l=lam_l, lambda_s=lam_l / zeta_s, rms_slope=1.0, seed=seed)
        persson.mean_separation(1e-2, heights=h, lambda_l=lam_l)  # the spline table, once per gamma
        for ps in PRESSURES:
            u, t_u = _cpu(persson.mean_separation, ps, heights=h, lambda_l=lam_l)
            gaps = np.linspace(0.0, 3.0 * u + 1e-12, 100)
            (dens, area), t_d = _cpu(persson.gap_distribution, gaps, ps, heights=h, lambda_l=lam_l)
            with mock.patch.object(persson, "_hk", persson._hk_exact):
                u_old, t_u_old = _cpu(persson.mean_separation, ps, heights=h, lambda_l=lam_l)
                (dens_old, area_old), t_d_old = _cpu(persson.gap_distribution, gaps, ps, heights=h, lambda_l=lam_l)
            pos = dens_old > 0
            ref, t_g = _cpu(gfmd.solve, h, sigma0=ps, interaction="hard_wall", tol=1e-8, threads=1)
            rows.append(dict(n=n, hurst=hurst, seed=seed, pressure=ps, u=u, u_rel_diff=abs(u - u_old) / abs(u_old),
                             density_rel_diff=float(np.max(np.abs(dens - dens_old)[pos] / dens_old[pos])),
                             area_diff=abs(area - area_old), cpu_mean_separation=t_u, cpu_gap_distribution=t_d,
                             cpu_mean_separation_before=t_u_old, cpu_gap_distribution_before=t_d_old, cpu_gfmd=t_g,
                             gfmd_status=ref.status, gfmd_mean_gap=float(ref.mean_gap)))
            print(rows[-1], flush=True)
    r = {k: [x[k] for x in rows] for k in rows[0]}
    ratio_u = np.array(r["cpu_mean_separation"]) / np.array(r["cpu_gfmd"])
    ratio_d = np.array(r["cpu_gap_distribution"]) / np.array(r["cpu_gfmd"])
    summary = dict(mean_separation_over_gfmd_median=float(np.median(ratio_u)),
                   mean_separation_over_gfmd_max=float(np.max(ratio_u)),
                   gap_distribution_over_gfmd_median=float(np.median(ratio_d)),
                   gap_distribution_over_gfmd_max=float(np.max(ratio_d)),
                   before_mean_separation_over_gfmd_median=float(np.median(np.array(r["cpu_mean_separation_before"])
                                                                           / np.array(r["cpu_gfmd"]))),
                   before_gap_distribution_over_gfmd_median=float(np.median(np.array(r["cpu_gap_distribution_before"])
                                                                            / np.array(r["cpu_gfmd"]))),
                   max_u_rel_diff=max(r["u_rel_diff"]), max_density_rel_diff=max(r["density_rel_diff"]))
    commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True,
                            cwd=Path(__file__).resolve().parents[1]).stdout.strip()
    a.out.parent.mkdir(parents=True, exist_ok=True)
    a.out.write_text(json.dumps(dict(commit=commit, command=" ".join(["python", *sys.argv]),
                                     machine=f"{platform.node()} ({platform.machine()}, one thread, shared 2-core VM)",
                                     date=time.strftime("%Y-%m-%d"), summary=summary, rows=rows), indent=1))
    print(json.dumps(summary, indent=1))
    return 0


if __name__ == "__main__":
    _record.track(CODE_PATHS)
    raise SystemExit(main())
