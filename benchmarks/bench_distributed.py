"""One GFMD solve over 1, 2 and 4 GPUs (gapsweep.gfmd.distributed; docs/gfmd.md "One solve over several
processes", docs/benchmarks.md "One solve over several GPUs"). One MPI rank per GPU; sub-communicators of 1, 2
and 4 ranks run the cases in turn while the other ranks wait.

Run (Python 3.12, cupy, NCCL, mpi4py, Open MPI; from the repository root):

    export NCCL_NVLS_ENABLE=0 NVSHMEM_DISABLE_NVLS=1
    PYTHONPATH=. mpiexec -n 2 python benchmarks/bench_distributed.py --quick --out /tmp/dist_quick.json   # ~30 s
    PYTHONPATH=. mpiexec -n 4 python benchmarks/bench_distributed.py --out benchmarks/results/distributed/h200x4.json
    # only the 65536^2 cases on 4 H200s (exponential and adhesion; adhesion on the lean L-BFGS, 2 pairs: 11
    # arrays of a GPU's rows + 3 of scratch, 120 GB per GPU estimated): ~5-8 minutes
    PYTHONPATH=. mpiexec -n 4 python benchmarks/bench_distributed.py --only-big \
        --out benchmarks/results/distributed/h200x4_challenge.json

(as root add ``--allow-run-as-root``; each rank takes GPU ``local rank % device count``, or set
CUDA_VISIBLE_DEVICES per rank). ``--quick``: correctness only, N = 1024 on 2 GPUs against one GPU (transform,
surface, every law). The full run (budget: under 9 minutes on 4 H200s):

1. quick checks (as above);
2. accuracy: N = 4096 and 8192 on 2 and 4 GPUs against the single-GPU solve (gfmd.solve on a cupy array),
   exponential law to tol 1e-9, adhesion at 4096;
3. strong scaling at N = 16384 and 32768 on 1, 2, 4 GPUs: the distributed FFT pair (forward + inverse) against
   one local cuFFT pair of the same grid (gapsweep.core.fft, one GPU), and the exponential solve for
   ``--scaling-iter`` force evaluations (time per evaluation = wall / evaluations, set-up included), with the
   single-GPU solver beside it where it fits; peak memory per GPU (cupy's pool high-water mark: pool bytes after
   the case, the pool freed before it);
4. the contact-mechanics challenge's constants on ``--big`` (65536)^2 over 4 GPUs, surface made in place:
   E* = 25 MPa, work of adhesion 50 mJ/m^2, range 2.071 nm, L = 0.1 mm, mean pressure 250 kPa, self-affine
   H = 0.8 between lambda_l = 20 um and lambda_s = 0.1 um, rms slope ``--rms-slope`` (1). Units: um and MPa.
   Exponential repulsion (gamma0 = 50 mJ/m^2, rho = 2.071 nm) and adhesion (Rose-Smith-Ferrante law, work 50
   mJ/m^2, rho 2.071 nm; the lean L-BFGS of gfmd._lean with ``--lbfgs-memory`` pairs, 2 by default); a case
   whose memory estimate (gfmd.distributed.solve_memory) exceeds the free GPU memory is recorded as skipped with
   both numbers, and adhesion then runs at ``--big``/2. Memory per GPU, measured beside the estimate: cupy's
   pool after the solve (its high-water mark: the pool keeps freed blocks; emptied before the case) and the
   device memory in use by the end (cudaMemGetInfo: total - free, the pool, cuFFT plans, NCCL and the CUDA
   context), the largest over the GPUs.
   Source and assumptions: the constants as stated by the challenge (Muser et al., Tribol. Lett. 65:118, 2017)
   and used by Adhesion's rough adhesive example on its topography; gapsweep's M2 spectrum has no plateau below
   the roll-off (C = 0 for q < q_l, where the challenge keeps C constant), and the rms slope of 1 is assumed.
   ``--start coarse`` (default): the coarse-to-fine start of gfmd._coarse (docs/gfmd.md "Coarse-to-fine
   start"; automatic levels down to 64 pixels a side, coarse tolerance 10 tol, each level within the same
   evaluation budget); ``iterations``/``s_per_evaluation`` are the 65536^2 grid's, the levels are recorded
   beside them (shape, evaluations, status, residual, wall time; ``coarse_cost`` in 65536^2 evaluations).
   Worst case with the default budgets (500 exponential, 250 adhesive evaluations at 0.24 / 0.65 s, coarse
   levels within the same budgets): about 7 minutes; chosen on the CPU proxy
   (benchmarks/bench_challenge_proxy.py).

JSON to ``--out`` (rank 0 rewrites it after every case, so a run cut short keeps what it measured). A failure
on any rank aborts the job (MPI_Abort) instead of leaving the others waiting in a collective."""

