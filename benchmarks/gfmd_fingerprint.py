"""Bit-level fingerprints of GFMD solves on every engine (issue 41: "numbers unchanged" across a refactor).

    PYTHONPATH=<checkout> python benchmarks/gfmd_fingerprint.py --out fp.json [--engines numba generic cupy]
    PYTHONPATH=<checkout> mpiexec -n 2 python benchmarks/gfmd_fingerprint.py --out fp2.json --distributed
    python benchmarks/gfmd_fingerprint.py --compare a.json b.json

Each case is solved once per engine ("numba": the CPU defaults; "generic": ``GAPSWEEP_GENERIC_KERNELS=1``, the
array code of every pass; "cupy": the GPU, heights as cupy arrays; ``--distributed``: the slab solver over the
ranks of ``mpi4py.MPI.COMM_WORLD``, numpy) and recorded as exact floats (``float.hex``): mean gap, iteration
count, the sum of the residual history and the pressure sum. Cases (64^2, small): exponential law "cg",
"lbfgs", "fire"; hard wall "pcg", "pk" periodic and free (64 x 48); adhesive and exponential on a rectangle
(the smooth minimiser), exponential with free boundaries; a batch of two exponential problems. Run it at two
commits on one machine and ``--compare`` the files: a refactor that keeps every number shows no difference
(the GPU's fused kernels are deterministic for a fixed grid, so this holds there too). Exit status 1 when the
files differ."""

from __future__ import annotations

import argparse
import json
import os
import sys
import warnings
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))
import _record

# the code this benchmark measures: a result measured before a later change to it is stale (scripts/check_docs.py)
CODE_PATHS = ["gapsweep/gfmd", "gapsweep/core", "gapsweep/surfaces"]


def _maps() -> tuple[np.ndarray, np.ndarray]:
    from gapsweep.surfaces import self_affine

    h = self_affine(64, 0.8, lambda_l=0.5, lambda_s=4 / 64, seed=3)
    h2 = self_affine(64, 0.7, lambda_l=0.5, lambda_s=4 / 64, seed=4)[:, :48]
    return h / h.std() * 0.01, h2 / h2.std() * 0.01


def _fp(r: Any, with_pressure: bool = True) -> list:
    out = [float(r.mean_gap).hex(), int(r.iterations), float(np.sum(r.history)).hex()]
    if with_pressure:
        p = r.pressure.get() if hasattr(r.pressure, "get") else r.pressure
        out.append(float(np.sum(p)).hex())
    return out


def one_process(engine: str) -> dict[str, list]:
    """The cases on one process with ``engine`` ("numba", "generic" or "cupy")."""
    from gapsweep.gfmd import solve
    from gapsweep.gfmd.batched import Problem, solve_batch

    os.environ.pop("GAPSWEEP_GENERIC_KERNELS", None)
    if engine == "generic":
        os.environ["GAPSWEEP_GENERIC_KERNELS"] = "1"
    h, h2 = _maps()
    if engine == "cupy":
        import cupy

        h, h2 = cupy.asarray(h), cupy.asarray(h2)
    exp = dict(sigma0=0.01, gamma0=1e-4, rho=2e-3, tol=1e-8)
    rect = dict(length=(1.0, 0.75))
    out: dict[str, list] = {}
    for m in ("cg", "lbfgs", "fire"):
        out[f"exponential {m}"] = _fp(solve(h, method=m, **exp))
    for m in ("pcg", "pk"):
        out[f"hard_wall {m}"] = _fp(solve(h, sigma0=0.01, interaction="hard_wall", method=m, tol=1e-9))
        out[f"hard_wall {m} free"] = _fp(solve(h2, sigma0=0.01, interaction="hard_wall", method=m, tol=1e-9,
                                               periodic=False, **rect))
    out["adhesive rectangle"] = _fp(solve(h2, sigma0=0.01, interaction="adhesive", work=1e-4, rho=2e-3, tol=1e-8,
                                          **rect), False)
    out["exponential rectangle"] = _fp(solve(h2, **exp, **rect), False)
    out["exponential free"] = _fp(solve(h2, periodic=False, **exp, **rect), False)
    rs = solve_batch([Problem(h, 0.01, gamma0=1e-4, rho=2e-3), Problem(h * 1.3, 0.02, gamma0=1e-4, rho=3e-3)],
                     tol=1e-8)
    out["batch"] = [_fp(r, False) for r in rs]
    os.environ.pop("GAPSWEEP_GENERIC_KERNELS", None)
    return out


def distributed() -> dict[str, list] | None:
    """The periodic cases over the ranks of COMM_WORLD (numpy slabs); on rank 0 the fingerprints, else None."""
    from mpi4py import MPI

    from gapsweep.core.slab import slab_rows
    from gapsweep.gfmd import distributed as dist

    comm = MPI.COMM_WORLD
    h, _ = _maps()
    rows = slab_rows(64, comm)
    out: dict[str, list] = {}
    for m in ("cg", "lbfgs", "fire"):
        r = dist.solve(h[rows], comm=comm, sigma0=0.01, gamma0=1e-4, rho=2e-3, method=m, tol=1e-8)
        out[f"exponential {m}"] = [*_fp(r, False), r.diagnostics["reductions"]]
    for m in ("pcg", "pk"):
        r = dist.solve(h[rows], comm=comm, sigma0=0.01, interaction="hard_wall", method=m, tol=1e-9)
        out[f"hard_wall {m}"] = [*_fp(r, False), r.diagnostics["reductions"]]
    r = dist.solve(h[rows], comm=comm, sigma0=0.01, interaction="adhesive", work=1e-4, rho=2e-3, tol=1e-8)
    out["adhesive"] = [*_fp(r, False), r.diagnostics["reductions"]]
    out["ranks"] = [comm.Get_size()]
    return out if comm.Get_rank() == 0 else None


def compare(a: Path, b: Path) -> int:
    """Print the cases whose fingerprints differ between the files ``a`` and ``b``; 1 when any does."""
    da, db = (json.loads(p.read_text()) for p in (a, b))
    diff = 0
    for eng in sorted(set(da) | set(db)):
        if eng == "provenance":
            continue
        ea, eb = da.get(eng, {}), db.get(eng, {})
        for case in sorted(set(ea) | set(eb)):
            if ea.get(case) != eb.get(case):
                diff += 1
                print(f"{eng} / {case}: {ea.get(case)} != {eb.get(case)}")
    print(f"{diff} case(s) differ" if diff else "identical")
    return 1 if diff else 0


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", type=Path)
    ap.add_argument("--engines", nargs="+", choices=("numba", "generic", "cupy"), default=["numba", "generic"])
    ap.add_argument("--distributed", action="store_true")
    ap.add_argument("--compare", nargs=2, type=Path)
    a = ap.parse_args()
    if a.compare:
        sys.exit(compare(*a.compare))
    if a.out is None:
        ap.error("--out is needed (or --compare A B)")
    warnings.simplefilter("ignore")
    if a.distributed:
        res = distributed()
        if res is not None:
            a.out.write_text(json.dumps({"distributed": res}, indent=1))
        return
    a.out.write_text(json.dumps({eng: one_process(eng) for eng in a.engines}, indent=1))


if __name__ == "__main__":
    _record.track(CODE_PATHS)
    main()
