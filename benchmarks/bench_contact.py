"""Hard-wall contact benchmarks (issue 12): gapsweep against tamaas and ContactMechanics side by side in one run,
one core; and the GPU timing. Writes ``<name>.md`` and ``<name>.json`` to --out (rows appended as they finish).

    OMP_NUM_THREADS=1 python benchmarks/bench_contact.py cpu --out OUT [--n 2048] [--hurst 0.3 0.8]
        [--sigma0 1e-3 1e-2 1e-1] [--seeds 1] [--tol 1e-8] [--methods pcg mpcg pk] [--peers tamaas contactmechanics]
        [--alone]     (gapsweep's methods only, no peer solve: --alone is --peers with no names)
    python benchmarks/bench_contact.py gpu --out OUT [--n 4096] [--sigma0 1e-2]      (cupy on an NVIDIA GPU)

Surfaces: the figure-2/3 surfaces of docs/model.md M6 (L = 1, E* = 1, lambda_l = 0.25, lambda_s = 2.5e-3,
rms slope 1, seed 1; H = 0.3 and 0.8; ``--seeds`` for held-out surfaces). A method named ``NAME:restart``
(e.g. ``mpcg:restart``) runs NAME with the CG restarted at every re-entry (``_constrained._KEEP = 0``, the rule
before issue 39) for a before/after comparison in one run. Stopping rule: every code is asked for the same
tolerance ``tol`` in its own measure (gapsweep: gap left in the contact and overlap outside it, over h_rms; tamaas: its
PolonskyKeerRey error; ContactMechanics: pentol = tol h_rms, forcetol = tol sigma0); then every code's fields are
scored by gapsweep's measure (``resid``) and the three codes' mean gap, contact area and elastic energy are
compared, so the accuracy reached is visible next to the time; ``err_vs_tight`` is each result's largest relative
error in mean gap and elastic energy against one gapsweep solve to ``--tight`` (default 1e-12, not timed); the
row ``pcg@peer_resid`` times gapsweep again
with ``tol`` = the smallest residual a peer reached (equal accuracy). Times are CPU seconds of this process
(``time.process_time``, one thread: OMP_NUM_THREADS=1, GAPSWEEP_FFT_THREADS=1) and wall seconds.
"""

from __future__ import annotations

import argparse
import contextlib
import ctypes
import json
import math
import os
import platform
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import sys as _sys
from pathlib import Path as _Path

from gapsweep import gfmd
from gapsweep.surface import self_affine

_sys.path.insert(0, str(_Path(__file__).resolve().parent))
import _record

# the code this benchmark measures: a result measured before a later change to it is stale
# (scripts/check_docs.py)
CODE_PATHS = ['gapsweep/gfmd', 'gapsweep/surfaces']


def surf(n: int, hurst: float, seed: int = 1) -> np.ndarray:
    return self_affine(n, hurst, lambda_l=0.25, lambda_s=2.5e-3, rms_slope=1.0, seed=seed)


def score(h: np.ndarray, u: np.ndarray, p: np.ndarray) -> dict:
    """gapsweep's hard-wall measures of any code's fields (u up to a constant, p >= 0 pressures)."""
    hc = h - h.mean()
    h_rms = float(np.sqrt(np.mean(hc**2)))
    S = p > 0
    g = u - hc
    g = g - g[S].mean()
    resid = max(float(np.sqrt(np.mean(g[S] ** 2))), max(0.0, -float(g[~S].min())) if (~S).any() else 0.0) / h_rms
    gap = np.where(S, 0.0, g)
    return {"mean_gap": float(gap.mean()), "area": float(S.mean()),
            "energy": 0.5 * float(np.mean((u - u.mean()) * (p - p.mean()))), "resid": resid}


@contextlib.contextmanager
def quiet_fd1():
    """tamaas prints its iteration table on the C-level stdout."""
    sys.stdout.flush()
    saved = os.dup(1)
    with open(os.devnull, "w") as null:
        os.dup2(null.fileno(), 1)
        try:
            yield
        finally:
            sys.stdout.flush()
            ctypes.CDLL(None).fflush(None)  # the C library's buffer, before fd 1 comes back
            os.dup2(saved, 1)
            os.close(saved)


