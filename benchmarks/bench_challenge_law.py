"""The challenge's law (hard wall + exponential adhesion, gfmd._bounded) on CPU windows of the challenge's
spectrum at its constants (E* = 25 MPa, gamma0 = 50 mJ/m^2, rho = 2.071 nm; units um and MPa): the challenge's
pixel (dx = 1.526 nm, rho/dx = 1.36, mu_rho = 0.84) and a coarser one (rho/dx = 0.5, mu_rho = 1.39), N = 256 and
512, loads 2.5, 0.25, 0 and -0.5 MPa (each solved on its own: from the flat body, tensile ones by continuation
from zero load). Status, iterations, wall time, contact area, mean gap. Writes
benchmarks/results/challenge/law_cpu.json:

    OMP_NUM_THREADS=1 PYTHONPATH=. python benchmarks/bench_challenge_law.py
"""

from __future__ import annotations

import datetime
import json
import platform
import subprocess
import time
from pathlib import Path

from gapsweep.gfmd import solve
from gapsweep.surfaces import challenge as ch

ROOT = Path(__file__).resolve().parents[1]



import sys as _sys  # noqa: E402
from pathlib import Path as _Path  # noqa: E402

_sys.path.insert(0, str(_Path(__file__).resolve().parent))
import _record  # noqa: E402

# the code this benchmark measures: a result measured before a later change to it is stale
# (scripts/check_docs.py)
CODE_PATHS = ['gapsweep/gfmd/_bounded.py', 'gapsweep/gfmd/interactions/hard_wall_adhesive.py']

def main() -> None:
    c = ch.CHALLENGE
    rows = []
    for n, dx in ((256, 1.526e-3), (512, 1.526e-3), (256, 4.142e-3), (512, 4.142e-3)):
        length = n * dx
        h = ch.surface(n, length=length, seed=1)
        for s in (2.5, 0.25, 0.0, -0.5):
            t = time.perf_counter()
            r = solve(h, sigma0=s, interaction="hard_wall_adhesive", work=c["work"], rho=c["rho"],
                      e_star=c["e_star"], length=length, tol=1e-8, backend="numpy", max_iter=20000)
            rows.append({"n": n, "dx_um": dx, "rho_dx": c["rho"] / dx, "mu_rho": r.diagnostics["mu_rho"],
                         "sigma0_MPa": s, "status": r.status, "iterations": r.iterations,
                         "wall_s": time.perf_counter() - t, "contact_area": r.contact_area, "mean_gap_um": r.mean_gap,
                         "residual": r.residual,
                         "last_attached_load": r.diagnostics.get("last_attached_load", float("nan"))})
            print(rows[-1], flush=True)
    commit = subprocess.run(["git", "rev-parse", "HEAD"], cwd=ROOT, capture_output=True, text=True).stdout.strip()
    out = {"command": "OMP_NUM_THREADS=1 PYTHONPATH=. python benchmarks/bench_challenge_law.py", "commit": commit,
           "machine": f"{platform.node()} ({platform.machine()}), 2 shared CPU cores, numpy FFT, tol 1e-8",
           "date": datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds"), "rows": rows}
    (ROOT / "benchmarks/results/challenge/law_cpu.json").write_text(json.dumps(out, indent=1) + "\n")


if __name__ == "__main__":
    _record.track(CODE_PATHS)
    main()
