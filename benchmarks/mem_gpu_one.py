"""GPU memory of one solve on one GPU against its estimate (issue 39 item 4: "memory figures that match what the
GPU's pool reaches"): ``gfmd._cuda.solve_memory`` beside the cupy memory pool's bytes after the solve (the pool
keeps every block it took: its size after the solve is its peak), per grid and law.

    python benchmarks/mem_gpu_one.py --n 8192 16384 32768 --out benchmarks/results/gfmd/mem_gpu_one.json
    python benchmarks/mem_gpu_one.py --n 4096 8192 16384 --laws hard_wall_adhesive --out OUT.json

The law ``hard_wall_adhesive`` is the contact-mechanics challenge's (docs/challenge.md): its surface drawn on the
GPU from the challenge's spectrum in a 25 um box (the box of ``benchmarks/challenge_refine.py``'s first stage),
one solve from the flat body to 0.25 MPa, against ``gfmd._bounded.memory_plan`` (backend "cupy", the surface
included) -- the estimate that guards a run of that law.

One GPU; every solve in a process of its own (a fresh pool, plan cache and kernel buffers: a process keeps
buffers per grid size, so a second size would add to the first), the caller's surface on the GPU as the sweep
passes it. Writes the JSON after every solve (with a provenance record) and prints a line per solve."""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
import warnings
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))
import _record

CODE_PATHS = ["gapsweep/gfmd/_cuda.py", "gapsweep/gfmd/_solvers.py", "gapsweep/gfmd/_constrained.py",
              "gapsweep/gfmd/_ops.py", "gapsweep/core/fft.py", "gapsweep/gfmd/_bounded.py",
              "gapsweep/surfaces/challenge.py"]
CASES = {"exponential": dict(interaction="exponential", gamma0=1e-3, sigma0=1e-2),
         "hard_wall": dict(interaction="hard_wall", sigma0=1e-2),
         "hard_wall_adhesive": dict(interaction="hard_wall_adhesive", sigma0=0.25)}
CHALLENGE_BOX = 25.0  # um


def _challenge(n: int) -> tuple[Any, dict, dict]:
    """The challenge's surface on the GPU, the law's keywords and memory_plan's estimate (as solve_memory's)."""
    from gapsweep.gfmd._bounded import memory_plan
    from gapsweep.surfaces import challenge

    c = challenge.CHALLENGE
    h = challenge.surface(n, seed=1, length=CHALLENGE_BOX, backend="cupy")
    kw = dict(CASES["hard_wall_adhesive"], work=c["work"], rho=c["rho"], e_star=c["e_star"], length=CHALLENGE_BOX,
              tol=1e-8, max_iter=20000)
    plan = memory_plan((n, n), 1, backend="cupy")
    return h, kw, {"bytes": plan["bytes_per_rank"], "parts": plan["parts"]}


def one(n: int, law: str) -> dict:
    """One solve in this process (a fresh pool): its pool bytes beside the estimate."""
    import cupy

    from gapsweep import gfmd
    from gapsweep.gfmd._cuda import solve_memory
    from gapsweep.surfaces import self_affine

    pool = cupy.get_default_memory_pool()
    kw = dict(CASES[law])
    if law == "hard_wall_adhesive":
        h, kw, est = _challenge(n)
    else:
        if law == "exponential":
            kw["rho"] = 2.0 / n  # rho/dx = 2: resolved
        est = solve_memory(n, interaction=law)
        h = cupy.asarray(self_affine(n, 0.8, lambda_l=0.5, lambda_s=4.0 / n, rms_slope=1.0, seed=5))
        kw["tol"] = 1e-6
    t0 = time.perf_counter()
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            r = gfmd.solve(h, host=False, **kw)
        cupy.cuda.Device().synchronize()
        status, it = r.status, int(r.iterations)
    except cupy.cuda.memory.OutOfMemoryError as e:
        status, it = f"out of memory: {e}", -1
    wall = time.perf_counter() - t0
    peak = pool.total_bytes()
    return dict(n=n, law=law, status=status, iterations=it, wall_s=round(wall, 3), pool_bytes=int(peak),
                estimate_bytes=int(est["bytes"]), pool_over_estimate=round(peak / est["bytes"], 4),
                excess_gb=round((peak - est["bytes"]) / 1e9, 3), parts=est["parts"])


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, nargs="+", default=[8192, 16384, 32768])
    ap.add_argument("--laws", nargs="+", default=["exponential", "hard_wall"], choices=tuple(CASES))
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--one", nargs=2, metavar=("N", "LAW"), help=argparse.SUPPRESS)  # a child: one solve
    a = ap.parse_args(argv)
    if a.one:
        print(json.dumps(one(int(a.one[0]), a.one[1])))
        return 0
    import cupy

    rows = []
    for n in a.n:
        for law in a.laws:
            p = subprocess.run([sys.executable, __file__, "--out", str(a.out), "--one", str(n), law],
                               capture_output=True, text=True)
            if p.returncode != 0:
                rows.append(dict(n=n, law=law, status=f"failed: {p.stderr.strip().splitlines()[-1:]}"))
            else:
                rows.append(json.loads(p.stdout.strip().splitlines()[-1]))
            r = rows[-1]
            print(f"n={n} {law}: {r['status']} {r.get('iterations')} it {r.get('wall_s')} s; pool "
                  f"{r.get('pool_bytes', 0) / 1e9:.2f} GB, estimate {r.get('estimate_bytes', 0) / 1e9:.2f} GB "
                  f"({r.get('pool_over_estimate')})", flush=True)
            a.out.parent.mkdir(parents=True, exist_ok=True)
            a.out.write_text(json.dumps({"gpu": cupy.cuda.runtime.getDeviceProperties(0)["name"].decode(),
                                         "rows": rows}, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    _record.track(CODE_PATHS)  # a child (--one) writes no file: the parent's record stamps the result
    raise SystemExit(main())
