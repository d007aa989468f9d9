"""GPU benchmark of the gap SDE (docs/model.md M5): 10^7 realisations, zeta 1 -> 100, dzeta = 0.01 (9,900 steps).

Times are warm (the first call, which compiles the kernel, is excluded) and include everything a user call
does: the host-side step plan, coefficient upload, the kernel, binning on the device and the copy of the counts.
The paper: 10^7 realisations in about 20 s on an RTX 4090D.

Kernel limit (issue 14, ``--limit``, needs cupy): the headline case (float32, 9,900 steps, histogram) side by
side with hand-written CUDA kernels of the same step count built with -use_fast_math
(benchmarks/sde_reference.cu): the plain cuRAND Euler-Maruyama kernel, the same with a hand-written Philox, and
the split step written in CUDA; each warp log1p variant (gapsweep._sde_kernels.VARIANTS) is timed too when warp is
installed (without warp the CUDA rows and gapsweep's CUDA engine are timed, the warp rows are left out and said so).
Times are the median of ``--repeat`` warm launches + count copies (events-free: synchronize, then the host clock).
The user-call cases need warp only for the paper's Euler-Maruyama scheme (skipped without it).

    python benchmarks/bench_sde_gpu.py --out results/sde_gpu            # on the GPU machine
    python benchmarks/bench_sde_gpu.py --out results/sde_gpu --limit --cases none   # kernel limit only
    python benchmarks/bench_sde_gpu.py --device cpu --n 20000 --out /tmp/x   # smoke test on the CPU
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import math
import os
import statistics
import sys as _sys
import time
from pathlib import Path
from pathlib import Path as _Path

import numpy as np

from gapsweep import sde

_sys.path.insert(0, str(_Path(__file__).resolve().parent))
import _record

# the code this benchmark measures: a result measured before a later change to it is stale
# (scripts/check_docs.py)
CODE_PATHS = ['gapsweep/gapdist']

PAPER_SECONDS = 20.0


def have_warp() -> bool:
    """Whether warp can be imported (the CUDA engine and the --limit reference kernels need only cupy)."""
    return importlib.util.find_spec("warp") is not None


def device_sync_and_name(device: str) -> tuple:
    """``(synchronize, name)`` of ``device``: through warp when installed, else through cupy (issue 22, item 7:
    --limit ran only with warp installed although it times cupy kernels)."""
    if have_warp() and not device.startswith("cpu"):
        import warp as wp

        wp.config.log_level = 30
        wp.init()
        return (lambda: wp.synchronize_device(device)), wp.get_device(device).name
    if have_warp():
        import warp as wp

        wp.config.log_level = 30
        wp.init()
        return (lambda: None), wp.get_device(device).name
    if device.startswith("cpu"):
        raise SystemExit("--device cpu runs the warp kernels: install warp (pip install warp-lang)")
    import cupy as cp

    idx = int(device.split(":", 1)[1]) if ":" in device else 0
    dev = cp.cuda.Device(idx)
    return dev.synchronize, cp.cuda.runtime.getDeviceProperties(idx)["name"].decode()


def fig6_h_rms(c0: float = 8e-6, hurst: float = 0.3, lambda_l: float = 0.25, lambda_s: float = 2.5e-3) -> float:
    """h_rms of the paper's Fig. 6 spectrum (C0/L^4 = 8e-6), continuum form of M2."""
    ql = 2 * math.pi / lambda_l
    zs = lambda_l / lambda_s
    return math.sqrt(c0 * ql**2 / (2 * math.pi) * (1 - zs ** (-2 * hurst)) / (2 * hurst))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", required=True, type=Path)
    ap.add_argument("--device", default="cuda:0")
    ap.add_argument("--n", type=int, default=10**7)
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--bins", type=int, default=200)
    ap.add_argument("--limit", action="store_true", help="also time the kernel limit (issue 14; needs cupy)")
    ap.add_argument("--cases", default="all", choices=("all", "none"), help="the six user-call cases")
    args = ap.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)

    sync, name = device_sync_and_name(args.device)
    fig6 = dict(hurst=0.3, h_rms=fig6_h_rms(), rho=2e-3, gamma0=1e-3, lambda_l=0.25, lambda_s=2.5e-3)
    stiff = dict(hurst=0.3, h_rms=2.34e-3, rho=5e-4, gamma0=1e-3, lambda_l=0.25, lambda_s=2.5e-3)
    cases = [
        ("fig6 s0=1e-4 C2=0.5, uniform dz=0.01, float32 (headline)", fig6, 1e-4, 0.5, 0.01, "uniform", "float32",
         "split"),
        ("fig6 s0=1e-4 C2=0, uniform dz=0.01, float32", fig6, 1e-4, 0.0, 0.01, "uniform", "float32", "split"),
        ("fig6 s0=1e-4 C2=0.5, uniform dz=0.01, float64", fig6, 1e-4, 0.5, 0.01, "uniform", "float64", "split"),
        ("fig6 s0=1e-4 C2=0.5, log dz=0.01 (463 steps), float32", fig6, 1e-4, 0.5, 0.01, "log", "float32",
         "split"),
        ("fig6 s0=1e-4 C2=0.5, paper's Euler-Maruyama, uniform dz=0.01, float32", fig6, 1e-4, 0.5, 0.01,
         "uniform", "float32", "euler"),
        ("M7 stiff rho=5e-4 C2=1 s0=1e-2, uniform dz=0.01, float32", stiff, 1e-2, 1.0, 0.01, "uniform",
         "float32", "split"),
    ]
    rows = []
    if args.limit:
        kernel_limit(args, fig6, name, sync)
    for label, p, s0, c2, dz, steps, dtype, scheme in (cases if args.cases == "all" else []):
        if scheme != "split" and not have_warp():
            print(f"skipped (needs warp): {label}", flush=True)
            continue
        kw = dict(p, c2=c2, dzeta=dz, steps=steps, dtype=dtype, scheme=scheme, n=args.n, device=args.device,
                  bins=args.bins, seed=1)
        t = time.perf_counter()
        sde.gap_histogram_counts(s0, **kw)  # compile + first run
        first = time.perf_counter() - t
        times, kernel_times = [], []
        for rep in range(args.repeat):
            sync()
            t = time.perf_counter()
            r = sde.gap_histogram_counts(s0, **{**kw, "seed": 2 + rep})
            times.append(time.perf_counter() - t)
            kernel_times.append(r.wall_time)
        steps_n = r.plan.n_steps
        best = min(times)
        rows.append(dict(case=label, device=name, n=args.n, n_steps=steps_n, dtype=dtype, steps=steps, scheme=scheme,
                         first_call_s=first, best_s=best, median_s=statistics.median(times),
                         launch_and_copy_best_s=min(kernel_times),
                         particle_steps_per_s=args.n * steps_n / best,
                         speedup_vs_paper_20s=PAPER_SECONDS * (steps_n / 9900) / best if steps == "uniform" else
                         PAPER_SECONDS / best,
                         nonfinite=r.nonfinite, outside=r.below + r.above,
                         mean=float(np.sum(0.5 * (r.edges[1:] + r.edges[:-1]) * r.counts) / max(r.counts.sum(), 1))))
        print(json.dumps(rows[-1]), flush=True)
    if not rows:
        return
    (args.out / "bench_sde_gpu.json").write_text(json.dumps(rows, indent=1))
    lines = [f"# SDE GPU benchmark on {name} (n = {args.n:.0e}, warm, best of {args.repeat})", "",
             "| case | steps | time best [s] | median [s] | particle-steps/s | speed-up vs paper 20 s |",
             "| --- | --- | --- | --- | --- | --- |"]
    for r in rows:
        lines.append(f"| {r['case']} | {r['n_steps']} | {r['best_s']:.3f} | {r['median_s']:.3f} | "
                     f"{r['particle_steps_per_s']:.2e} | {r['speedup_vs_paper_20s']:.0f}x |")
    (args.out / "bench_sde_gpu.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


def _median_time(fn, repeat: int, sync) -> float:
    fn()  # warm-up (compilation, first launch)
    times = []
    for _ in range(repeat):
        sync()
        t = time.perf_counter()
        fn()
        sync()
        times.append(time.perf_counter() - t)
    return statistics.median(times)


def kernel_limit(args, fig6: dict, gpu_name: str, device_sync) -> None:
    """Headline case: gapsweep's CUDA engine and (with warp installed) the warp split kernel, each log1p variant,
    vs hand-written fast-math CUDA kernels. Needs cupy only."""
    import cupy as cp

    warp = have_warp()
    if warp:
        from gapsweep.gapdist import _sde_kernels as K
    else:
        print("warp not installed: the warp rows are left out (CUDA engine and reference kernels only)", flush=True)

    s0, c2, n, nb = 1e-4, 0.5, args.n, args.bins
    kw = dict(fig6, c2=c2, dzeta=0.01, steps="uniform", dtype="float32", scheme="split", n=n, device=args.device,
              bins=nb, seed=1)
    plan = sde.plan_steps(s0, **{k: kw[k] for k in ("hurst", "h_rms", "rho", "gamma0", "lambda_l", "lambda_s")},
                          c2=c2, dzeta=0.01)
    edges = sde._default_edges(plan, nb)
    y_edges = (edges - plan.g0_end).astype(np.float32)
    lo, hi = float(y_edges[0]), float(y_edges[-1])
    inv_w = nb / (hi - lo)
    src = (Path(__file__).with_name("sde_reference.cu")).read_text()
    opts = ("-use_fast_math", "--std=c++17")
    mods = {"philox": cp.RawModule(code=src, options=opts)}
    try:
        inc = [f"-I{p}" for p in (os.environ.get("CUDA_PATH", "/usr/local/cuda") + "/include",) if os.path.isdir(p)]
        mods["curand"] = cp.RawModule(code="#define WITH_CURAND\n" + src, options=(*opts, *inc))
        mods["curand"].get_function("plain_em_curand")
    except Exception as exc:  # header not found: the hand-written Philox plain kernel stands in
        print(f"cuRAND kernel not built ({type(exc).__name__}: {str(exc)[:200]})", flush=True)
        mods.pop("curand", None)
    f32 = lambda a: cp.asarray(np.asarray(a, dtype=np.float32))  # noqa: E731
    drift, sd, cdz = plan.euler
    sd_d, drift_d, cdz_d = f32(sd), f32(drift), f32(cdz)
    counts = cp.zeros(nb + 3, dtype=cp.uint64)
    block = 256
    grid = ((n + block - 1) // block,)
    shmem = 4 * (nb + 3)

    def launcher(mod, kname):
        fn = mod.get_function(kname)

        def run():
            counts.fill(0)
            fn(grid, (block,), (np.int64(n), np.uint64(1), np.int32(plan.n_steps), sd_d, drift_d, cdz_d,
                                np.float32(1 / plan.rho), np.float32(plan.g0[0]), np.float32(plan.g0_end),
                                np.float32(lo), np.float32(inv_w), np.float32(hi), np.int32(nb), counts),
               shared_mem=shmem)
            counts.get()
        return run

    sync = cp.cuda.Device().synchronize
    rows = {}
    if "curand" in mods:
        rows["plain EM, cuRAND Philox normal4 (CUDA, fast math)"] = _median_time(
            launcher(mods["curand"], "plain_em_curand"), args.repeat, sync)
    rows["plain EM, hand Philox + Box-Muller (CUDA, fast math)"] = _median_time(
        launcher(mods["philox"], "plain_em_philox"), args.repeat, sync)
    ref_key = next(iter(rows))
    engine_counts = {}
    for engine in (("cuda", "warp") if warp else ("cuda",)):
        os.environ["GAPSWEEP_SDE_ENGINE"] = "auto" if engine == "cuda" else "warp"
        for variant in (["poly"] if engine == "cuda" else K.VARIANTS):
            if engine == "warp":
                K.VARIANT = variant
            launch_times: list[float] = []
            label = "gapsweep CUDA engine (cupy)" if engine == "cuda" else f"warp kernels, log1p={variant}"

            def call(key=f"{engine}/{variant}", launch_times=launch_times):
                r = sde.gap_histogram_counts(s0, **kw)
                engine_counts[key] = np.r_[r.counts, r.below, r.above, r.nonfinite]
                launch_times.append(r.wall_time)
            rows[f"split step, {label}: whole user call"] = _median_time(
                call, args.repeat, device_sync)
            # the same calls without the host-side step plan: coefficient upload + launch + count copy
            rows[f"split step, {label}: upload + launch + copy"] = statistics.median(launch_times[1:])
    os.environ.pop("GAPSWEEP_SDE_ENGINE", None)
    if warp:
        K.VARIANT = "poly"
    agree = int(np.abs(engine_counts["cuda/poly"] - engine_counts["warp/poly"]).sum()) if warp else None
    ref = rows[ref_key]
    lines = [f"# SDE kernel limit on {gpu_name} (n = {n:.0e} x {plan.n_steps} steps, float32, {nb}-bin histogram,"
             f" median of {args.repeat})", "",
             "| kernel | time [s] | ratio to the first row |",
             "| --- | --- | --- |"]
    for key, t in rows.items():
        lines.append(f"| {key} | {t:.4f} | {t / ref:.2f} |")
    lines += ["", f"sum |count difference| over bins, CUDA engine vs warp kernels (poly), same seed: {agree} of {n}"
              if warp else "warp not installed: no warp rows, no count comparison with the warp kernels"]
    text = "\n".join(lines)
    print(text, flush=True)
    (args.out / "sde_kernel_limit.md").write_text(text + "\n")
    (args.out / "sde_kernel_limit.json").write_text(json.dumps({"gpu": gpu_name, "n": n, "steps": plan.n_steps,
                                                                "times_s": rows,
                                                                "ratio_to_first_row": {k: t / ref for k, t in
                                                                                       rows.items()},
                                                                "count_diff": agree}, indent=1))


if __name__ == "__main__":
    _record.track(CODE_PATHS)
    main()
