"""Do the predictors' own error estimates bound their error against GFMD? (issue 30, items 4 and 5)

    python benchmarks/bench_bounds.py --set tuning  --out benchmarks/results/bounds    # choices are made here
    python benchmarks/bench_bounds.py --set heldout --out benchmarks/results/bounds    # and reported here
    python benchmarks/bench_bounds.py --set heldout --out benchmarks/results/bounds --table   # tables only

For every surface and pressure of the set: full GFMD (``gfmd.solve``, tol 1e-8, one thread) on the smallest
power-of-two grid with ``lambda_s >= 4 dx`` (N = 256 .. 1024) is the reference; its mean gap, cost and (at the
distribution pressures) its gap histogram (80 equal bins over its range) are cached in
``<out>/gfmd_<set>.json``, so a second run (or the test suite) needs no GFMD.

Mean gap: ``improved.hybrid(zeta_c="auto")`` at its defaults (tol 1e-6, rtol 0.05): its error against GFMD
(relative where ``|g0| >= h_rms``, in units of ``h_rms`` else), its ``error_estimate`` in the same units, and
whether the estimate bounds the error. On the tuning set the whole ladder (``finest=True``) is recorded too
(per grid: ``g0``, bracket, change, cost), from which the estimate's constants are chosen offline
(``--choose``). CPU seconds (``time.process_time``) of the hybrid and of GFMD side by side, one process.

Gap distribution: ``closure.multiscale_gap_samples`` at its defaults (2^17 samples, ``center="pixel"``) and with
the earlier centring (``center="sample"``): L1 against GFMD's histogram, the status, the self-check's
``l1_change``/``l1_estimate``, CPU seconds.

Sets: ``tuning`` = the tuning, held-out and fresh sets of ``analysis.predictors_heldout`` (23 surfaces, 162
points, 84 distributions: every set earlier work had looked at); ``heldout`` = 12 new surfaces (other seeds,
Hurst exponents, ``lambda_l``, ``zeta_s``, ``rho/h_rms``, ``gamma0``) at 6 new pressures (72 points, 36
distributions at the lowest and the two highest), made and run once after the choices were fixed; ``issue39`` and
``issue39b`` = issue 39's kind (H 0.1-0.3, rho/h_rms 0.05-0.07, zeta_s 30-60, pressures up to 0.8 E* g_rms; 6
surfaces x 5 pressures each, fresh seeds, mean gap only; their ladders are recorded and the earlier stopping rule
is replayed on them).
"""

from __future__ import annotations

import argparse
import itertools
import json
import logging
import math
import platform
import subprocess
import sys
import time
import warnings
from pathlib import Path

import numpy as np
import pandas as pd

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import sys as _sys
from pathlib import Path as _Path

from gapsweep import gfmd, surface
from gapsweep.theory import closure, improved
from studies.predictors_heldout import FRESH, FRESH_P, HELDOUT, HELDOUT_P, TUNING, TUNING_P, _grid

_sys.path.insert(0, str(_Path(__file__).resolve().parent))
import _record

# the code this benchmark measures: a result measured before a later change to it is stale
# (scripts/check_docs.py)
CODE_PATHS = ['gapsweep/gfmd', 'gapsweep/theory', 'gapsweep/surfaces']

log = logging.getLogger("bench_bounds")

# (H, lambda_l, zeta_s, rms slope, gamma0, rho/h_rms, seed); none of these seeds or parameter sets was used before
NEW = [(0.15, 0.5, 40, 1.0, 1e-3, 0.15, 51), (0.4, 0.25, 40, 0.3, 1e-2, 0.08, 52), (0.65, 0.5, 80, 1.0, 1e-4, 0.4, 53),
       (0.85, 0.125, 24, 0.3, 1e-3, 0.06, 54), (0.95, 0.5, 48, 1.0, 1e-2, 1.5, 55), (0.3, 0.25, 24, 1.0, 3e-3, 0.3, 56),
       (0.5, 0.5, 120, 0.3, 3e-4, 0.1, 57), (0.75, 0.25, 48, 1.0, 1e-3, 0.2, 58), (0.2, 0.5, 24, 0.3, 3e-3, 0.05, 59),
       (0.55, 0.125, 16, 1.0, 1e-3, 0.5, 60), (0.35, 0.5, 60, 1.0, 1e-4, 0.12, 61), (0.7, 0.5, 30, 0.3, 1e-2, 0.08, 62)]
