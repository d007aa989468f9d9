"""GFMD benchmarks (docs/benchmarks_gfmd.md).
Each subcommand writes ``<name>.md`` (markdown table) and ``<name>.json`` to --out.

    python benchmarks/bench_gfmd.py cost    --out OUT [--n 1024 2048] [--backend pyfftw numpy]
    python benchmarks/bench_gfmd.py targets --out OUT [--n 2048] [--tols 1e-6 1e-8] [--sigma0 1e-4 ... 1]
    python benchmarks/bench_gfmd.py speed   --out OUT [--n 1024 2048] [--tols 1e-3 ... 1e-8]
    python benchmarks/bench_gfmd.py peer    --out OUT [--n 1024]   (needs contactmechanics + adhesion)
    python benchmarks/bench_gfmd.py gpu     --out OUT [--n 4096 8192] (cupy on an NVIDIA GPU)
    python benchmarks/bench_gfmd.py batch   --out OUT [--n 512 1024 2048] [--backend cupy] (solve_batch vs a loop)

Cases are those of docs/model.md M6: L = 1, E* = 1, lambda_l = 0.25, lambda_s = 2.5e-3, gamma0 = 1e-3, g_rms = 1;
figure 2: H = 0.3, rho = 2e-3, 1e-3, 5e-4; figure 3: H = 0.8, rho = 5e-3, 2e-3, 1e-3; our pressure grid is
sigma0 = 1e-4, 1e-3, 1e-2, 1e-1, 1 (the paper does not state its grid). Surfaces: seed 1, fixed amplitudes.
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

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import sys as _sys
from pathlib import Path as _Path

from gapsweep import gfmd
from gapsweep.core.fft import get_backend
from gapsweep.surface import self_affine

_sys.path.insert(0, str(_Path(__file__).resolve().parent))
import _record

# the code this benchmark measures: a result measured before a later change to it is stale
# (scripts/check_docs.py)
CODE_PATHS = ['gapsweep/gfmd', 'gapsweep/core']

GAMMA0 = 1e-3
FIG2 = [(0.3, rho) for rho in (2e-3, 1e-3, 5e-4)]
FIG3 = [(0.8, rho) for rho in (5e-3, 2e-3, 1e-3)]
SIGMA0 = [1e-4, 1e-3, 1e-2, 1e-1, 1.0]
warnings.simplefilter("ignore", gfmd.UnderResolvedWarning)


def surf(n: int, hurst: float, seed: int = 1) -> np.ndarray:
    return self_affine(n, hurst, lambda_l=0.25, lambda_s=2.5e-3, rms_slope=1.0, seed=seed)


def write(out: Path, name: str, rows: list[dict], header: str) -> None:
    out.mkdir(parents=True, exist_ok=True)
    meta = {"host": platform.node(), "python": platform.python_version(), "cpus": os.cpu_count(),
            "command": " ".join(sys.argv)}
    (out / f"{name}.json").write_text(json.dumps({"meta": meta, "rows": rows}, indent=1))
    keys = list(rows[0]) if rows else []
    lines = [header, "", f"`{meta['command']}`", "", "| " + " | ".join(keys) + " |",
             "|" + " --- |" * len(keys)]
    for r in rows:
        lines.append("| " + " | ".join(_fmt(r[k]) for k in keys) + " |")
    (out / f"{name}.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines), flush=True)


def _fmt(v) -> str:
    if isinstance(v, float):
        return f"{v:.4g}" if math.isfinite(v) else str(v)
    return str(v)


def _time(fn, repeat: int) -> float:
    fn()
    best = math.inf
    for _ in range(repeat):
        t = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t)
    return best


# ---------------------------------------------------------------------------------------------------- cost
def cmd_cost(a) -> None:
    """Bare rfft2+irfft2 pair vs one force evaluation (irfft2 of a direction, softmax, rfft2, gradient) vs the
    solver's wall time per force evaluation, in one run, same backend."""
    rows = []
    for n in a.n:
        h = surf(n, 0.3)
        for name in a.backend:
            fb = get_backend(name, n, threads=a.threads)
            xp = fb.xp
            hx = xp.asarray(h)
            rng = np.random.default_rng(0)
            X = xp.asarray(fb.rfft2(xp.asarray(rng.standard_normal((n, n)))) * 1e-6 / n**2)
            pb = gfmd._Problem(hx, X.copy(), sigma0=1e-2, rho=2e-3, e_star=1.0, length=1.0, fft=fb,
                               ops=gfmd._make_ops(xp, n))
            sync = fb.synchronize

            def pair(fb=fb, X=X, hx=hx, sync=sync):
                fb.irfft2(X)
                fb.rfft2(hx)
                sync()

            def force(fb=fb, X=X, pb=pb, sync=sync):
                d = fb.irfft2(X)  # the direction's real-space image
                m = pb.ops.trial(pb.W, d, -1e-3, pb.Wt)
                S, _, _ = pb.ops.expstats(pb.Wt, m, pb.et, d)
                E = fb.rfft2(pb.et)
                pb.ops.grad_step(pb.X, X, 0.0, E, 1e-2 / S, pb.k, pb.G)
                sync()

            t_pair = _time(pair, a.repeat)
            t_force = _time(force, a.repeat)
            kw = dict(sigma0=1e-2, gamma0=GAMMA0, rho=2e-3, tol=1e-6, backend=name, threads=a.threads)
            gfmd.solve(h, **kw)  # warm-up: plans, kernels
            r = gfmd.solve(h, **kw)
            rows.append({"n": n, "backend": name, "threads": a.threads, "pair_ms": 1e3 * t_pair,
                         "force_eval_ms": 1e3 * t_force, "force/pair": t_force / t_pair,
                         "solve_s": r.wall_time, "iterations": r.iterations,
                         "solve_per_eval_ms": 1e3 * r.wall_time / r.iterations,
                         "solve_per_eval/pair": r.wall_time / r.iterations / t_pair})
    write(a.out, "cost", rows, "### Cost of a force evaluation vs a bare FFT pair (H=0.3, rho=2e-3, sigma0=1e-2)")


