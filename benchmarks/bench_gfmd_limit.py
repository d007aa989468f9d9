"""GFMD on one GPU at the limit (issue 22, items 3 and 5; docs/benchmarks_gfmd.md, "GPU at the limit").

One run measures, on the GPU it finds, everything against a bare cuFFT pair (irfft2 + rfft2 of the same grid,
gapsweep.fft's plans) timed in the same process:

* ``pairs``: whole exponential-law solves (figure-2 case H = 0.3, rho = 2e-3, the sigma0 grid, tol 1e-6, default
  method, fields left on the GPU, best of 3 after a warm-up) at n = 2048, 4096, 8192: seconds per solve, force
  evaluations, and ``pairs/eval = wall / evaluations / pair``; also the CUDA launches and host synchronisations
  of each kind per evaluation (counted by wrapping ``_CupyOps._launch``).
* ``memory``: for each n (default 2048 ... 32768), the surface generated on the GPU (``self_affine(...,
  backend="cupy")`` where the tree has it, else on the host and uploaded), one warm-up and one timed solve
  (sigma0 = 1e-2, tol 1e-6, fields on the GPU); cupy's pool high-water mark (``total_bytes`` after the solve,
  the pool emptied before) against ``gapsweep.gfmd._cuda.solve_memory`` (if the tree has it) and the cuFFT work
  areas of the two plans. A grid whose estimate exceeds the free memory is reported, not run (``--force``: run).
* ``surface``: ``self_affine(..., backend="cupy")`` against the numpy surface of the same seed (max relative
  difference), when the tree has it.

Run it once per tree to compare trees side by side in one device call (``--tag``); each writes
``<tag>.json`` and prints a table.

    PYTHONPATH=. python benchmarks/bench_gfmd_limit.py --out OUT --tag new
    PYTHONPATH=. python benchmarks/bench_gfmd_limit.py --out OUT --tag new --parts pairs --n 2048 4096
"""

from __future__ import annotations

import argparse
import collections
import json
import math
import statistics
import sys
import sys as _sys
import time
import warnings
from pathlib import Path
from pathlib import Path as _Path

import numpy as np

_sys.path.insert(0, str(_Path(__file__).resolve().parent))
import _record

# the code this benchmark measures: a result measured before a later change to it is stale
# (scripts/check_docs.py)
CODE_PATHS = ['gapsweep/gfmd', 'gapsweep/core']

GAMMA0 = 1e-3
SIGMA0 = [1e-4, 1e-3, 1e-2, 1e-1, 1.0]


def surface(n: int, seed: int = 1, gpu: bool = True):
    """Figure-2 surface (M6: H = 0.3, lambda_l = 0.25, lambda_s = 2.5e-3, g_rms = 1) on the GPU."""
    import inspect

    import cupy

    from gapsweep.surface import self_affine

    kw = dict(lambda_l=0.25, lambda_s=2.5e-3, rms_slope=1.0, seed=seed)
    if gpu and "backend" in inspect.signature(self_affine).parameters:
        return self_affine(n, 0.3, backend="cupy", **kw), "gpu"
    return cupy.asarray(self_affine(n, 0.3, **kw)), "host"


def bare_pair(n: int, repeat: int = 20, backend: str = "cupy") -> float:
    """Median seconds of irfft2 + rfft2 (gapsweep.core.fft's plans of ``backend``: cuFFT for "cupy") with a
    synchronisation; also bench_gpu_floor.py's reference pair."""
    from gapsweep.core.fft import get_backend

    fb = get_backend(backend, n)
    if backend == "cupy":
        import cupy as xp
    else:
        xp = np
    h = xp.asarray(np.random.default_rng(0).standard_normal((n, n)))
    X = xp.array(fb.rfft2(h))
    ts = []
    for i in range(repeat + 3):
        if xp is not np:
            xp.cuda.get_current_stream().synchronize()
        t = time.perf_counter()
        fb.irfft2(X)
        fb.rfft2(h)
        fb.synchronize()
        if i >= 3:
            ts.append(time.perf_counter() - t)
    return statistics.median(ts)


class LaunchCounter:
    """Counts kernel launches by kernel and host synchronisations: ``_CupyOps._launch`` (a launch and a
    synchronisation each), ``_CupyOps._enqueue`` (a launch, chained CG) and ``_CupyOps.chain_read`` (a
    synchronisation) where the tree has them."""

    def __init__(self) -> None:
        from gapsweep.gfmd import _cuda

        self.cls = _cuda._CupyOps
        self.saved = {}
        self.counts: collections.Counter = collections.Counter()
        self.syncs = 0
        for name in ("_launch", "_enqueue", "chain_read"):
            if hasattr(self.cls, name):
                self.saved[name] = getattr(self.cls, name)
                setattr(self.cls, name, self._wrap(name, self.saved[name]))

    def _wrap(self, name, orig):
        def wrap(ops, *args):
            if name != "chain_read":
                self.counts[args[0]] += 1
            if name != "_enqueue":
                self.syncs += 1
            return orig(ops, *args)
        return wrap

    def close(self) -> None:
        for name, fn in self.saved.items():
            setattr(self.cls, name, fn)