NEW_P = (2e-4, 1.5e-3, 8e-3, 4e-2, 0.2, 0.7)
# issue 39's kind (low H, rho/h_rms near the domain's edge 0.05, zeta_s ~ 50, high pressure, where a ladder stopped
# on one small step), fresh seeds, made after the stopping rule was chosen on the tuning set: mean gap only
ISSUE39 = [(0.2, 0.5, 50, 1.0, 1e-3, 0.05, 81), (0.2, 0.25, 50, 1.0, 1e-3, 0.05, 82),
           (0.2, 0.5, 50, 0.3, 1e-2, 0.05, 83), (0.25, 0.5, 40, 1.0, 1e-4, 0.06, 84),
           (0.15, 0.25, 60, 0.3, 1e-3, 0.05, 85), (0.3, 0.5, 50, 1.0, 1e-3, 0.07, 86)]
ISSUE39_P = (0.04, 0.1, 0.2, 0.4, 0.7)
# a second set of the kind with fresh seeds and parameters, made after the nonlinearity term (whose form,
# Delta (h_fine/rho)^1.5, was read off the first issue39 set) was fixed: the clean report for it
ISSUE39B = [(0.2, 0.25, 40, 1.0, 1e-3, 0.05, 91), (0.15, 0.5, 50, 1.0, 1e-2, 0.05, 92),
            (0.25, 0.25, 60, 0.3, 1e-3, 0.05, 93), (0.2, 0.5, 30, 1.0, 1e-4, 0.05, 94),
            (0.3, 0.25, 50, 1.0, 1e-3, 0.05, 95), (0.1, 0.5, 50, 0.3, 1e-3, 0.06, 96)]
ISSUE39B_P = (0.05, 0.15, 0.3, 0.5, 0.8)
SETS = {
    "tuning": [(TUNING, TUNING_P, (0, 2, 4)), (HELDOUT, HELDOUT_P, (0, 4, 5)), (FRESH, FRESH_P, (0, 4, 5))],
    "heldout": [(NEW, NEW_P, (0, 4, 5))],
    "issue39": [(ISSUE39, ISSUE39_P, ())],
    "issue39b": [(ISSUE39B, ISSUE39B_P, ())],
}
BINS = closure.L1_BINS


def _key(case: tuple, ps: float) -> str:
    return "|".join(f"{v:g}" for v in (*case, ps))


def points(name: str, distributions: bool = False):
    """``(case, pressure, n, h, kw, dist)`` of every point of the set ``name`` (only its distribution points with
    ``distributions``): one surface per case, ``kw`` the law's ``rho`` and ``gamma0``, ``dist`` whether the point
    has a gap distribution."""
    for cases, pressures, dist_idx in SETS[name]:
        for case in cases:
            hurst, lam_l, zeta_s, slope, gamma0, rr, seed = case
            n = _grid(lam_l, zeta_s)
            h = surface.self_affine(n, hurst, lambda_l=lam_l, lambda_s=lam_l / zeta_s, rms_slope=slope, seed=seed)
            kw = dict(rho=rr * surface.rms_height(h), gamma0=gamma0)
            for ip, ps in enumerate(pressures):
                if ip in dist_idx or not distributions:
                    yield case, ps, n, h, kw, ip in dist_idx


def distribution_points(name: str):
    """:func:`points` with a gap distribution."""
    return points(name, distributions=True)


def _reference(h: np.ndarray, s0: float, kw: dict, dist: bool) -> dict:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # rho < dx on some grids (docs/results/predictors_heldout.md)
        c0 = time.process_time()
        ref = gfmd.solve(h, sigma0=s0, tol=1e-8, threads=1, **kw)
        cpu = time.process_time() - c0
    if ref.status != "converged":
        raise SystemExit(f"GFMD reference did not converge ({ref.status})")
    out = dict(mean_gap=float(ref.mean_gap), iterations=int(ref.iterations), cpu=cpu)
    if dist:
        g = np.asarray(ref.gap, float).ravel()
        lo, hi = float(g.min()), float(g.max())
        out.update(lo=lo, hi=hi, frac=(np.histogram(g, bins=np.linspace(lo, hi, BINS + 1))[0] / g.size).tolist())
    return out