# ------------------------------------------------------------------------------------------------- targets
def cmd_targets(a) -> None:
    """Force evaluations to reach tol for every figure-2/3 case at one n (default method, cold start)."""
    rows = []
    for n in a.n:
        for hurst, rho in FIG2 + FIG3:
            h = surf(n, hurst)
            for s0 in a.sigma0:
                row = {"n": n, "H": hurst, "rho": rho, "sigma0": s0}
                for tol in a.tols:
                    r = gfmd.solve(h, sigma0=s0, gamma0=GAMMA0, rho=rho, tol=tol, method=a.method,
                                   backend=a.backend, max_iter=a.max_iter, threads=a.threads)
                    row[f"it@{tol:g}"] = r.iterations
                    row[f"status@{tol:g}"] = r.status
                    row[f"s@{tol:g}"] = r.wall_time
                row["mean_gap"] = r.mean_gap
                rows.append(row)
                print(row, flush=True)
    write(a.out, "targets", rows, f"### Force evaluations per case, method={a.method}, backend={a.backend}")


# --------------------------------------------------------------------------------------------------- speed
def cmd_speed(a) -> None:
    """Mean-gap error vs wall time over n and tol for every method: error against the same n at tol=1e-11
    (solver error) and against the finest n at tol=1e-11 (total error, discretisation included)."""
    rows = []
    for hurst, rho, s0 in a.cases:
        ref = {}
        for n in a.n:
            h = surf(n, hurst)
            ref[n] = gfmd.solve(h, sigma0=s0, gamma0=GAMMA0, rho=rho, tol=1e-11, backend=a.backend,
                                threads=a.threads, max_iter=20000).mean_gap
        finest = ref[max(a.n)]
        for n in a.n:
            h = surf(n, hurst)
            for method in a.methods:
                for tol in a.tols:
                    r = gfmd.solve(h, sigma0=s0, gamma0=GAMMA0, rho=rho, tol=tol, method=method,
                                   backend=a.backend, threads=a.threads, max_iter=20000)
                    rows.append({"H": hurst, "rho": rho, "sigma0": s0, "n": n, "method": method, "tol": tol,
                                 "iterations": r.iterations, "wall_s": r.wall_time, "status": r.status,
                                 "solver_err": abs(r.mean_gap - ref[n]) / abs(ref[n]),
                                 "total_err": abs(r.mean_gap - finest) / abs(finest)})
                    print(rows[-1], flush=True)
    write(a.out, "speed", rows, "### Mean-gap relative error vs wall time")
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        return
    fig, axes = plt.subplots(1, 2, figsize=(10, 4), constrained_layout=True)
    marks = {"cg": "o", "lbfgs": "s", "fire": "^"}
    colors = {n: c for n, c in zip(a.n, plt.cm.viridis(np.linspace(0, 0.9, len(a.n))))}
    for ax, key in zip(axes, ("solver_err", "total_err")):
        for r in rows:
            if r["H"] != a.cases[0][0] or r["rho"] != a.cases[0][1] or r["sigma0"] != a.cases[0][2]:
                continue
            ax.loglog(r["wall_s"], max(r[key], 1e-16), marks[r["method"]], color=colors[r["n"]], ms=5)
        ax.set_xlabel("wall time [s]")
        ax.set_ylabel(f"mean-gap {key.replace('_', ' ')} (relative)")
    for n, c in colors.items():
        axes[0].plot([], [], "o", color=c, label=f"n={n}")
    for m, mk in marks.items():
        axes[0].plot([], [], mk, color="k", label=m)
    axes[0].legend(fontsize=7)
    h0, r0, s0 = a.cases[0]
    fig.suptitle(f"GFMD speed vs error, H={h0}, rho={r0}, sigma0={s0} (one marker per tol in {a.tols})")
    fig.savefig(a.out / "speed.png", dpi=120)


