"""Leak rate against load with the theories side by side (issue 42; docs/model.md M8): the shipped jobs
``leakage`` (synthetic, periodic) and ``leakage_measured`` (a measured-like, non-periodic map in um and MPa), each
GFMD row's conductance from the Reynolds flow solve against four estimates: Bruggeman's effective medium and
Persson's critical junction, each from GFMD's own gap histogram (the store's columns) and from Persson's gap
distribution (``theory.persson.gap_distribution``, Almqvist et al. 2011: no contact solve at all).

    gapsweep run leakage --store leak.h5 && gapsweep run leakage_measured --store leak_measured.h5
    python -m studies.leakage leak.h5 leak_measured.h5 --out docs/results/flow

Writes ``leakage.csv`` (one row per job and load: means over seeds), ``leakage.json`` (command, commit, date)
and ``leakage.png`` (conductance against load, log scale; the solve's zero past the percolation point is drawn
at the bottom of the axis).
"""

from __future__ import annotations

import argparse
import json
import math
import platform
import subprocess
import sys
from datetime import UTC, datetime
from pathlib import Path

import numpy as np
import pandas as pd

from gapsweep import flow, jobs, store, surface, topography
from gapsweep.theory import persson


def _persson_estimates(job: str, sigma0: float, spec: dict) -> tuple[float, float]:
    """Bruggeman and critical-junction conductance from Persson's gap distribution at ``sigma0``."""
    s, m, fo = spec["surface"], spec.get("material", {}), spec["methods"]["gfmd"].get("flow", {})
    mu = fo.get("viscosity", 1.0) if isinstance(fo, dict) else 1.0
    e_star = m.get("e_star", 1.0)
    if s.get("kind") == "file":
        topo = topography.load(jobs.path(job).parent / s["path"], key=s.get("key"), unit=s.get("unit"),
                               pixel_size=s.get("pixel_size"), detrend=s.get("detrend", "mean"))
        h = topo.heights
        u = np.linspace(0.0, 8.0 * float(np.std(h)), 801)[1:]
        dens, atom = persson.gap_distribution(u, sigma0, e_star=e_star, heights=h, length=topo.length,
                                              periodic=topo.periodic)
    else:
        hurst = spec["grid"]["hurst"]
        hurst = hurst[0] if isinstance(hurst, list) else hurst
        kw = dict(hurst=hurst, lambda_l=s["lambda_l"], lambda_s=s["lambda_s"], rms_slope=s["rms_slope"],
                  e_star=e_star)
        h_rms = surface.continuum_rms_height(hurst, lambda_l=s["lambda_l"], lambda_s=s["lambda_s"],
                                             rms_slope=s["rms_slope"])
        u = np.linspace(0.0, 8.0 * h_rms, 1601)[1:]  # the density is negligible beyond a few h_rms
        dens, atom = persson.gap_distribution(u, sigma0, **kw)
    return (flow.bruggeman(u, dens, atom, viscosity=mu) if atom < 1 else 0.0,
            flow.critical_junction(u, dens, atom, viscosity=mu) if atom < 1 else 0.0)


def main(argv: list[str] | None = None) -> None:
    import tomllib

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("stores", nargs="+", type=Path)
    ap.add_argument("--out", type=Path, default=Path("docs/results/flow"))
    a = ap.parse_args(argv)
    commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True).stdout.strip()
    rows = []
    for p in a.stores:
        attrs = store.read_attrs(p)
        spec = tomllib.loads(attrs["spec_text"])
        job = spec["job"]["name"].replace("-", "_")
        df = store.read(p)
        g = df[(df.method == "gfmd") & (df.status == "done")]
        for s0, grp in g.groupby("sigma0"):
            pb, pc = _persson_estimates(job, float(s0), spec)
            rows.append({"job": job, "sigma0": float(s0), "seeds": len(grp),
                         "contact_area": grp.contact_area.mean(), "conductance": grp.conductance.mean(),
                         "conductance_sem": grp.conductance.std(ddof=1) / math.sqrt(len(grp)) if len(grp) > 1
                         else math.nan,
                         "percolating_fraction": grp.percolating.mean(),
                         "bruggeman_gfmd_hist": grp.flow_bruggeman.mean(),
                         "critical_junction_gfmd_hist": grp.flow_critical_junction.mean(),
                         "bruggeman_persson": pb, "critical_junction_persson": pc})
    out = pd.DataFrame(rows)
    a.out.mkdir(parents=True, exist_ok=True)
    out.to_csv(a.out / "leakage.csv", index=False)
    (a.out / "leakage.json").write_text(json.dumps({
        "what": "conductance against load: Reynolds flow on GFMD gaps vs Bruggeman and critical junction",
        "command": "python -m studies.leakage " + " ".join(sys.argv[1:] if argv is None else argv),
        "commit": commit, "machine": f"{platform.node()} {platform.machine()}",
        "date": datetime.now(UTC).isoformat(timespec="seconds"), "rows": rows}, indent=1) + "\n")
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    jobs_ = list(dict.fromkeys(out.job))
    fig, axes = plt.subplots(1, len(jobs_), figsize=(5.5 * len(jobs_), 4.2), squeeze=False)
    for ax, job in zip(axes[0], jobs_, strict=True):
        d = out[out.job == job].sort_values("sigma0")
        pos = d[d.conductance > 0]
        floor = pos.conductance.min() * 1e-3 if len(pos) else 1e-30
        k = d.conductance.where(d.conductance > 0, floor)
        ax.plot(d.sigma0, k, "ko-", label="Reynolds flow on the GFMD gap")
        for col, st, lab in (("bruggeman_gfmd_hist", "b--", "Bruggeman, GFMD histogram"),
                             ("critical_junction_gfmd_hist", "r--", "critical junction, GFMD histogram"),
                             ("bruggeman_persson", "b:", "Bruggeman, Persson P(g)"),
                             ("critical_junction_persson", "r:", "critical junction, Persson P(g)")):
            v = d[col].where(d[col] > 0, np.nan)
            ax.plot(d.sigma0, v, st, label=lab)
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_ylim(bottom=floor)
        ax.set_xlabel("sigma0" + (" [MPa]" if "measured" in job else " / E*"))
        ax.set_ylabel("conductance K" + (" [um^3 / (MPa s)]" if "measured" in job else " [L^3 / mu]"))
        ax.set_title(f"{job}: zero drawn at the bottom")
        ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(a.out / "leakage.png", dpi=110)
    print(out.to_string(), flush=True)


CODE_PATHS = ['gapsweep/flow', 'gapsweep/theory', 'gapsweep/gfmd', 'gapsweep/surfaces', 'gapsweep/sweep']

if __name__ == "__main__":
    import studies

    studies.track(CODE_PATHS)
    main()