from __future__ import annotations

import argparse
import json
import os
import socket
import sys
import time
import traceback
from pathlib import Path

import numpy as np
from mpi4py import MPI

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import sys as _sys  # noqa: E402
from pathlib import Path as _Path  # noqa: E402

import cupy  # noqa: E402

from gapsweep import gfmd  # noqa: E402
from gapsweep.core import fft as core_fft  # noqa: E402
from gapsweep.core.fft import get_backend  # noqa: E402
from gapsweep.core.slab import SlabFFT  # noqa: E402
from gapsweep.gfmd import _solvers, distributed  # noqa: E402
from gapsweep.gfmd._cuda import solve_memory as single_gpu_memory  # noqa: E402
from gapsweep.gfmd.distributed import solve_memory  # noqa: E402
from gapsweep.surfaces.synthetic import self_affine, self_affine_rows  # noqa: E402

_sys.path.insert(0, str(_Path(__file__).resolve().parent))
import _record  # noqa: E402  (benchmarks/_record.py: the provenance of every result file)

# the code this benchmark measures: a result measured before a later change to it is stale
# (scripts/check_docs.py)
CODE_PATHS = ['gapsweep/gfmd', 'gapsweep/core']

WORLD = MPI.COMM_WORLD
RANK, SIZE = WORLD.Get_rank(), WORLD.Get_size()
RESULTS: dict = {"cases": []}
CHALLENGE = dict(e_star=25.0, work=0.05, rho=2.071e-3, length=100.0, sigma0=0.25, hurst=0.8, lambda_l=20.0,
                 lambda_s=0.1)  # um, MPa (1 MPa um = 1 N/m = 1 J/m^2)


def log(msg: str) -> None:
    if RANK == 0:
        print(f"[{time.strftime('%H:%M:%S')}] {msg}", flush=True)


def save(path: Path) -> None:
    if RANK == 0:
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_suffix(".tmp")
        tmp.write_text(json.dumps(RESULTS, indent=1, default=float))
        os.replace(tmp, path)


def sync(comm) -> None:
    cupy.cuda.get_current_stream().synchronize()
    comm.Barrier()


def fresh() -> None:
    """Drop every cached GPU buffer: cupy's FFT plans, gapsweep's planned single-GPU FFT backends (their buffers)
    and cached |q| arrays, then the memory pool's free blocks (the pool's size afterwards is what is in use)."""
    core_fft._PLANS.clear()
    _solvers._half_q_cached.cache_clear()
    cupy.fft.config.get_plan_cache().clear()
    cupy.get_default_memory_pool().free_all_blocks()


def peak(comm) -> float:
    """Largest cupy pool size (bytes) over the ranks of ``comm``: the high-water mark since :func:`fresh`."""
    return comm.allreduce(float(cupy.get_default_memory_pool().total_bytes()), op=MPI.MAX)


def device_used(comm) -> float:
    """Largest device memory in use over the ranks of ``comm`` (cudaMemGetInfo: total - free)."""
    free, total = cupy.cuda.runtime.memGetInfo()
    return comm.allreduce(float(total - free), op=MPI.MAX)


def free_bytes(comm) -> float:
    return comm.allreduce(float(cupy.cuda.runtime.memGetInfo()[0]), op=MPI.MIN)


def case(out: Path, name: str, ranks: int, subs: dict, fn, **info) -> dict | None:
    """Run ``fn(sub)`` on the first ``ranks`` ranks; rank 0's return value is recorded. Collective on WORLD."""
    if ranks not in subs:
        log(f"{name}: skipped, needs {ranks} ranks")
        return None
    sub = subs[ranks]
    res = None
    t0 = time.perf_counter()
    fresh()
    if sub != MPI.COMM_NULL:
        try:
            res = fn(sub)
        except Exception:  # a rank that fails would leave the others waiting in a collective
            traceback.print_exc()
            sys.stdout.flush()
            sys.stderr.flush()
            WORLD.Abort(1)
    res = WORLD.bcast(res, root=0)
    fresh()
    WORLD.Barrier()
    if res is not None:
        res = {"case": name, "gpus": ranks, **info, **res, "case_wall_s": time.perf_counter() - t0}
        RESULTS["cases"].append(res)
        log(f"{name} on {ranks} GPU(s): " + ", ".join(f"{k}={v:.4g}" if isinstance(v, float) else f"{k}={v}"
                                                      for k, v in res.items() if k not in ("case", "history")))
        save(out)
    return res


