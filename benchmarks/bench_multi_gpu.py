"""The farm on 1, 2 and 4 GPUs of one node, in one call (docs/benchmarks.md, "Several GPUs: the farm").

For each set of jobs and each GPU count k: one launch ``mpiexec -n R --bind-to none python3 -m gapsweep run J1 J2
... --store S1 --store S2 ...`` with ``CUDA_VISIBLE_DEVICES=0..k-1`` -- rank 0 coordinates, the run's default layout
makes GPU workers (up to 8 per GPU under CUDA MPS, started by the run; one per GPU without MPS) and CPU workers of
the other ranks (docs/running.md, "Which layout"); R is the same for every k. Sets: ``figs`` = jobs/gpu/fig6,
fig4_5, fig2, fig3; ``pub`` = jobs/pub/fig2, fig3, fig4_5 (``--pub-seeds S``: S seeds instead of 16, copies written
under OUT/jobs); ``sde`` = jobs/bench_sde_gpus.toml.

Per run: wall (launch to exit), start-up (launch to the farm's start, ``farm_started_unix`` of the first job's
run record), sweep = wall - start-up, efficiency T1 / (k Tk) on both, GPU utilisation (nvidia-smi sampled every
0.5 s, mean per GPU over the run), GFMD wall per solve (median, max), row counts, and every store compared bit for
bit with the 1-GPU store of the same job (``store.diff``: every column but wall time and rank, the histograms).

``--fault-check``: figure 2 on 2 GPUs while a helper process holds all but 64 MB of GPU 1's memory (a real CUDA
out-of-memory in that GPU worker): every row done and the store equal to the 1-GPU store; then with GPUs 0 and 1
both held: the GPU rows stay pending, exit 5, one "no GPU left" line; the holders go and ``--resume`` gives the
1-GPU store.

``--budget SECONDS`` (default 470): a run whose estimate (its 1-GPU time / k, or a prior) would end past it is
skipped and recorded as such, and no launch runs past the budget + 60 s; the fault check runs if at least 90 s
of the budget are left (alone: ``--sets`` with no set).

    python3 benchmarks/bench_multi_gpu.py --out OUT --work /tmp/farm --gpus 1 2 4 --sets pub sde figs
    python3 benchmarks/bench_multi_gpu.py --out OUT --work /tmp/farm --sets --fault-check   # the fault check alone

(the second writes OUT/fault_check.json and reuses the first's /tmp/farm/gpus1/fig2.h5 as its reference; the
stores stay in --work, default --out).

``--layouts [SET@]G:K[:R][/each][/host] ...`` (issue 38): these layouts in order instead -- G GPUs, K ranks per GPU
(``auto``: the run's default, no flag), R ranks; ``/each``: the jobs one farm each (``--farm each``); ``/host``: the
GPU tasks' surfaces on the host (``GAPSWEEP_GPU_SURFACES=0``; stores also compared by grid point within
tolerance) -- each traced (``GAPSWEEP_TRACE``: per-worker busy/idle over the sweep and timelines, per farm its
window and the gaps between farms, the coordinator's latency, the longest units, the tail), with GPU utilisation
over the sweep, the processes holding contexts on several GPUs (``nvidia-smi --query-compute-apps``), stores
against the set's first run, and the table against T1_best (the best one-GPU wall time of the set, any layout)
with a summary (T1_best and its layout, the layouts tried, per GPU count the default's efficiency, utilisation and
idle share); sets ``mix`` (benchmarks/jobs/issue38) and ``mixsplit`` (the same with ``split_chains``, compared
with ``mix`` by grid point); writes OUT/NAME.json, OUT/NAME.md and OUT/NAME_runs.log (``--name``;
benchmarks/gpu_node_issue38.sh runs it).

    python3 benchmarks/bench_multi_gpu.py --out OUT --work /tmp/l --sets pub --layouts 1:auto 1:16 2:auto 4:auto

Writes OUT/results.json (every run, the node, the command) and OUT/table.md (OUT/fault_check.json for the fault
check alone); logs in OUT/runs.log.
"""

from __future__ import annotations

import argparse
import itertools
import json
import math
import os
import shutil
import signal
import statistics
import subprocess
import sys
import sys as _sys
import threading
import time
from pathlib import Path
from pathlib import Path as _Path

_sys.path.insert(0, str(_Path(__file__).resolve().parent))
import _record

# the code this benchmark measures: a result measured before a later change to it is stale
# (scripts/check_docs.py)
CODE_PATHS = ['gapsweep/sweep', 'gapsweep/gfmd', 'gapsweep/gapdist', 'gapsweep/surfaces', 'gapsweep/cli.py']

ROOT = Path(__file__).resolve().parents[1]
SETS = {
    "figs": [ROOT / "jobs" / "gpu" / f"{j}.toml" for j in ("fig6", "fig4_5", "fig2", "fig3")],
    "pub": [ROOT / "jobs" / "pub" / f"{j}.toml" for j in ("fig2", "fig3", "fig4_5")],
    "sde": [ROOT / "jobs" / "bench_sde_gpus.toml"],
    # issue 38's own mixed sweep: exponential law at N = 1024 and 4096, hard wall and adhesion at N = 2048
    "mix": [ROOT / "benchmarks" / "jobs" / "issue38" / f"mix_{j}.toml" for j in ("exp", "hard", "adh")],
}
SPLIT = 2  # "mixsplit": the mix jobs with [methods.gfmd] split_chains = SPLIT (not the adhesive one: refused)
# 1-GPU seconds assumed before it is measured (issue 26: figs 18.6 s under MPS, pub 120 s one worker per GPU;
# mix: a guess)
PRIOR = {"figs": 25.0, "pub": 120.0, "sde": 45.0, "mix": 40.0, "mixsplit": 40.0}
T_START = time.monotonic()


