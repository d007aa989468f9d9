"""Memory per rank of a distributed GFMD job's surface and kept fields on the CPU (numpy arrays traced by
tracemalloc), in units of the whole surface (8 n^2 bytes): the surface made in place by
``Context.surface_rows`` (gapsweep.sweep.slabs: ``self_affine_rows`` and the reduced h_rms/g_rms), its peak while
made and what stays held; rank 0's peak while the rank-0 writer (``fields.write_field_rows``) writes four fields
with the default row chunks (64 MiB; at these sizes a rank's whole slab fits one chunk, so the bound shown is the
slab's) and with 64 kB chunks. One run per rank count; the results of several runs go into one file.

Run (from the repository root; ~20 s on 2 cores):

    for P in 1 2 3 4; do PYTHONPATH=. mpiexec -n $P python benchmarks/mem_slab_surface.py --n 1024 \
        --out benchmarks/results/distributed/slab_surface_memory.json; done
"""

from __future__ import annotations

import argparse
import json
import platform
import sys as _sys
import tempfile
import time
import tracemalloc
from pathlib import Path
from pathlib import Path as _Path

import numpy as np
from mpi4py import MPI

from gapsweep.sweep import fields, slabs
from gapsweep.sweep import spec as specmod
from gapsweep.sweep.context import Context
from gapsweep.sweep.runner import _select

_sys.path.insert(0, str(_Path(__file__).resolve().parent))
import _record

# the code this benchmark measures: a result measured before a later change to it is stale
# (scripts/check_docs.py)
CODE_PATHS = ['gapsweep/sweep/slabs.py', 'gapsweep/sweep/fields.py', 'gapsweep/sweep/context.py']

JOB = """
[job]
name = "mem"
[grid]
hurst = [0.8]
rho = [2e-2]
sigma0 = [1e-2]
seeds = [0]
[surface]
lambda_l = 0.25
lambda_s = 0.0625
rms_slope = 1.0
[material]
gamma0 = 1e-3
[methods.gfmd]
n = {n}
backend = "numpy"
distributed = true
"""


def traced(fn) -> tuple[float, float, object]:
    tracemalloc.start()
    base = tracemalloc.get_traced_memory()[0]
    out = fn()
    cur, peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    return peak - base, cur - base, out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", required=True)
    ap.add_argument("--n", type=int, default=1024)
    args = ap.parse_args()
    comm = MPI.COMM_WORLD
    n = args.n
    d = comm.bcast(tempfile.mkdtemp() if comm.Get_rank() == 0 else None, root=0)
    (Path(d) / "j.toml").write_text(JOB.format(n=n)) if comm.Get_rank() == 0 else None
    comm.Barrier()
    t = _select(specmod.load(Path(d) / "j.toml"), None)[0][0]
    ctx = Context(rank=comm.Get_rank())
    peak, held, h = traced(lambda: (ctx.surface_rows(t, n, comm), ctx.surface_rows_rms(t, n, comm))[0])
    rows = {k: np.asarray(h) + i for i, k in enumerate(("displacement", "gap", "height", "pressure"))}
    writes = {}
    for k, (label, chunk) in enumerate((("default", slabs.CHUNK_BYTES), ("64kB", 64 << 10))):
        slabs.CHUNK_BYTES = chunk
        wpeak, _, _ = traced(lambda k=k: fields.write_field_rows(d, f"{k:016x}", rows, shape=(n, n), comm=comm,
                                                                 writer="rank0", length=1.0, attrs={"n": n}))
        writes[label] = {"chunk_bytes": chunk, "rank0_peak_bytes": comm.bcast(wpeak, root=0)}
    whole = 8.0 * n * n
    got = comm.gather((peak / whole, held / whole), root=0)
    if comm.Get_rank() == 0:
        P = comm.Get_size()
        row = {"ranks": P, "n": n, "surface_peak_per_rank": max(g[0] for g in got),
               "surface_held_per_rank": max(g[1] for g in got), "whole_surface_bytes": whole,
               "slab_bytes": 8.0 * -(-n // P) * n, "rank0_writer": writes}
        out = Path(args.out)
        data = json.loads(out.read_text()) if out.exists() else {"runs": []}
        data.update({"command": "for P in 1 2 3 4; do mpiexec -n $P python benchmarks/mem_slab_surface.py "
                                f"--n {n} --out {args.out}; done", "machine": platform.node(),
                     "cpu": platform.processor(), "date": time.strftime("%Y-%m-%d %H:%M:%S %Z")})
        data["runs"] = [r for r in data["runs"] if (r["ranks"], r["n"]) != (P, n)] + [row]
        out.write_text(json.dumps(data, indent=1))
        print(row)


if __name__ == "__main__":
    _record.track(CODE_PATHS)
    main()