def surface(n: int, comm=None, **kw):
    # lambda_s = 8 pixels up to 8192^2, then 1/1024 (the mode set, made on the host by every rank, stays ~1.6M)
    p = dict(hurst=0.8, lambda_l=0.25, lambda_s=max(8.0 / n, 1.0 / 1024), rms_slope=1.0, seed=1)
    p.update(kw)
    if comm is None:
        return self_affine(n, backend="cupy", **p)
    return self_affine_rows(n, comm=comm, backend="cupy", **p)


def law_kw(law: str, n: int) -> dict:
    if law == "exponential":
        return dict(interaction="exponential", sigma0=1e-2, gamma0=1e-3, rho=2.0 / n)
    if law == "adhesive":
        return dict(interaction="adhesive", sigma0=1e-2, work=2e-4, rho=2.0 / n)
    return dict(interaction="hard_wall", sigma0=1e-2)


def summary(r) -> dict:
    return {"mean_gap": float(r.mean_gap), "contact_area": float(r.contact_area),
            "elastic_energy": float(r.elastic_energy), "iterations": int(r.iterations), "status": r.status,
            "residual": float(r.residual), "wall_s": float(r.wall_time)}


def compare(single: dict, dist: dict) -> dict:
    return {"d_mean_gap_rel": abs(dist["mean_gap"] - single["mean_gap"]) / abs(single["mean_gap"]),
            "d_contact_area": abs(dist["contact_area"] - single["contact_area"]),
            "d_elastic_rel": abs(dist["elastic_energy"] - single["elastic_energy"]) / abs(single["elastic_energy"])}


# ------------------------------------------------------------------------------------------------ cases
def quick(out: Path, subs: dict, n: int = 1024) -> None:
    ranks = 2 if 2 in subs else 1

    def transform(sub):
        a = cupy.random.default_rng(3).standard_normal((n, n))
        f = SlabFFT((n, n), sub, backend="cupy")
        A = f.rfft2(a[f.row])
        ref = cupy.fft.rfft2(a).T[f.col]
        fwd = float(cupy.abs(A - ref).max() / cupy.abs(ref).max())
        back = float(cupy.abs(f.irfft2(A) / a.size - a[f.row]).max() / cupy.abs(a).max())
        return {"forward_rel": sub.allreduce(fwd, op=MPI.MAX), "inverse_rel": sub.allreduce(back, op=MPI.MAX)}

    case(out, "quick transform vs cupy rfft2", ranks, subs, transform, n=n)

    def surf(sub):
        h = surface(n)
        hl = surface(n, sub)
        rows = gfmd.slab_rows(n, sub)
        d = float(cupy.abs(hl - h[rows]).max() / cupy.sqrt(cupy.mean(h * h)))
        return {"surface_diff_over_hrms": sub.allreduce(d, op=MPI.MAX)}

    case(out, "quick surface vs single-GPU generator", ranks, subs, surf, n=n)
    for law in ("exponential", "adhesive", "hard_wall"):
        case(out, f"quick {law} vs single GPU", ranks, subs, lambda sub, law=law: _versus_single(sub, n, law, 1e-9),
             n=n, law=law)


def _versus_single(sub, n: int, law: str, tol: float, max_iter: int = 3000) -> dict:
    kw = dict(law_kw(law, n), tol=tol, max_iter=max_iter, host=False)
    single = None
    if sub.Get_rank() == 0:
        single = summary(gfmd.solve(surface(n), **kw))
    fresh()
    sync(sub)
    h = surface(n, sub)
    r = gfmd.solve(h, comm=sub, **kw)
    dist = summary(r)
    if sub.Get_rank() != 0:
        return None
    return {"single": single, "distributed": dist, **compare(single, dist),
            "exchanges": r.diagnostics["exchanges"], "reductions": r.diagnostics["reductions"]}


