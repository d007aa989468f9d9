"""A hard-wall solve that cycled instead of converging: the reproducer of a bug fixed by the fresh start after
``max(30, i)`` iterations without a new lowest residual (docs/gfmd.md, "A cycling hard-wall solve, and the fresh
start that ends it"); the "shipped" row is the solver as it is now.

Found on one H200 (``bench_gpu_floor.py --hardwall-methods mpcg:2048``: the coarse level at 2048^2, started from a
uniform pressure, ran its 2000 iterations without reaching 1e-2; ``benchmarks/results/gpu_floor/
hardwall_coarsest_h200.json``), reproduced here on the CPU: the figure-2 surface of docs/model.md M6 (H = 0.3,
seed 1, N = 4096, lambda_s = 2.5e-3) coarsened to 2048^2 (``_constrained.coarsen``: an ordinary self-affine map
with lambda_s = 5.1 pixels), ``sigma0 = 0.1``, method "pcg" (the GPU's default; a uniform start), tol 1e-8.
Rows: the shipped constants, and the same solve with the CG restarted at every re-entry (``_KEEP = 0``, the rule
before issue 39) and with the re-entry stiffness ``_REENTRY`` 10x lower or higher -- each a module constant set
for that one solve. Iterations, status, residual, wall seconds and the residual's last 8 values (a cycle shows as
a repeating pattern). Writes ``<out>/<name>.json`` and ``.md``.

    OMP_NUM_THREADS=1 python benchmarks/bench_hardwall_cycle.py --out benchmarks/results/contact   (~4 min)
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))

import _record

from gapsweep import gfmd
from gapsweep.gfmd import _constrained as C
from gapsweep.surfaces import self_affine

# the code this benchmark measures: a result measured before a later change to it is stale
# (scripts/check_docs.py)
CODE_PATHS = ["gapsweep/gfmd", "gapsweep/surfaces"]

VARIANTS = [("shipped", {}), ("restart at every re-entry (_KEEP = 0)", {"_KEEP": 0.0}),
            ("_REENTRY = 1e-3", {"_REENTRY": 1e-3}), ("_REENTRY = 0.1", {"_REENTRY": 0.1})]


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--name", default="hardwall_cycle")
    ap.add_argument("--max-iter", type=int, default=600)
    a = ap.parse_args(argv)
    a.out.mkdir(parents=True, exist_ok=True)
    h = C.coarsen(self_affine(4096, 0.3, lambda_l=0.25, lambda_s=2.5e-3, rms_slope=1.0, seed=1), np)
    rows = []
    for label, consts in VARIANTS:
        saved = {k: getattr(C, k) for k in consts}
        for k, v in consts.items():
            setattr(C, k, v)
        try:
            t = time.perf_counter()
            r = gfmd.solve(h, sigma0=0.1, interaction="hard_wall", tol=1e-8, method="pcg", max_iter=a.max_iter)
            wall = time.perf_counter() - t
        finally:
            for k, v in saved.items():
                setattr(C, k, v)
        rows.append({"variant": label, "n": h.shape[0], "sigma0": 0.1, "method": "pcg", "status": r.status,
                     "iterations": r.iterations, "residual": r.residual, "wall_s": wall,
                     "last_residuals": [float(x) for x in r.history[-8:]]})
        print(rows[-1], flush=True)
    meta = {"command": " ".join(["python", *sys.argv]), "date": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime())}
    (a.out / f"{a.name}.json").write_text(json.dumps({"meta": meta, "rows": rows}, indent=1))
    lines = [f"### A cycling hard-wall solve ({meta['date']})", "", f"`{meta['command']}`", "",
             "| variant | status | iterations | residual | wall s | last residuals |",
             "| --- | --- | --- | --- | --- | --- |"]
    lines += [f"| {r['variant']} | {r['status']} | {r['iterations']} | {r['residual']:.3g} | {r['wall_s']:.1f} | "
              f"{' '.join(f'{x:.2g}' for x in r['last_residuals'])} |" for r in rows]
    (a.out / f"{a.name}.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    _record.track(CODE_PATHS)
    sys.exit(main())