def env(devices: str) -> dict[str, str]:
    e = dict(os.environ, CUDA_VISIBLE_DEVICES=devices, PYTHONUNBUFFERED="1", OMP_NUM_THREADS="1",
             NUMBA_NUM_THREADS="1", GAPSWEEP_FFT_THREADS="1", OMPI_ALLOW_RUN_AS_ROOT="1",
             OMPI_ALLOW_RUN_AS_ROOT_CONFIRM="1", OMPI_MCA_rmaps_base_oversubscribe="1")
    e["PYTHONPATH"] = os.pathsep.join(x for x in (str(ROOT), os.environ.get("PYTHONPATH", "")) if x)
    return e


def elapsed() -> float:
    return time.monotonic() - T_START


class _SmiPoller:
    """One ``nvidia-smi --query-... -lms 500`` process read line by line on a thread (the two samplers below):
    each line with ``fields`` comma-separated values and a numeric first one goes to :meth:`_take`."""

    def __init__(self, query: str, fields: int) -> None:
        self.proc = None
        self._fields = fields
        if shutil.which("nvidia-smi"):
            self.proc = subprocess.Popen(["nvidia-smi", query, "--format=csv,noheader,nounits", "-lms", "500"],
                                         stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
            self.thread = threading.Thread(target=self._read, daemon=True)
            self.thread.start()

    def _read(self) -> None:
        for line in self.proc.stdout:
            parts = [x.strip() for x in line.split(",")]
            if len(parts) == self._fields and parts[0].isdigit():
                try:
                    self._take(parts)
                except ValueError:
                    pass

    def _take(self, parts: list[str]) -> None:
        raise NotImplementedError

    def _halt(self) -> bool:
        """Stop the poller; False if none ran (no nvidia-smi)."""
        if self.proc is None:
            return False
        self.proc.terminate()
        self.proc.wait()
        self.thread.join(timeout=5)
        return True


class GpuSampler(_SmiPoller):
    """nvidia-smi's utilisation of every GPU every 0.5 s while a run goes on; mean per GPU index (``stop``), or
    over a window of wall-clock time (``window``: the sweep without start-up)."""

    def __init__(self) -> None:
        self.samples: dict[int, list[float]] = {}
        self.timed: list[tuple[float, int, float]] = []  # (wall clock, GPU, utilisation [%])
        super().__init__("--query-gpu=index,utilization.gpu", 2)

    def _take(self, parts: list[str]) -> None:
        gpu, util = int(parts[0]), float(parts[1])
        self.samples.setdefault(gpu, []).append(util)
        self.timed.append((time.time(), gpu, util))

    def window(self, k: int, t0: float, t1: float) -> dict:
        """Mean utilisation per GPU over [t0, t1] and the share of its samples at >= 80 %."""
        mean, high = [], []
        for i in range(k):
            xs = [u for t, g, u in self.timed if g == i and t0 <= t <= t1]
            mean.append(round(statistics.fmean(xs), 1) if xs else None)
            high.append(round(sum(x >= 80 for x in xs) / len(xs), 2) if xs else None)
        return {"mean_pct": mean, "share_ge_80pct": high}

    def stop(self, k: int) -> list[float | None]:
        if not self._halt():
            return []
        return [round(statistics.fmean(self.samples[i]), 1) if self.samples.get(i) else None for i in range(k)]


def launch(jobs: list[Path], stores: list[Path], devices: str, ranks: int, log, extra: list[str], timeout: float,
           env_extra: dict[str, str] | None = None) -> tuple[int, float]:
    """One mpiexec launch of ``jobs`` into ``stores`` (new stores, or ``--resume`` in ``extra``); (exit code,
    wall seconds)."""
    args = [sys.executable, "-m", "gapsweep", "-q", "run", *map(str, jobs)]
    for s in stores:
        args += ["--store", str(s)]
    args += [*([] if "--resume" in extra else ["--overwrite"]), "--progress", "none", *extra]
    if ranks > 1:
        args = ["mpiexec", "-n", str(ranks), "--bind-to", "none", *args]
    log.write(f"$ CUDA_VISIBLE_DEVICES={devices} {' '.join(args)}\n")
    log.flush()
    t0 = time.perf_counter()
    e = env(devices)
    e.update(env_extra or {})
    p = subprocess.Popen(args, env=e, stdout=log, stderr=subprocess.STDOUT, start_new_session=True)
    try:
        rc = p.wait(timeout=timeout)
    except subprocess.TimeoutExpired:  # the whole group: mpiexec and its ranks
        rc = 124
        for sig in (signal.SIGTERM, signal.SIGKILL):
            try:
                os.killpg(p.pid, sig)
                p.wait(timeout=15)
                break
            except (ProcessLookupError, subprocess.TimeoutExpired):
                continue
    return rc, time.perf_counter() - t0


def run_record(path: Path) -> dict:
    from gapsweep import store

    try:
        return json.loads(store.read_attrs(path)["runs"])[-1]
    except Exception:
        return {}


def store_stats(path: Path) -> dict:
    from gapsweep import store

    try:
        df = store.read(path)
    except Exception as e:
        return {"error": str(e)[:200]}
    out = {"rows": {k: int(v) for k, v in df.status.value_counts().items()}}
    g = df[(df.method == "gfmd") & (df.status != "pending")]
    if len(g):
        out["gfmd_solves"] = len(g)
        out["gfmd_wall_median_s"] = round(float(g.wall_time.median()), 4)
        out["gfmd_wall_max_s"] = round(float(g.wall_time.max()), 3)
    return out


def one_run(name: str, jobs: list[Path], k: int, out: Path, ranks: int, extra: list[str], log, timeout: float,
            ) -> dict:
    d = out / f"gpus{k}"
    d.mkdir(parents=True, exist_ok=True)
    stores = [d / f"{j.stem}.h5" for j in jobs]
    sampler = GpuSampler()
    t_launch = time.time()
    rc, wall = launch(jobs, stores, ",".join(str(i) for i in range(k)), ranks, log, extra, timeout)
    util = sampler.stop(k)
    rec = run_record(stores[0])
    start = rec.get("farm_started_unix")
    r = {"set": name, "gpus": k, "ranks": ranks, "rc": rc, "wall_s": round(wall, 2),
         "startup_s": round(start - t_launch, 2) if start else None, "gpu_util_pct": util,
         "jobs": [j.name for j in jobs], "stores": {}}
    r["sweep_s"] = round(wall - r["startup_s"], 2) if r["startup_s"] is not None else None
    for j, s in zip(jobs, stores):
        st = store_stats(s)
        base = out / "gpus1" / s.name
        if k > 1 and base.exists() and s.exists():
            from gapsweep import store

            diff = store.diff(s, base)
            st["equal_to_1gpu"] = not diff
            if diff:
                st["diff"] = diff[:5]
        st["run"] = {x: rec.get(x) for x in ("gpus", "device_faults", "stopped")} if s == stores[0] else None
        r["stores"][j.stem] = st
    return r


def pub_jobs(out: Path, seeds: int | None) -> list[Path]:
    if not seeds:
        return SETS["pub"]
    d = out / "jobs"
    d.mkdir(parents=True, exist_ok=True)
    res = []
    for j in SETS["pub"]:
        text = j.read_text().replace("seeds = {start = 0, count = 16}", f"seeds = {{start = 0, count = {seeds}}}")
        (d / j.name).write_text(text)
        res.append(d / j.name)
    return res


def compile_kernels(log) -> float:
    """Compile (or load from the disk cache) the GPU kernels once on GPU 0, as the first launch would."""
    code = ("import cupy\nfrom gapsweep import gfmd, sde\nfrom gapsweep.surface import self_affine\n"
            "h = cupy.asarray(self_affine(64, 0.3, lambda_l=0.25, lambda_s=4.0 / 64, seed=0))\n"
            "gfmd.solve(h, sigma0=1e-2, gamma0=1e-3, rho=2e-2, backend='cupy', host=False)\n"
            "from gapsweep.sweep.context import _rms_gpu\n"  # a GPU task's surface and its rms values (issue 38)
            "_rms_gpu(self_affine(64, 0.3, lambda_l=0.25, lambda_s=4.0 / 64, seed=0, backend='cupy'), "
            "{'length': 1.0})\n"
            "sde.gap_histogram_counts(1e-2, hurst=0.3, h_rms=2.34e-3, rho=2e-3, gamma0=1e-3, lambda_l=0.25, "
            "lambda_s=2.5e-3, c2=1.0, n=1000, device='cuda', bins=16)\n")
    t0 = time.perf_counter()
    subprocess.run([sys.executable, "-c", code], env=env("0"), stdout=log, stderr=subprocess.STDOUT, timeout=300)
    return round(time.perf_counter() - t0, 1)


class Holder:
    """A process that holds all but 64 MB of one GPU's memory until it is told to go (a real out-of-memory for
    any other process that opens a context there)."""

    CODE = ("import sys, pathlib, cupy\nfree, total = cupy.cuda.runtime.memGetInfo()\n"
            "x = cupy.empty(max(0, free - (64 << 20)), dtype=cupy.uint8)\nx[-1] = 1\n"
            "cupy.cuda.Device().synchronize()\n"
            "pathlib.Path(sys.argv[1]).write_text(f'{free} {total}')\nsys.stdin.read()\n")

    def __init__(self, gpu: int, flag: Path) -> None:
        self.flag = flag
        flag.unlink(missing_ok=True)
        self.proc = subprocess.Popen([sys.executable, "-c", self.CODE, str(flag)], env=env(str(gpu)),
                                     stdin=subprocess.PIPE, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        end = time.monotonic() + 60
        while not flag.exists() and self.proc.poll() is None and time.monotonic() < end:
            time.sleep(0.1)
        self.ok = flag.exists()

    def release(self) -> None:
        self.proc.stdin.close()
        try:
            self.proc.wait(timeout=30)
        except subprocess.TimeoutExpired:
            self.proc.kill()


def fault_check(out: Path, ranks: int, log) -> dict:
    """Figure 2 on GPUs 0, 1 with GPU 1 held (then both held, then resumed), against the 1-GPU store."""
    from gapsweep import store

    job = SETS["figs"][2]
    d = out / "fault"
    d.mkdir(parents=True, exist_ok=True)
    ref = out / "gpus1" / "fig2.h5"
    res: dict = {"job": job.name}
    if not ref.exists():
        rc, wall = launch([job], [ref], "0", ranks, log, [], 300)
        res["reference"] = {"rc": rc, "wall_s": round(wall, 2)}
    held = Holder(1, d / "hold1")
    try:
        rc, wall = launch([job], [d / "one_held.h5"], "0,1", ranks, log, [], 300)
    finally:
        held.release()
    rec = run_record(d / "one_held.h5")
    res["one_gpu_held"] = {"holder_ok": held.ok, "rc": rc, "wall_s": round(wall, 2),
                           "device_faults": rec.get("device_faults"), **store_stats(d / "one_held.h5"),
                           "equal_to_1gpu": (d / "one_held.h5").exists() and not store.diff(d / "one_held.h5", ref)}
    holders = [Holder(g, d / f"hold{g}") for g in (0, 1)]
    try:
        rc, wall = launch([job], [d / "both_held.h5"], "0,1", ranks, log, [], 300)
    finally:
        for h in holders:
            h.release()
    rec = run_record(d / "both_held.h5")
    res["both_gpus_held"] = {"holder_ok": all(h.ok for h in holders), "rc": rc, "wall_s": round(wall, 2),
                             "stopped": rec.get("stopped"), **store_stats(d / "both_held.h5")}
    rc, wall = launch([job], [d / "both_held.h5"], "0,1", ranks, log, ["--resume"], 300)
    res["resumed"] = {"rc": rc, "wall_s": round(wall, 2), **store_stats(d / "both_held.h5"),
                      "equal_to_1gpu": (d / "both_held.h5").exists() and not store.diff(d / "both_held.h5", ref)}
    return res


# ---------------------------------------------------------------------------------------------- layouts (issue 38)
LAYOUT_FLAGS = ("each", "host")


def parse_layout(text: str) -> tuple[int, int | None, int | None, str, bool]:
    """``G:K[:R][/each][/host]``: G GPUs, K ranks per GPU (``auto``: gapsweep's default, no flag), R ranks (default
    --ranks); ``/each``: the jobs of the launch one farm each (``--farm each``, the behaviour before issue 38's
    joint farm), else one farm for all (the default); ``/host``: the GPU tasks' surfaces made on the host
    (``GAPSWEEP_GPU_SURFACES=0``, as before issue 38), else on their GPU (the default). Returns (G, K, R, farm,
    host surfaces)."""
    text, *flags = text.split("/")
    parts = text.split(":")
    if len(parts) not in (2, 3) or not parts[0].isdigit() or any(f not in LAYOUT_FLAGS for f in flags):
        raise SystemExit(f"--layouts: expected G:K[:R][/each][/host] (K an integer or auto), got {text!r}")
    k = None if parts[1] == "auto" else int(parts[1])
    return (int(parts[0]), k, (int(parts[2]) if len(parts) == 3 else None), "each" if "each" in flags
            else "together", "host" in flags)


def wait_no_mps(log, timeout: float = 20.0) -> float:
    """Wait until no MPS daemon runs on the node (the one a run started stops once its ranks are gone); after
    ``timeout`` s, quit every daemon of a gapsweep pipe folder left in the temporary folder (and say so)."""
    import tempfile

    from gapsweep.sweep import gpus

    t0 = time.monotonic()
    while gpus.mps_processes() and time.monotonic() - t0 < timeout:
        time.sleep(0.1)
    left = gpus.mps_processes()
    ctl = shutil.which("nvidia-cuda-mps-control")
    if left and ctl:
        for pipe in Path(tempfile.gettempdir()).glob("gapsweep-mps-*/pipe"):
            log.write(f"!! MPS daemon still running after {timeout:.0f} s ({left}): quit {pipe}\n")
            subprocess.run([ctl], input="quit\n", text=True, capture_output=True, timeout=60,
                           env=dict(os.environ, CUDA_MPS_PIPE_DIRECTORY=str(pipe),
                                    CUDA_MPS_LOG_DIRECTORY=str(pipe.parent / "log")))
        while gpus.mps_processes() and time.monotonic() - t0 < timeout + 30:
            time.sleep(0.1)
    return round(time.monotonic() - t0, 2)


class AppSampler(_SmiPoller):
    """Which processes hold a CUDA context on which GPU (``nvidia-smi --query-compute-apps`` every 0.5 s)."""

    def __init__(self) -> None:
        self.seen: dict[str, set[str]] = {}
        self.mem: dict[tuple[str, str], float] = {}
        self.uuid: dict[str, str] = {}
        if shutil.which("nvidia-smi"):
            try:
                out = subprocess.run(["nvidia-smi", "--query-gpu=index,uuid", "--format=csv,noheader"],
                                     capture_output=True, text=True, timeout=20).stdout
                self.uuid = {u.strip(): i.strip() for i, u in (x.split(",") for x in out.splitlines() if "," in x)}
            except (OSError, subprocess.SubprocessError, ValueError):
                pass
        super().__init__("--query-compute-apps=pid,gpu_uuid,used_memory", 3)

    def _take(self, parts: list[str]) -> None:
        gpu = self.uuid.get(parts[1], parts[1])
        self.seen.setdefault(parts[0], set()).add(gpu)
        self.mem[(parts[0], gpu)] = max(self.mem.get((parts[0], gpu), 0.0), float(parts[2]))

    def stop(self) -> dict:
        if not self._halt():
            return {}
        multi = {pid: sorted(g) for pid, g in self.seen.items() if len(g) > 1}
        return {"processes": len(self.seen), "on_several_gpus": multi,
                "mib_on_other_gpus": {pid: {g: self.mem.get((pid, g)) for g in gs} for pid, gs in multi.items()}}


def _q(xs: list[float], q: float) -> float | None:
    if not xs:
        return None
    xs = sorted(xs)
    return round(xs[min(len(xs) - 1, int(q * (len(xs) - 1) + 0.5))], 4)


def _farm_summary(recs: dict, t_launch: float) -> dict:
    """One farm's records (rank -> trace record): its start (the earliest rank's), its first unit and its last
    unit's end (s after the launch), its units."""
    start = min(r["start"] for r in recs.values())
    us = [u for r in recs.values() for u in r["units"]]
    first = min((u[1] for u in us), default=None)
    last = max((u[2] for u in us), default=None)
    return {"start_s": round(start - t_launch, 2),
            "first_unit_s": None if first is None else round(first - t_launch, 2),
            "last_unit_end_s": None if last is None else round(last - t_launch, 2), "units": len(us),
            "gpu_units": sum(bool(u[3]) for u in us)}


def analyse_trace(d: Path, t_launch: float, t_end: float, farm_start: float | None) -> dict:
    """The farms' timeline (gapsweep.sweep.trace files ``rank<R>.farm<F>.json`` in ``d``; one farm per launch
    with ``--farm together``, one per job with ``--farm each``): per worker busy/idle seconds over the sweep (the
    first farm's start to the last unit's end: the gaps between the farms of a launch count as idle) and its
    units (times from the launch), per farm its start, first unit and last unit's end (``farms``: the gaps
    between them are the jobs' serial phases), coordinator latency (handled - asked), the longest units (the
    critical path's candidates) and the tail (the last unit's end to the exit)."""
    farms: dict[int, dict[int, dict]] = {}
    for f in sorted(d.glob("rank*.json")):
        try:
            r = json.loads(f.read_text())
            farms.setdefault(int(r.get("farm", 0)), {})[r["rank"]] = r
        except (OSError, ValueError, KeyError):
            continue
    if not farms:
        return {"error": f"no trace files in {d}"}
    allr = [r for recs in farms.values() for r in recs.values()]
    t0 = min(farm_start or math.inf, min(r["start"] for r in allr))
    last = max((u[2] for r in allr for u in r["units"]), default=t0)
    window = max(last - t0, 1e-9)
    workers, lat, units = [], [], []
    ranks = sorted({r["rank"] for r in allr})
    for rank in ranks:
        mine = [farms[f][rank] for f in sorted(farms) if rank in farms[f]]
        us = [u for r in mine for u in r["units"]]
        if not us and rank == 0:
            continue
        busy = sum(u[2] - u[1] for u in us)
        la = []
        for f in sorted(farms):
            r, coord = farms[f].get(rank), farms[f].get(0, {})
            if r is not None:
                la += [h - a for a, h in zip(r["asks"], coord.get("handled", {}).get(str(rank), []))]
        lat += la
        units += [(u[2] - u[1], rank, mine[0]["gpu"], u[0], u[4] if len(u) > 4 else None) for u in us]
        first = min((u[1] for u in us), default=None)
        end = max((u[2] for u in us), default=None)
        workers.append({
            "rank": rank, "gpu": mine[0]["gpu"], "units": len(us),
            "gpu_units": sum(bool(u[3]) for u in us), "busy_s": round(busy, 2),
            "io_s": round(sum(u[5] for u in us if len(u) > 5), 3),  # writing and sending its rows
            "idle_s": round(window - busy, 2), "idle_pct": round(100 * (1 - busy / window), 1),
            "first_unit_after_launch_s": round(first - t_launch, 2) if first else None,
            "last_unit_end_after_farm_start_s": round(end - t0, 2) if end else None,
            "latency_median_ms": None if not la else round(1e3 * statistics.median(la), 2),
            "timeline": [[round(u[1] - t_launch, 3), round(u[2] - t_launch, 3), u[0], int(bool(u[3]))] for u in us]})
    g = [w for w in workers if w["gpu"] is not None]
    units.sort(reverse=True)
    ms = [1e3 * x for x in lat]
    fs = [_farm_summary(farms[f], t_launch) for f in sorted(farms)]
    gaps = [round(b["first_unit_s"] - a["last_unit_end_s"], 2) for a, b in itertools.pairwise(fs)
            if a["last_unit_end_s"] is not None and b["first_unit_s"] is not None]
    coords = [farms[f].get(0, {}) for f in sorted(farms)]
    return {
        "farms": fs, "gaps_between_farms_s": gaps,
        "farm_window_s": round(window, 2), "tail_s": round(t_end - last, 2),
        "workers": workers,
        "gpu_workers_idle_pct_mean": round(statistics.fmean(w["idle_pct"] for w in g), 1) if g else None,
        "gpu_workers_idle_pct_max": max((w["idle_pct"] for w in g), default=None),
        "gpu_workers_busy_s_sum": round(sum(w["busy_s"] for w in g), 2),
        "gpu_workers_io_s_sum": round(sum(w["io_s"] for w in g), 2),  # of the busy time: rows written and sent
        "cpu_workers_busy_s_sum": round(sum(w["busy_s"] for w in workers if w["gpu"] is None), 2),
        "coordinator": {"busy_s": round(sum(c.get("busy_s") or 0 for c in coords), 3),
                        "rows": sum(c.get("rows") or 0 for c in coords),
                        "latency_ms": {"median": _q(ms, 0.5), "p95": _q(ms, 0.95), "max": _q(ms, 1.0),
                                       "n": len(lat)}},
        "longest_units": [{"s": round(du, 2), "rank": rk, "gpu": gp, "unit": k, "tasks": nt}
                          for du, rk, gp, k, nt in units[:8]],
        "first_unit_after_launch_s": min((w["first_unit_after_launch_s"] for w in workers
                                          if w["first_unit_after_launch_s"] is not None), default=None),
    }


def run_dir(i: int, name: str, g: int, per_gpu: int | None, farm: str, host: bool = False) -> str:
    return f"run{i}_{name}_g{g}_k{per_gpu or 'auto'}" + ("_each" if farm == "each" else "") + ("_host" if host else "")


def layout_run(i: int, name: str, jobs: list[Path], g: int, per_gpu: int | None, ranks: int, work: Path,
               extra: list[str], log, timeout: float, ref: list[Path] | None, farm: str = "together",
               host: bool = False) -> dict:
    """One launch of ``jobs`` on GPUs 0..g-1 with ``per_gpu`` ranks per GPU (None: gapsweep's default), traced."""
    from gapsweep import store

    d = work / run_dir(i, name, g, per_gpu, farm, host)
    shutil.rmtree(d, ignore_errors=True)
    d.mkdir(parents=True)
    stores = [d / f"{j.stem}.h5" for j in jobs]
    waited = wait_no_mps(log)
    args = [*extra, *([] if per_gpu is None else ["--ranks-per-gpu", str(per_gpu)]),
            *(["--farm", "each"] if farm == "each" and len(jobs) > 1 else [])]
    sampler, apps = GpuSampler(), AppSampler()
    t_launch = time.time()
    rc, wall = launch(jobs, stores, ",".join(map(str, range(g))), ranks, log, args, timeout,
                      env_extra={"GAPSWEEP_TRACE": str(d / "trace"),
                                 **({"GAPSWEEP_GPU_SURFACES": "0"} if host else {})})
    t_end = time.time()
    sampler.stop(g)
    rec = run_record(stores[0])
    start = rec.get("farm_started_unix")
    r = {"run": i, "set": name, "gpus": g, "ranks_per_gpu": per_gpu or "auto", "farm": farm,
         "surfaces": "host" if host else "gpu", "ranks": ranks, "rc": rc,
         "wall_s": round(wall, 2), "startup_s": round(start - t_launch, 2) if start else None,
         "mps_wait_before_s": waited, "layout": {x: rec.get(x) for x in ("ranks_per_gpu", "mps")},
         "gpu_ranks": sum(x is not None for x in rec.get("gpus") or []),
         "gpu_util_whole_run": sampler.window(g, t_launch, t_end),
         "gpu_util_sweep": sampler.window(g, start or t_launch, t_end),
         "cuda_contexts": apps.stop(), "stores": {}}
    r["sweep_s"] = round(wall - r["startup_s"], 2) if r["startup_s"] is not None else None
    for j, s_ in enumerate(stores):
        st = store_stats(s_)
        if ref is not None and s_.exists() and ref[j].exists():
            diff = store.diff(s_, ref[j])
            st["equal_to_reference"] = not diff
            if diff:
                st["diff"] = diff[:5]
            if host:  # surfaces made on the host: equal to the reference's to round-off, results within tolerance
                st["within_tolerance_of_reference"] = within_tolerance(s_, ref[j])
        r["stores"][s_.stem] = st
    r["trace"] = analyse_trace(d / "trace", t_launch, t_end, start)
    return r


def _lay(r: dict) -> str:
    return (f"{r['gpus']}:{r['ranks_per_gpu']}" + ("/each" if r.get("farm") == "each" else "")
            + ("/host" if r.get("surfaces") == "host" else ""))


def layout_table(rows: list[dict]) -> tuple[str, dict]:
    """The table against T1_best (the best one-GPU wall time of a set, any layout), and per set the summary:
    T1_best and its layout, the layouts tried (``G:K[/each]`` -> wall), the default's one-GPU time over T1_best,
    and per GPU count the default's efficiency, mean GPU utilisation over the sweep and the GPU workers' idle
    share (mean and largest, from the trace)."""
    summary: dict = {}
    for name in sorted({r["set"] for r in rows}):
        mine = [r for r in rows if r["set"] == name and not r.get("skipped")]
        one = [r for r in mine if r.get("gpus") == 1 and r.get("rc") == 0 and r.get("wall_s")]
        best = min(one, key=lambda r: r["wall_s"]) if one else None
        summary[name] = {"T1_best_s": best["wall_s"] if best else None,
                         "T1_best_layout": _lay(best) if best else None,
                         "layouts_tried": {_lay(r): r.get("wall_s") for r in mine}}
        default1 = [r["wall_s"] for r in one if _lay(r) == "1:auto"]
        summary[name]["default_over_best_on_1_gpu"] = round(min(default1) / best["wall_s"], 3) if best and default1 \
            else None
    lines = ["| set | GPUs | ranks per GPU (run) | layout | ranks | wall [s] | start-up [s] | eff. T1_best/(k T_k) | "
             "GPU util sweep [%] | GPU workers idle mean/max [%] | gaps between farms [s] | "
             "latency median/p95 [ms] | longest unit [s] | stores = reference | rc |", "|" + " --- |" * 15]
    for r in rows:
        if r.get("skipped"):
            lines.append(f"| {r['set']} | {r['gpus']} | {r['ranks_per_gpu']} | | | skipped: {r['skipped']} |"
                         + " |" * 9)
            continue
        t1 = summary[r["set"]]["T1_best_s"]
        eff = round(t1 / (r["gpus"] * r["wall_s"]), 3) if t1 and r.get("wall_s") else None
        r["efficiency_vs_T1_best"] = eff
        tr = r.get("trace", {})
        lat = tr.get("coordinator", {}).get("latency_ms", {})
        eq = [s.get("equal_to_reference") for s in r["stores"].values()]
        same = "ref" if all(e is None for e in eq) else ("yes" if all(eq) else f"no {eq}")
        tol = [s.get("within_tolerance_of_reference") for s in r["stores"].values()]
        if any(tol):  # host surfaces: round-off apart from the reference's, compared by grid point
            worst = max((x.get("mean_gap_rel_max") or 0.0) for x in tol if x)
            diff_status = sum(x.get("status_differs", 0) for x in tol if x)
            same = f"{same}; mean gap within {worst:.1e} rel., {diff_status} status differ"
        longest = (tr.get("longest_units") or [{}])[0].get("s")
        lay = r.get("layout", {}).get("ranks_per_gpu")
        if _lay(r) == f"{r['gpus']}:auto":
            summary[r["set"]].setdefault("default_by_gpus", {})[str(r["gpus"])] = {
                "wall_s": r["wall_s"], "efficiency_vs_T1_best": eff, "gpu_util_sweep_pct": r["gpu_util_sweep"],
                "gpu_workers_idle_pct_mean": tr.get("gpu_workers_idle_pct_mean"),
                "gpu_workers_idle_pct_max": tr.get("gpu_workers_idle_pct_max")}
        lines.append(f"| {r['set']} | {r['gpus']} | {r['ranks_per_gpu']} ({lay}) | {_lay(r)} | "
                     f"{r['ranks']} | {r['wall_s']} | {r.get('startup_s')} | "
                     f"{'-' if eff is None else f'{100 * eff:.0f} %'} | {r['gpu_util_sweep']['mean_pct']} | "
                     f"{tr.get('gpu_workers_idle_pct_mean')}/{tr.get('gpu_workers_idle_pct_max')} | "
                     f"{tr.get('gaps_between_farms_s')} | {lat.get('median')}/{lat.get('p95')} | {longest} | "
                     f"{same} | {r['rc']} |")
    return "\n".join(lines) + "\n", summary


def split_jobs(work: Path) -> list[Path]:
    """The mix jobs with ``split_chains = SPLIT`` (copies under WORK/jobs; the adhesive job as it is)."""
    d = work / "jobs"
    d.mkdir(parents=True, exist_ok=True)
    res = []
    for j in SETS["mix"]:
        text = j.read_text()
        if "adhesive" not in text:
            text = text.replace("[methods.gfmd]\n", f"[methods.gfmd]\nsplit_chains = {SPLIT}\n")
            j = d / f"split_{j.name}"
            j.write_text(text)
        res.append(j)
    return res


def set_jobs(name: str, work: Path, pub_seeds: int | None) -> tuple[str, list[Path]]:
    name, _, files = name.partition("=")
    return name, ([Path(f).resolve() for f in files.split(",")] if files else
                  pub_jobs(work, pub_seeds) if name == "pub" else split_jobs(work) if name == "mixsplit"
                  else SETS[name])


def within_tolerance(a: Path, b: Path) -> dict:
    """Rows of store ``a`` against ``b`` by grid point (method, hurst, rho, seed, n, sigma0) -- stores whose task
    ids differ (split chains): how many matched, how many differ in status, the largest relative difference of
    the mean gap (the solver's tolerance bounds it), and how many are bit for bit equal."""
    from gapsweep import store

    try:
        da, db = store.read(a), store.read(b)
    except Exception as e:
        return {"error": str(e)[:200]}
    k = ["method", "hurst", "rho", "seed", "n", "sigma0"]
    m = da.merge(db, on=k, suffixes=("_a", "_b"))
    ok = m[(m.status_a == "done") & (m.status_b == "done")]
    rel = ((ok.mean_gap_a - ok.mean_gap_b).abs() / ok.mean_gap_b.abs()) if len(ok) else None
    return {"matched": len(m), "rows": [len(da), len(db)], "status_differs": int((m.status_a != m.status_b).sum()),
            "mean_gap_rel_max": None if rel is None else float(rel.max()),
            "bit_equal": int((ok.mean_gap_a == ok.mean_gap_b).sum())}


def run_layouts(a, out: Path, work: Path, extra: list[str], res: dict, log) -> list[dict]:
    """``--layouts``: each ``[SET@]G:K[:R]`` in order (SET: the first of --sets when left out) while the budget
    lasts; every store against the first run's store of its set; T1_best per set from its one-GPU runs."""
    rows: list[dict] = []
    res["layout_runs"] = rows
    ref: dict[str, list[Path]] = {}
    t1: dict[str, float] = {}
    for i, item in enumerate(a.layouts):
        sname, _, text = item.rpartition("@")
        defs = {x.partition("=")[0]: x for x in a.sets}  # a set named in --sets with its files
        name, jobs = set_jobs(defs.get(sname, sname) if sname else a.sets[0], work, a.pub_seeds)
        g, k, ranks, farm, host = parse_layout(text)
        ranks = ranks or a.ranks
        if g > a.max_gpus:
            rows.append({"set": name, "gpus": g, "ranks_per_gpu": k or "auto", "skipped": "not on this node"})
            continue
        est = (t1[name] / g * 1.3 + 15) if name in t1 else PRIOR.get(name, 60.0)
        if elapsed() + est > a.budget:
            rows.append({"set": name, "gpus": g, "ranks_per_gpu": k or "auto",
                         "skipped": f"budget ({elapsed():.0f} s + ~{est:.0f} s)"})
            continue
        log.write(f"== {name} on {g} GPU(s), ranks per GPU {k or 'auto'}, {ranks} ranks, {elapsed():.0f} s\n")
        log.flush()
        r = layout_run(i, name, jobs, g, k, ranks, work, extra, log, farm=farm, host=host,
                       timeout=max(30.0, min(a.launch_timeout, a.budget + 60 - elapsed())), ref=ref.get(name))
        rows.append(r)
        if name not in ref and r["rc"] == 0:
            ref[name] = [work / run_dir(i, name, g, k, farm, host) / f"{j.stem}.h5" for j in jobs]
        if name == "mixsplit" and "mix" in ref:  # other task ids: compared by grid point, within tolerance
            here = [work / run_dir(i, name, g, k, farm, host) / f"{j.stem}.h5" for j in jobs]
            r["against_mix"] = {h.stem: within_tolerance(h, m) for h, m in zip(here, ref["mix"])}
        if g == 1 and r["rc"] == 0:
            t1[name] = min(t1.get(name, r["wall_s"]), r["wall_s"])
        print(json.dumps({x: r.get(x) for x in ("set", "gpus", "ranks_per_gpu", "gpu_ranks", "rc", "wall_s",
                                               "startup_s", "layout")}), flush=True)
        res["table"], res["summary"] = layout_table(rows)
        (out / f"{a.name}.json").write_text(json.dumps(res, indent=1))
    return rows


def node() -> dict:
    out = {"cores": len(os.sched_getaffinity(0)), "host": os.uname().nodename,
           "date": time.strftime("%Y-%m-%d %H:%M:%S %Z")}
    try:
        out["gpus"] = subprocess.run(["nvidia-smi", "--query-gpu=index,name,memory.total,driver_version",
                                      "--format=csv,noheader"], capture_output=True, text=True,
                                     timeout=20).stdout.strip().splitlines()
    except (OSError, subprocess.SubprocessError):
        out["gpus"] = []
    try:
        out["commit"] = subprocess.run(["git", "-C", str(ROOT), "rev-parse", "HEAD"], capture_output=True,
                                       text=True, timeout=10).stdout.strip()
    except (OSError, subprocess.SubprocessError):
        out["commit"] = ""
    out["commit"] = out["commit"] or os.environ.get("GAPSWEEP_COMMIT", "unknown")  # a copy without .git
    return out


def table(rows: list[dict]) -> str:
    one = {r["set"]: r for r in rows if r["gpus"] == 1 and r.get("wall_s")}
    lines = ["| set | GPUs | ranks | wall [s] | start-up [s] | sweep [s] | eff. wall | eff. sweep | GPU util [%] | "
             "stores = 1-GPU | rc |", "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |"]
    for r in rows:
        if r.get("skipped"):
            lines.append(f"| {r['set']} | {r['gpus']} | | skipped: {r['skipped']} | | | | | | | |")
            continue
        b = one.get(r["set"])
        eff = f"{100 * b['wall_s'] / (r['gpus'] * r['wall_s']):.0f} %" if b else "-"
        effs = (f"{100 * b['sweep_s'] / (r['gpus'] * r['sweep_s']):.0f} %" if b and b.get("sweep_s")
                and r.get("sweep_s") else "-")
        eq = [s.get("equal_to_1gpu") for s in r["stores"].values()]
        same = "-" if r["gpus"] == 1 else ("yes" if all(eq) else f"no ({eq})")
        lines.append(f"| {r['set']} | {r['gpus']} | {r['ranks']} | {r['wall_s']:.1f} | {r.get('startup_s')} | "
                     f"{r.get('sweep_s')} | {eff} | {effs} | {r.get('gpu_util_pct')} | {same} | {r['rc']} |")
    return "\n".join(lines) + "\n"


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--out", required=True)
    p.add_argument("--gpus", type=int, nargs="+", default=[1, 2, 4])
    p.add_argument("--sets", nargs="*", default=["pub", "sde", "figs"],
                   help=f"job sets: {', '.join(SETS)}, or NAME=JOB.toml[,JOB.toml...] (e.g. a CPU smoke test)")
    p.add_argument("--ranks", type=int, default=len(os.sched_getaffinity(0)),
                   help="MPI ranks of every launch (default: the cores of this node)")
    p.add_argument("--pub-seeds", type=int, default=None, help="seeds of the pub jobs (default: their 16)")
    p.add_argument("--budget", type=float, default=470.0, help="seconds after which no run starts")
    p.add_argument("--fault-check", action="store_true")
    p.add_argument("--work", default=None, help="folder of the stores (default: --out); e.g. /tmp/farm, so that "
                                                 "only the JSON, the table and the log land in --out")
    p.add_argument("--run-args", default="", help="more `gapsweep run` options, e.g. '--lookahead 0'")
    p.add_argument("--layouts", nargs="*", default=None, metavar="[SET@]G:K[:R]",
                   help="issue 38: run these layouts in order (G GPUs, K ranks per GPU or auto, R ranks), traced "
                        "(GAPSWEEP_TRACE); writes OUT/NAME.json, OUT/NAME.md, OUT/NAME_runs.log")
    p.add_argument("--name", default="layouts", help="file names of --layouts (default: layouts)")
    p.add_argument("--max-gpus", type=int, default=None, help="GPUs of this node (default: nvidia-smi's count)")
    p.add_argument("--launch-timeout", type=float, default=300.0, help="seconds one launch may take")
    a = p.parse_args()
    out = Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    work = Path(a.work) if a.work else out
    work.mkdir(parents=True, exist_ok=True)
    sys.path.insert(0, str(ROOT))
    extra = a.run_args.split()
    rows: list[dict] = []
    res: dict = {"command": " ".join(sys.argv), "node": node(), "runs": rows}
    if a.layouts is not None:
        if a.max_gpus is None:
            from gapsweep.sweep import gpus

            a.max_gpus = gpus.visible_count()
        with open(out / f"{a.name}_runs.log", "a") as log:
            res["compile_s"] = compile_kernels(log) if shutil.which("nvidia-smi") else None
            lrows = run_layouts(a, out, work, extra, res, log)
        res["table"], res["summary"] = layout_table(lrows)
        res["total_s"] = round(elapsed(), 1)
        (out / f"{a.name}.json").write_text(json.dumps(res, indent=1))
        (out / f"{a.name}.md").write_text(res["table"] + "\n" + json.dumps(res["summary"], indent=1) + "\n")
        print(res["table"])
        print(json.dumps(res["summary"], indent=1))
        print(f"total {res['total_s']} s")
        return 0 if all(r.get("rc", 0) == 0 for r in lrows) else 1
    with open(out / "runs.log", "a") as log:
        res["compile_s"] = compile_kernels(log) if shutil.which("nvidia-smi") else None
        for name in a.sets:
            name, _, files = name.partition("=")
            jobs = ([Path(f).resolve() for f in files.split(",")] if files else
                    pub_jobs(work, a.pub_seeds) if name == "pub" else SETS[name])
            t1 = None
            for k in sorted(a.gpus):
                est = (t1 / k * 1.25 + 15) if t1 else PRIOR.get(name, 60.0)
                if elapsed() + est > a.budget:
                    rows.append({"set": name, "gpus": k, "skipped": f"budget ({elapsed():.0f} s + ~{est:.0f} s)"})
                    continue
                log.write(f"== {name} on {k} GPU(s), {elapsed():.0f} s into the call\n")
                log.flush()
                r = one_run(name, jobs, k, work, a.ranks, extra, log, timeout=max(30.0, a.budget + 60 - elapsed()))
                rows.append(r)
                if k == 1:
                    t1 = r["wall_s"]
                print(json.dumps({x: r[x] for x in ("set", "gpus", "rc", "wall_s", "startup_s", "gpu_util_pct")}),
                      flush=True)
                (out / "results.json").write_text(json.dumps(res, indent=1))
        if a.fault_check:
            if elapsed() + 90 < a.budget:  # about four launches of figure 2
                res["fault_check"] = fault_check(work, a.ranks, log)
                print(json.dumps(res["fault_check"])[:2000], flush=True)
            else:
                res["fault_check"] = {"skipped": f"budget ({elapsed():.0f} s)"}
    res["total_s"] = round(elapsed(), 1)
    if rows:
        (out / "results.json").write_text(json.dumps(res, indent=1))
        (out / "table.md").write_text(table(rows))
        print(table(rows))
    else:  # the fault check alone: beside the scaling results of the same --out, not over them
        (out / "fault_check.json").write_text(json.dumps(res, indent=1))
    print(f"total {res['total_s']} s")
    ok = all(r.get("rc", 0) == 0 for r in rows)
    return 0 if ok else 1


if __name__ == "__main__":
    _record.track(CODE_PATHS)
    sys.exit(main())
