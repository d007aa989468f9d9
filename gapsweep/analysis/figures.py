"""Figures of a sweep (docs/model.md M6 for the paper's) from aggregated frames, PNG and PDF.

* :func:`fig_mean_gap_pressure` -- figures 2 (H = 0.3) and 3 (H = 0.8): ``g0/h_rms`` against
  ``sigma0/(E* g_rms)``, one panel per ``rho``: GFMD (open circles, standard error bars), the field theory
  (solid: the paper's form; thin dash-dot: the continuum form) and both limits of M4 dashed (red: high
  pressure ``rho ln(gamma0/(rho sigma0))``; blue: low pressure, plus ``h_rms^2/(2 rho)``).
* :func:`fig_mean_gap_hurst` -- figures 4 and 5: ``g0/h_rms`` against ``H`` at fixed ``sigma0/(E* g_rms)``.
* :func:`fig_gap_distribution` -- figure 6: ``h_rms P(g)`` against ``g/h_rms``: GFMD (open symbols with error
  bars), SDE (and Fokker-Planck) with the calibrated ``C2`` (solid) and the default ``C2`` (dotted), and the
  low-pressure (rigid, Gaussian) reference of M5 (dashed).
* :func:`fig_agreement` -- the agreement tiers of the theory against ``h_rms/rho`` and pressure.

Every function takes the frames of :mod:`gapsweep.analysis.aggregate` / :mod:`gapsweep.analysis.compare` and returns a
``matplotlib.figure.Figure`` built with the object-oriented API: importing this module never selects a backend
(Jupyter keeps its own), and :func:`save` writes PNG and PDF through the figure's own canvas. Each figure carries
a footer with the grid size ``N`` and the number of seeds behind its points (:func:`footer`); GFMD points whose
interaction is under-resolved (``rho < L/N``, docs/model.md M7) are drawn filled grey and named in the legend.
The theory lines are evaluated on a dense grid with ``gapsweep.theory`` when the group's parameters are known,
else the stored theory points are joined.
"""

from __future__ import annotations

import logging
import math
import warnings
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import matplotlib
import numpy as np
import pandas as pd
from matplotlib.figure import Figure

from gapsweep.analysis.aggregate import HistogramStats

log = logging.getLogger(__name__)

__all__ = ["STYLE", "fig_agreement", "fig_gap_distribution", "fig_mean_gap_hurst", "fig_mean_gap_pressure", "footer",
           "has_data", "save"]

STYLE = {
    "font.size": 10, "axes.labelsize": 10, "axes.titlesize": 10, "legend.fontsize": 8.5, "xtick.labelsize": 9,
    "ytick.labelsize": 9, "lines.linewidth": 1.4, "lines.markersize": 5, "axes.grid": True, "grid.alpha": 0.25,
    "figure.dpi": 100, "savefig.dpi": 200, "savefig.bbox": "tight", "pdf.fonttype": 42,
}
GFMD = {"marker": "o", "mfc": "none", "mec": "k", "ecolor": "k", "color": "k", "ls": "none", "capsize": 2,
        "elinewidth": 0.8, "label": "GFMD"}
HIGH = {"color": "tab:red", "ls": "--", "lw": 1.1, "label": "high-pressure limit"}
LOW = {"color": "tab:blue", "ls": "--", "lw": 1.1, "label": "low-pressure limit"}
THEORY = {"color": "tab:green", "ls": "-", "label": "field theory (paper)"}
CONTINUUM = {"color": "0.45", "ls": "-.", "lw": 0.9, "label": "field theory (continuum)"}


def _close(a: Any, b: float, rtol: float = 1e-6) -> np.ndarray:
    return np.isclose(np.asarray(a, float), b, rtol=rtol, atol=0.0)


def _finest(g: pd.DataFrame) -> pd.DataFrame:
    if g.empty or "n" not in g:
        return g
    return g[g["n"] == g.groupby(["hurst", "rho", "sigma0"])["n"].transform("max")]


def _first(g: pd.DataFrame, col: str) -> float:
    v = g[col].dropna() if col in g else pd.Series(dtype=float)
    return float(v.iloc[0]) if len(v) else math.nan