# ---------------------------------------------------------------------------------------------------- peer
def peer_solve(h: np.ndarray, *, sigma0: float, rho: float, tol: float, x0: np.ndarray, maxiter: int):
    """ContactMechanics + Adhesion at fixed mean pressure (docs/benchmarks_gfmd.md):
    PeriodicFFTElasticHalfSpace with
    stiffness_q0 = 0, RepulsiveExponential(gamma0, rho, 0, 1), the load term sigma0 L^2 <u> added, scipy
    L-BFGS-B; stopped by the same rule as gapsweep (rms force imbalance and load error below tol)."""
    import scipy.optimize
    from Adhesion.Interactions import RepulsiveExponential
    from ContactMechanics import PeriodicFFTElasticHalfSpace

    n = h.shape[0]
    sub = PeriodicFFTElasticHalfSpace((n, n), 1.0, physical_sizes=(1.0, 1.0), stiffness_q0=0.0)
    pot = RepulsiveExponential(GAMMA0, rho, 0.0, 1.0)
    da = 1.0 / n**2
    cache = {}

    def fun(x):
        u = x.reshape(n, n)
        e_el, f_el = sub.evaluate(u, pot=True, forces=True)
        v, dv, _ = pot.evaluate(u - h, True, True)
        energy = e_el + float(np.sum(v)) * da + sigma0 * float(np.mean(u))
        grad = -f_el + dv * da + sigma0 * da
        cache["x"], cache["g"] = x, grad
        return energy, grad.ravel()

    def stop(intermediate_result):
        g = cache["g"] / da  # pressure imbalance p_el - p + sigma0
        if np.shares_memory(cache["x"], intermediate_result.x) or np.array_equal(cache["x"], intermediate_result.x):
            load = abs(float(g.mean())) / sigma0
            res = float(np.sqrt(np.mean((g - g.mean()) ** 2))) / sigma0
            cache["res"], cache["load"] = res, load
            if res <= tol and load <= tol:
                raise StopIteration

    t = time.perf_counter()
    sol = scipy.optimize.minimize(fun, x0.ravel(), jac=True, method="L-BFGS-B", callback=stop,
                                  options={"maxiter": maxiter, "maxfun": 10 * maxiter, "ftol": 0.0,
                                           "gtol": 0.0, "maxcor": 10})
    wall = time.perf_counter() - t
    u = sol.x.reshape(n, n)
    return {"mean_gap": float(np.mean(u - h)), "nit": int(sol.nit), "nfev": int(sol.nfev), "wall_s": wall,
            "residual": cache.get("res", math.nan), "load_error": cache.get("load", math.nan),
            "message": str(sol.message)}


def cmd_peer(a) -> None:
    rows = []
    for hurst in a.hurst:
        h = surf(a.n[0], hurst)
        for s0 in a.sigma0:
            kw = dict(sigma0=s0, gamma0=GAMMA0, rho=a.rho, tol=a.tol, backend=a.backend, threads=a.threads)
            gfmd.solve(h, **{**kw, "tol": 1e-2})  # warm-up (plans, kernels)
            ours = gfmd.solve(h, **kw)
            # Same start for the peer: our linear-response displacement of M4 plus the exact g0 offset.
            lin = gfmd.solve(h, **{**kw, "max_iter": 1})
            x0 = lin.displacement + lin.mean_gap
            peer = peer_solve(h, sigma0=s0, rho=a.rho, tol=a.tol, x0=x0, maxiter=a.max_iter)
            rows.append({"H": hurst, "sigma0": s0, "rho": a.rho, "n": a.n[0], "tol": a.tol,
                         "gapsweep_evals": ours.iterations, "gapsweep_s": ours.wall_time,
                         "peer_nit": peer["nit"], "peer_evals": peer["nfev"], "peer_s": peer["wall_s"],
                         "eval_ratio": peer["nfev"] / ours.iterations, "time_ratio": peer["wall_s"] / ours.wall_time,
                         "peer_residual": peer["residual"], "peer_load_error": peer["load_error"],
                         "gap_rel_diff": abs(peer["mean_gap"] - ours.mean_gap) / ours.mean_gap})
            print(rows[-1], peer["message"], flush=True)
    write(a.out, "peer", rows, "### Side by side with ContactMechanics + Adhesion (scipy L-BFGS-B), one thread")


