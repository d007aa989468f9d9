"""The report's leak-rate figure (issue 42; docs/model.md M8): for a contact job whose GFMD rows carry the flow
extension's columns (``[methods.gfmd] flow``), the conductance ``K`` from the Reynolds flow solve against the
load, mean over seeds, with the Bruggeman and critical-junction estimates from each row's own gap histogram
(columns ``flow_bruggeman``, ``flow_critical_junction``). Loads at which every seed sealed (``K = 0``) are marked
at the bottom of the log axis, not dropped."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np
import pandas as pd

from gapsweep.analysis import figures

__all__ = ["fig_leak", "has_flow", "table"]

COLUMNS = ("conductance", "flow_bruggeman", "flow_critical_junction", "percolating", "contact_area")


def has_flow(df: pd.DataFrame, job: str) -> bool:
    """Whether the job's done GFMD rows carry a finite conductance (the flow extension ran)."""
    if "conductance" not in df.columns:
        return False
    g = df[(df["job"] == job) & (df["method"].astype(str) == "gfmd") & (df["status"].astype(str) == "done")]
    return bool(len(g)) and bool(np.isfinite(pd.to_numeric(g["conductance"], errors="coerce")).any())


def table(df: pd.DataFrame, job: str) -> pd.DataFrame:
    """Per load (finest ``n``): the means over seeds of :data:`COLUMNS`, the seeds and the sealed fraction."""
    g = df[(df["job"] == job) & (df["method"].astype(str) == "gfmd") & (df["status"].astype(str) == "done")]
    g = g[g["n"] == g["n"].max()]
    rows = []
    for s0, grp in g.groupby("sigma0"):
        rec: dict[str, Any] = {"sigma0": float(s0), "seeds": len(grp)}
        for c in COLUMNS:
            rec[c] = float(pd.to_numeric(grp[c], errors="coerce").mean())
        rows.append(rec)
    return pd.DataFrame(rows)


def fig_leak(df: pd.DataFrame, *, job: str, info: Mapping[str, Any] | None = None, note: str | None = None):
    """Conductance against load (log-log): the flow solve on GFMD's gaps, and the two estimates from the gap
    histogram. Axes over E* (model units) or in the store's pressure unit."""
    import matplotlib

    units = (info or {}).get("units") or {}
    punit = units.get("pressure")
    with matplotlib.rc_context(figures.STYLE):
        t = table(df, job)
        fig, axes = figures._panels(1, width=5.0, height=3.6)
        ax = axes[0]
        x = t["sigma0"].to_numpy(float)
        k = t["conductance"].to_numpy(float)
        pos = k[k > 0]
        floor = float(pos.min()) * 1e-2 if len(pos) else 1e-30
        ax.plot(x, np.where(k > 0, k, floor), "ko-", mfc="none", label="Reynolds flow on the GFMD gap")
        sealed = k <= 0
        if sealed.any():
            ax.plot(x[sealed], np.full(sealed.sum(), floor), ls="none", marker="v", color="k", ms=7,
                    label="sealed (K = 0)")
        for col, st, lab in (("flow_bruggeman", "b--", "Bruggeman (gap histogram)"),
                             ("flow_critical_junction", "r:", "critical junction (gap histogram)")):
            v = t[col].to_numpy(float)
            ax.plot(x, np.where(v > 0, v, np.nan), st, label=lab)
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_ylim(bottom=floor * 0.5)
        ax.set_xlabel(r"$\sigma_0$" + (f" [{punit}]" if punit else r" / $E^*$"))
        ax.set_ylabel(r"conductance $K$ (leak rate $= K\,\Delta p / L$)")
        ax.set_title(f"leakage, job {job}")
        ax.legend(fontsize=7)
        fig.tight_layout(rect=(0, 0.06 if note else 0, 1, 1))
        if note:
            fig.text(0.01, 0.01, note, fontsize=7)
    return fig
