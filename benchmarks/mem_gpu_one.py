"""GPU memory of one solve on one GPU against its estimate (issue 39 item 4: "memory figures that match what the
GPU's pool reaches"): ``gfmd._cuda.solve_memory`` beside the cupy memory pool's bytes after the solve (the pool
keeps every block it took: its size after the solve is its peak), per grid and law.

    python benchmarks/mem_gpu_one.py --n 8192 16384 32768 --out benchmarks/results/gfmd/mem_gpu_one.json

One process, one GPU; every solve starts from an empty pool and plan cache (the caller's surface on the GPU, as
the sweep passes it). Writes the JSON (with a provenance record) and prints a table."""

from __future__ import annotations

import argparse
import json
import sys
import time
import warnings
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))
import _record

CODE_PATHS = ["gapsweep/gfmd/_cuda.py", "gapsweep/gfmd/_solvers.py", "gapsweep/gfmd/_constrained.py",
              "gapsweep/gfmd/_ops.py", "gapsweep/core/fft.py"]
CASES = {"exponential": dict(interaction="exponential", gamma0=1e-3, sigma0=1e-2),
         "hard_wall": dict(interaction="hard_wall", sigma0=1e-2)}


def main(argv: list[str] | None = None) -> int:
    import cupy

    from gapsweep import gfmd
    from gapsweep.gfmd._cuda import solve_memory
    from gapsweep.surfaces import self_affine

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, nargs="+", default=[8192, 16384, 32768])
    ap.add_argument("--laws", nargs="+", default=["exponential", "hard_wall"], choices=tuple(CASES))
    ap.add_argument("--out", type=Path, required=True)
    a = ap.parse_args(argv)
    pool = cupy.get_default_memory_pool()
    rows = []
    for n in a.n:
        h0 = self_affine(n, 0.8, lambda_l=0.5, lambda_s=4.0 / n, rms_slope=1.0, seed=5)
        for law in a.laws:
            kw = dict(CASES[law])
            if law == "exponential":
                kw["rho"] = 2.0 / n  # rho/dx = 2: resolved
            est = solve_memory(n, interaction=law)
            cupy.fft.config.get_plan_cache().clear()
            pool.free_all_blocks()
            h = cupy.asarray(h0)
            base = pool.total_bytes()
            t0 = time.perf_counter()
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                r = gfmd.solve(h, tol=1e-6, host=False, **kw)
            cupy.cuda.Device().synchronize()
            wall = time.perf_counter() - t0
            peak = pool.total_bytes()
            rows.append(dict(n=n, law=law, status=r.status, iterations=int(r.iterations), wall_s=round(wall, 3),
                             pool_bytes=int(peak), estimate_bytes=int(est["bytes"]),
                             pool_over_estimate=round(peak / est["bytes"], 4),
                             excess_gb=round((peak - est["bytes"]) / 1e9, 3), heights_bytes=int(base),
                             parts=est["parts"]))
            print(f"n={n} {law}: {r.status} {r.iterations} it {wall:.2f} s; pool {peak / 1e9:.2f} GB, "
                  f"estimate {est['bytes'] / 1e9:.2f} GB ({peak / est['bytes']:.3f})", flush=True)
            del r, h
    a.out.parent.mkdir(parents=True, exist_ok=True)
    a.out.write_text(json.dumps({"gpu": cupy.cuda.runtime.getDeviceProperties(0)["name"].decode(),
                                 "rows": rows}, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    _record.track(CODE_PATHS)
    raise SystemExit(main())