# ----------------------------------------------------------------------------------------------------- gpu
def cmd_gpu(a) -> None:
    import cupy

    name = cupy.cuda.runtime.getDeviceProperties(0)["name"].decode()
    rows = []
    for n in a.n:
        for hurst, rho in (FIG2 if a.all_cases else FIG2[:1]):
            h = cupy.asarray(surf(n, hurst))
            for s0 in a.sigma0:
                kw = dict(sigma0=s0, gamma0=GAMMA0, rho=rho, method=a.method)
                gfmd.solve(h, tol=1e-2, **kw)  # warm-up: cuFFT plans, kernels
                for tol in a.tols:
                    def best(host, tol=tol, kw=kw, h=h):
                        # best of 3 (the first call of a mode allocates its pinned host blocks)
                        rs = []
                        for _ in range(3):
                            cupy.cuda.get_current_stream().synchronize()
                            rs.append(gfmd.solve(h, tol=tol, host=host, **kw))
                        return min(rs, key=lambda x: x.wall_time)
                    r = best(True)
                    r_dev = best(False)
                    r_gap = best(("gap",))
                    fb = get_backend("cupy", n)
                    X = fb.rfft2(h)
                    t_pair = _time(lambda fb=fb, X=X, h=h: (fb.irfft2(X), fb.rfft2(h), fb.synchronize()), 5)
                    f3 = [r_dev.gap, r_dev.pressure, r_dev.displacement]
                    t_pageable = _time(lambda f3=f3: [cupy.asnumpy(f) for f in f3], 3)  # the old copy
                    t_pinned = _time(lambda f3=f3, fb=fb: fb.to_host_many(dict(enumerate(f3))), 3)  # one pinned batch
                    rows.append({"gpu": name, "n": n, "H": hurst, "rho": rho, "sigma0": s0, "tol": tol,
                                 "method": r.method, "iterations": r.iterations, "wall_s": r.wall_time,
                                 "wall_s_fields_on_gpu": r_dev.wall_time, "wall_s_gap_only": r_gap.wall_time,
                                 "copy3_pageable_ms": 1e3 * t_pageable, "copy3_pinned_ms": 1e3 * t_pinned,
                                 "status": r.status, "pair_ms": 1e3 * t_pair,
                                 "per_eval/pair": r.wall_time / r.iterations / t_pair,
                                 "per_eval/pair_on_gpu": r_dev.wall_time / r.iterations / t_pair,
                                 "mean_gap": r.mean_gap})
                    print(rows[-1], flush=True)
    write(a.out, "gpu", rows,
          f"### GPU ({name}), cupy backend, float64; wall_s includes copying the three fields to the host "
          "(pinned, asynchronous); copy3_*: the three n x n float64 fields alone, pageable (cupy.asnumpy) vs pinned")


