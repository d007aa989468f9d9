"""Sweeps on 1, 2, 4, 8 GPUs of one node, one store per GPU (docs/benchmarks.md, "Several GPUs").

For each GPU count G and job, G shard runs start together, shard i on GPU i (``CUDA_VISIBLE_DEVICES``), each an
MPI farm of ``--ranks / G`` ranks (``--ranks-per-gpu`` of them on the GPU, the rest on CPU units) or a single
process when that is 1; the shard stores are merged on the CPU (``gapsweep merge``) and the merged store is
compared with the G = 1 store (bit for bit, and within the tolerance of benchmarks/compare_stores.py against
``--reference`` stores, e.g. the CPU stores of docs/results/stores.tgz). Wall time is from the start of the
first shard to the end of the last, merge excluded (reported beside it).

    python benchmarks/bench_multi_gpu.py --out OUT --gpus 1 2 4 8 --jobs fig6 fig4_5 fig2 fig3 sde
    python benchmarks/bench_multi_gpu.py --out OUT --gpus 1 2 --devices 0,0 --jobs fig6   # 2 shards, 1 GPU

Jobs: ``figN`` = jobs/gpu/figN.toml; ``sde`` = jobs/bench_sde_gpus.toml (16 tasks x 10^8 realisations).
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
JOBS = {"sde": ROOT / "jobs" / "bench_sde_gpus.toml"}


def job_file(name: str) -> Path:
    if name.endswith(".toml"):  # any job file (its stem names the stores)
        return Path(name).resolve()
    return JOBS.get(name, ROOT / "jobs" / "gpu" / f"{name}.toml")


def run_job(job: str, g: int, devices: list[str], out: Path, ranks: int, per_gpu: int, log) -> dict:
    name = Path(job).stem if job.endswith(".toml") else job
    d = out / f"gpus{g}"
    d.mkdir(parents=True, exist_ok=True)
    per = max(1, ranks // g)
    procs = []
    t0 = time.perf_counter()
    for i in range(g):
        store = d / (f"{name}.h5" if g == 1 else f"{name}_{i}of{g}.h5")
        args = [sys.executable, "-m", "gapsweep", "run", str(job_file(job)), "--store", str(store), "--overwrite",
                "--progress", "log", "--ranks-per-gpu", str(per_gpu)]
        if g > 1:
            args += ["--shard", f"{i}/{g}"]
        if per > 1 and shutil.which("mpiexec"):
            args = ["mpiexec", "-n", str(per), "--bind-to", "none", *args]
        env = dict(os.environ, CUDA_VISIBLE_DEVICES=devices[i % len(devices)])
        procs.append((store, subprocess.Popen(args, env=env, stdout=log, stderr=subprocess.STDOUT)))
    rcs = [p.wait() for _, p in procs]
    wall = time.perf_counter() - t0
    res = {"job": name, "job_file": str(job_file(job)), "gpus": g, "ranks_per_shard": per, "wall_s": wall, "rc": rcs}
    final = d / f"{name}.h5"
    if g > 1:
        t1 = time.perf_counter()
        m = subprocess.run([sys.executable, "-m", "gapsweep", "merge", *[str(s) for s, _ in procs], "--out",
                            str(final), "--overwrite"], stdout=log, stderr=subprocess.STDOUT)
        res["merge_s"], res["merge_rc"] = time.perf_counter() - t1, m.returncode
    res["store"] = str(final)
    return res


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--out", required=True)
    p.add_argument("--gpus", type=int, nargs="+", default=[1, 2, 4, 8])
    p.add_argument("--jobs", nargs="+", default=["fig6", "fig4_5", "fig2", "fig3", "sde"])
    p.add_argument("--devices", default=None, help="comma list of GPU ids to cycle through (default 0..G-1)")
    p.add_argument("--ranks", type=int, default=os.cpu_count() or 1, help="MPI ranks per node, split over shards")
    p.add_argument("--ranks-per-gpu", type=int, default=2)
    p.add_argument("--reference", default=None, help="folder of reference stores <job>.h5 (compare_stores)")
    a = p.parse_args()
    out = Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    sys.path.insert(0, str(ROOT))
    from benchmarks.compare_stores import compare
    from gapsweep import store

    rows = []
    with open(out / "runs.log", "a") as log:
        for g in a.gpus:
            devices = a.devices.split(",") if a.devices else [str(i) for i in range(g)]
            for job in a.jobs:
                log.write(f"== {job} on {g} GPU(s) {time.strftime('%H:%M:%S')}\n")
                log.flush()
                r = run_job(job, g, devices, out, a.ranks, a.ranks_per_gpu, log)
                name = r["job"]
                base = out / "gpus1" / f"{name}.h5"
                if g > 1 and base.exists():
                    r["diff_vs_1gpu"] = store.diff(r["store"], base)[:5]
                if a.reference and (Path(a.reference) / f"{name}.h5").exists():
                    c = compare(r["store"], str(Path(a.reference) / f"{name}.h5"))
                    r["vs_reference_ok"] = c["ok"]
                    r["vs_reference"] = c["methods"]
                rows.append(r)
                print(json.dumps({k: v for k, v in r.items() if k != "vs_reference"}), flush=True)
    (out / "results.json").write_text(json.dumps(rows, indent=1, default=float))
    one = {r["job"]: r["wall_s"] for r in rows if r["gpus"] == 1}
    lines = ["| GPUs | job | wall [s] | speed-up | efficiency | merge [s] | store = 1-GPU store |",
             "| --- | --- | --- | --- | --- | --- | --- |"]
    for r in rows:
        sp = one.get(r["job"], float("nan")) / r["wall_s"]
        same = "—" if r["gpus"] == 1 else ("yes" if not r.get("diff_vs_1gpu") else f"no: {r['diff_vs_1gpu'][:2]}")
        lines.append(f"| {r['gpus']} | {r['job']} | {r['wall_s']:.1f} | {sp:.2f} | {100 * sp / r['gpus']:.0f} % | "
                     f"{r.get('merge_s', 0):.1f} | {same} |")
    (out / "table.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))
    return 0 if all(rc == 0 for r in rows for rc in r["rc"]) else 1


if __name__ == "__main__":
    if shutil.which("mpiexec") is None:
        print("note: mpiexec not found: shards run as single processes", file=sys.stderr)
    sys.exit(main())