def l1_to_reference(x: np.ndarray, ref: dict) -> float:
    """L1 between the samples' density and GFMD's cached histogram (``closure.l1_distance``'s definition)."""
    a = np.histogram(x, bins=np.linspace(ref["lo"], ref["hi"], BINS + 1))[0] / x.size
    return float(np.sum(np.abs(a - np.asarray(ref["frac"]))) + (1.0 - a.sum()))


def _cpu(f, *args, **kwargs):
    """``f(*args, **kwargs)`` and its CPU seconds (process time: every thread)."""
    c0 = time.process_time()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        r = f(*args, **kwargs)
    return r, time.process_time() - c0


def ladders_only(name: str, out: Path) -> pd.DataFrame:
    """The tuning ladders again (cached GFMD references, no distributions): for a new estimate form."""
    cache = json.loads((out / f"gfmd_{name}.json").read_text())
    rows = []
    for case, ps, n, h, kw, _ in points(name):
        key = _key(case, ps)
        ref = cache[key]
        scale = max(abs(ref["mean_gap"]), surface.rms_height(h))
        lad, _ = _cpu(improved.hybrid, ps * case[3], h, zeta_c="auto", lambda_l=case[1], finest=True, **kw)
        rows += [dict(key=key, scale=scale, gfmd=ref["mean_gap"], full_cost=ref["iterations"] * n * n,
                      k_max=improved._max_mode(h), **lv) for lv in lad.ladder]
    return pd.DataFrame(rows)


def evaluate(name: str, out: Path) -> tuple[pd.DataFrame, pd.DataFrame, list[dict]]:
    cache_file = out / f"gfmd_{name}.json"
    cache = json.loads(cache_file.read_text()) if cache_file.exists() else {}
    rows, drows, ladders = [], [], []
    for case, ps, n, h, kw, dist in points(name):
        hurst, lam_l, zeta_s, slope, gamma0, rr, seed = case
        h_rms = surface.rms_height(h)
        s0 = ps * slope
        key = _key(case, ps)
        if key not in cache or (dist and "frac" not in cache[key]):
            cache[key] = _reference(h, s0, kw, dist)
            cache_file.write_text(json.dumps(cache))
        ref = cache[key]
        scale = max(abs(ref["mean_gap"]), h_rms)
        hy, t_hy = _cpu(improved.hybrid, s0, h, zeta_c="auto", lambda_l=lam_l, **kw)
        base = dict(hurst=hurst, lambda_l=lam_l, zeta_s=zeta_s, rms_slope=slope, gamma0=gamma0, rho_over_h=rr,
                    seed=seed, n=n, pressure=ps, h_rms=h_rms, gfmd=ref["mean_gap"], scale=scale)
        err = (hy.mean_gap - ref["mean_gap"]) / scale
        rows.append(dict(base, hybrid=hy.mean_gap, err=err, estimate=hy.error_estimate / scale,
                         bound=abs(err) <= hy.error_estimate / scale, status=hy.status, n_c=hy.n_c,
                         cost=hy.cost / (ref["iterations"] * n * n), cpu_hybrid=t_hy, cpu_gfmd=ref["cpu"]))
        if name != "heldout":  # the whole ladder: for choosing the estimate's constants offline (tuning)
            # and for replaying the earlier stopping rule on the issue-39 cases
            lad, _ = _cpu(improved.hybrid, s0, h, zeta_c="auto", lambda_l=lam_l, finest=True, **kw)
            for lv in lad.ladder:
                ladders.append(dict(key=key, scale=scale, gfmd=ref["mean_gap"], full_cost=ref["iterations"]
                                    * n * n, k_max=improved._max_mode(h), **lv))
        if dist:
            drows.append(dict(base, **_distribution(s0, h, lam_l, seed, kw, ref)))
        log.info("%s p=%g: err %+.4f est %.4f (%s, n_c %d) %.2f/%.2f cpu s", key, ps, err,
                 hy.error_estimate / scale, hy.status, hy.n_c, t_hy, ref["cpu"])
    return pd.DataFrame(rows), pd.DataFrame(drows), ladders


