"""Where the leak rate vanishes: the relative contact area at which the non-contact area of a hard-wall contact
on a self-affine surface stops percolating, at several grid sizes (docs/model.md M8; compare Dapp, Lucke,
Persson & Muser, PRL 108, 244301 (2012): about 0.42 for large systems).

For each size and seed the load ``sigma0`` is bisected (geometrically) between a load that leaks and one that
seals, each step a hard-wall GFMD solve and the cluster test of :func:`gapsweep.flow.open_clusters` (pressure
drop along axis 0 for even seeds, axis 1 for odd ones); at the two final loads :func:`gapsweep.flow.solve` checks
that the leak rate is positive at the leaking one and exactly 0 at the sealing one. The threshold of a sample is
the mean contact area of the two final loads.

    python -m studies.percolation --sizes 64 128 256 512 --seeds 8 --out docs/results/flow/percolation.json
"""

from __future__ import annotations

import argparse
import json
import math
import platform
import subprocess
import sys
import time
from datetime import UTC, datetime
from pathlib import Path

import numpy as np

from gapsweep import flow, gfmd, surface


def threshold(n: int, seed: int, *, hurst: float, lambda_l: float, lambda_s_px: float, steps: int) -> dict:
    h = surface.self_affine(n, hurst, seed=seed, lambda_l=lambda_l, lambda_s=lambda_s_px / n, rms_slope=0.1)
    axis = seed % 2
    lo, hi = 1e-4, 1.0  # sigma0 / E*: the first leaks, the second seals (checked below)
    res = {}
    for s in (lo, hi):
        r = gfmd.solve(h, sigma0=s, interaction="hard_wall", tol=1e-8)
        res[s] = r
    if not flow.open_clusters(res[lo].gap, axis=axis)[1] or flow.open_clusters(res[hi].gap, axis=axis)[1]:
        raise RuntimeError(f"n={n} seed={seed}: bracket does not straddle the percolation point")
    for _ in range(steps):
        mid = math.sqrt(lo * hi)
        r = gfmd.solve(h, sigma0=mid, interaction="hard_wall", tol=1e-8)
        if not r.converged:
            raise RuntimeError(f"n={n} seed={seed} sigma0={mid}: GFMD {r.status}")
        res[mid] = r
        if flow.open_clusters(r.gap, axis=axis)[1]:
            lo = mid
        else:
            hi = mid
    leak_lo = flow.solve(res[lo].gap, axis=axis).leak_rate
    leak_hi = flow.solve(res[hi].gap, axis=axis).leak_rate
    assert leak_lo > 0 and leak_hi == 0.0
    return {"n": n, "seed": seed, "axis": axis, "sigma0_leaks": lo, "sigma0_seals": hi,
            "area_leaks": res[lo].contact_area, "area_seals": res[hi].contact_area,
            "threshold": 0.5 * (res[lo].contact_area + res[hi].contact_area), "leak_rate_at_leaks": leak_lo}


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", type=int, nargs="+", default=[64, 128, 256])
    ap.add_argument("--seeds", type=int, default=8)
    ap.add_argument("--hurst", type=float, default=0.8)
    ap.add_argument("--lambda-l", type=float, default=0.5)
    ap.add_argument("--lambda-s-px", type=float, default=4.0, help="short cut-off in pixels")
    ap.add_argument("--steps", type=int, default=10)
    ap.add_argument("--out", type=Path, default=Path("docs/results/flow/percolation.json"))
    a = ap.parse_args(argv)
    # the commit the run starts from (read now: HEAD may move while a long run goes on)
    commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True).stdout.strip()
    rows, summary = [], []
    for n in a.sizes:
        t0 = time.perf_counter()
        th = []
        for s in range(a.seeds):
            r = threshold(n, s, hurst=a.hurst, lambda_l=a.lambda_l, lambda_s_px=a.lambda_s_px, steps=a.steps)
            rows.append(r)
            th.append(r["threshold"])
        x = np.array(th)
        summary.append({"n": n, "seeds": a.seeds, "mean": float(x.mean()),
                        "sem": float(x.std(ddof=1) / math.sqrt(x.size)) if x.size > 1 else math.nan,
                        "min": float(x.min()), "max": float(x.max()), "seconds": time.perf_counter() - t0})
        print(json.dumps(summary[-1]), flush=True)
    out = {"what": "relative contact area where the non-contact area stops percolating (hard wall, GFMD)",
           "reference": "Dapp, Lucke, Persson & Muser, PRL 108, 244301 (2012): about 0.42",
           "command": "python -m studies.percolation " + " ".join(sys.argv[1:] if argv is None else argv),
           "commit": commit, "machine": f"{platform.node()} {platform.machine()} {platform.processor()}",
           "date": datetime.now(UTC).isoformat(timespec="seconds"),
           "parameters": {"hurst": a.hurst, "lambda_l": a.lambda_l, "lambda_s_px": a.lambda_s_px,
                          "rms_slope": 0.1, "steps": a.steps},
           "summary": summary, "samples": rows}
    a.out.parent.mkdir(parents=True, exist_ok=True)
    a.out.write_text(json.dumps(out, indent=1) + "\n", encoding="utf-8")


CODE_PATHS = ["gapsweep/flow", "gapsweep/gfmd/_constrained.py", "gapsweep/gfmd/_constrained_ops.py",
              "studies/percolation.py"]

if __name__ == "__main__":
    import studies

    studies.track(CODE_PATHS)
    main()