def _theory_curve(sigma0: np.ndarray, *, hurst: float, h_rms: float, rho: float, gamma0: float, lambda_l: float,
                  lambda_s: float, e_star: float, form: str, domain: list[str] | None = None) -> np.ndarray | None:
    """Field-theory mean gap on a dense grid (M4) or None when gapsweep.theory or a parameter is missing.
    ``domain``: a list that receives the theory's PredictorDomainWarning messages (docs/theory.md, 'Validity')."""
    if not all(np.isfinite([hurst, h_rms, rho, gamma0, lambda_l, lambda_s, e_star])):
        return None
    try:
        from gapsweep import theory
        from gapsweep.theory.domain import PredictorDomainWarning
    except ImportError:
        return None
    with warnings.catch_warnings(record=True) as caught:
        # a figure draws the theory wherever the data are, as the paper's figures do; outside the validated domain
        # the figure says so on the panel (OUTSIDE_NOTE) and the log says why, instead of a raw warning per curve
        warnings.simplefilter("always", PredictorDomainWarning)
        y = np.asarray(theory.mean_gap(sigma0, hurst=hurst, h_rms=h_rms, rho=rho, gamma0=gamma0, lambda_l=lambda_l,
                                       lambda_s=lambda_s, e_star=e_star, form=form), dtype=float)
    for w in caught:
        if issubclass(w.category, PredictorDomainWarning):
            if str(w.message) not in _DOMAIN_LOGGED:  # once per message and process: a report draws many panels
                _DOMAIN_LOGGED.add(str(w.message))
                log.info("figure: %s", w.message)
        else:  # any other warning is not ours to swallow
            warnings.warn_explicit(w.message, w.category, w.filename, w.lineno)
    if domain is not None:
        domain.extend(str(w.message) for w in caught if issubclass(w.category, PredictorDomainWarning))
    return y


_DOMAIN_LOGGED: set[str] = set()

#: the note a panel carries where its field-theory curve lies (partly) outside the theory's validated domain
OUTSIDE_NOTE = "field theory outside its\nvalidated domain (docs/theory.md)"


def _panels(n: int, width: float = 3.6, height: float = 3.1):
    fig = Figure(figsize=(width * max(n, 1), height))
    axes = fig.subplots(1, max(n, 1), squeeze=False)
    return fig, axes[0]


UNDER = {"marker": "o", "color": "0.55", "mec": "k", "ls": "none", "ms": 5, "zorder": 3,
         "label": "GFMD, under-resolved ($\\rho < L/N$)"}


def _under_resolved(g: pd.DataFrame) -> np.ndarray:
    """GFMD rows whose interaction range is below the grid spacing, ``rho < L/N`` (docs/model.md M7)."""
    if g.empty or "n" not in g:
        return np.zeros(len(g), dtype=bool)
    length = g["length"].to_numpy(float) if "length" in g else np.ones(len(g))
    length = np.where(np.isfinite(length), length, 1.0)  # L = 1 by default (docs/model.md M1)
    n = g["n"].to_numpy(float)
    return (n > 0) & (g["rho"].to_numpy(float) < length / np.where(n > 0, n, 1.0))


def _gfmd_points(ax: Any, gf: pd.DataFrame, x: str) -> None:
    """GFMD means with standard-error bars; under-resolved points filled grey on top."""
    ax.errorbar(gf[x], gf["mean_reduced"], yerr=gf["sem_reduced"].fillna(0.0), **GFMD)
    bad = _under_resolved(gf)
    if bad.any():
        ax.plot(gf[x].to_numpy()[bad], gf["mean_reduced"].to_numpy()[bad], **UNDER)


def has_data(agg: pd.DataFrame, sources: Sequence[str] = ("gfmd", "theory:paper")) -> bool:
    """Whether ``agg`` has at least one finite mean from ``sources`` (a figure built from it is not blank)."""
    if agg is None or len(agg) == 0:
        return False
    a = agg[agg["source"].isin(list(sources)) & (agg["count"] > 0)]
    return bool(len(a)) and bool(np.isfinite(a["mean_reduced"].to_numpy(float)).any())


