"""The report's contact section: hard-wall and adhesive sweeps (docs/gfmd.md, docs/analysis.md "Contact").

For the jobs whose interaction law is not the exponential repulsion (the store's spec names ``[interaction] kind``),
:func:`tables` gathers per job and pressure the GFMD quantities (contact area, elastic energy, mean gap, the
hard wall's contact atom, the load-path flags) and, where the job ran Persson's theory, puts it side by side:
``dev = (Persson - GFMD) / GFMD`` for the contact area and the mean separation (the mean gap), with a summary of
the largest and median ``|dev|``. :func:`plan` lists the figures: contact area, mean gap and elastic energy against
pressure (GFMD and Persson), the pressure distributions and the gap distributions (the contact atom at ``g = 0``
and the free surface's atom at ``p = 0`` named in the legend, not drawn as densities). Only data that exist get a
panel; the report leaves out any figure that still has an empty panel.

Seeds: values are averaged over seeds (a file surface has one); the tables give the count.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import numpy as np
import pandas as pd

from analysis import figures

__all__ = ["CONTACT_LAWS", "is_contact", "plan", "summary", "tables"]

CONTACT_LAWS = ("hard_wall", "adhesive")
PERSSON = {"color": "tab:purple", "ls": "-", "marker": "s", "ms": 4, "mfc": "none", "label": "Persson's theory"}
MAX_CURVES = 5


def is_contact(df: pd.DataFrame) -> pd.Series:
    """Rows of jobs with a contact law (``interaction`` column, set by ``analysis.report.load``)."""
    if "interaction" not in df:
        return pd.Series(False, index=df.index)
    return df["interaction"].astype(str).isin(CONTACT_LAWS)


def _mean(g: pd.DataFrame, col: str) -> tuple[float, float]:
    v = pd.to_numeric(g[col], errors="coerce").to_numpy(float) if col in g else np.array([])
    v = v[np.isfinite(v)]
    if not v.size:
        return math.nan, math.nan
    return float(v.mean()), (float(v.std(ddof=1) / math.sqrt(v.size)) if v.size > 1 else math.nan)


def tables(df: pd.DataFrame) -> tuple[pd.DataFrame, pd.DataFrame]:
    """``(points, persson)``: GFMD contact quantities per (job, law, hurst, rho, sigma0, n) over the done rows,
    with counts of rows not done and the OR of their flags; and GFMD side by side with Persson's theory per
    pressure (empty when no contact job ran Persson's theory)."""
    rows, side = [], []
    cdf = df[is_contact(df)]
    if cdf.empty:
        return pd.DataFrame(), pd.DataFrame()
    for (job, law, hurst, rho), g in cdf.groupby(["job", "interaction", "hurst", "rho"], sort=True):
        gf = g[g["method"].astype(str) == "gfmd"]
        th = g[(g["method"].astype(str) == "theory") & (g["status"].astype(str) == "done")]
        for (n, s0), p in gf.groupby(["n", "sigma0"], sort=True):
            done = p[p["status"].astype(str) == "done"]
            flags = pd.to_numeric(p.get("flags", pd.Series(dtype=float)), errors="coerce").fillna(0).astype(int)
            rec: dict[str, Any] = {"job": job, "interaction": law, "hurst": hurst, "rho": rho, "n": int(n),
                                   "sigma0": s0, "count": len(done), "not_done": len(p) - len(done),
                                   "flags": int(np.bitwise_or.reduce(np.maximum(flags.to_numpy(), 0)))
                                   if len(flags) else 0}
            for col in ("contact_area", "elastic_energy", "mean_gap", "contact_atom", "pressure_atom", "h_rms",
                        "g_rms", "e_star"):
                rec[col], rec[f"{col}_sem"] = _mean(done, col)
            rec["sigma0_reduced"] = s0 / (rec["e_star"] * rec["g_rms"]) if rec["g_rms"] else math.nan
            rows.append(rec)
            t = th[np.isclose(th["sigma0"].to_numpy(float), s0, rtol=1e-9, atol=0.0)]
            if len(t) and len(done):
                a_p, s_p = _mean(t, "contact_area")[0], _mean(t, "mean_gap_persson")[0]
                side.append({"job": job, "hurst": hurst, "n": int(n), "sigma0": s0,
                             "sigma0_reduced": rec["sigma0_reduced"], "gfmd_area": rec["contact_area"],
                             "persson_area": a_p, "area_dev": (a_p - rec["contact_area"]) / rec["contact_area"],
                             "gfmd_mean_gap": rec["mean_gap"], "persson_separation": s_p,
                             "gap_dev": (s_p - rec["mean_gap"]) / rec["mean_gap"],
                             "gap_dev_h_rms": (s_p - rec["mean_gap"]) / rec["h_rms"]})
    return pd.DataFrame(rows), pd.DataFrame(side)


def summary(persson: pd.DataFrame) -> pd.DataFrame:
    """Per job: largest and median ``|dev|`` of Persson's contact area and mean separation against GFMD, and the
    pressures where they are reached."""
    out = []
    for job, g in persson.groupby("job") if len(persson) else []:
        for q, col in (("contact area", "area_dev"), ("mean separation", "gap_dev")):
            d = g[col].to_numpy(float)
            ok = np.isfinite(d)
            if not ok.any():
                continue
            k = int(np.nanargmax(np.abs(np.where(ok, d, np.nan))))
            out.append({"job": job, "quantity": q, "points": int(ok.sum()),
                        "max_abs_dev": float(np.abs(d[k])), "at_sigma0": float(g["sigma0"].iloc[k]),
                        "median_abs_dev": float(np.median(np.abs(d[ok]))),
                        "sign": "Persson above GFMD" if np.all(d[ok] > 0) else
                        ("Persson below GFMD" if np.all(d[ok] < 0) else "both signs")})
    return pd.DataFrame(out)


# ---------------------------------------------------------------------------------------------------------
# figures


def _xscale(ax: Any, s: np.ndarray) -> None:
    if np.all(s > 0):
        ax.set_xscale("log")


def fig_contact(points: pd.DataFrame, persson: pd.DataFrame, *, job: str, note: str | None = None):
    """Contact area, mean gap and elastic energy against the applied pressure ``sigma0/E*`` (one job, finest n):
    GFMD (mean over seeds, standard errors where several) and Persson's theory where the job ran it."""
    import matplotlib

    with matplotlib.rc_context(figures.STYLE):
        p = points[points["job"] == job]
        p = p[p["n"] == p["n"].max()].sort_values("sigma0")
        p = p[p["count"] > 0]
        th = persson[persson["job"] == job].sort_values("sigma0") if len(persson) else persson
        fig, axes = figures._panels(3)
        x = p["sigma0"].to_numpy(float) / p["e_star"].to_numpy(float)
        for ax, col, ylabel, tcol, letter in (
                (axes[0], "contact_area", "contact area $A/A_0$", "persson_area", "a"),
                (axes[1], "mean_gap", "mean gap $g_0$ (units of the map)", "persson_separation", "b"),
                (axes[2], "elastic_energy", "elastic energy per area $U_{el}/A_0$", None, "c")):
            y = p[col].to_numpy(float)
            ax.errorbar(x, y, yerr=np.nan_to_num(p[f"{col}_sem"].to_numpy(float)), **figures.GFMD)
            jump = (p["flags"].to_numpy(int) & 1) > 0
            if jump.any():  # load-path jumps (adhesion) marked, not hidden
                ax.plot(x[jump], y[jump], ls="none", marker="x", ms=8, color="tab:red",
                        label="jump along the load path")
            if tcol and len(th):
                ax.plot(th["sigma0"].to_numpy(float) / p["e_star"].iloc[0], th[tcol].to_numpy(float), **PERSSON)
            _xscale(ax, x)
            if np.all(y[np.isfinite(y)] > 0) and col != "mean_gap":
                ax.set_yscale("log")
            ax.set_xlabel(r"pressure $\sigma_0/E^*$")
            ax.set_ylabel(ylabel)
            ax.set_title(f"({letter}) {ylabel.split(' $')[0].split(' (')[0]}")
        figures._finish(fig, axes, note)
    return fig


def _pick(keys: list[float], k: int = MAX_CURVES) -> list[float]:
    if len(keys) <= k:
        return keys
    return [keys[i] for i in np.unique(np.linspace(0, len(keys) - 1, k).round().astype(int))]


def fig_distributions(df: pd.DataFrame, hists: Mapping[str, tuple], phists: Mapping[str, tuple], *, job: str,
                      note: str | None = None):
    """Gap density (the free points; the contact atom at g = 0 in the legend) and pressure density (p/sigma0 for
    compressive loads; the free-surface atom at p = 0 in the legend) of one job's GFMD rows (finest n, first
    seed), up to five pressures."""
    import matplotlib

    with matplotlib.rc_context(figures.STYLE):
        g = df[(df["job"] == job) & (df["method"].astype(str) == "gfmd") & (df["status"].astype(str) == "done")]
        g = g[(g["n"] == g["n"].max()) & (g["seed"] == g["seed"].min())] if len(g) else g
        loads = _pick(sorted(set(g["sigma0"].astype(float))))
        fig, axes = figures._panels(2)
        cmap = matplotlib.colormaps["viridis"]
        scale = bool(len(loads)) and min(loads) > 0
        for i, s0 in enumerate(loads):
            row = g[np.isclose(g["sigma0"].to_numpy(float), s0, rtol=1e-9, atol=0.0)].iloc[0]
            col = cmap(i / max(len(loads) - 1, 1))
            tid = row["task_id"]
            if tid in hists:
                e, d, _ = hists[tid]
                atom = float(row.get("contact_atom", math.nan))
                lab = f"$\\sigma_0$ = {s0:g}" + (f" (atom g=0: {atom:.3f})" if math.isfinite(atom) else "")
                axes[0].stairs(d, e, color=col, label=lab)
                axes[0].plot(0.5 * (e[1:] + e[:-1]), d, ls="none", marker=".", ms=2, color=col)
            if tid in phists:
                e, d, atom = phists[tid]
                f = s0 if scale else 1.0
                axes[1].stairs(d * f, e / f, color=col, label=f"_p{i}")
                axes[1].plot(0.5 * (e[1:] + e[:-1]) / f, d * f, ls="none", marker=".", ms=2, color=col,
                             label=f"p=0 atom at $\\sigma_0$ = {s0:g}: {atom:.3f}" if atom > 0 else f"_q{i}")
        axes[0].set_xlabel("gap $g$ (units of the map)")
        axes[0].set_ylabel("density $P(g)$ of the free points")
        axes[0].set_title("(a) gap distribution")
        if scale:  # compressive loads: the pressures span decades (contact spots at low load)
            axes[1].set_xscale("log")
            axes[1].set_yscale("log")
        axes[1].set_xlabel(r"local pressure $p/\sigma_0$" if scale else r"local pressure $p/E^*$")
        axes[1].set_ylabel("density of the loaded points")
        axes[1].set_title("(b) pressure distribution")
        figures._finish(fig, axes, note)
    return fig


def _note(a: pd.DataFrame, job: str, quick: bool) -> str:
    """Footer: GFMD grid sizes, seeds, the job, and the quick-job warning."""
    gf = a[(a["method"].astype(str) == "gfmd") & (a["status"].astype(str) == "done")]
    ns = sorted({int(x) for x in gf["n"]})
    seeds = gf["seed"].nunique()
    parts = [f"GFMD: N = {', '.join(map(str, ns))}; seeds: {seeds}"
             + ("; error bars: standard error over seeds" if seeds > 1 else "; one seed: no error bars"),
             f"job {job}"]
    if quick:
        parts.append(figures.QUICK_NOTE)
    return " | ".join(parts)


def plan(df: pd.DataFrame, hists: Mapping[str, tuple], phists: Mapping[str, tuple], points: pd.DataFrame,
         persson: pd.DataFrame, quick: set[str] | frozenset[str] = frozenset()) -> list[tuple[str, str, Any]]:
    """``[(name, caption, make)]`` of the contact figures, per contact job with finished GFMD rows."""
    out: list[tuple[str, str, Any]] = []

    def note(a: pd.DataFrame, job: str) -> str:
        return _note(a, job, job in quick)

    for job in sorted(set(points["job"])) if len(points) else []:
        p = points[(points["job"] == job) & (points["count"] > 0)]
        if p.empty:
            continue
        law = str(p["interaction"].iloc[0])
        tag = "".join(c if c.isalnum() else "_" for c in job) or "store"
        has_p = len(persson) and (persson["job"] == job).any()
        a = df[df["job"] == job]
        out.append((f"contact_{tag}", f"Contact area, mean gap and elastic energy against pressure, {law} (job "
                    f"{job}{'; GFMD and Persson side by side' if has_p else ''})",
                    lambda job=job, a=a: fig_contact(points, persson, job=job, note=note(a, job))))
        tids = set(a[a["method"].astype(str) == "gfmd"]["task_id"])
        if tids & set(hists) or tids & set(phists):
            out.append((f"contact_distributions_{tag}", f"Gap and pressure distributions, {law} (job {job})",
                        lambda job=job, a=a: fig_distributions(df, hists, phists, job=job, note=note(a, job))))
    return out
