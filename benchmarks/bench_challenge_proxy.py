"""CPU proxy of the contact-mechanics challenge's 65536^2 solve (benchmarks/bench_distributed.py, ``challenge``):
force evaluations to convergence of the plain start against the coarse-to-fine start (``start="coarse"``,
gapsweep.gfmd._coarse; docs/gfmd.md "Coarse-to-fine start").

The proxy keeps what sets the local difficulty: the pixel (dx = 100 um / 65536 = 1.526 nm, so rho/dx = 1.357 as
at 65536^2), the short cut-off lambda_s = 0.1 um, H = 0.8, E* = 25 MPa, work of adhesion 50 mJ/m^2, range
rho = 2.071 nm, mean pressure 0.25 MPa (units um and MPa). The box is L = N dx with N = 512 .. 2048 (0.78 ..
3.1 um) and lambda_l = L/2 (the challenge's 20 um does not fit). The rms slope is chosen so that the spectrum
C(q) at q > 2 pi/lambda_l equals the challenge's (rms slope 1 between 20 um and 0.1 um):
g_proxy^2 = (q_s^(2-2H) - q_l,proxy^(2-2H)) / (q_s^(2-2H) - q_l^(2-2H)) (continuum M2 integral), i.e. 0.69 at
N = 512, 0.80 at 1024, 0.87 at 2048.

Cases (``--case``; each under 2 minutes on one core, single process or ``mpiexec -n 2``, where the solve is
split over the ranks):
  exp-1024      exponential law (gamma0 = work), N = 1024, seed 1: flat (linear-response start) vs coarse;
  adh-1024      adhesion, N = 1024, seed 1, lean L-BFGS with 2 pairs (the 65536^2 path): flat vs coarse,
                and the exponential law's (coarse-started) answer as the start of adhesion;
  exp-2048-s2   held out: exponential, N = 2048, seed 2, sigma0 = 0.5 MPa;
  adh-512-s2    held out: adhesion, N = 512, seed 2, sigma0 = 0.5 MPa;
  exp-4096      exponential, N = 4096, seed 1, coarse only (the flat start, not run: ~300 evaluations of
                4096^2 by the 83 / 156 of 1024 / 2048).
The coarse-to-fine settings (automatic levels down to 64 pixels a side, coarse tolerance 10 tol) were chosen on
seed 1 at N = 512 .. 2048; the held-out cases check them without change. Recorded per solve: status,
evaluations of the requested grid, the coarse levels' cost in evaluations of the requested grid
(``sum_l n_l 4^-l``), residual, mean gap, contact area, wall time.

Run (repository root; JSON to --out, rank 0 rewrites it after every case):

    PYTHONPATH=. python benchmarks/bench_challenge_proxy.py --case exp-1024 adh-1024 \
        --out benchmarks/results/distributed/challenge_proxy.json
    PYTHONPATH=. mpiexec -n 2 python benchmarks/bench_challenge_proxy.py --case exp-1024 adh-1024 \
        --out benchmarks/results/distributed/challenge_proxy_mpi2.json
"""

from __future__ import annotations

import argparse
import json
import math
import os
import platform
import sys
import time
import warnings
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import sys as _sys  # noqa: E402
from pathlib import Path as _Path  # noqa: E402

from gapsweep import gfmd  # noqa: E402
from gapsweep.gfmd import distributed  # noqa: E402
from gapsweep.surfaces.synthetic import self_affine  # noqa: E402

_sys.path.insert(0, str(_Path(__file__).resolve().parent))
import _record  # noqa: E402  (benchmarks/_record.py: the provenance of every result file)

# the code this benchmark measures: a result measured before a later change to it is stale
# (scripts/check_docs.py)
CODE_PATHS = ['gapsweep/gfmd', 'gapsweep/core', 'gapsweep/surfaces']

DX = 100.0 / 65536  # um: the challenge's pixel
C = dict(e_star=25.0, work=0.05, rho=2.071e-3, sigma0=0.25, hurst=0.8, lambda_l=20.0, lambda_s=0.1)
CASES = {
    "exp-1024": dict(n=1024, seed=1, sigma0=0.25, laws=("exponential",)),
    "adh-1024": dict(n=1024, seed=1, sigma0=0.25, laws=("adhesive",), exp_start=True),
    "exp-2048-s2": dict(n=2048, seed=2, sigma0=0.5, laws=("exponential",)),
    "adh-512-s2": dict(n=512, seed=2, sigma0=0.5, laws=("adhesive",)),
    "exp-4096": dict(n=4096, seed=1, sigma0=0.25, laws=("exponential",), flat=False),
}


