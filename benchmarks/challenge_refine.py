"""Refinement study of the contact-mechanics challenge's law (issue 37 item 4; docs/challenge.md "Refinement
study"): the same surface (the challenge's spectrum, one realisation: M2's modes depend on ``(seed, kx, ky)`` only,
so every grid samples the same band-limited surface) on grids ``N -> 2N -> 4N`` of one box, the hard wall with
exponential adhesion (``interaction="hard_wall_adhesive"``, gapsweep.gfmd._bounded) at the challenge's constants
(E* = 25 MPa, gamma0 = 50 mJ/m^2, rho = 2.071 nm; units um and MPa).

Per grid: the reference load reached along the loading path (loads ``sigma_ref x 2^-k``, ``k = ramp .. 0``, the
first from the flat body touching the highest summit, each later one from the previous load's state), then the
loads ``sigma_ref (1 +- delta)`` from the reference state. Outputs at the reference load: relative contact area
(``g = 0`` pixels), mean gap, and the contact stiffness ``K = -d sigma0 / d <g>`` (central difference of the
two neighbouring loads). Every solve must converge: a solve that does not (any other status, the iteration cap
included) is recorded and the script exits with status 1 after writing what it has; no number of an
unconverged solve enters the table. Between grids: the relative change of each output and, with three grids, the
observed order ``p = log2(|Q_N - Q_2N| / |Q_2N - Q_4N|)``.

On the CPU at small N (tested: tests/test_challenge_refine.py), the box scaled down by ``--box`` so that the
finest pixel is the challenge's (1.526 nm at ``4N = 1024`` with ``--box 1.5625``, i.e. 100 um / 64)::

    OMP_NUM_THREADS=1 PYTHONPATH=. python benchmarks/challenge_refine.py --n 256 512 1024 --box 1.5625 \\
        --out benchmarks/results/challenge/refine_cpu.json

On GPUs, one rank per GPU (the solve split over the ranks, surfaces made in place; ``--pairs``: L-BFGS pairs,
2 or 3 at 65536^2 on four 141 GB GPUs, gfmd._bounded.memory_plan)::

    mpiexec -n 4 python benchmarks/challenge_refine.py --gpu --n 16384 32768 65536 --pairs 2 \\
        --out benchmarks/results/challenge/refine_h200x4.json

The full box (``--box 100``, the default) needs ``N > 2000`` (the grid must carry ``lambda_s = 0.1 um``).
Without mpiexec the solves run on one process (numpy/pyFFTW on the CPU; with ``--gpu`` one GPU)."""

from __future__ import annotations

import argparse
import itertools
import json
import math
import sys
import time
import warnings
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parent))
import _record

# the code this benchmark measures: a result measured before a later change to it is stale (scripts/check_docs.py)
CODE_PATHS = ["gapsweep/gfmd/_bounded.py", "gapsweep/gfmd/interactions/hard_wall_adhesive.py",
              "gapsweep/gfmd/distributed.py", "gapsweep/core/slab.py", "gapsweep/surfaces"]
OUTPUTS = ("contact_area", "mean_gap_um", "stiffness_MPa_per_um")


def _comm(gpu: bool) -> Any:
    """MPI.COMM_WORLD when run under mpiexec with more than one rank (or on a GPU: the slab path), else None."""
    try:
        from mpi4py import MPI
    except ImportError:
        return None
    comm = MPI.COMM_WORLD
    if comm.Get_size() > 1 or gpu:
        if gpu:
            import cupy

            cupy.cuda.Device(comm.Get_rank() % cupy.cuda.runtime.getDeviceCount()).use()
        return comm
    return None


def _surface(n: int, box: float, seed: int, comm: Any, gpu: bool) -> Any:
    from gapsweep.surfaces import challenge as ch
    from gapsweep.surfaces.synthetic import self_affine_rows

    c = ch.CHALLENGE
    if comm is None:
        h = ch.surface(n, length=box, seed=seed)
        if gpu:
            import cupy

            h = cupy.asarray(h)
        return h
    return self_affine_rows(n, c["hurst"], comm=comm, lambda_l=box, lambda_r=min(c["lambda_r"], box),
                            lambda_s=c["lambda_s"], length=box, rms_slope=c["rms_slope"], seed=seed,
                            backend="cupy" if gpu else "numpy")


