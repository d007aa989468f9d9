"""Compare the values of two stores of the same job run differently (e.g. GFMD on the GPU vs the CPU stores in
docs/results/stores.tgz): rows are matched by their grid point (method, hurst, rho, sigma0, seed, n), so specs
that differ only in where they run (``backend``, task ids) compare. Prints one markdown row per method and exits
1 when a difference exceeds its tolerance (stated in TOL, relative to the row's h_rms for mean gaps).

    python benchmarks/compare_stores.py GPU.h5 CPU.h5 [--json OUT.json]
"""

from __future__ import annotations

import argparse
import json
import sys
import sys as _sys
from pathlib import Path as _Path

import h5py
import numpy as np

_sys.path.insert(0, str(_Path(__file__).resolve().parent))
import _record

# the code this benchmark measures: a result measured before a later change to it is stale
# (scripts/check_docs.py)
CODE_PATHS = ['gapsweep/sweep/api.py']

# tolerance per method: (mean gap |diff| / h_rms, histogram L1 distance, other means |diff| / h_rms)
TOL = {
    "gfmd": (1e-6, 1e-3),  # both converged to tol = 1e-6 (force residual); round-off paths differ
    "theory": (1e-12, 0.0),  # same formulas and surfaces on the CPU
    "fokker_planck": (1e-9, 1e-6),  # same CPU solver
    "sde": (1e-3, 2e-2),  # 10^7 float32 realisations; CUDA vs warp engine round differently (fast math)
}
KEYS = ("method", "hurst", "rho", "sigma0", "seed", "n")


def _load(path: str) -> dict:
    with h5py.File(path, "r") as f:
        t, r = f["tasks"][...], f["results"][...]
        edges, dens = f["histograms"]["edges"][...], f["histograms"]["density"][...]
    rows = {}
    for k in range(t.shape[0]):
        key = tuple(t[c][k].decode() if isinstance(t[c][k], bytes) else t[c][k].item() for c in KEYS)
        rows[key] = (r[k], edges[k], dens[k])
    return rows


def compare(a: str, b: str) -> dict:
    ra, rb = _load(a), _load(b)
    out: dict = {"a": a, "b": b, "only_a": len(set(ra) - set(rb)), "only_b": len(set(rb) - set(ra)), "methods": {}}
    for key in sorted(set(ra) & set(rb), key=str):
        m = key[0]
        x, ex, dx = ra[key]
        y, ey, dy = rb[key]
        s = out["methods"].setdefault(m, {"rows": 0, "status_equal": 0, "iterations_equal": 0, "mean_gap": 0.0,
                                          "other_means": 0.0, "hist_l1": 0.0, "gap_std_rel": 0.0})
        s["rows"] += 1
        s["status_equal"] += int(x["status"] == y["status"])
        s["iterations_equal"] += int(x["iterations"] == y["iterations"])
        h = abs(float(y["h_rms"])) or 1.0
        if np.isfinite(x["mean_gap"]) or np.isfinite(y["mean_gap"]):
            s["mean_gap"] = max(s["mean_gap"], abs(float(x["mean_gap"]) - float(y["mean_gap"])) / h)
        for c in ("mean_gap_paper", "mean_gap_continuum", "mean_gap_discrete"):
            if np.isfinite(x[c]) or np.isfinite(y[c]):
                s["other_means"] = max(s["other_means"], abs(float(x[c]) - float(y[c])) / h)
        if np.isfinite(y["gap_std"]) and y["gap_std"]:
            s["gap_std_rel"] = max(s["gap_std_rel"], abs(float(x["gap_std"]) / float(y["gap_std"]) - 1))
        if np.isfinite(dx).all() and np.isfinite(dy).all():
            # L1 distance of the two densities, each on its own bins, over a common fine grid
            grid = np.linspace(min(ex[0], ey[0]), max(ex[-1], ey[-1]), 8 * len(dx) + 1)
            mid = 0.5 * (grid[1:] + grid[:-1])

            def on(e, d, mid=mid):
                i = np.searchsorted(e, mid, side="right") - 1
                ok = (i >= 0) & (i < len(d))
                return np.where(ok, d[np.clip(i, 0, len(d) - 1)], 0.0)

            s["hist_l1"] = max(s["hist_l1"], float(np.sum(np.abs(on(ex, dx) - on(ey, dy)) * np.diff(grid))))
    ok = out["only_a"] == 0 and out["only_b"] == 0
    for m, s in out["methods"].items():
        tg, th = TOL.get(m, (0.0, 0.0))
        s["tol_mean_gap"], s["tol_hist_l1"] = tg, th
        s["ok"] = (s["status_equal"] == s["rows"] and s["mean_gap"] <= tg and s["other_means"] <= max(tg, 1e-12)
                   and s["hist_l1"] <= th)
        ok &= s["ok"]
    out["ok"] = ok
    return out


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("a")
    p.add_argument("b")
    p.add_argument("--json")
    a = p.parse_args()
    res = compare(a.a, a.b)
    print(f"{a.a} vs {a.b}: rows only in one: {res['only_a']} / {res['only_b']}")
    print("| method | rows | same status | same iterations | max mean-gap diff / h_rms (tol) | theory forms | "
          "max hist L1 (tol) | max gap_std rel | within tol |")
    print("| --- | --- | --- | --- | --- | --- | --- | --- | --- |")
    for m, s in res["methods"].items():
        print(f"| {m} | {s['rows']} | {s['status_equal']} | {s['iterations_equal']} | {s['mean_gap']:.2e} "
              f"({s['tol_mean_gap']:.0e}) | {s['other_means']:.2e} | {s['hist_l1']:.2e} ({s['tol_hist_l1']:.0e}) | "
              f"{s['gap_std_rel']:.2e} | {'yes' if s['ok'] else 'NO'} |")
    if a.json:
        with open(a.json, "w") as f:
            json.dump(res, f, indent=1, default=float)
    return 0 if res["ok"] else 1


if __name__ == "__main__":
    _record.track(CODE_PATHS, header=True)
    sys.exit(main())