def proxy_slope(lambda_l: float) -> float:
    """rms slope of the proxy spectrum (module docstring)."""
    e = 2.0 - 2.0 * C["hurst"]
    qs, ql, qp = (2 * math.pi / v for v in (C["lambda_s"], C["lambda_l"], lambda_l))
    return math.sqrt((qs**e - qp**e) / (qs**e - ql**e))


def summary(r, t: float) -> dict:
    d = r.diagnostics
    return {"status": r.status, "evaluations": int(r.iterations), "coarse_cost": float(d.get("coarse_cost", 0.0)),
            "fine_equivalent": r.iterations + float(d.get("coarse_cost", 0.0)), "residual": float(r.residual),
            "mean_gap": float(r.mean_gap), "contact_area": float(r.contact_area), "wall_s": t,
            "levels": d.get("levels")}


def run_case(name: str, comm, tol: float, max_iter: int) -> dict:
    c = CASES[name]
    n = c["n"]
    length = n * DX
    lam_l = length / 2
    g = proxy_slope(lam_l)
    h = self_affine(n, C["hurst"], lambda_l=lam_l, lambda_s=C["lambda_s"], length=length, rms_slope=g,
                    seed=c["seed"])
    rows = gfmd.slab_rows(n, comm)
    hl = np.ascontiguousarray(h[rows])
    out = {"case": name, "n": n, "seed": c["seed"], "sigma0": c["sigma0"], "length_um": length, "lambda_l_um": lam_l,
           "rms_slope": g, "h_rms_um": float(h.std()), "tol": tol, "max_iter": max_iter}
    for law in c["laws"]:
        kw = dict(comm=comm, interaction=law, rho=C["rho"], sigma0=c["sigma0"], e_star=C["e_star"], length=length,
                  tol=tol, max_iter=max_iter)
        kw.update(dict(gamma0=C["work"]) if law == "exponential" else dict(work=C["work"], memory=2))
        res = {}
        for start in (("flat", "coarse") if c.get("flat", True) else ("coarse",)):
            comm.Barrier()
            t0 = time.perf_counter()
            r = distributed.solve(hl, start=start, **kw)
            res[start] = summary(r, time.perf_counter() - t0)
        if c.get("exp_start"):  # alternative: the exponential law's answer (coarse-started) as adhesion's start
            comm.Barrier()
            t0 = time.perf_counter()
            e = distributed.solve(hl, comm=comm, interaction="exponential", gamma0=C["work"], rho=C["rho"],
                                  sigma0=c["sigma0"], e_star=C["e_star"], length=length, tol=tol,
                                  max_iter=max_iter, start="coarse")
            r = distributed.solve(hl, initial=(e.displacement, e.mean_gap), **kw)
            s = summary(r, time.perf_counter() - t0)
            s["exponential_start"] = summary(e, 0.0)
            s["fine_equivalent"] += e.iterations + e.diagnostics["coarse_cost"]
            res["exponential_then_adhesive"] = s
        if "flat" in res and res["flat"]["status"] == res["coarse"]["status"] == "converged":
            res["d_mean_gap_rel"] = abs(res["coarse"]["mean_gap"] / res["flat"]["mean_gap"] - 1.0)
            res["d_contact_area"] = abs(res["coarse"]["contact_area"] - res["flat"]["contact_area"])
        out[law] = res
    return out


def main() -> None:
    from mpi4py import MPI

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--case", nargs="+", default=["exp-1024", "adh-1024"], choices=sorted(CASES))
    ap.add_argument("--out", required=True, type=Path)
    ap.add_argument("--tol", type=float, default=1e-6)
    ap.add_argument("--max-iter", type=int, default=3000)
    args = ap.parse_args()
    comm = MPI.COMM_WORLD
    warnings.simplefilter("ignore")  # rho/dx < 1 on the coarse levels: expected
    res = {"command": " ".join(sys.argv), "ranks": comm.Get_size(), "machine": platform.node(),
           "cpu": platform.processor() or platform.machine(), "python": platform.python_version(),
           "numpy": np.__version__, "date": time.strftime("%Y-%m-%d %H:%M:%S %Z"),
           "omp_num_threads": os.environ.get("OMP_NUM_THREADS"), "constants": C, "dx_um": DX, "units": "um, MPa",
           "cases": []}
    for name in args.case:
        res["cases"].append(run_case(name, comm, args.tol, args.max_iter))
        if comm.Get_rank() == 0:
            args.out.parent.mkdir(parents=True, exist_ok=True)
            tmp = args.out.with_suffix(".tmp")
            tmp.write_text(json.dumps(res, indent=1))
            os.replace(tmp, args.out)
            print(json.dumps({k: v for k, v in res["cases"][-1].items()}, indent=None)[:2000], flush=True)


if __name__ == "__main__":
    _record.track(CODE_PATHS)
    main()