def part_pairs(a, rows: list) -> None:
    import cupy

    from gapsweep import gfmd

    for n in a.n_pairs:
        h, _ = surface(n)
        pair = bare_pair(n)
        for s0 in SIGMA0:
            kw = dict(sigma0=s0, gamma0=GAMMA0, rho=2e-3, tol=1e-6, host=False)
            gfmd.solve(h, **{**kw, "tol": 1e-2})  # warm-up: plans, kernels
            best = None
            for _ in range(3):
                cupy.cuda.get_current_stream().synchronize()
                r = gfmd.solve(h, **kw)
                best = r if best is None or r.wall_time < best.wall_time else best
            cnt = LaunchCounter()
            try:
                r2 = gfmd.solve(h, **kw)
            finally:
                cnt.close()
            ev = best.iterations
            row = {"part": "pairs", "n": n, "sigma0": s0, "evals": ev, "status": best.status,
                   "wall_s": best.wall_time, "pair_ms": 1e3 * pair, "pairs/eval": best.wall_time / ev / pair,
                   "pairs/solve": best.wall_time / pair, "syncs/eval": cnt.syncs / r2.iterations,
                   "launches": dict(cnt.counts), "mean_gap": best.mean_gap, "residual": best.residual}
            rows.append(row)
            print(json.dumps(row), flush=True)
        del h


def part_phases(a, rows: list) -> None:
    """Where a solve's time goes: each kernel launch (with its synchronisation), each FFT (synchronised after
    it, for this part only), the minimiser loop and the rest (set-up, result), summed over one solve."""
    for n in a.n_phases:
        rows.append(_phases(n))
        print(json.dumps(rows[-1]), flush=True)


def _phases(n: int) -> dict:
    import cupy

    from gapsweep import gfmd
    from gapsweep.core.fft import _CupyBackend
    from gapsweep.gfmd import _cuda, _softmax

    sync = cupy.cuda.get_current_stream().synchronize
    h, _ = surface(n)
    kw = dict(sigma0=1e-2, gamma0=GAMMA0, rho=2e-3, tol=1e-6, host=False)
    gfmd.solve(h, **kw)
    acc: collections.Counter = collections.Counter()
    saved = {}

    def timed(cls, name, key):
        fn = getattr(cls, name)
        saved[(cls, name)] = fn

        def wrap(*args, **kwargs):
            sync()
            t = time.perf_counter()
            r = fn(*args, **kwargs)
            sync()
            acc[key(args)] += time.perf_counter() - t
            return r
        setattr(cls, name, wrap)

    timed(_cuda._CupyOps, "_launch", lambda args: args[1])
    if hasattr(_cuda._CupyOps, "_enqueue"):  # chained CG: timed with a synchronisation here (this part only)
        timed(_cuda._CupyOps, "_enqueue", lambda args: args[1] + " (queued)")
    timed(_CupyBackend, "rfft2", lambda args: "rfft2")
    timed(_CupyBackend, "irfft2", lambda args: "irfft2")
    runner = _softmax._RUNNERS["cg"]

    def loop(*args, **kwargs):
        sync()
        t = time.perf_counter()
        r = runner(*args, **kwargs)
        sync()
        acc["LOOP (cg, all of the above inside)"] += time.perf_counter() - t
        return r
    _softmax._RUNNERS["cg"] = loop
    try:
        sync()
        t = time.perf_counter()
        r = gfmd.solve(h, **kw)
        sync()
        total = time.perf_counter() - t
    finally:
        _softmax._RUNNERS["cg"] = runner
        for (cls, name), fn in saved.items():
            setattr(cls, name, fn)
    return {"part": "phases", "n": n, "evals": r.iterations, "total_ms": 1e3 * total,
            "ms": {k: round(1e3 * v, 3) for k, v in sorted(acc.items(), key=lambda kv: -kv[1])}}


def _plan_work(n: int) -> int:
    """Bytes of the work areas of gapsweep.fft's two cuFFT plans of an n x n grid (0 if not readable)."""
    from gapsweep.core.fft import get_backend

    fb = get_backend("cupy", n)
    total = 0
    for plan in (fb._plans or ())[:2]:
        wa = getattr(plan, "work_area", None)
        total += int(wa.mem.size) if wa is not None and hasattr(wa, "mem") else 0
    return total


