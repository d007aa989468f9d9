"""GPU solvers against the FFT-pair floor, side by side in one run on one GPU (issue 30, items 2 and 3;
docs/benchmarks.md). Writes ``gpu_floor.json`` (all rows, the machine and the command) to ``--out`` and prints a
summary table. Parts (``--parts``, default all):

* ``pairs``: a bare cuFFT R2C + C2R pair (gapsweep.core.fft's plans, median of 20) at N = 2048, 4096, 8192 and
  the exponential law's whole solve (figure-2 surface H = 0.3, rho = 2e-3, gamma0 = 1e-3, sigma0 = 1e-2,
  tol 1e-6, default method, fields left on the GPU, best of 2 after a warm-up): ms per force evaluation and
  ``pairs/eval`` = (wall / evaluations) / pair (the measure of bench_gfmd.py's ``gpu`` command).
* ``hardwall``: the hard wall at N = 4096 (same surface, tol 1e-8, default GPU method "pcg"), sigma0 = 1e-3,
  1e-2, 1e-1: wall time, iterations, FFT pairs, ms per iteration and pairs per iteration; ``--hardwall-methods``
  times several methods side by side (``mpcg:1024``: the coarse levels stopped at 1024^2, an experiment on the
  solver's ``_COARSEST``), ``--hardwall-seeds`` other surfaces of the same spectrum.
* ``free``: free boundaries (``periodic=False``) against a periodic solve of the same map, N = 4096:
  exponential (L-BFGS on the doubled grid; also with fewer stored pairs, ``--free-memory``, and the opt-in
  nonlinear CG, method "cg") and hard wall (sigma0 = 1e-2): time ratio per solve and per evaluation (issue
  30's goal <= 4).
* ``big``: the hard wall at 4096^2 (a check of the memory plan) and 32768^2 on one GPU (sigma0 = 1e-2, tol 1e-6,
  at most 600 iterations, the surface generated on the GPU): ``solve_memory``'s estimate, cupy's pool peak
  (excluding and including the surface), the device, time, iterations and status; not run (the numbers
  reported) when the estimate exceeds the free memory (``--force``: run anyway).

``--quick`` (< 1 min on an H200): N = 1024, 2048 for the pairs, 2048 for the hard wall and the free maps, the
32768 grid estimated only (4096 measured). ``--backend numpy`` runs the same logic on the CPU at toy sizes (a
check of the script, not a measurement). Run with the tree first on the path:

    PYTHONPATH=. python benchmarks/bench_gpu_floor.py --out benchmarks/results/gpu_floor/h200     (~4-5 min)
    PYTHONPATH=. python benchmarks/bench_gpu_floor.py --out /tmp/gpu_floor --quick                 (< 1 min)
    PYTHONPATH=. python benchmarks/bench_gpu_floor.py --out /tmp/gpu_floor --backend numpy         (CPU, ~20 s)
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
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))  # bench_gfmd_limit (the reference pair)

import sys as _sys
from pathlib import Path as _Path

import bench_gfmd_limit

from gapsweep import gfmd
from gapsweep.gfmd import _free
from gapsweep.surfaces import self_affine

_sys.path.insert(0, str(_Path(__file__).resolve().parent))
import _record

# the code this benchmark measures: a result measured before a later change to it is stale
# (scripts/check_docs.py)
CODE_PATHS = ['gapsweep/gfmd', 'gapsweep/core']

GAMMA0, RHO = 1e-3, 2e-3
warnings.simplefilter("ignore", gfmd.UnderResolvedWarning)


class Device:
    """The array namespace of the run: cupy (the measurement) or numpy (a check of the script on the CPU)."""

    def __init__(self, backend: str) -> None:
        self.backend = backend
        if backend == "cupy":
            import cupy

            self.xp = cupy
            props = cupy.cuda.runtime.getDeviceProperties(cupy.cuda.Device().id)
            self.name = props["name"].decode() if isinstance(props["name"], bytes) else str(props["name"])
            self.pool = cupy.get_default_memory_pool()
        else:
            self.xp, self.name, self.pool = np, platform.processor() or "cpu", None

    def sync(self) -> None:
        if self.xp is not np:
            self.xp.cuda.get_current_stream().synchronize()

    def surface(self, n: int, seed: int = 1) -> Any:
        """Figure-2 surface (docs/model.md M6: H = 0.3, lambda_l = 0.25, lambda_s = 2.5e-3, g_rms = 1; the
        bench_gfmd.py ``gpu`` cases), generated on the device; toy grids (n <= 800, the numpy check) resolve
        lambda_s = 4/n instead."""
        lam = 2.5e-3 if n > 800 else 4.0 / n
        return self_affine(n, 0.3, lambda_l=0.25, lambda_s=lam, rms_slope=1.0, seed=seed, backend=self.backend)

    def free_bytes(self) -> tuple[int, int]:
        if self.xp is np:
            return 0, 0
        self.pool.free_all_blocks()
        return self.xp.cuda.runtime.memGetInfo()

    def pair(self, n: int, repeat: int = 20) -> float:
        """Median seconds of one irfft2 + rfft2 of gapsweep.core.fft's plans, synchronised
        (bench_gfmd_limit.bare_pair)."""
        return bench_gfmd_limit.bare_pair(n, repeat, self.backend)

    def solve(self, h: Any, repeat: int = 2, **kw) -> Any:
        """Best of ``repeat`` solves after one warm-up at tol 1e-2 (plans, kernels), fields left on the device."""
        kw = {"backend": self.backend, "host": False, **kw}
        gfmd.solve(h, **{**kw, "tol": 1e-2})
        rs = []
        for _ in range(repeat):
            self.sync()
            rs.append(gfmd.solve(h, **kw))
        return min(rs, key=lambda r: r.wall_time)


def _row(part: str, **kw) -> dict:
    row = {"part": part, **kw}
    print(json.dumps(row, default=str), flush=True)
    return row


def part_pairs(dev: Device, a, rows: list) -> None:
    for n in a.n_pairs:
        t_pair = dev.pair(n)
        h = dev.surface(n)
        r = dev.solve(h, sigma0=1e-2, gamma0=GAMMA0, rho=RHO, tol=1e-6)
        per = r.wall_time / max(r.iterations, 1)
        rows.append(_row("pairs", n=n, pair_ms=1e3 * t_pair, method=r.method, evals=r.iterations,
                         solve_s=r.wall_time, ms_per_eval=1e3 * per, pairs_per_eval=per / t_pair, status=r.status))


def _with_coarsest(coarsest: int | None, f, *args, **kw):
    """``f(*args, **kw)`` with the "mpcg" coarse levels stopped at grids of side ``coarsest`` (an experiment on
    ``gfmd._constrained._COARSEST``, restored after; ``None``: as shipped)."""
    from gapsweep.gfmd import _constrained

    saved = _constrained._COARSEST
    _constrained._COARSEST = coarsest or saved
    try:
        return f(*args, **kw)
    finally:
        _constrained._COARSEST = saved


def part_hardwall(dev: Device, a, rows: list) -> None:
    n = a.n_hardwall
    t_pair = dev.pair(n)
    for seed in a.hardwall_seeds:
        h = dev.surface(n, seed)
        for s0 in (1e-3, 1e-2, 1e-1):
            for spec in a.hardwall_methods:
                method, _, coarsest = spec.partition(":")
                r = _with_coarsest(int(coarsest) if coarsest else None, dev.solve, h, sigma0=s0,
                                   interaction="hard_wall", tol=1e-8, max_iter=5000, method=method)
                it = max(r.iterations, 1)
                pairs = r.diagnostics.get("fft_pairs", math.nan)
                rows.append(_row("hardwall", n=n, seed=seed, sigma0=s0, method=spec if coarsest else r.method,
                                 iterations=r.iterations,
                                 coarse_iterations=r.diagnostics.get("coarse_iterations", []),
                                 solve_s=r.wall_time, ms_per_iteration=1e3 * r.wall_time / it, fft_pairs=pairs,
                                 pair_ms=1e3 * t_pair, pairs_per_iteration_time=r.wall_time / it / t_pair,
                                 contact_area=r.contact_area, mean_gap=r.mean_gap, residual=r.residual,
                                 status=r.status))


def _free_syncs(dev: Device, h: Any, **kw) -> float:
    """Host synchronisations per evaluation of the free minimiser's fused passes (``_FreeCupyOps._run``, one each),
    counted in an untimed solve at tol 1e-3 (NaN on numpy)."""
    if dev.xp is np:
        return math.nan
    from gapsweep.gfmd import _cuda

    cls, orig, calls = _cuda._FreeCupyOps, _cuda._FreeCupyOps._run, [0]

    def run(ops, *args):
        calls[0] += 1
        return orig(ops, *args)

    cls._run = run
    try:
        r = gfmd.solve(h, backend=dev.backend, host=False, **{**kw, "tol": 1e-3})
    finally:
        cls._run = orig
    return calls[0] / max(r.iterations, 1)


def _free_vs_periodic(dev: Device, h: Any, label: str, **kw) -> dict:
    per = dev.solve(h, periodic=True, **kw)
    free = dev.solve(h, periodic=False, repeat=1, **kw)  # one timed solve after the warm-up (the slow side)
    e_p, e_f = max(per.iterations, 1), max(free.iterations, 1)
    syncs = _free_syncs(dev, h, periodic=False, **kw) if label != "hard_wall" else math.nan
    return {"free_syncs_per_eval": syncs, "law": label, "periodic_s": per.wall_time, "periodic_evals": per.iterations,
            "periodic_method": per.method, "free_s": free.wall_time, "free_evals": free.iterations,
            "free_method": free.method, "ratio_per_solve": free.wall_time / per.wall_time,
            "ratio_per_eval": (free.wall_time / e_f) / (per.wall_time / e_p),
            "periodic_ms_per_eval": 1e3 * per.wall_time / e_p, "free_ms_per_eval": 1e3 * free.wall_time / e_f,
            "status": f"{per.status}/{free.status}"}


def part_free(dev: Device, a, rows: list) -> None:
    n = a.n_free
    h = dev.surface(n)
    saved = _free._MEMORY
    try:
        for m in a.free_memory:  # stored L-BFGS pairs of the free smooth minimiser on the device
            _free._MEMORY = m
            rows.append(_row("free", n=n, lbfgs_pairs=m, **_free_vs_periodic(
                dev, h, "exponential", sigma0=1e-2, gamma0=GAMMA0, rho=RHO, tol=1e-6, max_iter=2000)))
    finally:
        _free._MEMORY = saved
    if a.free_cg:  # the free map's nonlinear CG (method "cg"): one direction instead of the L-BFGS pairs
        per = dev.solve(h, periodic=True, sigma0=1e-2, gamma0=GAMMA0, rho=RHO, tol=1e-6, max_iter=5000)
        free = dev.solve(h, periodic=False, method="cg", sigma0=1e-2, gamma0=GAMMA0, rho=RHO, tol=1e-6,
                         max_iter=2000, repeat=1)
        e_p, e_f = max(per.iterations, 1), max(free.iterations, 1)
        rows.append(_row("free", n=n, law="exponential (free method cg)", periodic_s=per.wall_time,
                         periodic_evals=per.iterations, free_s=free.wall_time, free_evals=free.iterations,
                         ratio_per_solve=free.wall_time / per.wall_time,
                         ratio_per_eval=(free.wall_time / e_f) / (per.wall_time / e_p),
                         status=f"{per.status}/{free.status}"))
    rows.append(_row("free", n=n, **_free_vs_periodic(dev, h, "hard_wall", sigma0=1e-2, interaction="hard_wall",
                                                      tol=1e-8, max_iter=5000)))


def _release(dev: Device) -> None:
    """Drop cached FFT plans and buffers of earlier parts and empty the pool (bench_gfmd_limit._pool_peak)."""
    from gapsweep.core import fft

    fft._PLANS.clear()
    gfmd._solvers._half_q_cached.cache_clear()
    if dev.xp is not np:
        dev.xp.fft.config.get_plan_cache().clear()
        dev.pool.free_all_blocks()


def _hard_wall_memory(dev: Device, n: int, row: dict, max_iter: int) -> None:
    """Surface on the device, then one hard-wall solve (sigma0 = 1e-2, tol 1e-6, fields left there): time,
    status and the pool's high-water mark against ``solve_memory`` (into ``row``)."""
    from gapsweep.gfmd._cuda import solve_memory

    _release(dev)
    t = time.perf_counter()
    h = dev.surface(n)
    dev.sync()
    row["surface_s"] = time.perf_counter() - t
    if dev.pool is not None:
        dev.pool.free_all_blocks()  # the surface's temporaries
    base = dev.pool.total_bytes() if dev.pool is not None else 0  # the surface itself
    r = gfmd.solve(h, sigma0=1e-2, interaction="hard_wall", tol=1e-6, max_iter=max_iter, backend=dev.backend,
                   host=False)
    dev.sync()
    peak = (dev.pool.total_bytes() - base) if dev.pool is not None else math.nan
    est = solve_memory(n, interaction="hard_wall")["bytes"]
    row.update({"status": r.status, "iterations": r.iterations, "solve_s": r.wall_time, "residual": r.residual,
                "contact_area": r.contact_area, "pool_peak_GB_excl_heights": peak / 1e9,
                "pool_peak_GB_incl_heights": (peak + base) / 1e9, "arrays_measured": (peak + base) / (8 * n * n),
                "estimate/measured": est / (peak + base) if peak == peak else math.nan})
    del r, h
    _release(dev)