def accuracy(out: Path, subs: dict, sizes: list[int]) -> None:
    for n in sizes:
        for ranks in (2, 4):
            case(out, "accuracy exponential", ranks, subs,
                 lambda sub, n=n: _versus_single(sub, n, "exponential", 1e-9), n=n, law="exponential")
        if n == sizes[0]:
            for ranks in (2, 4):
                case(out, "accuracy adhesive", ranks, subs,
                     lambda sub, n=n: _versus_single(sub, n, "adhesive", 1e-9), n=n, law="adhesive")


def _fft_pair(sub, n: int, reps: int = 5) -> dict:
    f = SlabFFT((n, n), sub, backend="cupy")
    a = cupy.random.default_rng(1).standard_normal(f.real_shape)
    for _ in range(2):
        a2 = f.irfft2(f.rfft2(a))
    del a2
    sync(sub)
    t0 = time.perf_counter()
    for _ in range(reps):
        b = f.irfft2(f.rfft2(a))
        del b
    sync(sub)
    t = (time.perf_counter() - t0) / reps
    return {"fft_pair_s": t, "fft_peak_bytes_per_gpu": peak(sub)}


def _local_pair(n: int, reps: int = 5) -> float:
    fft = get_backend("cupy", n)
    a = cupy.random.default_rng(1).standard_normal((n, n))
    for _ in range(2):
        fft.irfft2(fft.rfft2(a))
    cupy.cuda.get_current_stream().synchronize()
    t0 = time.perf_counter()
    for _ in range(reps):
        fft.irfft2(fft.rfft2(a))
    cupy.cuda.get_current_stream().synchronize()
    return (time.perf_counter() - t0) / reps


def scaling(out: Path, subs: dict, sizes: list[int], iters: int) -> None:
    for n in sizes:
        def one_gpu(sub, n=n):
            res = {"local_cufft_pair_s": _local_pair(n)}
            fresh()
            need = single_gpu_memory(n)["bytes"]
            if need < 0.95 * free_bytes(sub):
                r = gfmd.solve(surface(n), **law_kw("exponential", n), tol=1e-12, max_iter=iters, host=False)
                res.update({"single_gpu_solver_s": r.wall_time, "single_gpu_evaluations": r.iterations,
                            "single_gpu_s_per_evaluation": r.wall_time / r.iterations,
                            "single_gpu_peak_bytes": peak(sub)})
            else:
                res["single_gpu_solver"] = f"skipped: needs {need / 1e9:.1f} GB"
            return res

        local = case(out, "local cuFFT pair and single-GPU solver", 1, subs, one_gpu, n=n) or {}
        for ranks in (1, 2, 4):
            def run(sub, n=n):
                res = _fft_pair(sub, n)
                fresh()
                est = solve_memory((n, n), sub.Get_size(), "exponential")["bytes_per_rank"]
                if est > 0.97 * free_bytes(sub):
                    res["solve"] = f"skipped: estimate {est / 1e9:.1f} GB per GPU > free"
                    return res
                h = surface(n, sub)
                r = gfmd.solve(h, comm=sub, **law_kw("exponential", n), tol=1e-12, max_iter=iters, host=False)
                sync(sub)
                res.update({"solve_wall_s": r.wall_time, "evaluations": r.iterations,
                            "s_per_evaluation": r.wall_time / r.iterations, "peak_bytes_per_gpu": peak(sub),
                            "device_used_bytes_per_gpu": device_used(sub),
                            "estimate_bytes_per_gpu": est, "exchanges": r.diagnostics["exchanges"],
                            "reductions": r.diagnostics["reductions"]})
                return res

            res = case(out, "strong scaling exponential", ranks, subs, run, n=n,
                       local_cufft_pair_s=local.get("local_cufft_pair_s"))
            if res and local.get("local_cufft_pair_s"):
                res["fft_pair_over_local"] = res["fft_pair_s"] / local["local_cufft_pair_s"]
                save(out)