def part_memory(a, rows: list) -> None:
    import cupy

    from gapsweep import gfmd
    from gapsweep.core import fft

    try:
        from gapsweep.gfmd._cuda import solve_memory
    except ImportError:
        solve_memory = None
    pool = cupy.get_default_memory_pool()
    for n in a.n_memory:
        fft._PLANS.clear()  # plans and buffers of earlier sizes go (so the pool measures this size alone)
        gfmd._solvers._half_q_cached.cache_clear()
        cupy.fft.config.get_plan_cache().clear()
        pool.free_all_blocks()
        free, total = cupy.cuda.runtime.memGetInfo()
        est = solve_memory(n) if solve_memory else None
        row = {"part": "memory", "n": n, "gpu_free_GB": free / 1e9, "gpu_total_GB": total / 1e9,
               "estimate_GB": est["bytes"] / 1e9 if est else None}
        if est and est["bytes"] > free and not a.force:
            row["status"] = f"not run: the estimate {est['bytes'] / 1e9:.1f} GB exceeds the free {free / 1e9:.1f} GB"
            rows.append(row)
            print(json.dumps(row), flush=True)
            continue
        try:
            t = time.perf_counter()
            h, where = surface(n)
            cupy.cuda.get_current_stream().synchronize()
            row["surface_s"], row["surface_on"] = time.perf_counter() - t, where
            pool.free_all_blocks()
            base = pool.total_bytes()  # the surface
            kw = dict(sigma0=1e-2, gamma0=GAMMA0, rho=2e-3, host=False)
            r0 = gfmd.solve(h, tol=1e-2, **kw)  # warm-up
            del r0
            peak = pool.total_bytes() - base
            pool.free_all_blocks()
            cupy.cuda.get_current_stream().synchronize()
            r = gfmd.solve(h, tol=1e-6, **kw)
            row.update({"status": r.status, "evals": r.iterations, "solve_s": r.wall_time,
                        "residual": r.residual, "mean_gap": r.mean_gap, "contact_area": r.contact_area,
                        "pool_peak_GB_excl_heights": peak / 1e9,
                        "pool_peak_GB_incl_heights": (peak + base) / 1e9,
                        "arrays_measured": (peak + base) / (8 * n * n),
                        "cufft_work_GB": _plan_work(n) / 1e9})
            if est:
                row["estimate/measured"] = est["bytes"] / (peak + base)
            del r, h
        except Exception as exc:  # out of memory: reported, not hidden
            row["status"] = f"failed: {type(exc).__name__}: {str(exc)[:200]}"
        pool.free_all_blocks()
        rows.append(row)
        print(json.dumps(row), flush=True)


def _pool_peak(solve_fn, n: int) -> tuple[float, object]:
    """``(bytes the pool grew by during solve_fn(), its result)``, FFT plans and caches of every size dropped."""
    import cupy

    from gapsweep import gfmd
    from gapsweep.core import fft

    pool = cupy.get_default_memory_pool()
    fft._PLANS.clear()
    gfmd._solvers._half_q_cached.cache_clear()
    cupy.fft.config.get_plan_cache().clear()
    pool.free_all_blocks()
    base = pool.total_bytes()
    r = solve_fn()
    return pool.total_bytes() - base, r


def part_methods(a, rows: list) -> None:
    """Memory (grid-sized arrays, surface excluded) and time of each exponential-law method and of the hard wall
    (pcg, tol 1e-8), the surface on the GPU; sizes ``--n-methods``."""
    import cupy

    from gapsweep import gfmd

    try:
        from gapsweep.gfmd._cuda import solve_memory
    except ImportError:
        solve_memory = None
    for n in a.n_methods:
        h, _ = surface(n)
        cases = [("exponential", m, dict(gamma0=GAMMA0, rho=2e-3, tol=1e-6, method=m)) for m in ("cg", "lbfgs", "fire")]
        cases.append(("hard_wall", "pcg", dict(interaction="hard_wall", tol=1e-8, method="pcg")))
        for law, method, kw in cases:
            if n > a.n_methods_max.get(method, 1 << 30):
                continue
            try:
                peak, r = _pool_peak(lambda kw=kw, h=h: gfmd.solve(h, sigma0=1e-2, host=False, max_iter=20000, **kw), n)
                cupy.cuda.get_current_stream().synchronize()
                t = time.perf_counter()
                r = gfmd.solve(h, sigma0=1e-2, host=False, max_iter=20000, **kw)
                cupy.cuda.get_current_stream().synchronize()
                wall = time.perf_counter() - t
                row = {"part": "methods", "n": n, "law": law, "method": method, "status": r.status,
                       "iterations": r.iterations, "solve_s": wall, "pool_GB_excl_heights": peak / 1e9,
                       "arrays_excl_heights": peak / (8 * n * n), "mean_gap": r.mean_gap}
                if solve_memory is not None and law == "exponential":
                    try:
                        row["estimate/measured"] = solve_memory(n, method=method, heights_on_gpu=False)["bytes"] / peak
                    except Exception:
                        pass
                del r
            except Exception as exc:
                row = {"part": "methods", "n": n, "law": law, "method": method,
                       "status": f"failed: {type(exc).__name__}: {str(exc)[:200]}"}
            rows.append(row)
            print(json.dumps(row), flush=True)
        del h