def _distribution(s0: float, h: np.ndarray, lam_l: float, seed: int, kw: dict, ref: dict) -> dict:
    ms, t_ms = _cpu(closure.multiscale_gap_samples, s0, h, lambda_l=lam_l, seed=seed, **kw)
    old, t_old = _cpu(closure.multiscale_gap_samples, s0, h, lambda_l=lam_l, seed=seed, center="sample",
                      check=False, **kw)
    return dict(g0_over_h=ref["mean_gap"] / float(np.sqrt(np.mean((h - h.mean()) ** 2))), n_c=ms.n_c,
                l1=l1_to_reference(ms.samples, ref), l1_change=ms.l1_change, l1_estimate=ms.l1_estimate,
                status=ms.status, l1_sample_centring=l1_to_reference(old.samples, ref), status_old=old.status,
                cpu_multiscale=t_ms, cpu_sample_centring=t_old, cpu_gfmd=ref["cpu"])


def choose(ladders: pd.DataFrame, rtol: float = 0.05) -> pd.DataFrame:
    """Coverage, tightness and cost of the estimate ``E = safety max(bracket/2, change) + shift_fraction Delta +
    floor scale`` and of the stopping rule ``E <= rtol scale`` of ``improved.hybrid``, for a grid of the three
    constants, replayed on the recorded ladders."""
    groups = [g.reset_index(drop=True) for _, g in ladders.groupby("key", sort=False)]
    out = []
    for steps, *w in itertools.product((1, 2), (1.0, 1.5, 2.0), (0.0, 0.25, 0.35, 0.5),
                                       (0.0, 5e-4, 1e-3, 2e-3, 4e-3), (0.0, 0.05, 0.07, 0.1)):
        cov, cost, conv, ratio, rel = [], [], [], [], []
        for lad in groups:
            # rung i has seen i changes; stopping before the last rung needs ``steps`` of them (improved._auto)
            stop = next((i for i in range(steps, len(lad))
                         if _estimate(lad, i, w, steps) <= rtol * lad.loc[i, "scale"]), len(lad) - 1)
            r = lad.loc[stop]
            e, err = _estimate(lad, stop, w, steps), abs(r["g0"] - r["gfmd"])
            cov.append(err <= e)
            conv.append(e <= rtol * r["scale"])
            cost.append(r["cost"] / r["full_cost"])
            ratio.append(e / max(err, 1e-300))
            rel.append(e / r["scale"])
        out.append(dict(steps=steps, safety=w[0], shift_fraction=w[1], floor=w[2], coverage=float(np.mean(cov)),
                        nonlinearity=w[3], points=len(cov),
                        converged=int(np.sum(conv)), median_estimate_over_error=float(np.median(ratio)),
                        median_estimate_rel=float(np.median(rel)), median_cost=float(np.median(cost)),
                        max_cost=float(np.max(cost))))
    return pd.DataFrame(out)


def _estimate(lad: pd.DataFrame, i: int, w, steps: int) -> float:
    """``E`` of ``improved._auto`` at rung ``i`` of a recorded ladder: the largest of the last ``steps`` changes;
    ``w = (safety, shift_fraction, floor[, nonlinearity])``."""
    r = lad.loc[i]
    ch = lad.loc[max(1, i - steps + 1):i, "change"].dropna()
    change = float(ch.max()) if len(ch) else 0.0
    raw = 0.5 * r["bracket"] if r["k_c"] >= r["k_max"] else max(0.5 * r["bracket"], change)
    x = r["fine_over_rho"] if len(w) > 3 else 0.0
    return w[0] * raw + max(w[1], (w[3] if len(w) > 3 else 0.0) * x**1.5) * r["shift"] + w[2] * r["scale"]


def _commit() -> str:
    """The checkout's commit (``+dirty`` with uncommitted changes to tracked files)."""
    root = Path(__file__).resolve().parents[1]
    try:
        rev = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=root, capture_output=True, text=True,
                             check=True).stdout.strip()
        dirty = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no"], cwd=root,
                               capture_output=True, text=True, check=True).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return "unknown"
    return rev + ("+dirty" if dirty else "")