def hard_wall_big(out: Path, subs: dict, n: int, ranks: int, max_iter: int, tol: float) -> None:
    """The hard wall (method pcg) at ``n``^2 on ``ranks`` GPUs, surface made in place: time, iterations, status,
    memory per GPU beside the estimate. One GPU's plan for this grid is printed beside it (does it fit one?)."""
    est = solve_memory((n, n), ranks, "hard_wall")["bytes_per_rank"]

    def run(sub):
        if est > 0.97 * free_bytes(sub):
            return {"skipped": f"estimate {est / 1e9:.1f} GB per GPU > free {free_bytes(sub) / 1e9:.1f} GB"}
        t0 = time.perf_counter()
        h = surface(n, sub)
        sync(sub)
        t_surf = time.perf_counter() - t0
        r = gfmd.solve(h, comm=sub, **law_kw("hard_wall", n), tol=tol, max_iter=max_iter, host=False)
        sync(sub)
        return {**summary(r), "surface_s": t_surf, "s_per_iteration": r.wall_time / max(r.iterations, 1),
                "peak_bytes_per_gpu": peak(sub), "device_used_bytes_per_gpu": device_used(sub),
                "estimate_bytes_per_gpu": est, "tol": tol}

    case(out, "hard wall big", ranks, subs, run, n=n, sigma0=1e-2,
         single_gpu_estimate_bytes=single_gpu_memory(n, interaction="hard_wall")["bytes"])


