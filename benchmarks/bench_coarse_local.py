"""The coarse-to-fine start on one CPU process against the plain start (issue 39 item 4; docs/gfmd.md
"Coarse-to-fine start"): process CPU seconds of ``gfmd.solve(..., start="flat")``, ``start="coarse"`` (the plain
minimisers and FFT engine, ``gapsweep.gfmd._coarse.solve_local``) and the former one-process path, the slab
solver on numpy's FFT (``distributed.solve(..., comm=SelfComm(), start="coarse")``), side by side in one run.

Cases nobody tuned the start on (the one-process driver was written against a 1024^2 exponential and a 512^2
adhesive surface of seed 11, H 0.7, not these): other seeds and Hurst exponents, a rectangular grid and box (the
exponential law then on the smooth L-BFGS), adhesion, and the contact-mechanics challenge's pixel in um / MPa
(``bench_challenge_proxy.py``'s constants on a 512^2 box). Each case: one warm-up solve per start (plans, numba),
then ``--repeats`` rounds alternating the starts, the minimum CPU time per start. Single thread:

    OMP_NUM_THREADS=1 NUMBA_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1 PYTHONPATH=$PWD nice -n 10 \\
        python benchmarks/bench_coarse_local.py --repeats 2 --json benchmarks/results/round3/coarse_local.json

``--backend cupy``: the same cases on one GPU, wall seconds synchronised, fields left on the device; there
``start="coarse"`` is the distributed solver on one rank (the slab path), so the rows' ``slab`` equals ``coarse``:

    PYTHONPATH=$PWD python benchmarks/bench_coarse_local.py --backend cupy --repeats 3 --json OUT.json
"""

from __future__ import annotations

import argparse
import json
import math
import os
import platform
import subprocess
import sys
import time
import warnings
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from gapsweep import gfmd  # noqa: E402
from gapsweep.gfmd import distributed  # noqa: E402
from gapsweep.gfmd._coarse import SelfComm  # noqa: E402
from gapsweep.surfaces.synthetic import self_affine  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))
import _record  # noqa: E402

# the code this benchmark measures: a result measured before a later change to it is stale
# (scripts/check_docs.py)
CODE_PATHS = ['gapsweep/gfmd', 'gapsweep/surfaces']

DX = 100.0 / 65536  # um: the challenge's pixel (bench_challenge_proxy.py)


def cases() -> list[tuple[str, np.ndarray, dict]]:
    out = []
    h = self_affine(1024, 0.8, lambda_l=0.5, lambda_s=4 / 1024, rms_slope=1.0, seed=3)
    out.append(("exponential 1024^2 H0.8 s3", h, dict(interaction="exponential", gamma0=1e-4, rho=2 / 1024,
                                                      sigma0=5e-3, tol=1e-8)))
    h = self_affine(768, 0.5, lambda_l=0.5, lambda_s=4 / 768, rms_slope=0.7, seed=8)[:, :512]
    out.append(("exponential 768x512 H0.5 s8 (rectangle)", h, dict(interaction="exponential", gamma0=1e-4,
                                                                   rho=1.5 / 768, sigma0=1e-2, tol=1e-8,
                                                                   length=(1.0, 512 / 768))))
    h = self_affine(512, 0.5, lambda_l=0.5, lambda_s=3 / 512, rms_slope=0.8, seed=7)
    out.append(("adhesive 512^2 H0.5 s7", h, dict(interaction="adhesive", work=2e-4, rho=2 / 512, sigma0=1e-2,
                                                  tol=1e-8)))
    h = self_affine(512, 0.8, lambda_l=512 * DX / 2, lambda_s=0.1, rms_slope=0.69, seed=4, length=512 * DX)
    out.append(("exponential 512^2 challenge pixel um/MPa s4", h,
                dict(interaction="exponential", gamma0=0.05, rho=2.071e-3, sigma0=0.5, e_star=25.0,
                     length=512 * DX, tol=1e-8)))
    return out


