"""Hard wall on one CPU core (issue 22, item 1): what the cheaper passes and a sweep chain's warm start buy.

    OMP_NUM_THREADS=1 GAPSWEEP_FFT_THREADS=1 python benchmarks/bench_hardwall_cpu.py passes [--n 1024]
    OMP_NUM_THREADS=1 GAPSWEEP_FFT_THREADS=1 python benchmarks/bench_hardwall_cpu.py chain [--n 1024]
        [--sigma0 1e-3 3e-3 1e-2 3e-2 1e-1 2e-1] [--hurst 0.8]
    OMP_NUM_THREADS=1 GAPSWEEP_FFT_THREADS=1 python benchmarks/bench_hardwall_cpu.py loops [--n 1024] [--hurst 0.8]
        [--seed 1] [--sigma0 1e-3 1e-2 1e-1] [--loops real spectral real spectral] [--max-iter 5000]

``passes``: CPU ms of one iteration's element-wise passes (contact_sum, gap, zstats, direction, rstats, update,
rescale; the three input copies the harness needs included) on a clustered contact set of the fig-2 surface
(p = max(h - 0.3 h_rms, 0), area 0.38), next to one FFT convolution of the same grid (the solver spends 2-3 per
iteration). Run it on two commits to compare kernels.

``chain``: a sweep chain along increasing loads, each load solved cold ("mpcg", coarse-to-fine start) and warm
(``initial=`` the previous load's result: its pressure rescaled to the new load, "pcg"); iterations, FFT pairs,
CPU seconds side by side per load, and the mean gaps' relative difference (both to tol 1e-8). Surfaces: the
fig-2/3 surfaces of benchmarks/bench_contact.py.

``loops`` (issue 30): the iteration loops of gapsweep/gfmd/_constrained.py side by side on one surface ("mpcg",
tol 1e-8; lambda_s = 2.56 / n, so n = 1024 is the fig-2/3 surface and smaller n stay resolved): ``real`` (the
real-space loop: ``r = K t`` and ``u = K p`` afresh after a clipping projection), ``spectral`` (``p~`` kept in
Fourier space, the default on the CPU). (An integer ``K`` once ran the real-space loop that skipped the fresh
``K p`` after clipping, re-syncing ``u`` every ``K`` iterations: it broke convergence, results/contact/
issue30_lag_resync_512.txt, and was deleted.) Iterations, FFT pairs per iteration,
CPU seconds, residual, status and the mean gap's relative difference to the first loop listed."""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

# appended, not prepended: PYTHONPATH=<another checkout> times that checkout's kernels (passes on two commits)
sys.path.append(str(Path(__file__).resolve().parents[1]))

import sys as _sys
from pathlib import Path as _Path

from gapsweep.core.fft import get_backend
from gapsweep.gfmd import solve
from gapsweep.gfmd._constrained_ops import make_ops
from gapsweep.surface import self_affine

_sys.path.insert(0, str(_Path(__file__).resolve().parent))
import _record

# the code this benchmark measures: a result measured before a later change to it is stale
# (scripts/check_docs.py)
CODE_PATHS = ['gapsweep/gfmd', 'gapsweep/core']


def surf(n: int, hurst: float, seed: int = 1) -> np.ndarray:
    """The fig-2/3 surfaces of benchmarks/bench_contact.py (not imported: it puts this checkout first)."""
    return self_affine(n, hurst, lambda_l=0.25, lambda_s=2.5e-3, rms_slope=1.0, seed=seed)


