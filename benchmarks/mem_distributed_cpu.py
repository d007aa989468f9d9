"""Peak memory per rank of distributed solves on the CPU (gfmd.distributed.solve over MPI ranks, numpy arrays
traced by tracemalloc) against gfmd.distributed.solve_memory's estimate, in arrays ``A`` of a rank's rows (the
surface counted as one). Transforms and elementwise passes run over chunks of 4 rows, as their temporaries are
small against the grid at large n (the estimate's case). Each law is solved once untraced first (imports, caches).

Run (from the repository root; ~1 minute on 2 cores):

    PYTHONPATH=. mpiexec -n 2 python benchmarks/mem_distributed_cpu.py \
        --out benchmarks/results/distributed/cpu_memory.json
"""

from __future__ import annotations

import argparse
import json
import platform
import sys as _sys
import time
import tracemalloc
import warnings
from pathlib import Path as _Path

from mpi4py import MPI

from gapsweep.core import slab
from gapsweep.gfmd import _lean, distributed, slab_rows
from gapsweep.surfaces.synthetic import self_affine

_sys.path.insert(0, str(_Path(__file__).resolve().parent))
import _record

# the code this benchmark measures: a result measured before a later change to it is stale
# (scripts/check_docs.py)
CODE_PATHS = ['gapsweep/gfmd', 'gapsweep/core/slab.py']

CASES = [("exponential", "exponential", dict(sigma0=1e-2, gamma0=1e-3, rho=0.01)),
         ("adhesive", "adhesive", dict(sigma0=1e-3, interaction="adhesive", work=1e-3, rho=0.01)),
         ("adhesive tensile", "adhesive", dict(sigma0=-1e-3, interaction="adhesive", work=1e-3, rho=0.01)),
         ("hard wall pcg", "hard_wall", dict(sigma0=1e-2, interaction="hard_wall", method="pcg")),
         ("hard wall pk", "hard_wall", dict(sigma0=1e-2, interaction="hard_wall", method="pk"))]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", required=True)
    ap.add_argument("--n", type=int, default=256)
    args = ap.parse_args()
    comm = MPI.COMM_WORLD
    n = args.n
    slab.DEFAULT_CHUNK, _lean.CHUNK["numpy"] = 4 * n, 4 * n
    h = self_affine(n, 0.8, lambda_l=0.25, lambda_s=1 / 20, seed=5)[slab_rows(n, comm)].copy()
    a = 8.0 * -(-n // comm.Get_size()) * n
    rows = []
    for name, kind, kw in CASES:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            distributed.solve(h, comm=comm, host=False, tol=1e-4, **kw)  # imports and caches, untraced
            tracemalloc.start()
            base = tracemalloc.get_traced_memory()[0]
            r = distributed.solve(h, comm=comm, host=False, tol=1e-8, **kw)
            peak = tracemalloc.get_traced_memory()[1] - base
            tracemalloc.stop()
        est = distributed.solve_memory((n, n), comm.Get_size(), kind, tensile=kw["sigma0"] < 0)
        rows.append({"case": name, "status": r.status, "iterations": r.iterations,
                     "measured_arrays_per_rank": 1.0 + max(comm.allgather(peak)) / a,
                     "estimated_arrays_per_rank": est["arrays"] + est["scratch_arrays"],
                     "estimated_solver_arrays": est["arrays"]})
    if comm.Get_rank() == 0:
        out = {"command": f"mpiexec -n {comm.Get_size()} python benchmarks/mem_distributed_cpu.py --out {args.out}",
               "n": n, "ranks": comm.Get_size(), "machine": platform.node(), "cpu": platform.processor(),
               "date": time.strftime("%Y-%m-%d %H:%M:%S %Z"), "cases": rows}
        with open(args.out, "w") as f:
            json.dump(out, f, indent=1)
        for row in rows:
            print(row)


if __name__ == "__main__":
    _record.track(CODE_PATHS)
    main()