# --------------------------------------------------------------------------------------------------- batch
def cmd_batch(a) -> None:
    """gfmd.solve_batch of one surface at the figure pressures x rho values vs the same problems one by one, same
    backend, same run; agreement of mean gaps and iteration counts."""
    backend = a.backend[0]
    if backend == "cupy":
        import cupy

        xp = cupy
        name = cupy.cuda.runtime.getDeviceProperties(0)["name"].decode()
        sync = cupy.cuda.get_current_stream().synchronize
    else:
        xp, name, sync = np, platform.processor() or "cpu", (lambda: None)
    rows = []
    for n in a.n:
        hs = [xp.asarray(surf(n, 0.3, seed=seed)) for seed in range(1, a.surfaces + 1)]
        probs = [gfmd.BatchProblem(heights=h, sigma0=s0, gamma0=GAMMA0, rho=rho)
                 for h in hs for rho in (2e-3, 1e-3) for s0 in a.sigma0]
        kw = dict(tol=a.tol, backend=backend, max_iter=a.max_iter, host=a.host == "all")
        gfmd.solve_batch(probs[:2], **{**kw, "tol": 1e-2})  # warm-up: plans, kernels
        for p in probs[:2]:
            gfmd.solve(p.heights, sigma0=p.sigma0, gamma0=GAMMA0, rho=p.rho, tol=1e-2, backend=backend)
        sync()
        t = time.perf_counter()
        rb = gfmd.solve_batch(probs, **kw)
        sync()
        t_cold = time.perf_counter() - t  # includes the batched FFT plans of each stack size
        del rb  # free its fields (pinned host blocks go back to cupy's pool, as in a sweep that stored them)
        t = time.perf_counter()
        rb = gfmd.solve_batch(probs, **kw)
        sync()
        t_batch = time.perf_counter() - t
        t = time.perf_counter()
        r1 = [gfmd.solve(p.heights, sigma0=p.sigma0, gamma0=GAMMA0, rho=p.rho, **kw) for p in probs]
        sync()
        t_loop = time.perf_counter() - t
        evals = sum(r.iterations for r in rb)
        rows.append({"device": name, "backend": backend, "n": n, "problems": len(probs), "tol": a.tol,
                     "force_evals": evals, "batch_s_first": t_cold, "batch_s": t_batch, "one_by_one_s": t_loop,
                     "speed-up": t_loop / t_batch,
                     "batch_ms/eval": 1e3 * t_batch / evals, "loop_ms/eval": 1e3 * t_loop / max(1, sum(
                         r.iterations for r in r1)),
                     "same_iterations": sum(x.iterations == y.iterations for x, y in zip(rb, r1)),
                     "max_rel_gap_diff": max(abs(x.mean_gap - y.mean_gap) / abs(y.mean_gap) for x, y in zip(rb, r1)),
                     "converged": sum(r.converged for r in rb)})
        print(rows[-1], flush=True)
    write(a.out, f"batch_{backend}", rows, f"### Batched GFMD on {name} ({backend}): solve_batch vs one by one, "
          f"{a.surfaces} surface(s) (H = 0.3) x rho = 2e-3, 1e-3 x the sigma0 grid; "
          f"fields on the host in both modes: {a.host}; batch_s: second call (FFT plans cached), "
          "batch_s_first: first call")


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("cmd", choices=["cost", "targets", "speed", "peer", "gpu", "batch"])
    p.add_argument("--out", type=Path, required=True)
    p.add_argument("--n", type=int, nargs="+")
    p.add_argument("--backend", nargs="+", default=None)
    p.add_argument("--threads", type=int, default=1)
    p.add_argument("--repeat", type=int, default=5)
    p.add_argument("--tols", type=float, nargs="+")
    p.add_argument("--sigma0", type=float, nargs="+", default=SIGMA0)
    p.add_argument("--method", default="auto")
    p.add_argument("--methods", nargs="+", default=["cg", "lbfgs", "fire"])
    p.add_argument("--max-iter", type=int, default=5000)
    p.add_argument("--hurst", type=float, nargs="+", default=[0.3, 0.8])
    p.add_argument("--rho", type=float, default=2e-3)
    p.add_argument("--tol", type=float, default=1e-6)
    p.add_argument("--all-cases", action="store_true")
    p.add_argument("--host", default="none", choices=["none", "all"],
                   help="batch: fields to the host (all) or left on the GPU (none: the solver alone)")
    p.add_argument("--surfaces", type=int, default=2, help="batch: surfaces (each x 2 rho x the sigma0 grid)")
    a = p.parse_args(argv)
    defaults = {
        "cost": dict(n=[1024, 2048], backend=["pyfftw", "numpy"]),
        "targets": dict(n=[2048], tols=[1e-6, 1e-8], backend="auto"),
        "speed": dict(n=[1024, 2048], tols=[1e-3, 1e-4, 1e-6, 1e-8], backend="auto"),
        "peer": dict(n=[1024], backend="auto"),
        "gpu": dict(n=[4096], tols=[1e-6, 1e-8]),
        "batch": dict(n=[512, 1024, 2048], backend=["cupy"]),
    }[a.cmd]
    for k, v in defaults.items():
        if getattr(a, k) is None:
            setattr(a, k, v)
    if isinstance(a.backend, list) and a.cmd in ("targets", "speed", "peer"):
        a.backend = a.backend[0]
    # The figure surfaces (lambda_s = 2.5e-3) need n > 800 (Nyquist, M2).
    a.cases = [(0.3, 2e-3, 1e-2), (0.8, 1e-3, 1e-3)]
    {"cost": cmd_cost, "targets": cmd_targets, "speed": cmd_speed, "peer": cmd_peer, "gpu": cmd_gpu,
     "batch": cmd_batch}[a.cmd](a)


if __name__ == "__main__":
    _record.track(CODE_PATHS)
    main()