def run_gapsweep(h, s0, tol, method):
    from gapsweep.gfmd import _constrained

    method, _, variant = method.partition(":")
    keep = _constrained._KEEP
    _constrained._KEEP = 0.0 if variant == "restart" else keep
    try:
        t, w = time.process_time(), time.perf_counter()
        r = gfmd.solve(h, sigma0=s0, interaction="hard_wall", tol=tol, method=method, backend="auto")
        cpu, wall = time.process_time() - t, time.perf_counter() - w
    finally:
        _constrained._KEEP = keep
    # iters: fine-grid iterations; "mpcg" adds its coarse levels' iterations (finest first) in coarse_iters
    return {**score(h, r.displacement, r.pressure), "iters": r.iterations,
            "coarse_iters": "+".join(map(str, r.diagnostics.get("coarse_iterations", []))) or "-",
            "cpu_s": cpu, "wall_s": wall, "ok": r.converged}


def run_tamaas(h, s0, tol):
    import tamaas

    n = h.shape[0]
    m = tamaas.ModelFactory.createModel(tamaas.model_type.basic_2d, [1.0, 1.0], [n, n])
    m.E, m.nu = 1.0, 0.0
    t, w = time.process_time(), time.perf_counter()
    with quiet_fd1():
        solver = tamaas.PolonskyKeerRey(m, h.copy(), tol)
        solver.max_iter = 100000
        solver.solve(s0)
    cpu, wall = time.process_time() - t, time.perf_counter() - w
    u, p = np.array(m.displacement), np.array(m.traction)
    return {**score(h, u, p), "iters": -1, "coarse_iters": "-", "cpu_s": cpu, "wall_s": wall, "ok": True}


def run_contactmechanics(h, s0, tol):
    from ContactMechanics import PeriodicFFTElasticHalfSpace
    from ContactMechanics.Systems import NonSmoothContactSystem
    from SurfaceTopography import Topography

    n = h.shape[0]
    system = NonSmoothContactSystem(PeriodicFFTElasticHalfSpace((n, n), 1.0, physical_sizes=(1.0, 1.0)),
                                    Topography(h, (1.0, 1.0)))
    t, w = time.process_time(), time.perf_counter()
    res = system.minimize_proxy(external_force=s0, pentol=tol * float(h.std()), forcetol=tol * s0 / n**2,
                                maxiter=100000)
    cpu, wall = time.process_time() - t, time.perf_counter() - w
    return {**score(h, res.x, res.jac * n * n), "iters": int(res.nit), "coarse_iters": "-", "cpu_s": cpu,
            "wall_s": wall, "ok": bool(res.success)}


def write(out: Path, name: str, rows: list[dict], header: str) -> None:
    out.mkdir(parents=True, exist_ok=True)
    import datetime
    import subprocess

    try:
        commit = subprocess.run(["git", "rev-parse", "HEAD"], capture_output=True, text=True,
                                cwd=Path(__file__).resolve().parents[1]).stdout.strip()
    except OSError:
        commit = ""
    meta = {"host": platform.node(), "machine": f"{platform.machine()} {platform.processor()}".strip(),
            "python": platform.python_version(), "cpus": os.cpu_count(), "commit": commit,
            "date": datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds"),
            "command": " ".join(sys.argv)}
    (out / f"{name}.json").write_text(json.dumps({"meta": meta, "rows": rows}, indent=1))
    keys = list(rows[0]) if rows else []
    lines = [header, "", f"`{meta['command']}`", "", "| " + " | ".join(keys) + " |", "|" + " --- |" * len(keys)]
    for r in rows:
        lines.append("| " + " | ".join(f"{v:.4g}" if isinstance(v, float) else str(v) for v in r.values()) + " |")
    (out / f"{name}.md").write_text("\n".join(lines) + "\n")


