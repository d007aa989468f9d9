"""The flow solve against the contact solve that made its gap: same map, same machine (issue 42, item 5).

    OMP_NUM_THREADS=1 NUMBA_NUM_THREADS=1 python benchmarks/bench_flow.py --n 256 1024 \
        --out benchmarks/results/flow/bench_flow.json

For each size: a self-affine surface (H = 0.8, lambda_l = L/2, lambda_s = 4 pixels, rms slope 0.1), the
hard-wall GFMD solve at ``--sigma0`` (tol 1e-8, defaults otherwise) timed with its wall clock, then
``flow.solve`` on its gap field (pressure drop along axis 1, ``solver="auto"``: a direct solve up to 70 000
unknowns, else pyamg's AMG-preconditioned CG when installed; tol 1e-8, the default) timed the same way, each the
best of ``--repeat`` runs after one warm-up on a small grid (so neither pays numba's compilation). Both on the
CPU in one process; the GPU path is not timed here (no GPU).
"""

from __future__ import annotations

import argparse
import json
import platform
import subprocess
import sys
import time
from datetime import UTC, datetime
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import sys as _sys
from pathlib import Path as _Path

from gapsweep import flow, gfmd, surface

_sys.path.insert(0, str(_Path(__file__).resolve().parent))
import _record

# the code this benchmark measures: a result measured before a later change to it is stale
# (scripts/check_docs.py)
CODE_PATHS = ['gapsweep/flow']

def one(n: int, sigma0: float, repeat: int) -> dict:
    h = surface.self_affine(n, 0.8, seed=1, lambda_l=0.5, lambda_s=4 / n, rms_slope=0.1)
    tg, tf = [], []
    for _ in range(repeat):
        t = time.perf_counter()
        r = gfmd.solve(h, sigma0=sigma0, interaction="hard_wall", tol=1e-8)
        tg.append(time.perf_counter() - t)
        t = time.perf_counter()
        f = flow.solve(r.gap, axis=1)
        tf.append(time.perf_counter() - t)
    return {"n": n, "sigma0": sigma0, "contact_area": r.contact_area, "gfmd_status": r.status,
            "gfmd_iterations": r.iterations, "gfmd_seconds": min(tg), "flow_seconds": min(tf),
            "ratio": min(tf) / min(tg), "flow_solver": f.solver, "flow_iterations": f.iterations,
            "flow_residual": f.residual, "flow_converged": f.converged, "percolating": f.percolating,
            "unknowns_fraction": f.connected_fraction, "conductance_over_mean_gap_cubed": f.ratio}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, nargs="+", default=[256, 1024])
    ap.add_argument("--sigma0", type=float, default=0.01)
    ap.add_argument("--repeat", type=int, default=2)
    ap.add_argument("--out", type=Path, default=Path("benchmarks/results/flow/bench_flow.json"))
    a = ap.parse_args()
    # the commit the run starts from (read now: HEAD may move while a long run goes on)
    commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True).stdout.strip()
    one(32, a.sigma0, 1)  # warm-up: numba's compilation, pyamg's import
    rows = []
    for n in a.n:
        rows.append(one(n, a.sigma0, a.repeat))
        print(json.dumps(rows[-1]), flush=True)
    try:
        import pyamg

        amg = pyamg.__version__
    except ImportError:
        amg = None
    out = {"what": "flow solve vs the hard-wall contact solve that made the gap, same map, CPU, one process",
           "command": "python benchmarks/bench_flow.py " + " ".join(sys.argv[1:]), "commit": commit,
           "machine": f"{platform.node()} {platform.machine()} {platform.processor()}, 2 cores shared",
           "date": datetime.now(UTC).isoformat(timespec="seconds"), "pyamg": amg, "rows": rows}
    a.out.parent.mkdir(parents=True, exist_ok=True)
    a.out.write_text(json.dumps(out, indent=1) + "\n", encoding="utf-8")


if __name__ == "__main__":
    _record.track(CODE_PATHS)
    main()