def challenge(out: Path, subs: dict, n: int, rms_slope: float, exp_iter: int, adh_iter: int, tol: float,
              lambda_s: float, ranks: int, pairs: int, laws: tuple[str, ...], start: str = "coarse",
              levels: int | None = None, length: float | None = None) -> None:
    # --length: a box of the challenge's pixel size at a smaller N (e.g. 50 um at 32768^2 on 2 GPUs: the same
    # dx = 1.526 nm, spectrum and constants on a quarter of the challenge's area)
    c = dict(CHALLENGE, lambda_s=lambda_s, length=CHALLENGE["length"] if length is None else length)

    def run(sub, n, law, max_iter):
        fresh()
        m = solve_memory((n, n), sub.Get_size(), law, memory=pairs)
        est, arr = m["bytes_per_rank"], m["array_bytes"]
        free = free_bytes(sub)
        if est > 0.97 * free:
            return {"skipped": True, "estimate_bytes_per_gpu": est, "free_bytes_per_gpu": free}
        sync(sub)
        t0 = time.perf_counter()
        h = self_affine_rows(n, c["hurst"], comm=sub, lambda_l=c["lambda_l"], lambda_s=c["lambda_s"],
                             length=c["length"], rms_slope=rms_slope, seed=1, backend="cupy")
        sync(sub)
        t_surface = time.perf_counter() - t0
        params = dict(gamma0=c["work"]) if law == "exponential" else dict(work=c["work"], memory=pairs)
        r = distributed.solve(h, comm=sub, interaction=law, rho=c["rho"], sigma0=c["sigma0"], e_star=c["e_star"],
                              length=c["length"], tol=tol, max_iter=max_iter, host=False, start=start,
                              levels=levels, **params)
        sync(sub)
        pool, used = peak(sub), device_used(sub)
        lv = r.diagnostics.get("levels") or []
        fine_s = r.wall_time - sum(x["wall_s"] for x in lv)  # the requested grid's part (coarse levels apart)
        return {"skipped": False, "surface_s": t_surface, **summary(r), "s_per_evaluation": fine_s / r.iterations,
                "start": start, "levels": lv, "coarse_cost": r.diagnostics.get("coarse_cost", 0.0),
                "coarse_wall_s": sum(x["wall_s"] for x in lv),
                "peak_bytes_per_gpu": pool, "device_used_bytes_per_gpu": used, "estimate_bytes_per_gpu": est,
                "pool_peak_over_estimate": pool / est, "array_bytes_per_gpu": arr,
                "lbfgs_memory": pairs if law == "adhesive" else None, "mean_gap_nm": 1e3 * r.mean_gap,
                "dx_nm": 1e3 * c["length"] / n, "rho_over_dx": c["rho"] / (c["length"] / n)}

    info = dict(constants=c, rms_slope=rms_slope, tol=tol, units="um, MPa", lbfgs_memory=pairs)
    if "exponential" in laws:
        case(out, "challenge exponential", ranks, subs, lambda sub: run(sub, n, "exponential", exp_iter), n=n,
             **info)
    if "adhesive" not in laws:
        return
    res = case(out, "challenge adhesive", ranks, subs, lambda sub: run(sub, n, "adhesive", adh_iter), n=n, **info)
    if res and res.get("skipped"):
        case(out, "challenge adhesive", ranks, subs, lambda sub: run(sub, n // 2, "adhesive", adh_iter), n=n // 2,
             **info)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", required=True, type=Path)
    ap.add_argument("--quick", action="store_true", help="correctness at N=1024 on 2 GPUs only (seconds)")
    ap.add_argument("--quick-n", type=int, default=1024, help="grid of the correctness checks")
    ap.add_argument("--accuracy-sizes", type=int, nargs="*", default=[4096, 8192])
    ap.add_argument("--sizes", type=int, nargs="*", default=[16384, 32768], help="strong-scaling grids")
    ap.add_argument("--scaling-iter", type=int, default=30)
    ap.add_argument("--big", type=int, default=65536)
    ap.add_argument("--big-iter", type=int, default=500, help="force evaluations allowed, exponential at --big")
    ap.add_argument("--adhesive-iter", type=int, default=250, help="force evaluations allowed, adhesion at --big "
                    "(each coarse level of --start coarse may take as many of its own grid)")
    ap.add_argument("--start", default="coarse", choices=["coarse", "flat"],
                    help="start of the challenge solves: coarse-to-fine (default) or the plain start")
    ap.add_argument("--levels", type=int, default=None, help="coarse levels of --start coarse (default: automatic)")
    ap.add_argument("--big-tol", type=float, default=1e-6)
    ap.add_argument("--rms-slope", type=float, default=1.0)
    ap.add_argument("--lambda-s", type=float, default=CHALLENGE["lambda_s"], help="short cut-off (um)")
    ap.add_argument("--skip-big", action="store_true")
    ap.add_argument("--only-big", action="store_true", help="only the challenge cases (after the quick checks)")
    ap.add_argument("--big-ranks", type=int, default=4, help="GPUs of the challenge cases (4, or 8 on 8 GPUs)")
    ap.add_argument("--big-laws", nargs="+", default=["exponential", "adhesive"], choices=["exponential", "adhesive"])
    ap.add_argument("--length", type=float, default=None,
                    help="box side (um) of the challenge cases (default the challenge's 100 um)")
    ap.add_argument("--hardwall-n", type=int, default=0, help="the hard wall at this N (0: not run), e.g. 32768")
    ap.add_argument("--hardwall-ranks", type=int, default=2, help="GPUs of the --hardwall-n case")
    ap.add_argument("--hardwall-iter", type=int, default=1000)
    ap.add_argument("--lbfgs-memory", type=int, default=2, help="L-BFGS pairs of the adhesive solves (lean path)")
    args = ap.parse_args()

    local = int(os.environ.get("OMPI_COMM_WORLD_LOCAL_RANK", os.environ.get("MPI_LOCALRANKID", RANK)))
    ndev = cupy.cuda.runtime.getDeviceCount()
    cupy.cuda.Device(local % ndev).use()
    props = cupy.cuda.runtime.getDeviceProperties(local % ndev)
    names = WORLD.gather(props["name"].decode() if isinstance(props["name"], bytes) else str(props["name"]))
    RESULTS.update({"command": " ".join(sys.argv), "ranks": SIZE, "host": socket.gethostname(), "gpus": names,
                    "date": time.strftime("%Y-%m-%d %H:%M:%S %Z"), "cupy": cupy.__version__,
                    "nccl": cupy.cuda.nccl.get_version() if hasattr(cupy.cuda, "nccl") else None,
                    "python": sys.version.split()[0], "numpy": np.__version__})
    subs = {}
    for p in sorted({1, 2, 4, args.big_ranks, args.hardwall_ranks}):
        if p <= SIZE:
            subs[p] = WORLD.Split(0 if RANK < p else MPI.UNDEFINED, RANK)
    t0 = time.perf_counter()
    log(f"{SIZE} ranks, GPUs {names}")
    quick(args.out, subs, args.quick_n)
    if not args.quick:
        if not args.only_big:
            accuracy(args.out, subs, args.accuracy_sizes)
            scaling(args.out, subs, args.sizes, args.scaling_iter)
        if args.hardwall_n:
            hard_wall_big(args.out, subs, args.hardwall_n, args.hardwall_ranks, args.hardwall_iter, 1e-6)
        if not args.skip_big:
            challenge(args.out, subs, args.big, args.rms_slope, args.big_iter, args.adhesive_iter, args.big_tol,
                      args.lambda_s, args.big_ranks if args.big_ranks in subs else max(subs), args.lbfgs_memory,
                      tuple(args.big_laws), args.start, args.levels, args.length)
    RESULTS["total_wall_s"] = time.perf_counter() - t0
    save(args.out)
    log(f"done in {RESULTS['total_wall_s']:.1f} s -> {args.out}")


if __name__ == "__main__":
    _record.track(CODE_PATHS)
    main()