def cmd_passes(a: argparse.Namespace) -> None:
    n = a.n
    h = surf(n, 0.8)
    h = h - h.mean()
    p = np.maximum(h - 0.3 * h.std(), 0.0)
    rng = np.random.default_rng(0)
    u, g, gs, z, t, r = (rng.random((n, n)) for _ in range(6))
    ops = make_ops(np)

    def once() -> None:
        ops.contact_sum(u, h, p)
        ops.gap(u, h, 0.1, p, g, gs)
        ops.zstats(z, gs, p)
        ops.direction(t, z, 0.1, 0.5, p)
        ops.rstats(r, t, gs, p)
        q = p.copy()
        ops.update(q, t, g, 1e-3)
        ops.rescale(q, u.copy(), r, 1.0, 0.0, True)

    fft = get_backend("pyfftw", n, threads=1)
    mult = rng.random((n, n // 2 + 1))
    out = np.empty((n, n))
    once()
    fft.convolve(u, mult, out)
    reps = 20
    t0 = time.process_time()
    for _ in range(reps):
        once()
    tp = (time.process_time() - t0) / reps
    t0 = time.process_time()
    for _ in range(reps):
        fft.convolve(u, mult, out)
    tc = (time.process_time() - t0) / reps
    print(f"n={n} area={np.mean(p > 0):.3f}: passes per iteration {tp * 1e3:.2f} ms, one FFT convolution "
          f"{tc * 1e3:.2f} ms ({type(ops).__name__})")


def cmd_chain(a: argparse.Namespace) -> None:
    for hurst in a.hurst:
        h = surf(a.n, hurst)
        solve(h, sigma0=a.sigma0[0], interaction="hard_wall", tol=1e-8, max_iter=2)  # plans, jit
        prev = None
        print(f"H={hurst} n={a.n}: sigma0 | cold its/pairs/CPU s | warm its/pairs/CPU s | ratio | rel. diff mean gap")
        tot_c = tot_w = 0.0
        for s0 in a.sigma0:
            t0 = time.process_time()
            cold = solve(h, sigma0=s0, interaction="hard_wall", tol=1e-8)
            tc = time.process_time() - t0
            if prev is None:
                warm, tw = cold, tc
            else:
                t0 = time.process_time()
                warm = solve(h, sigma0=s0, interaction="hard_wall", tol=1e-8, initial=prev)
                tw = time.process_time() - t0
            tot_c += tc
            tot_w += tw
            diff = abs(warm.mean_gap / cold.mean_gap - 1)
            print(f"{s0:g} | {cold.iterations}/{cold.diagnostics['fft_pairs']}/{tc:.2f} | "
                  f"{warm.iterations}/{warm.diagnostics['fft_pairs']}/{tw:.2f} | {tc / tw:.2f} | {diff:.1e}",
                  flush=True)
            prev = warm
        print(f"chain total: cold {tot_c:.2f} s, warm {tot_w:.2f} s, ratio {tot_c / tot_w:.2f}")


def cmd_loops(a: argparse.Namespace) -> None:
    from gapsweep.gfmd import _constrained as C

    n = a.n
    h = self_affine(n, a.hurst, lambda_l=0.25, lambda_s=2.56 / n, rms_slope=1.0, seed=a.seed)
    solve(h[:64, :64].copy(), sigma0=1e-2, interaction="hard_wall")  # jit
    solve(h, sigma0=1e-2, interaction="hard_wall", tol=1e-2)  # plans
    for s0 in a.sigma0:
        ref = None
        for loop in a.loops:
            C._SPECTRAL = loop == "spectral"
            t0 = time.process_time()
            r = solve(h, sigma0=s0, interaction="hard_wall", tol=1e-8, method="mpcg", max_iter=a.max_iter)
            cpu = time.process_time() - t0
            ref = ref or r
            pairs = r.diagnostics["fft_pairs"]
            print(f"n={n} H={a.hurst} seed={a.seed} sigma0={s0:g} loop={loop}: iterations {r.iterations} "
                  f"(coarse {r.diagnostics['coarse_iterations']}), FFT pairs {pairs} "
                  f"({pairs / max(r.iterations, 1):.2f} per iteration), CPU {cpu:.2f} s, residual {r.residual:.2e} "
                  f"{r.status}, mean gap rel. diff {abs(r.mean_gap / ref.mean_gap - 1):.1e}", flush=True)
    C._SPECTRAL = True


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = ap.add_subparsers(dest="cmd", required=True)
    p = sub.add_parser("passes")
    p.add_argument("--n", type=int, default=1024)
    c = sub.add_parser("chain")
    c.add_argument("--n", type=int, default=1024)
    c.add_argument("--sigma0", type=float, nargs="+", default=[1e-3, 3e-3, 1e-2, 3e-2, 1e-1, 2e-1])
    c.add_argument("--hurst", type=float, nargs="+", default=[0.8])
    lp = sub.add_parser("loops")
    lp.add_argument("--n", type=int, default=1024)
    lp.add_argument("--hurst", type=float, default=0.8)
    lp.add_argument("--seed", type=int, default=1)
    lp.add_argument("--sigma0", type=float, nargs="+", default=[1e-3, 1e-2, 1e-1])
    lp.add_argument("--loops", nargs="+", choices=["real", "spectral"],
                    default=["real", "spectral", "real", "spectral"])
    lp.add_argument("--max-iter", type=int, default=5000)
    a = ap.parse_args()
    {"passes": cmd_passes, "chain": cmd_chain, "loops": cmd_loops}[a.cmd](a)


if __name__ == "__main__":
    _record.track(CODE_PATHS, header=True)
    main()
