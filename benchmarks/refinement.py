"""Grid-refinement and tolerance study of GFMD (docs/gfmd.md): the
same resolution-independent surface (docs/model.md M2,
seed fixed) solved on n = 1024 ... 8192, errors of the mean gap and of the gap histogram against the finest grid,
and errors against tol on one grid.

    python benchmarks/refinement.py --out OUT [--n 1024 2048] [--backend auto|numpy|pyfftw|cupy]

Cases: docs/model.md M6 (L = 1, E* = 1, lambda_l = 0.25, lambda_s = 2.5e-3, gamma0 = 1e-3, g_rms = 1), figure 2
(H = 0.3, rho = 2e-3, 1e-3, 5e-4) and figure 3 (H = 0.8, rho = 5e-3, 2e-3, 1e-3) at sigma0 = 1e-4, 1e-2, 1.
Writes refinement.json (every run: mean gap, iterations, histogram on fixed edges) and refinement.md; the
constants of gapsweep.resolution are an envelope of these errors.
"""

from __future__ import annotations

import argparse
import json
import platform
import sys
import time
import warnings
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import sys as _sys
from pathlib import Path as _Path

from gapsweep import gfmd
from gapsweep.surface import rms_height, self_affine

_sys.path.insert(0, str(_Path(__file__).resolve().parent))
import _record

# the code this benchmark measures: a result measured before a later change to it is stale
# (scripts/check_docs.py)
CODE_PATHS = ['gapsweep/gfmd', 'gapsweep/surfaces']

GAMMA0 = 1e-3
CASES = [(0.3, 2e-3), (0.3, 1e-3), (0.3, 5e-4), (0.8, 5e-3), (0.8, 2e-3), (0.8, 1e-3)]
SIGMA0 = [1e-4, 1e-2, 1.0]
NBINS = 120
warnings.simplefilter("ignore", gfmd.UnderResolvedWarning)


def hist_l1(p: list[float], q: list[float], edges: list[float]) -> float:
    """L1 distance of two densities on the same edges: int |P - Q| dg, in [0, 2]."""
    return float(np.sum(np.abs(np.asarray(p) - np.asarray(q)) * np.diff(edges)))


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--n", type=int, nargs="+", default=[1024, 2048])
    ap.add_argument("--backend", default="auto")
    ap.add_argument("--sigma0", type=float, nargs="+", default=SIGMA0)
    ap.add_argument("--cases", nargs="+", default=None, help="H:rho pairs, e.g. 0.3:2e-3")
    ap.add_argument("--tols", type=float, nargs="+", default=[1e-3, 1e-4, 1e-5, 1e-6, 1e-7, 1e-8])
    ap.add_argument("--ref-tol", type=float, default=1e-10)
    ap.add_argument("--threads", type=int, default=1)
    a = ap.parse_args(argv)
    cases = [tuple(float(x) for x in c.split(":")) for c in a.cases] if a.cases else CASES
    ns = sorted(a.n)
    xp = np
    if a.backend == "cupy":
        import cupy as xp
    rows = []
    t0 = time.perf_counter()
    for hurst, rho in cases:
        surfaces = {}
        for s0 in a.sigma0:
            edges = None
            for n in ns:
                if n not in surfaces:
                    surfaces[n] = xp.asarray(self_affine(n, hurst, lambda_l=0.25, lambda_s=2.5e-3, seed=1))
                h = surfaces[n]
                kw = dict(sigma0=s0, gamma0=GAMMA0, rho=rho, backend=a.backend, threads=a.threads,
                          max_iter=20000, host=a.backend != "cupy")
                r = gfmd.solve(h, tol=a.ref_tol, **kw)
                if edges is None:  # fixed bins for all n of this case, from the coarsest grid, padded
                    g = np.asarray(r.gap.get() if hasattr(r.gap, "get") else r.gap)
                    lo, hi = float(g.min()), float(g.max())
                    pad = 0.25 * (hi - lo)
                    edges = np.linspace(lo - pad, hi + pad, NBINS + 1)
                _, dens = r.histogram(edges)
                row = {"H": hurst, "rho": rho, "sigma0": s0, "n": n, "tol": a.ref_tol,
                       "h_rms": rms_height(np.asarray(h.get() if hasattr(h, "get") else h)),
                       "mean_gap": r.mean_gap, "iterations": r.iterations, "wall_s": r.wall_time,
                       "status": r.status, "edges": edges.tolist(), "density": np.asarray(dens).tolist()}
                rows.append(row)
                print({k: v for k, v in row.items() if k not in ("edges", "density")}, flush=True)
                if n == ns[-1]:
                    # Tolerance study on the finest grid: cold starts, as a production run would do.
                    for tol in a.tols:
                        rt = gfmd.solve(h, tol=tol, **kw)
                        _, dt = rt.histogram(edges)
                        rows.append({**row, "tol": tol, "mean_gap": rt.mean_gap, "iterations": rt.iterations,
                                     "wall_s": rt.wall_time, "status": rt.status,
                                     "density": np.asarray(dt).tolist()})
    a.out.mkdir(parents=True, exist_ok=True)
    meta = {"host": platform.node(), "command": " ".join(sys.argv), "n": ns, "ref_tol": a.ref_tol,
            "backend": a.backend, "seconds": time.perf_counter() - t0}
    if a.backend == "cupy":
        meta["gpu"] = xp.cuda.runtime.getDeviceProperties(0)["name"].decode()
    (a.out / "refinement.json").write_text(json.dumps({"meta": meta, "rows": rows}))
    write_tables(a.out, rows, meta)