def cmd_cpu(a) -> None:
    if a.alone:
        a.peers = []
    peers = {"tamaas": run_tamaas, "contactmechanics": run_contactmechanics}
    rows = []
    for hurst, seed in ((hh, sd) for hh in a.hurst for sd in a.seeds):
        h = surf(a.n, hurst, seed)
        gfmd.solve(h[:64, :64].copy(), sigma0=1e-2, interaction="hard_wall")  # compile kernels
        gfmd.solve(h, sigma0=a.sigma0[0], interaction="hard_wall", tol=1e-2)  # FFT plans (wisdom)
        for s0 in a.sigma0:
            res = {m: run_gapsweep(h, s0, a.tol, m) for m in a.methods}
            for name in a.peers:
                try:
                    res[name] = peers[name](h, s0, a.tol)
                except ImportError as exc:
                    print(f"{name}: not installed ({exc})", flush=True)
            peer_resid = [res[k]["resid"] for k in a.peers if k in res]
            if peer_resid:  # the peers stop tighter in gapsweep's measure: also time gapsweep at their accuracy
                res[f"{a.methods[0]}@peer_resid"] = run_gapsweep(h, s0, min(peer_resid), a.methods[0])
            ref = res[a.methods[0]]
            # Accuracy reached: every code scored against one tight-tolerance solve (not timed).
            tight = gfmd.solve(h, sigma0=s0, interaction="hard_wall", tol=a.tight, method="pcg", max_iter=100000)
            tq = score(h, tight.displacement, tight.pressure)
            for code, r in res.items():
                r["err_vs_tight"] = max(abs(r["mean_gap"] / tq["mean_gap"] - 1), abs(r["energy"] / tq["energy"] - 1))
                row = {"H": hurst, "seed": seed, "sigma0": s0, "n": a.n, "tol": a.tol, "code": code, **r,
                       "gap_rel_diff": abs(r["mean_gap"] - ref["mean_gap"]) / ref["mean_gap"],
                       "energy_rel_diff": abs(r["energy"] - ref["energy"]) / ref["energy"],
                       "cpu_ratio_vs_gapsweep": r["cpu_s"] / ref["cpu_s"]}
                rows.append(row)
                print({k: (f"{v:.4g}" if isinstance(v, float) else v) for k, v in row.items()}, flush=True)
            write(a.out, a.name, rows, "### Hard wall, one core: gapsweep vs tamaas vs ContactMechanics")


def cmd_gpu(a) -> None:
    import cupy

    name = cupy.cuda.runtime.getDeviceProperties(0)["name"].decode()
    rows = []
    for n in a.n:
        h_host = surf(n, 0.3)
        h = cupy.asarray(h_host)
        for s0 in a.sigma0:
            kw = dict(sigma0=s0, interaction="hard_wall", tol=a.tol, host=False)
            gfmd.solve(h, **kw)  # warm-up: plans, kernels
            best, r = math.inf, None
            for _ in range(a.repeat):
                cupy.cuda.Device().synchronize()
                t = time.perf_counter()
                r = gfmd.solve(h, **kw)
                cupy.cuda.Device().synchronize()
                best = min(best, time.perf_counter() - t)
            cpu = gfmd.solve(h_host, sigma0=s0, interaction="hard_wall", tol=a.tol) if n <= a.check_n else None
            rows.append({"gpu": name, "n": n, "sigma0": s0, "tol": a.tol, "iters": r.iterations,
                         "converged": r.converged, "best_s_fields_on_gpu": best, "area": r.contact_area,
                         "mean_gap": r.mean_gap,
                         "cpu_gap_rel_diff": (abs(cpu.mean_gap - r.mean_gap) / cpu.mean_gap) if cpu else math.nan})
            print(rows[-1], flush=True)
    write(a.out, "contact_gpu", rows, f"### Hard wall on the GPU ({name}), fields left on the GPU")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = ap.add_subparsers(dest="cmd", required=True)
    c = sub.add_parser("cpu")
    c.add_argument("--out", type=Path, required=True)
    c.add_argument("--n", type=int, default=2048)
    c.add_argument("--hurst", type=float, nargs="+", default=[0.3, 0.8])
    c.add_argument("--sigma0", type=float, nargs="+", default=[1e-3, 1e-2, 1e-1])
    c.add_argument("--seeds", type=int, nargs="+", default=[1])
    c.add_argument("--tol", type=float, default=1e-8)
    c.add_argument("--tight", type=float, default=1e-12,
                   help="tolerance of the reference solve every code is scored against (err_vs_tight)")
    c.add_argument("--methods", nargs="+", default=["pcg", "pk"], help="gapsweep methods; the first is the reference")
    c.add_argument("--peers", nargs="*", default=["tamaas", "contactmechanics"])
    c.add_argument("--alone", action="store_true", help="gapsweep only (no peer solves)")
    c.add_argument("--name", default="contact_cpu", help="output file stem")
    g = sub.add_parser("gpu")
    g.add_argument("--out", type=Path, required=True)
    g.add_argument("--n", type=int, nargs="+", default=[4096])
    g.add_argument("--sigma0", type=float, nargs="+", default=[1e-2])
    g.add_argument("--tol", type=float, default=1e-8)
    g.add_argument("--repeat", type=int, default=3)
    g.add_argument("--check-n", type=int, default=0, help="also solve on the CPU up to this n and compare")
    a = ap.parse_args()
    {"cpu": cmd_cpu, "gpu": cmd_gpu}[a.cmd](a)


if __name__ == "__main__":
    _record.track(CODE_PATHS)
    main()