def replay_lines(ladders: pd.DataFrame) -> list[str]:
    """Coverage and cost of the earlier stopping rule (one change, ``(1.5, 0.25, 2e-3)``), of two changes alone
    and of the current rule (two changes and the nonlinearity term) replayed on a set's recorded ladders
    (``choose``'s replay)."""
    lines = []
    for label, steps, w in (("earlier rule (one change; 1.5, 0.25, 2e-3)", 1, (1.5, 0.25, 2e-3)),
                            ("two changes alone (1.5, 0.35, 1e-3)", 2, (1.5, 0.35, 1e-3)),
                            ("current rule (two changes; 1.5, 0.35, 1e-3, nonlinearity 0.07)", 2,
                             (1.5, 0.35, 1e-3, 0.07))):
        cov = []
        for _, lad in ladders.groupby("key", sort=False):
            lad = lad.reset_index(drop=True)
            stop = next((i for i in range(steps, len(lad))
                         if _estimate(lad, i, w, steps) <= 0.05 * lad.loc[i, "scale"]), len(lad) - 1)
            r = lad.loc[stop]
            e, err = _estimate(lad, stop, w, steps), abs(r["g0"] - r["gfmd"])
            cov.append(dict(bound=err <= e, conv=e <= 0.05 * r["scale"], err=err / r["scale"], est=e / r["scale"],
                            cost=r["cost"] / r["full_cost"]))
        c = pd.DataFrame(cov)
        miss = c[~c.bound]
        lines.append(f"- replayed on the recorded ladders, {label}: bound at {int(c.bound.sum())}/{len(c)}, "
                     f"\"converged\" and not bounded at {int((~c.bound & c.conv).sum())} (worst error "
                     f"{miss.err.max() if len(miss) else 0:.4f} with estimate "
                     f"{miss.est[miss.err.idxmax()] if len(miss) else 0:.4f}); cost (force evaluations x grid points) "
                     f"median {c.cost.median():.3f}, max {c.cost.max():.3f}")
    return lines


def write(df: pd.DataFrame, dd: pd.DataFrame, name: str, out: Path, wall: float, commit: str = "",
          ladders: pd.DataFrame | None = None) -> None:
    df.to_csv(out / f"hybrid_{name}.csv", index=False)
    dd.to_csv(out / f"multiscale_{name}.csv", index=False)
    conv = df.status == "converged"
    exceed = df[~df.bound]
    lines = [f"# Error estimates against GFMD: the {name} set (issues 30, 39)\n",
             f"`python benchmarks/bench_bounds.py --set {name} --out {out}` (commit {commit or _commit()}) on "
             f"{platform.node()} "
             f"({platform.processor() or platform.machine()}, Python {platform.python_version()}, one thread, "
             f"shared 2-core VM), {time.strftime('%Y-%m-%d')}; {wall / 60:.1f} min wall. GFMD references cached in "
             f"`gfmd_{name}.json`. Method: the script's docstring.\n",
             "## Mean gap: `improved.hybrid(zeta_c=\"auto\")` at its defaults\n",
             f"- points: {len(df)}; the estimate bounds the error at **{int(df.bound.sum())}/{len(df)} "
             f"({100 * df.bound.mean():.1f} %)**; exceeded at {len(exceed)} (by up to "
             f"{(exceed.err.abs() / exceed.estimate.clip(lower=1e-300)).max() if len(exceed) else 0:.2f}x), "
             f"{int((~df.bound & conv).sum())} of them \"converged\"",
             f"- error (relative / in h_rms): max {df.err.abs().max():.4f}, median {df.err.abs().median():.4f}; "
             f"within 5 %: {int((df.err.abs() <= 0.05).sum())}/{len(df)}; \"converged\" and outside 5 %: "
             f"{int((conv & (df.err.abs() > 0.05)).sum())}",
             f"- status: {df.status.value_counts().to_dict()}",
             f"- estimate / error where the error exceeds 1e-3: median "
             f"{(df.estimate / df.err.abs())[df.err.abs() > 1e-3].median():.2f}",
             f"- CPU seconds per point (process time, same process): hybrid median {df.cpu_hybrid.median():.3f} s, "
             f"GFMD (tol 1e-8) median {df.cpu_gfmd.median():.3f} s; ratio of sums "
             f"{df.cpu_hybrid.sum() / df.cpu_gfmd.sum():.3f}, median of per-point ratios "
             f"{(df.cpu_hybrid / df.cpu_gfmd).median():.3f}; cost (force evaluations x grid points) median "
             f"{df.cost.median():.3f}, max {df.cost.max():.3f}"]
    if ladders is not None and name != "tuning":
        lines += replay_lines(ladders)
    lines.append("")
    if len(dd):
        bad = dd.l1 > 0.15
        lines += ["## Gap distribution: `closure.multiscale_gap_samples` at its defaults (2^17 samples)\n",
                  f"- distributions: {len(dd)}; L1 <= 0.15 at **{int((~bad).sum())}/{len(dd)}**; max L1 "
                  f"{dd.l1.max():.3f}, median {dd.l1.median():.3f}; earlier centring (`center=\"sample\"`): "
                  f"{int((dd.l1_sample_centring <= 0.15).sum())}/{len(dd)}, max {dd.l1_sample_centring.max():.3f}, "
                  f"median {dd.l1_sample_centring.median():.3f}",
                  f"- misses reporting \"converged\": {int((bad & (dd.status == 'converged')).sum())}; flagged but "
                  f"within 0.15: {int((~bad & (dd.status != 'converged')).sum())}; status "
                  f"{dd.status.value_counts().to_dict()}",
                  f"- self-check: l1_estimate >= L1 at {int((dd.l1_estimate >= dd.l1).sum())}/{len(dd)}",
                  f"- CPU seconds: multiscale median {dd.cpu_multiscale.median():.2f} s (max "
                  f"{dd.cpu_multiscale.max():.2f}), GFMD median {dd.cpu_gfmd.median():.2f} s (max "
                  f"{dd.cpu_gfmd.max():.2f})\n",
                  "| H | lambda_l | zeta_s | rho/h | seed | N | p | n_c | L1 | L1 (sample centring) | l1_change | "
                  "status | CPU s ms / GFMD |", "| " + " | ".join(["---"] * 13) + " |"]
        for r in dd.itertuples():
            lines.append(f"| {r.hurst:g} | {r.lambda_l:g} | {r.zeta_s:g} | {r.rho_over_h:g} | {r.seed} | {r.n} | "
                         f"{r.pressure:g} | {r.n_c} | {r.l1:.3f} | {r.l1_sample_centring:.3f} | {r.l1_change:.3f} | "
                         f"{r.status} | {r.cpu_multiscale:.2f} / {r.cpu_gfmd:.2f} |")
    (out / f"bounds_{name}.md").write_text("\n".join(lines) + "\n")
    print((out / f"bounds_{name}.md").read_text())