def part_big(dev: Device, a, rows: list) -> None:
    from gapsweep.gfmd._cuda import solve_memory

    for n in (a.n_memcheck, a.n_big):
        est = solve_memory(n, interaction="hard_wall")
        _release(dev)
        free, total = dev.free_bytes()
        row = {"n": n, "device": dev.name, "estimate_GB": est["bytes"] / 1e9, "estimate_arrays": est["arrays"],
               "gpu_free_GB": free / 1e9, "gpu_total_GB": total / 1e9}
        if n == a.n_big and a.quick:
            rows.append(_row("big", status="not run (--quick)", **row))
            continue
        if dev.xp is not np and est["bytes"] > free and not a.force:
            rows.append(_row("big", status=f"not run: the estimate {est['bytes'] / 1e9:.1f} GB exceeds the free "
                                           f"{free / 1e9:.1f} GB (--force runs it)", **row))
            continue
        try:
            _hard_wall_memory(dev, n, row, 600)
        except Exception as exc:  # out of memory and the like: reported, not hidden
            row["status"] = f"failed: {type(exc).__name__}: {str(exc)[:200]}"
            _release(dev)
        rows.append(_row("big", **row))


def summary(rows: list) -> str:
    out = ["| part | case | numbers |", "| --- | --- | --- |"]
    for r in rows:
        p = r["part"]
        if "n" not in r:
            case, nums = "-", str(r.get("status"))
        elif p == "pairs":
            case, nums = f"exponential N={r['n']}", (f"pair {r['pair_ms']:.3g} ms, {r['ms_per_eval']:.3g} ms/eval, "
                                                     f"**{r['pairs_per_eval']:.2f} pairs/eval** ({r['evals']} evals, "
                                                     f"{r['status']})")
        elif p == "hardwall":
            case, nums = f"hard wall N={r['n']} seed={r.get('seed', 1)} sigma0={r['sigma0']:g} {r['method']}", (
                f"**{r['solve_s']:.3g} s**, {r['iterations']} it, {r['ms_per_iteration']:.3g} ms/it, "
                f"{r['fft_pairs']} pairs ({r['status']})")
        elif p == "free":
            m = f", {r['lbfgs_pairs']} L-BFGS pairs" if "lbfgs_pairs" in r else ""
            case, nums = f"free/periodic {r['law']} N={r['n']}{m}", (
                f"**{r['ratio_per_solve']:.2f}x per solve**, {r['ratio_per_eval']:.2f}x per eval "
                f"({r['free_s']:.3g} s / {r['periodic_s']:.3g} s; {r['free_evals']} / {r['periodic_evals']} evals; "
                f"{r['status']})")
            if r.get("free_syncs_per_eval", math.nan) == r.get("free_syncs_per_eval"):
                nums += f"; {r['free_syncs_per_eval']:.1f} host syncs per free evaluation"
        else:
            case = f"hard wall N={r['n']} memory on one GPU"
            nums = (f"estimate {r['estimate_GB']:.1f} GB ({r['estimate_arrays']:.2f} arrays), free "
                    f"{r['gpu_free_GB']:.1f} GB; {r['status']}")
            if "solve_s" in r:
                nums += (f", {r['solve_s']:.3g} s, {r['iterations']} it, pool peak {r['pool_peak_GB_incl_heights']:.1f}"
                         f" GB incl. heights ({r['arrays_measured']:.2f} arrays)")
        out.append(f"| {p} | {case} | {nums} |")
    return "\n".join(out)