def part_surface(a, rows: list) -> None:
    import cupy

    from gapsweep.surface import self_affine

    for n in a.n_surface:
        for hurst, seed in ((0.3, 1), (0.8, 7)):
            kw = dict(lambda_l=0.25, lambda_s=2.5e-3, rms_slope=1.0, seed=seed)
            try:
                g = cupy.asnumpy(self_affine(n, hurst, backend="cupy", **kw))
            except TypeError:
                rows.append({"part": "surface", "n": n, "status": "tree has no backend option"})
                return
            c = self_affine(n, hurst, **kw)
            rows.append({"part": "surface", "n": n, "H": hurst, "seed": seed,
                         "max_rel_diff": float(np.abs(g - c).max() / np.abs(c).max())})
            print(json.dumps(rows[-1]), flush=True)


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--out", type=Path, required=True)
    p.add_argument("--tag", default="run")
    p.add_argument("--parts", nargs="+", default=["surface", "pairs", "memory"])
    p.add_argument("--n-pairs", type=int, nargs="+", default=[2048, 4096, 8192])
    p.add_argument("--n-memory", type=int, nargs="+", default=[2048, 4096, 8192, 16384, 32768])
    p.add_argument("--n-surface", type=int, nargs="+", default=[1024, 4096])
    p.add_argument("--n-phases", type=int, nargs="+", default=[2048, 8192])
    p.add_argument("--n-methods", type=int, nargs="+", default=[2048, 4096, 16384])
    p.add_argument("--force", action="store_true", help="memory: run sizes whose estimate exceeds the free memory")
    a = p.parse_args(argv)
    a.n_methods_max = {"fire": 4096}  # FIRE needs hundreds of evaluations: the large grid only for the others
    import cupy

    warnings.simplefilter("ignore")
    props = cupy.cuda.runtime.getDeviceProperties(0)
    meta = {"gpu": props["name"].decode(), "cupy": cupy.__version__,
            "cuda_runtime": cupy.cuda.runtime.runtimeGetVersion(), "python": sys.version.split()[0],
            "command": " ".join(sys.argv), "tag": a.tag,
            "date": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime())}
    print(json.dumps(meta), flush=True)
    rows: list = []
    parts = {"surface": part_surface, "pairs": part_pairs, "memory": part_memory, "phases": part_phases,
             "methods": part_methods}
    for name in a.parts:
        try:
            parts[name](a, rows)
        except Exception as exc:  # one part failing must not lose the others
            rows.append({"part": name, "status": f"failed: {type(exc).__name__}: {str(exc)[:300]}"})
            print(rows[-1], flush=True)
    a.out.mkdir(parents=True, exist_ok=True)
    (a.out / f"{a.tag}.json").write_text(json.dumps({"meta": meta, "rows": rows}, indent=1))
    summary = collections.defaultdict(list)
    for r in rows:
        if r.get("part") == "pairs" and "n" in r:
            summary[r["n"]].append(r)
    print(f"\n[{a.tag}] {meta['gpu']}: whole solves, fields on the GPU, figure-2 case rho = 2e-3, tol 1e-6")
    print("| n | pair ms | evals (sigma0 1e-4..1) | s per solve | pairs/eval | mean pairs/eval | syncs/eval |")
    print("| --- | --- | --- | --- | --- | --- | --- |")
    for n, rs in summary.items():
        evals = " / ".join(str(r["evals"]) for r in rs)
        walls = " / ".join(format(r["wall_s"], ".4f") for r in rs)
        ratios = " / ".join(format(r["pairs/eval"], ".2f") for r in rs)
        print(f"| {n} | {rs[0]['pair_ms']:.3f} | {evals} | {walls} | {ratios} | "
              f"{statistics.mean(r['pairs/eval'] for r in rs):.2f} | "
              f"{statistics.mean(r['syncs/eval'] for r in rs):.2f} |")
    for r in rows:
        if r.get("part") == "memory":
            print({k: (round(v, 3) if isinstance(v, float) and math.isfinite(v) else v) for k, v in r.items()})


if __name__ == "__main__":
    _record.track(CODE_PATHS)
    main()