def _gpu_memory(n: int, comm: Any, pairs: int | None) -> dict[str, float]:
    """This GPU's memory pool (bytes held, the largest over the ranks) and ``gfmd._bounded.memory_plan``'s
    estimate for the grid (the slab path on ranks, the 2-D cuFFT path on one GPU without MPI); the pool is then
    emptied so that the next grid's number is its own."""
    import cupy

    from gapsweep.gfmd._bounded import _MEMORY, memory_plan

    pool = cupy.get_default_memory_pool()
    held = float(pool.total_bytes())
    ranks = 1 if comm is None else comm.Get_size()
    if comm is not None:
        held = max(comm.allgather(held))
    plan = memory_plan((n, n), ranks, memory=_MEMORY if pairs is None else pairs,
                       backend="cupy" if comm is None else "slab-cupy")
    cupy.fft.config.get_plan_cache().clear()
    pool.free_all_blocks()
    return {"gpu_pool_bytes": held, "plan_bytes": float(plan["bytes_per_rank"]),
            "pool_over_plan": held / plan["bytes_per_rank"]}


def study(ns: list[int], *, box: float, sigma_ref: float, ramp: int, delta: float, tol: float, max_iter: int,
          pairs: int | None, seed: int, gpu: bool = False, log: Any = print, progress: Any = None) -> dict[str, Any]:
    """The study (module docstring); returns ``{"grids": [...], "solves": [...], "changes": [...], "ok"}``.
    ``progress(partial)``: called on rank 0 after every solve with the record so far (``"ok": None`` while it
    runs), so that a run stopped by a time limit leaves what it measured."""
    from gapsweep import gfmd
    from gapsweep.surfaces import challenge as ch

    c = ch.CHALLENGE
    comm = _comm(gpu)
    rank = 0 if comm is None else comm.Get_rank()
    law = dict(interaction="hard_wall_adhesive", work=c["work"], rho=c["rho"], e_star=c["e_star"], length=box,
               tol=tol, max_iter=max_iter)
    if pairs is not None:
        law["memory"] = pairs
    if comm is not None:
        law["comm"] = comm
    elif not gpu:
        law["backend"] = "auto"
    solves: list[dict] = []
    grids: list[dict] = []
    ok = True
    for n in ns:
        h = _surface(n, box, seed, comm, gpu)
        dx = box / n
        prev = None
        rec: dict[str, Any] = {"n": n, "dx_um": dx, "rho_dx": c["rho"] / dx,
                               "mu_rho": ch.mu_rho(c["work"], c["rho"], c["e_star"], dx)}
        at: dict[str, Any] = {}
        loads = [sigma_ref * 2.0 ** -k for k in range(ramp, -1, -1)]
        for role, s in [*((f"path {i}", s) for i, s in enumerate(loads)), ("minus", sigma_ref * (1 - delta)),
                        ("plus", sigma_ref * (1 + delta))]:
            start = at.get("ref") if role in ("minus", "plus") else prev
            t = time.perf_counter()
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                r = gfmd.solve(h, sigma0=s, initial=start, host=False, **law)
            row = {"n": n, "role": role, "sigma0_MPa": s, "status": r.status, "iterations": int(r.iterations),
                   "residual": float(r.residual), "wall_s": time.perf_counter() - t,
                   "contact_area": float(r.contact_area), "mean_gap_um": float(r.mean_gap),
                   "from": "flat" if start is None else "previous load" if role.startswith("path") else "reference"}
            solves.append(row)
            if rank == 0:
                log(json.dumps(row))
                if progress is not None:
                    progress({"grids": grids, "solves": solves, "changes": [], "ok": None})
            if r.status != "converged":
                ok = False
                break
            prev = r
            if role == f"path {len(loads) - 1}":
                at["ref"] = r
            at[role] = r
        if not ok:
            grids.append({**rec, "complete": False})
            break
        ref, lo, hi = at["ref"], at["minus"], at["plus"]
        stiff = -(hi.sigma0 - lo.sigma0) / (hi.mean_gap - lo.mean_gap)
        grids.append({**rec, "complete": True, "contact_area": float(ref.contact_area),
                      "mean_gap_um": float(ref.mean_gap), "stiffness_MPa_per_um": float(stiff),
                      "fine_wall_s": sum(x["wall_s"] for x in solves if x["n"] == n)})
        del h, prev, at, ref, lo, hi
        if gpu:  # the memory pool's bytes (its peak: it keeps freed blocks) against the plan that guards the run
            grids[-1].update(_gpu_memory(n, comm, pairs))
    done = [g for g in grids if g["complete"]]
    changes = []
    for a, b in itertools.pairwise(done):
        changes.append({"from_n": a["n"], "to_n": b["n"],
                        **{f"rel_change_{q}": abs(b[q] - a[q]) / abs(b[q]) for q in OUTPUTS}})
    for a, b, cc in zip(done, done[1:], done[2:]):
        for q in OUTPUTS:
            d1, d2 = abs(a[q] - b[q]), abs(b[q] - cc[q])
            changes.append({"order_of": q, "ns": [a["n"], b["n"], cc["n"]],
                            "p": math.log2(d1 / d2) if d1 > 0 and d2 > 0 else math.nan})
    return {"grids": grids, "solves": solves, "changes": changes, "ok": ok, "ranks": 1 if comm is None else
            comm.Get_size(), "rank": rank}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--n", type=int, nargs="+", default=[256, 512, 1024], help="grid sides, coarsest first")
    ap.add_argument("--box", type=float, default=100.0, help="box side (um); the challenge's is 100")
    ap.add_argument("--sigma-ref", type=float, default=0.25, help="reference load (MPa; docs/challenge.md)")
    ap.add_argument("--ramp", type=int, default=3, help="loads sigma_ref 2^-k, k = ramp .. 0, on the path")
    ap.add_argument("--delta", type=float, default=0.05, help="relative load step of the stiffness")
    ap.add_argument("--tol", type=float, default=1e-8)
    ap.add_argument("--max-iter", type=int, default=20000)
    ap.add_argument("--pairs", type=int, default=None, help="L-BFGS pairs (default: the solver's, 10)")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--gpu", action="store_true", help="cupy: one GPU per rank")
    ap.add_argument("--out", type=Path, default=None, help="JSON result (provenance added at exit)")
    a = ap.parse_args(argv)
    if sorted(a.n) != a.n or len(set(a.n)) != len(a.n) or min(a.n) < 16:
        ap.error(f"--n: increasing grid sides >= 16, got {a.n}")
    if not (a.box > 0 and a.sigma_ref > 0 and 0 < a.delta < 0.5 and a.ramp >= 0):
        ap.error("--box, --sigma-ref > 0, 0 < --delta < 0.5, --ramp >= 0")
    head = {"command": " ".join(["python", *sys.argv]), "args": {k: str(v) for k, v in vars(a).items()},
            "law": "hard_wall_adhesive (challenge constants)"}

    def write(res: dict) -> None:
        if a.out is not None:
            a.out.parent.mkdir(parents=True, exist_ok=True)
            a.out.write_text(json.dumps({**head, **{k: v for k, v in res.items() if k != "rank"}}, indent=1) + "\n")

    res = study(a.n, box=a.box, sigma_ref=a.sigma_ref, ramp=a.ramp, delta=a.delta, tol=a.tol, max_iter=a.max_iter,
                pairs=a.pairs, seed=a.seed, gpu=a.gpu, progress=write)
    if res["rank"] == 0:
        for g in res["grids"]:
            print(json.dumps(g))
        write(res)
    return 0 if res["ok"] else 1


if __name__ == "__main__":
    _record.track(CODE_PATHS)
    sys.exit(main())
