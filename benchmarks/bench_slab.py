"""The slab transform's FFT pair (gapsweep.core.slab.SlabFFT: forward + inverse) on 1..P GPUs against one local
cuFFT pair of the whole grid (gapsweep.core.fft on one GPU), with the tiled transpose kernel and with cupy's
strided copy, side by side in one run (docs/benchmarks.md, "One solve over several GPUs").

    PYTHONPATH=. mpiexec -n 2 python benchmarks/bench_slab.py --sizes 16384 32768 --out slab.json

(as root add ``--allow-run-as-root``; one rank per GPU, ``NCCL_NVLS_ENABLE=0``). JSON to ``--out`` (rank 0)."""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

from mpi4py import MPI

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import sys as _sys  # noqa: E402
from pathlib import Path as _Path  # noqa: E402

import cupy  # noqa: E402

from gapsweep.core import slab  # noqa: E402
from gapsweep.core.fft import get_backend  # noqa: E402

_sys.path.insert(0, str(_Path(__file__).resolve().parent))
import _record  # noqa: E402  (benchmarks/_record.py: the provenance of every result file)

# the code this benchmark measures: a result measured before a later change to it is stale
# (scripts/check_docs.py)
CODE_PATHS = ['gapsweep/core/slab.py', 'gapsweep/core/fft.py']

WORLD = MPI.COMM_WORLD


def timed(fft, a, comm, reps: int) -> float:
    """Seconds per forward + inverse pair of ``fft`` (a SlabFFT or a local backend) on ``a``."""
    for _ in range(2):
        fft.irfft2(fft.rfft2(a))
    cupy.cuda.get_current_stream().synchronize()
    comm.Barrier()
    t0 = time.perf_counter()
    for _ in range(reps):
        fft.irfft2(fft.rfft2(a))
    cupy.cuda.get_current_stream().synchronize()
    comm.Barrier()
    return (time.perf_counter() - t0) / reps


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", type=int, nargs="+", default=[16384])
    ap.add_argument("--reps", type=int, default=5)
    ap.add_argument("--out", type=Path, required=True)
    args = ap.parse_args()
    rank, size = WORLD.Get_rank(), WORLD.Get_size()
    cupy.cuda.Device(rank % cupy.cuda.runtime.getDeviceCount()).use()
    rows = []
    for n in args.sizes:
        if rank == 0:
            fft = get_backend("cupy", n)
            a = cupy.random.default_rng(1).standard_normal((n, n))
            local = timed(fft, a, MPI.COMM_SELF, args.reps)
            del a, fft
            cupy.get_default_memory_pool().free_all_blocks()
        local = WORLD.bcast(local if rank == 0 else None)
        for p in range(1, size + 1):
            sub = WORLD.Split(0 if rank < p else MPI.UNDEFINED, rank)
            res = {}
            if sub != MPI.COMM_NULL:
                f = slab.SlabFFT((n, n), sub, backend="cupy")
                a = cupy.random.default_rng(1).standard_normal(f.real_shape)
                for tiled in (False, True):
                    slab.TILED_TRANSPOSE = tiled
                    res["tiled" if tiled else "strided"] = timed(f, a, sub, args.reps)
                del a, f
                cupy.get_default_memory_pool().free_all_blocks()
                sub.Free()
            res = WORLD.bcast(res, root=0)
            row = {"n": n, "gpus": p, "local_cufft_pair_s": local, "pair_strided_s": res["strided"],
                   "pair_tiled_s": res["tiled"], "tiled_over_local": res["tiled"] / local,
                   "strided_over_local": res["strided"] / local}
            rows.append(row)
            if rank == 0:
                print(json.dumps(row), flush=True)
            WORLD.Barrier()
    if rank == 0:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        name = cupy.cuda.runtime.getDeviceProperties(0)["name"]
        args.out.write_text(json.dumps({"command": " ".join(sys.argv), "ranks": size, "gpu": str(name),
                                        "date": time.strftime("%Y-%m-%d %H:%M:%S %Z"), "rows": rows}, indent=1,
                                       default=str))


if __name__ == "__main__":
    _record.track(CODE_PATHS)
    main()
