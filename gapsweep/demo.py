"""The built-in demo (``gapsweep demo``): the paper's figure 2 by GFMD and the field theory, and a gap
distribution by GFMD, the SDE and the Fokker-Planck equation (docs/model.md M4-M6).

:func:`run` runs the shipped job spec ``gapsweep/jobs/demo.toml`` (package data: it works from an installed
wheel) into ``out/demo.h5`` and draws ``out/fig2_demo.png`` (mean gap ``g0/h_rms`` against ``sigma0/(E* g_rms)``:
GFMD means with standard errors over seeds, the field theory and both limits, one panel per rho) and
``out/gap_distribution_demo.png``. :func:`fig2_theory` is the field-theory part alone (continuum ``h_rms`` of the
g_rms = 1 spectrum), for a machine without the time for GFMD.
"""

from __future__ import annotations

import logging
import warnings
from pathlib import Path
from typing import Any

import numpy as np

from gapsweep import theory
from gapsweep.surfaces import synthetic as surface
from gapsweep.theory.domain import PredictorDomainWarning
from gapsweep.theory.field import DOMAIN_RHO_OVER_H_RMS

log = logging.getLogger(__name__)

FIG2 = {"hurst": 0.3, "lambda_l": 0.25, "lambda_s": 2.5e-3, "gamma0": 1e-3, "e_star": 1.0, "rms_slope": 1.0}
FIG2_RHOS = (2e-3, 1e-3, 5e-4)


def fig2_theory_table(pressures: np.ndarray | None = None) -> tuple[np.ndarray, dict[float, dict[str, np.ndarray]]]:
    """Field-theory mean gap (paper form, M4) and both limits, in units of h_rms, per rho."""
    p = FIG2
    sig = np.logspace(-4, 0, 9) if pressures is None else np.asarray(pressures, dtype=float)
    h_rms = surface.continuum_rms_height(p["hurst"], lambda_l=p["lambda_l"], lambda_s=p["lambda_s"])
    common = dict(hurst=p["hurst"], h_rms=h_rms, gamma0=p["gamma0"], lambda_l=p["lambda_l"],
                  lambda_s=p["lambda_s"], e_star=p["e_star"])
    out = {}
    for rho in FIG2_RHOS:
        with warnings.catch_warnings():
            # the paper's figure 2 draws the field theory where it was not validated; fig2_theory says so once
            warnings.simplefilter("ignore", PredictorDomainWarning)
            g0 = theory.mean_gap(sig, rho=rho, **common)
        out[rho] = {
            "theory": g0 / h_rms,
            "high": theory.flat_gap(sig, rho=rho, gamma0=p["gamma0"]) / h_rms,
            "low": (theory.flat_gap(sig, rho=rho, gamma0=p["gamma0"]) + h_rms**2 / (2 * rho)) / h_rms,
        }
    return sig, out


def fig2_theory(out_dir: str | Path = "out") -> str:
    """Write ``fig2_theory.png`` (field theory and both limits) into ``out_dir``; returns the figure-2 table."""
    from matplotlib.figure import Figure

    sig, curves = fig2_theory_table()
    head = "sigma0/(E* g_rms) | " + " | ".join(f"g0/h_rms rho={r:g}" for r in FIG2_RHOS)
    lines = [head, "-" * len(head)]
    for i, s in enumerate(sig):
        lines.append(f"{s:17.3e} | " + " | ".join(f"{curves[r]['theory'][i]:17.4f}" for r in FIG2_RHOS))
    h_rms = surface.continuum_rms_height(FIG2["hurst"], lambda_l=FIG2["lambda_l"], lambda_s=FIG2["lambda_s"])
    outside = [r for r in FIG2_RHOS if r / h_rms < DOMAIN_RHO_OVER_H_RMS]
    if outside:
        lines.append(f"(rho = {', '.join(f'{r:g}' for r in outside)}: rho/h_rms < {DOMAIN_RHO_OVER_H_RMS}, outside the "
                     "field theory's validated domain, as in the paper's figure; docs/theory.md, 'Validity')")
    table = "\n".join(lines)

    dense, dcurves = fig2_theory_table(np.logspace(-4.5, 0.5, 200))
    fig = Figure(figsize=(5.5, 4.2), layout="constrained")
    ax = fig.subplots()
    for rho, color in zip(FIG2_RHOS, ("C0", "C1", "C2")):
        c = dcurves[rho]
        ax.semilogx(dense, c["theory"], color=color, label=f"field theory, rho/L = {rho:g}")
        ax.semilogx(dense, c["high"], color=color, ls="--", lw=0.8)
        ax.semilogx(dense, c["low"], color=color, ls=":", lw=0.8)
    ax.set_xlabel(r"$\sigma_0/(E^* \bar g)$")
    ax.set_ylabel(r"$g_0/h_\mathrm{rms}$")
    ax.set_title("Fig. 2 (field theory): H = 0.3; dashed: high-, dotted: low-pressure limit", fontsize=8)
    ax.legend(fontsize=8)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    fig.savefig(out / "fig2_theory.png", dpi=150)
    return table