PARTS = {"pairs": part_pairs, "hardwall": part_hardwall, "big": part_big, "free": part_free}


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--out", type=Path, required=True)
    p.add_argument("--backend", choices=["cupy", "numpy"], default="cupy")
    p.add_argument("--quick", action="store_true", help="small sizes, < 1 min on an H200; the big grid estimated only")
    p.add_argument("--parts", nargs="+", choices=list(PARTS), default=list(PARTS))
    p.add_argument("--no-free-cg", dest="free_cg", action="store_false",
                   help="free: skip the exponential law's free solve with method cg")
    p.add_argument("--hardwall-methods", nargs="+", default=["auto"],
                   help="hardwall: the methods timed side by side (auto, pk, pcg, mpcg; mpcg:SIDE stops its coarse "
                        "levels at grids of side SIDE, an experiment; default: the GPU's default)")
    p.add_argument("--hardwall-seeds", type=int, nargs="+", default=[1],
                   help="hardwall: surface seeds (default 1, the issue's surface; others are held out)")
    p.add_argument("--budget", type=float, default=330.0, help="seconds after which no further part starts")
    p.add_argument("--force", action="store_true", help="big: run even where the estimate exceeds the free memory")
    p.add_argument("--free-memory", type=int, nargs="+", default=None,
                   help="stored L-BFGS pairs of the free smooth minimiser to time (default: 12 4)")
    a = p.parse_args(argv)
    if a.backend == "numpy":  # toy sizes: a check of the script's logic, not a measurement
        a.n_pairs, a.n_hardwall, a.n_free, a.n_memcheck, a.n_big = [128, 256], 128, 128, 128, 256
    elif a.quick:
        a.n_pairs, a.n_hardwall, a.n_free, a.n_memcheck, a.n_big = [1024, 2048], 2048, 2048, 4096, 32768
    else:
        a.n_pairs, a.n_hardwall, a.n_free, a.n_memcheck, a.n_big = [2048, 4096, 8192], 4096, 4096, 4096, 32768
    if a.free_memory is None:
        a.free_memory = [12] if a.quick else [12, 4]
    dev = Device(a.backend)
    rows: list[dict] = []
    t0 = time.perf_counter()
    for name in (k for k in PARTS if k in a.parts):
        if time.perf_counter() - t0 > a.budget:  # the device time is lent: stop with what was measured
            rows.append(_row(name, status=f"skipped: the run passed --budget {a.budget:g} s"))
            continue
        PARTS[name](dev, a, rows)
    meta = {"host": platform.node(), "device": dev.name, "backend": a.backend, "python": platform.python_version(),
            "cpus": os.cpu_count(), "command": " ".join(sys.argv), "date": time.strftime("%Y-%m-%d %H:%M UTC",
                                                                                       time.gmtime()),
            "total_s": time.perf_counter() - t0}
    a.out.mkdir(parents=True, exist_ok=True)
    (a.out / "gpu_floor.json").write_text(json.dumps({"meta": meta, "rows": rows}, indent=1, default=str))
    table = summary(rows)
    (a.out / "gpu_floor.md").write_text(f"### GPU floor ({dev.name}, {meta['date']})\n\n`{meta['command']}`\n\n"
                                        f"{table}\n")
    print(table)
    print(f"total {meta['total_s']:.1f} s on {dev.name}")
    bad = [r for r in rows if str(r.get("status", "")).startswith("failed")]
    return 1 if bad else 0


if __name__ == "__main__":
    _record.track(CODE_PATHS)
    sys.exit(main())