def _read(path: Path) -> pd.DataFrame:
    """A result csv; an empty frame for a set without distributions (pandas cannot read a header-less file)."""
    try:
        return pd.read_csv(path)
    except pd.errors.EmptyDataError:
        return pd.DataFrame()


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--set", choices=tuple(SETS), default="heldout")
    ap.add_argument("--out", type=Path, default=Path("benchmarks/results/bounds"))
    ap.add_argument("--table", action="store_true", help="rewrite the markdown from the csv files of a run")
    ap.add_argument("--choose", action="store_true", help="replay the tuning ladders for the estimate's constants")
    ap.add_argument("--ladders", action="store_true", help="record the tuning ladders again (cached GFMD only)")
    a = ap.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(message)s")
    a.out.mkdir(parents=True, exist_ok=True)
    if a.ladders:
        ladders_only(a.set, a.out).to_csv(a.out / f"ladders_{a.set}.csv", index=False)
        return 0
    if a.choose:
        tab = choose(pd.read_csv(a.out / "ladders_tuning.csv"))
        tab.to_csv(a.out / "choose_tuning.csv", index=False)
        print(tab.to_string(index=False))
        return 0
    if a.table:
        lad = a.out / f"ladders_{a.set}.csv"
        write(pd.read_csv(a.out / f"hybrid_{a.set}.csv"), _read(a.out / f"multiscale_{a.set}.csv"), a.set,
              a.out, math.nan, ladders=pd.read_csv(lad) if lad.exists() else None)
        return 0
    t0, commit = time.perf_counter(), _commit()
    df, dd, ladders = evaluate(a.set, a.out)
    if ladders:
        pd.DataFrame(ladders).to_csv(a.out / f"ladders_{a.set}.csv", index=False)
    write(df, dd, a.set, a.out, time.perf_counter() - t0, commit, pd.DataFrame(ladders) if ladders else None)
    return 0


if __name__ == "__main__":
    _record.track(CODE_PATHS)
    raise SystemExit(main())