def footer(agg: pd.DataFrame, *, quick: bool = False, extra: str = "") -> str:
    """One line for a figure: GFMD grid sizes ``N``, seeds per point, what the error bars are, and a warning for
    quick (smoke-test) jobs."""
    parts = []
    gf = agg[(agg["source"] == "gfmd") & (agg["count"] > 0)] if len(agg) else agg
    if len(gf):
        ns = sorted({int(x) for x in gf["n"].dropna() if x > 0})
        seeds = sorted({int(x) for x in gf["count"]})
        parts.append("GFMD: N = " + ", ".join(map(str, ns)) + "; seeds per point: "
                     + (f"{seeds[0]}" if len(seeds) == 1 else f"{seeds[0]}-{seeds[-1]}")
                     + ("; error bars: standard error over seeds" if max(seeds) >= 2 else "; one seed: no error bars"))
    th = agg[agg["source"].astype(str).str.startswith("theory") & (agg["count"] > 0)] if len(agg) else agg
    if len(th):
        parts.append("theory: continuum h_rms" if not (th["n"] > 0).any() else "theory")
    if extra:
        parts.append(extra)
    if quick:
        parts.append("QUICK JOB: smoke test, not for conclusions")
    return " | ".join(parts)


QUICK_NOTE = "QUICK JOB: smoke test, not for conclusions"


def _with_quick(note: str | None, quick: bool) -> str | None:
    if quick and QUICK_NOTE not in (note or ""):
        return " | ".join(x for x in (note, QUICK_NOTE) if x)
    return note