def run(h: np.ndarray, kw: dict, start: str, gpu: Any = None) -> tuple[object, float]:
    """The solve and its process CPU seconds; on the GPU (``gpu``: cupy) its wall seconds, synchronised, with
    the fields left on the device."""
    if gpu is not None:
        gpu.cuda.get_current_stream().synchronize()
        c = time.perf_counter()
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            r = gfmd.solve(h, start=start, backend="cupy", host=False, **kw)
        gpu.cuda.get_current_stream().synchronize()
        return r, time.perf_counter() - c
    c = time.process_time()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        if start == "slab":
            r = distributed.solve(h, comm=SelfComm(), start="coarse", **kw)
        else:
            r = gfmd.solve(h, start=start, **kw)
    return r, time.process_time() - c


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=2)
    ap.add_argument("--json", type=Path, default=None)
    ap.add_argument("--only", default="")
    ap.add_argument("--backend", choices=["cpu", "cupy"], default="cpu",
                    help="cupy: the same cases on one GPU (start='coarse' is the slab path there), wall seconds")
    args = ap.parse_args()
    gpu = None
    if args.backend == "cupy":
        import cupy as gpu
    rows = []
    starts = ("flat", "coarse", "slab") if gpu is None else ("flat", "coarse")
    for name, h, kw in cases():
        if args.only not in name:
            continue
        if gpu is not None:
            h = gpu.asarray(h)
        res, cpu = {}, {s: math.inf for s in starts}
        for s in starts:
            res[s] = run(h, kw, s, gpu)[0]  # warm-up
        for _ in range(args.repeats):
            for s in starts:
                res[s], t = run(h, kw, s, gpu)
                cpu[s] = min(cpu[s], t)
        if gpu is not None:  # the GPU's coarse start is the slab path: one row per start pair
            res["slab"], cpu["slab"] = res["coarse"], cpu["coarse"]
        a, b, c = res["flat"], res["coarse"], res["slab"]
        row = dict(case=name, shape=list(h.shape), law=kw["interaction"],
                   status={s: res[s].status for s in starts},
                   evaluations={s: int(res[s].iterations) for s in starts},
                   coarse_cost={s: float(res[s].diagnostics.get("coarse_cost", 0.0)) for s in starts},
                   cpu_s=cpu, coarse_over_flat=cpu["coarse"] / cpu["flat"], slab_over_flat=cpu["slab"] / cpu["flat"],
                   mean_gap_rel_diff=abs(b.mean_gap / a.mean_gap - 1),
                   contact_area_diff_pixels=abs(b.contact_area - a.contact_area) * h.size,
                   gap_max_diff_rel=float(abs(b.gap - a.gap).max() / abs(a.gap).max()), backend=args.backend,
                   seconds="wall (GPU, synchronised)" if gpu is not None else "process CPU")
        rows.append(row)
        print(f"{name:45s} evals flat/coarse/slab {a.iterations}/{b.iterations}+{row['coarse_cost']['coarse']:.1f}/"
              f"{c.iterations}  {'wall' if gpu is not None else 'CPU'} s "
              f"{cpu['flat']:.3f}/{cpu['coarse']:.3f}/{cpu['slab']:.3f}  coarse/flat "
              f"{row['coarse_over_flat']:.2f} slab/flat {row['slab_over_flat']:.2f}  gap diff "
              f"{row['mean_gap_rel_diff']:.1e}", flush=True)
        assert all(res[s].converged for s in starts), row["status"]
    commit = subprocess.run(["git", "rev-parse", "HEAD"], cwd=ROOT, capture_output=True, text=True).stdout.strip()
    meta = dict(machine=platform.processor() or platform.machine(), cpus=os.cpu_count(), load=os.getloadavg()[0],
                python=platform.python_version(), repeats=args.repeats, commit=commit,
                command="python " + " ".join(sys.argv), date=time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
                threads={k: os.environ.get(k) for k in ("OMP_NUM_THREADS", "NUMBA_NUM_THREADS",
                                                        "OPENBLAS_NUM_THREADS")})
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(dict(meta=meta, rows=rows), indent=1))


if __name__ == "__main__":
    _record.track(CODE_PATHS)
    main()
