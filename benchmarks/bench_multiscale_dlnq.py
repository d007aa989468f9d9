"""The multiscale gap distribution's step in ln q (issue 39 item 3): L1 against GFMD and CPU time per group width.

    python benchmarks/bench_multiscale_dlnq.py --set tuning  --dlnq 0.04 0.1 0.2 0.3 0.5   # the choice is made here
    python benchmarks/bench_multiscale_dlnq.py --set heldout --dlnq 0.04 0.3               # and reported here

``closure.multiscale_gap_samples`` at its defaults but for ``dlnq`` (the width in ``ln q`` of the shell groups the
local-response process steps through, docs/theory.md "Multiscale gap distribution") on the distribution points
of ``bench_bounds.py``'s sets, against GFMD's cached gap histograms (``benchmarks/results/bounds/gfmd_<set>.json``,
tol 1e-8): L1 (80 bins over GFMD's range), whether the self-check's ``l1_estimate`` covers it, the status, CPU
seconds (one thread, process time) and their ratio to the cached GFMD solve's CPU seconds. Writes
``<out>/multiscale_dlnq_<set>.csv`` and ``.md``.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import pandas as pd

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))

import _record
import bench_bounds as bb

from gapsweep.theory import closure

CODE_PATHS = ["gapsweep/theory", "gapsweep/gfmd", "gapsweep/surfaces"]


def evaluate(name: str, widths: list[float], out: Path) -> pd.DataFrame:
    cache = json.loads((out / f"gfmd_{name}.json").read_text())
    rows = []
    for case, ps, n, h, kw, _ in bb.distribution_points(name):
        lam_l, slope, seed = case[1], case[3], case[6]
        ref = cache[bb._key(case, ps)]
        for w in widths:
            ms, t = bb._cpu(closure.multiscale_gap_samples, ps * slope, h, lambda_l=lam_l, seed=seed, dlnq=w, **kw)
            rows.append(dict(key=bb._key(case, ps), n=n, dlnq=w, l1=bb.l1_to_reference(ms.samples, ref),
                             l1_estimate=ms.l1_estimate, status=ms.status, cpu=t, cpu_gfmd=ref["cpu"]))
    return pd.DataFrame(rows)


def table(df: pd.DataFrame, name: str) -> str:
    g = df.assign(ok=df.l1 <= 0.15, covered=df.l1_estimate >= df.l1, ratio=df.cpu / df.cpu_gfmd,
                  miss=(df.status == "converged") & (df.l1 > 0.15)).groupby("dlnq")
    lines = [f"# Multiscale gap distribution: the shell-group width dlnq, set `{name}`\n",
             f"{df.key.nunique()} distributions; L1 against GFMD (80 bins), CPU seconds one thread.\n",
             "| dlnq | L1 <= 0.15 | L1 median | L1 max | l1_estimate >= L1 | 'converged' with L1 > 0.15 | "
             "CPU s median | CPU / GFMD median |", "| --- | --- | --- | --- | --- | --- | --- | --- |"]
    for w, r in g:
        lines.append(f"| {w:g} | {int(r.ok.sum())}/{len(r)} | {r.l1.median():.3f} | {r.l1.max():.3f} | "
                     f"{int(r.covered.sum())}/{len(r)} | {int(r.miss.sum())} | {r.cpu.median():.3f} | "
                     f"{r.ratio.median():.3f} |")
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--set", choices=("tuning", "heldout"), default="heldout")
    ap.add_argument("--dlnq", type=float, nargs="+", default=[0.04, 0.3])
    ap.add_argument("--out", type=Path, default=Path("benchmarks/results/bounds"))
    a = ap.parse_args(argv)
    df = evaluate(a.set, a.dlnq, a.out)
    df.to_csv(a.out / f"multiscale_dlnq_{a.set}.csv", index=False)
    (a.out / f"multiscale_dlnq_{a.set}.md").write_text(table(df, a.set))
    print(table(df, a.set))
    return 0


if __name__ == "__main__":
    _record.track(CODE_PATHS)
    raise SystemExit(main())