def _finish(fig: Figure, axes: Sequence[Any], note: str | None) -> None:
    """One shared legend (every label once, below the panels) and the footer line."""
    handles, labels = [], []
    for ax in axes:
        for h, lab in zip(*ax.get_legend_handles_labels()):
            if lab not in labels and not lab.startswith("_"):
                handles.append(h)
                labels.append(lab)
    ncol = max(1, min(len(labels), int(fig.get_figwidth() // 1.9)))
    if handles:
        fig.legend(handles, labels, loc="lower center", ncol=ncol, frameon=False)
    rows = math.ceil(len(labels) / ncol) if handles else 0
    fh = fig.get_figheight() + 0.24 * rows + (0.22 if note else 0.0)
    fig.set_figheight(fh)
    foot = (0.22 / fh) if note else 0.0
    if handles:
        fig.legends[-1].set_bbox_to_anchor((0.5, foot))
    if note:
        fig.text(0.5, 0.01, note, ha="center", va="bottom", fontsize=7.5, color="0.3")
    fig.tight_layout(rect=(0, foot + 0.24 * rows / fh + 0.01, 1, 1))


def fig_mean_gap_pressure(agg: pd.DataFrame, *, hurst: float, rhos: Sequence[float] | None = None,
                          title: str | None = None, note: str | None = None, quick: bool = False) -> Figure:
    """``g0/h_rms`` vs ``sigma0/(E* g_rms)``, one panel per ``rho`` (descending, as the paper's figures 2 and 3,
    docs/model.md M6): GFMD with standard errors, the field theory and both limits of M4.

    ``agg`` is :func:`analysis.aggregate.aggregate_mean_gap`. With ``rhos=None`` only the ``rho`` values that have
    data get a panel; an explicitly requested ``rho`` without data gets a panel that says so.
    """
    with matplotlib.rc_context(STYLE):
        a = agg[_close(agg["hurst"], hurst)] if len(agg) else agg
        if rhos is None:
            rs = sorted({r for r in a["rho"] if has_data(a[_close(a["rho"], r)])}, reverse=True) if len(a) else []
        else:
            rs = sorted(rhos, reverse=True)
        fig, axes = _panels(len(rs))
        for ax, rho, letter in zip(axes, rs, "abcdefghijklmnop"):
            g = a[_close(a["rho"], rho)]
            gf = _finest(g[(g["source"] == "gfmd") & (g["count"] > 0)]).sort_values("sigma0")
            th = g[(g["source"] == "theory:paper") & (g["count"] > 0)].sort_values("sigma0")
            ref = th if len(th) else gf
            ax.set_title(f"({letter}) H = {hurst:g}, $\\rho/L$ = {rho:g}")
            ax.set_xscale("log")
            ax.set_xlabel(r"reduced pressure $\sigma_0/(E^*\bar g)$")
            ax.set_ylabel(r"mean gap $g_0/\bar h$")
            if ref.empty:
                ax.text(0.5, 0.5, "no data", transform=ax.transAxes, ha="center", va="center")
                continue
            h = _first(ref, "h_rms")
            gr, es = _first(ref, "g_rms"), _first(ref, "e_star")
            s_all = np.concatenate([gf["sigma0"].to_numpy(float), th["sigma0"].to_numpy(float)])
            s = np.geomspace(s_all.min() / 1.5, s_all.max() * 1.5, 200)
            x = s / (es * gr)
            gamma0 = _first(ref, "gamma0")
            flat = rho * (math.log(gamma0) - math.log(rho) - np.log(s))  # M4 high-pressure limit
            ax.plot(x, flat / h, **HIGH)
            ax.plot(x, (flat + h**2 / (2 * rho)) / h, **LOW)
            params = {"hurst": hurst, "h_rms": h, "rho": rho, "gamma0": gamma0, "lambda_l": _first(ref, "lambda_l"),
                      "lambda_s": _first(ref, "lambda_s"), "e_star": es}
            outside: list[str] = []
            y = _theory_curve(s, form="paper", domain=outside, **params)
            if y is not None:
                ax.plot(x, y / h, **THEORY)
                if outside:
                    ax.text(0.03, 0.03, OUTSIDE_NOTE, transform=ax.transAxes, fontsize=6, color="0.35",
                            ha="left", va="bottom")
                yc = _theory_curve(s, form="continuum", **params)
                if yc is not None:
                    ax.plot(x, yc / h, **CONTINUUM)
            elif len(th):
                ax.plot(th["sigma0_reduced"], th["mean_reduced"], **THEORY)
            if len(gf):
                _gfmd_points(ax, gf, "sigma0_reduced")
            lo = min(np.nanmin(flat / h), np.nanmin(gf["mean_reduced"]) if len(gf) else np.inf)
            hi = max(np.nanmax((flat + h**2 / (2 * rho)) / h), np.nanmax(gf["mean_reduced"]) if len(gf) else -np.inf)
            ax.set_ylim(lo - 0.05 * (hi - lo), hi + 0.05 * (hi - lo))
        if title:
            fig.suptitle(title)
        _finish(fig, axes, _with_quick(note, quick))
    return fig


def fig_mean_gap_hurst(agg: pd.DataFrame, *, sigma0_reduced: float | Sequence[float], rho: float,
                       title: str | None = None, rtol: float = 0.02, note: str | None = None,
                       quick: bool = False) -> Figure:
    """``g0/h_rms`` vs ``H`` at ``sigma0/(E* g_rms) = sigma0_reduced`` (within ``rtol``), the paper's figures 4
    and 5 (docs/model.md M6); one panel per reduced pressure when several are given."""
    levels = [sigma0_reduced] if np.ndim(sigma0_reduced) == 0 else list(sigma0_reduced)
    with matplotlib.rc_context(STYLE):
        fig, axes = _panels(len(levels), width=3.8, height=3.2)
        for ax, level, letter in zip(axes, levels, "abcdefghijklmnop"):
            a = (agg[_close(agg["rho"], rho) & _close(agg["sigma0_reduced"], float(level), rtol)]
                 if len(agg) else agg)
            gf = _finest(a[(a["source"] == "gfmd") & (a["count"] > 0)]).sort_values("hurst")
            th = a[(a["source"] == "theory:paper") & (a["count"] > 0)].sort_values("hurst")
            prefix = f"({letter}) " if len(levels) > 1 else ""
            ax.set_title(title if (title and len(levels) == 1) else
                         f"{prefix}$\\rho/L$ = {rho:g}, $\\sigma_0/(E^*\\bar g)$ = {float(level):g}")
            ax.set_xlabel("Hurst exponent $H$")
            ax.set_ylabel(r"mean gap $g_0/\bar h$")
            if gf.empty and th.empty:
                ax.text(0.5, 0.5, "no data", transform=ax.transAxes, ha="center", va="center")
                continue
            if len(th):
                line = _dense_hurst_line(th, rho)
                if line is not None:
                    ax.plot(line[0], line[1], **THEORY)
                else:
                    ax.plot(th["hurst"], th["mean_reduced"], **THEORY)
            if len(gf):
                _gfmd_points(ax, gf, "hurst")
        if title and len(levels) > 1:
            fig.suptitle(title)
        _finish(fig, axes, _with_quick(note, quick))
    return fig


def _dense_hurst_line(th: pd.DataFrame, rho: float) -> tuple[np.ndarray, np.ndarray] | None:
    """Theory ``g0/h_rms`` on a dense H grid, only when ``h_rms(H)`` is the continuum value for ``g_rms`` (the
    default normalisation of M2), checked against every stored theory point (else None: join the points)."""
    try:
        from gapsweep.surface import continuum_rms_height
    except ImportError:
        return None
    r = th.iloc[0]
    ll, ls, gr, es = (float(r[k]) for k in ("lambda_l", "lambda_s", "g_rms", "e_star"))
    if not all(np.isfinite([ll, ls, gr, es])):
        return None
    for _, t in th.iterrows():
        if not math.isclose(continuum_rms_height(float(t["hurst"]), lambda_l=ll, lambda_s=ls, rms_slope=gr),
                            float(t["h_rms"]), rel_tol=1e-6):
            return None
    hs = np.linspace(th["hurst"].min(), th["hurst"].max(), 60)
    ys = []
    for hh in hs:
        h = continuum_rms_height(float(hh), lambda_l=ll, lambda_s=ls, rms_slope=gr)
        y = _theory_curve(np.asarray([float(r["sigma0"])]), hurst=float(hh), h_rms=h, rho=rho,
                          gamma0=float(r["gamma0"]), lambda_l=ll, lambda_s=ls, e_star=es, form="paper")
        if y is None:
            return None
        ys.append(float(y[0]) / h)
    return hs, np.asarray(ys)


#: the rigid low-pressure reference of the gap distribution is drawn where eta = rho q_l E*/(2 sigma0) is at least
#: this (docs/model.md M4 limits: each mode's displacement is below 1/(1 + eta) of its height, here < 10 %)
RIGID_ETA = 10.0


def rigid_eta(rho: float, sigma0: float, lambda_l: float, e_star: float = 1.0) -> float:
    """The stiffness ratio ``eta = rho q_l E*/(2 sigma0)`` with ``q_l = 2 pi/lambda_l`` (docs/model.md M4); NaN
    when a parameter is missing."""
    try:
        v = rho * (2 * math.pi / float(lambda_l)) * float(e_star) / (2 * float(sigma0))
    except (TypeError, ValueError, ZeroDivisionError):
        return math.nan
    return v if math.isfinite(v) else math.nan


def fig_gap_distribution(hagg: Mapping[tuple, HistogramStats], *, hurst: float, rho: float, max_curves: int = 5,
                         title: str | None = None, note: str | None = None, quick: bool = False) -> Figure:
    """Figure 6 (M6): ``h_rms P(g)`` vs ``g/h_rms`` for each pressure (one colour each, at most ``max_curves``
    evenly picked): GFMD (open circles with the per-bin standard error), the Fokker-Planck density at the
    calibrated ``C2`` (solid; key method "fp_calibrated", from :func:`analysis.compare.calibrate_c2`), the SDE and
    Fokker-Planck runs of the store at their own ``C2`` (dotted / dash-dot: uncalibrated, the value in the legend)
    and the rigid low-pressure reference (dashed) ``N(g0_rigid, h_rms^2)``,
    ``g0_rigid = rho ln(gamma0/(rho sigma0)) + h_rms^2/(2 rho)`` (M5), drawn only where it applies: the rigid
    limit needs ``eta = rho q_l E*/(2 sigma0) >= RIGID_ETA`` (M4: every mode's elastic displacement is below
    ``1/(1 + eta)`` of its height); at higher pressures the body follows the roughness and the curve would
    mislead. Labels name methods and parameters, never the store's job names.

    ``hagg``: :func:`analysis.aggregate.aggregate_histograms`, optionally merged with the calibrated models.
    """
    with matplotlib.rc_context(STYLE):
        fig, axes = _panels(1, width=6.8, height=3.4)
        ax = axes[0]
        sel = {k: v for k, v in hagg.items() if math.isclose(k[1], hurst, rel_tol=1e-6)
               and math.isclose(k[2], rho, rel_tol=1e-6)}
        gf: dict[float, tuple[float, HistogramStats]] = {}
        for k, v in sel.items():
            if k[0] == "gfmd" and (k[3] not in gf or k[4] > gf[k[3]][0]):
                gf[k[3]] = (k[4], v)
        ax.set_title(title or f"H = {hurst:g}, $\\rho/L$ = {rho:g}")
        ax.set_xlabel(r"gap $g/\bar h$")
        ax.set_ylabel(r"density $\bar h\,P(g)$")
        sigmas = sorted({k[3] for k in sel})
        if not sigmas:
            ax.text(0.5, 0.5, "no data", transform=ax.transAxes, ha="center", va="center")
            return fig
        if len(sigmas) > max_curves:
            sigmas = [sigmas[i] for i in np.unique(np.linspace(0, len(sigmas) - 1, max_curves).round().astype(int))]
        colors = matplotlib.colormaps["viridis"](np.linspace(0.0, 0.85, len(sigmas)))
        styles = {"fp_calibrated": ("-", "Fokker-Planck, fitted $C_2$"), "sde": (":", "SDE, $C_2$ = {c2}"),
                  "fokker_planck": ("-.", "Fokker-Planck, $C_2$ = {c2}")}
        seen: set[tuple[str, str]] = set()
        drew_rigid = skipped_rigid = False
        for s, col in zip(sigmas, colors):
            ref = gf.get(s, (0, None))[1]
            hs = [v.get("h_rms", np.nan) for k, v in sel.items() if k[3] == s]
            h = ref["h_rms"] if ref is not None and np.isfinite(ref.get("h_rms", np.nan)) else \
                next((x for x in hs if np.isfinite(x)), None)
            if h is None:
                continue
            if ref is not None:
                ax.errorbar(ref.centres / h, ref["density"] * h, yerr=np.nan_to_num(ref["sem"]) * h, marker="o",
                            mfc="none", mec=col, ecolor=col, ls="none", ms=3.5, capsize=1.5, elinewidth=0.7,
                            label=f"GFMD, $\\sigma_0/E^*$ = {s:.3g}")
                gamma0 = ref.get("gamma0", np.nan)
                eta = rigid_eta(rho, s, ref.get("lambda_l", np.nan), ref.get("e_star", 1.0))
                if np.isfinite(gamma0) and not eta >= RIGID_ETA:
                    skipped_rigid = True
                elif np.isfinite(gamma0):
                    drew_rigid = True
                    g0r = rho * (math.log(gamma0) - math.log(rho) - math.log(s)) + h**2 / (2 * rho)
                    gg = np.linspace(ref["edges"][0], ref["edges"][-1], 300)
                    ax.plot(gg / h, np.exp(-0.5 * ((gg - g0r) / h) ** 2) / math.sqrt(2 * math.pi), color=col, ls="--",
                            lw=0.9)
            for (m, _hh, _rr, ss, _n, c2, *_), v in sorted(sel.items(), key=lambda kv: (kv[0][0], kv[0][5])):
                if m not in styles or ss != s:
                    continue
                ls, name = styles[m]
                name = name.format(c2=f"{c2:.3g}" if c2 is not None and np.isfinite(c2) else "default")
                lbl = None if (m, name) in seen else name
                seen.add((m, name))
                e = v["edges"]
                ax.plot(np.repeat(e, 2)[1:-1] / h, np.repeat(v["density"], 2) * h, color=col, ls=ls, lw=1.0,
                        label=lbl)
        if drew_rigid:
            ax.plot([], [], color="0.4", ls="--", lw=0.9, label=f"rigid limit (only where $\\eta \\geq$ {RIGID_ETA:g})")
        ax.legend(loc="center left", bbox_to_anchor=(1.01, 0.5), frameon=False, fontsize=8)
        rigid_note = (f"rigid-limit reference drawn only where eta = rho q_l E*/(2 sigma0) >= {RIGID_ETA:g} (it "
                      "does not apply at higher pressures)") if skipped_rigid else ""
        lines = [x for x in (" | ".join(x for x in (note or _hist_footer(sel), "QUICK JOB: smoke test, not for "
                                                    "conclusions" if quick else "") if x), rigid_note) if x]
        fig.text(0.5, 0.005, "\n".join(lines), ha="center", va="bottom", fontsize=7.5, color="0.3")
        fig.tight_layout(rect=(0, 0.05 * max(1, len(lines)), 1, 1))
    return fig


def _hist_footer(sel: Mapping[tuple, HistogramStats]) -> str:
    """N and seeds behind the GFMD histograms of a gap-distribution figure."""
    g = [(k[4], v.get("n_hist", 0)) for k, v in sel.items() if k[0] == "gfmd"]
    if not g:
        return ""
    ns = sorted({int(n) for n, _ in g if n > 0})
    seeds = sorted({int(c) for _, c in g})
    return (f"GFMD: N = {', '.join(map(str, ns))}; seeds per histogram: "
            + (f"{seeds[0]}" if len(seeds) == 1 else f"{seeds[0]}-{seeds[-1]}")
            + "; error bars: standard error over seeds (Poisson with one seed)")


_TIER_COLORS = {"<=1%": "tab:green", "<=5%": "yellowgreen", "<=10%": "orange", ">10%": "tab:red",
                "ill-conditioned": "0.7", "no GFMD data": "white"}


def fig_agreement(points: pd.DataFrame, *, title: str | None = None, note: str | None = None) -> Figure:
    """Agreement tiers (from :func:`analysis.compare.agreement_regions`) in the plane ``h_rms/rho`` vs
    ``sigma0/(E* g_rms)``, marker shape per H."""
    with matplotlib.rc_context(STYLE):
        fig, axes = _panels(1, width=4.4, height=3.2)
        ax = axes[0]
        ax.set_xscale("log")
        ax.set_xlabel(r"reduced pressure $\sigma_0/(E^*\bar g)$")
        ax.set_ylabel(r"roughness over range $\bar h/\rho$")
        ax.set_title(title or "field theory (paper) vs GFMD")
        if points.empty:
            ax.text(0.5, 0.5, "no data", transform=ax.transAxes, ha="center", va="center")
            return fig
        markers = dict(zip(sorted(points["hurst"].unique()), "osD^v<>phX*"))
        for tier, col in _TIER_COLORS.items():
            p = points[points["tier"] == tier]
            for h, q in p.groupby("hurst"):
                ax.scatter(q["sigma0_reduced"], q["h_rms_over_rho"], c=col, marker=markers[h], edgecolors="k",
                           linewidths=0.4, s=22)
            if len(p):
                ax.scatter([], [], c=col, edgecolors="k", linewidths=0.4, label=tier)
        for h, mk in markers.items():
            ax.scatter([], [], marker=mk, facecolors="none", edgecolors="k", label=f"H = {h:g}")
        ax.legend(loc="center left", bbox_to_anchor=(1.01, 0.5), frameon=False, title="|theory - GFMD|/GFMD")
        if note:
            fig.text(0.5, 0.005, note, ha="center", va="bottom", fontsize=7.5, color="0.3")
        fig.tight_layout(rect=(0, 0.05 if note else 0, 1, 1))
    return fig


def save(fig: Figure, out_dir: str | Path, name: str) -> list[Path]:
    """Write ``name.png`` and ``name.pdf`` into ``out_dir`` (created) and close the figure."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    paths = [out / f"{name}.png", out / f"{name}.pdf"]
    with matplotlib.rc_context(STYLE):
        for p in paths:
            fig.savefig(p)
    return paths
