"""Where the multiscale gap distribution's CPU time goes, against a GFMD solve of the same map (issue 39 item 3:
"multiscale at <= 10 % of a GFMD solve's CPU time at equal grid; profile first").

On the distribution points of ``bench_bounds.py``'s set (default ``heldout``: 12 surfaces nobody tuned on, three
pressures each), one thread, process time, side by side in one run:

* ``whole``: ``closure.multiscale_gap_samples`` at its defaults (2^17 samples, ``dlnq`` 0.3, the self-check on);
* its parts, called the way it calls them: ``hybrid`` (``improved.hybrid(zeta_c="auto", finest=True)``: the
  ladder of coarse GFMD solves), ``sample`` (``closure._level_samples`` on the chosen coarse grid: the
  local-response walk over the finer shell groups for every sample and the table of its mean drift), ``check``
  (the same on the ladder's previous grid) and ``l1`` (``closure.l1_distance`` between the two);
* ``gfmd``: ``gfmd.solve`` of the whole map (tol 1e-8, the exponential law, one thread), timed afresh here.

Writes ``<out>/<name>.csv`` and ``<name>.md`` (medians of the parts' shares and of ``whole / gfmd``, by grid).

    OMP_NUM_THREADS=1 python benchmarks/bench_multiscale_cost.py --out benchmarks/results/bounds   (~3 min)
"""

from __future__ import annotations

import argparse
import math
import sys
import time
import warnings
from pathlib import Path

import numpy as np
import pandas as pd

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))

import _record
import bench_bounds as bb

from gapsweep import gfmd
from gapsweep.theory import closure, improved

# the code this benchmark measures: a result measured before a later change to it is stale
# (scripts/check_docs.py)
CODE_PATHS = ["gapsweep/theory", "gapsweep/gfmd", "gapsweep/surfaces"]


def _timed(f, *args, **kwargs):
    c0 = time.process_time()
    r = f(*args, **kwargs)
    return r, time.process_time() - c0