def run(job: str | Path, out_dir: str | Path = "out") -> dict[str, Any]:
    """Run the demo job into ``out_dir/demo.h5`` (finishing what is missing; a store of an older demo spec is
    replaced) and draw its figures. Returns ``{"store", "status", "table", "figures", "summary"}`` (text for
    the CLI; ``summary`` is the run's, from which the CLI takes its exit code as for ``gapsweep run``: a demo that
    leaves rows failed or pending does not exit 0)."""
    from gapsweep.sweep import api as store
    from gapsweep.sweep import runner

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    path = out / "demo.h5"
    try:
        summary = runner.run(job, path, resume=True)
    except runner.RunError:  # a demo store of an older demo spec: start again
        # ... but only a demo store: another job's store (or a damaged file) there is never replaced (issue 19)
        try:
            other = store.read_attrs(path).get("job_name")
        except Exception as e:
            raise runner.RunError(f"demo --out {out}: {path} exists and is not a demo store ({e}); choose "
                                  "another --out") from None
        if other != runner._load(job).name:
            raise runner.RunError(f"demo --out {out}: {path} is a store of job {other!r}, not the demo's; "
                                  "choose another --out") from None
        log.info("%s holds another job spec: replacing it", path)
        summary = runner.run(job, path, overwrite=True)
    df = store.read(path)
    done = df[df.status == "done"]
    table = ""
    if len(done):
        tab = (done.assign(g=done.mean_gap / done.h_rms)
               .groupby(["method", "hurst", "rho", "sigma0"]).g.mean().unstack("method"))
        table = tab.to_string(float_format=lambda x: f"{x:.4f}")
    return {"store": path, "status": store.status(path), "table": table,
            "figures": draw(df, store.read_histograms(path), out), "summary": summary}


def draw(df: Any, hists: dict, out_dir: str | Path) -> list[Path]:
    """Figure 2 (GFMD with error bars, field theory, both limits; a panel per rho) and the gap distribution at
    the largest rho with SDE / Fokker-Planck runs, from a store frame and its histograms."""
    from gapsweep.analysis import aggregate, figures

    out = Path(out_dir)
    made: list[Path] = []
    agg = aggregate.aggregate_mean_gap(df)
    if figures.has_data(agg):
        for hurst in sorted(set(agg["hurst"])):
            fig = figures.fig_mean_gap_pressure(agg, hurst=hurst, note=figures.footer(agg),
                                                title=f"Mean gap against pressure, H = {hurst:g} (the paper's fig. 2)")
            made.append(figures.save(fig, out, "fig2_demo")[0])
            break
    hagg = aggregate.aggregate_histograms(df, hists)
    with_model = sorted({(k[1], k[2]) for k in hagg if k[0] in ("sde", "fokker_planck")})
    if with_model:
        hurst, rho = with_model[-1]
        fig = figures.fig_gap_distribution(hagg, hurst=hurst, rho=rho)
        made.append(figures.save(fig, out, "gap_distribution_demo")[0])
    return made