def write_tables(out: Path, rows: list[dict], meta: dict) -> None:
    """Errors against the finest grid (reference tol) and against the reference tol on the finest grid."""
    ns = meta["n"]
    ref_tol = meta["ref_tol"]
    lines = ["### Grid refinement: mean-gap error |dg0|/h_rms and histogram L1 error vs the finest grid "
             f"(n = {ns[-1]}, tol = {ref_tol:g})", "", f"`{meta['command']}`", "",
             "| H | rho | sigma0 | h_rms/rho | rho n/L | " + " | ".join(f"n={n}: gap err / hist L1" for n in ns[:-1])
             + " | evals at finest n |", "|" + " --- |" * (6 + len(ns) - 1)]
    keyed = {}
    for r in rows:
        keyed[(r["H"], r["rho"], r["sigma0"], r["n"], r["tol"])] = r
    cases = sorted({(r["H"], r["rho"], r["sigma0"]) for r in rows})
    for hurst, rho, s0 in cases:
        ref = keyed[(hurst, rho, s0, ns[-1], ref_tol)]
        cells = []
        for n in ns[:-1]:
            r = keyed[(hurst, rho, s0, n, ref_tol)]
            cells.append(f"{abs(r['mean_gap'] - ref['mean_gap']) / ref['h_rms']:.2e} / "
                         f"{hist_l1(r['density'], ref['density'], ref['edges']):.2e}")
        lines.append(f"| {hurst} | {rho:g} | {s0:g} | {ref['h_rms'] / rho:.3g} | {rho * ns[0]:.3g}.. | "
                     + " | ".join(cells) + f" | {ref['iterations']} |")
    tols = sorted({r["tol"] for r in rows if r["tol"] != ref_tol}, reverse=True)
    lines += ["", f"### Tolerance: mean-gap error |dg0|/h_rms / histogram L1 error vs tol = {ref_tol:g} at n = {ns[-1]}"
              " (force evaluations in brackets)", "",
              "| H | rho | sigma0 | " + " | ".join(f"tol={t:g}" for t in tols) + " |", "|" + " --- |" * (3 + len(tols))]
    for hurst, rho, s0 in cases:
        ref = keyed[(hurst, rho, s0, ns[-1], ref_tol)]
        cells = []
        for t in tols:
            r = keyed.get((hurst, rho, s0, ns[-1], t))
            if r is None:
                cells.append("")
                continue
            cells.append(f"{abs(r['mean_gap'] - ref['mean_gap']) / ref['h_rms']:.1e} / "
                         f"{hist_l1(r['density'], ref['density'], ref['edges']):.1e} ({r['iterations']})")
        lines.append(f"| {hurst} | {rho:g} | {s0:g} | " + " | ".join(cells) + " |")
    (out / "refinement.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    _record.track(CODE_PATHS)
    main()