def parts(s0: float, h: np.ndarray, lam_l: float, seed: int, rho: float, gamma0: float,
          whole: np.ndarray) -> dict:
    """The parts of ``closure.multiscale_gap_samples`` at its defaults, each timed (its steps 1, 2-3 and 4);
    ``parts_match_whole``: the parts drew the same samples as the whole call ``whole`` (same seed, same order of
    draws), i.e. they still are that function's steps."""
    samples, dlnq, center = 2**17, 0.3, "pixel"
    shells = improved._Shells(h, 1.0)
    hyb, t_h = _timed(improved.hybrid, s0, h, zeta_c="auto", rho=rho, gamma0=gamma0, lambda_l=lam_l, length=1.0,
                      e_star=1.0, tol=1e-8, rtol=0.05, max_cost_fraction=0.1, finest=True, _shells=shells)
    base = math.log(rho / 2.0) - math.log(gamma0 / rho)
    rng = np.random.default_rng(seed)

    def level(k_c, res, shift, bracket):
        q, pw = improved._grouped(*shells.fine(k_c), dlnq)
        return closure._level_samples(res.gap, shift, bracket, q, pw, rho, base, samples, center, rng), int(q.size)

    (g, groups), t_s = _timed(level, hyb.k_c, hyb.result, hyb.shift, hyb.shift_error)
    t_c = t_l = 0.0
    if groups and hyb.previous is not None:
        k_p, _, shift_p, err_p, res_p = hyb.previous
        (gp, _), t_c = _timed(level, k_p, res_p, shift_p, err_p)
        _, t_l = _timed(closure.l1_distance, gp, g)
    return {"n_c": hyb.n_c, "groups": groups, "hybrid_s": t_h, "sample_s": t_s, "check_s": t_c, "l1_s": t_l,
            "parts_match_whole": bool(np.array_equal(g, whole))}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--set", choices=tuple(bb.SETS), default="heldout")
    ap.add_argument("--name", default=None)
    a = ap.parse_args(argv)
    name = a.name or f"multiscale_cost_{a.set}"
    a.out.mkdir(parents=True, exist_ok=True)
    warnings.simplefilter("ignore")  # rho < dx on some grids, as bench_bounds
    rows = []
    for case, ps, n, h, kw, _ in bb.distribution_points(a.set):
        hurst, lam_l, zeta_s, slope, gamma0, rr, seed = case
        s0 = ps * slope
        closure.multiscale_gap_samples(s0, h, lambda_l=lam_l, seed=seed, **kw)  # warm-up: plans, kernels
        ms, t_w = _timed(closure.multiscale_gap_samples, s0, h, lambda_l=lam_l, seed=seed, **kw)
        row = {"hurst": hurst, "lambda_l": lam_l, "zeta_s": zeta_s, "rms_slope": slope, "gamma0": gamma0,
               "rho_over_h": rr, "seed": seed, "pressure": ps, "n": n, "pixels": n * n, "samples": ms.samples.size,
               "whole_s": t_w, **parts(s0, h, lam_l, seed, whole=ms.samples, **kw)}
        ref, t_g = _timed(gfmd.solve, h, sigma0=s0, tol=1e-8, threads=1, **kw)
        row.update(gfmd_s=t_g, gfmd_iterations=int(ref.iterations), gfmd_status=ref.status,
                   whole_over_gfmd=t_w / t_g, hybrid_over_gfmd=row["hybrid_s"] / t_g)
        rows.append(row)
        print(f"{bb._key(case, ps)}: whole {t_w:.3f} s (hybrid {row['hybrid_s']:.3f}, sample {row['sample_s']:.3f}, "
              f"check {row['check_s']:.3f}, l1 {row['l1_s']:.3f}), gfmd {t_g:.3f} s", flush=True)
    df = pd.DataFrame(rows)
    df.to_csv(a.out / f"{name}.csv", index=False)
    parts_s = df[["hybrid_s", "sample_s", "check_s", "l1_s"]].sum(axis=1)
    lines = [f"### Multiscale gap distribution: CPU time by part against GFMD ({a.set} set, "
             f"{time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())})", "",
             f"`python {' '.join(sys.argv)}`", "",
             f"- {len(df)} distributions; whole call / GFMD solve: median **{df.whole_over_gfmd.median():.3f}**, "
             f"at or below 0.10 at **{int((df.whole_over_gfmd <= 0.10).sum())}/{len(df)}**",
             f"- the hybrid's coarse solves alone / GFMD: median {df.hybrid_over_gfmd.median():.3f}",
             f"- shares of the parts' sum (median): hybrid {(df.hybrid_s / parts_s).median():.2f}, sampling "
             f"{(df.sample_s / parts_s).median():.2f}, self-check {(df.check_s / parts_s).median():.2f}, L1 "
             f"{(df.l1_s / parts_s).median():.2f}; the parts' sum / the whole call: median "
             f"{(parts_s / df.whole_s).median():.2f}; the parts drew the whole call's samples at "
             f"{int(df.parts_match_whole.sum())}/{len(df)}", "",
             "| n | distributions | whole / GFMD (median) | at or below 0.10 | GFMD s (median) | whole s (median) |",
             "| --- | --- | --- | --- | --- | --- |"]
    for n, d in df.groupby("n"):  # the table, and the same as lines a docs link can match without a "|"
        lines.insert(6, f"- N = {n}: whole / GFMD median {d.whole_over_gfmd.median():.3f}, GFMD median "
                        f"{d.gfmd_s.median():.3f} s ({len(d)} distributions)")
        lines.append(f"| {n} | {len(d)} | {d.whole_over_gfmd.median():.3f} | {int((d.whole_over_gfmd <= 0.1).sum())}"
                     f"/{len(d)} | {d.gfmd_s.median():.3f} | {d.whole_s.median():.3f} |")
    (a.out / f"{name}.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    _record.track(CODE_PATHS)
    sys.exit(main())
