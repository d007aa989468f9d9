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

import json
import logging
import math
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from gapsweep.analysis import figures, leak
from gapsweep.theory import persson

__all__ = ["CONTACT_LAWS", "Labels", "fig_contact", "fig_distributions", "fig_map", "is_contact", "job_info",
           "job_infos", "map_fields", "plan", "summary", "tables", "units"]

log = logging.getLogger("gapsweep.analysis.contact")

CONTACT_LAWS = ("hard_wall", "adhesive", "hard_wall_adhesive")
PERSSON = {"color": "tab:purple", "ls": "-", "marker": "s", "ms": 4, "mfc": "none", "label": "Persson's theory"}
MAX_CURVES = 5
SYMBOLS = (
    "Symbols of the contact figures: sigma0 applied mean pressure, E* contact modulus, g0 mean gap, A/A0 contact "
    "area fraction, P(g) density of the gaps of the free points, P(p) density of the local pressures of the loaded "
    "points (docs/gfmd.md). Axes are in the store's units (attribute `units`) or, without them, pressures over E* "
    "and lengths in units of L (of the map, for a file surface). Open circles: GFMD mean over seeds with its "
    "standard error; squares: Persson's theory with the surface's own spectrum; steps: GFMD densities on the "
    "store's bins; dashed in the same colour: Persson's distributions (hard wall).")


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
            # adhesion at a tensile load: the most tensile load the continuation from zero load stayed attached
            # at, over every row (a detached row has it too: the pull-off bracket), mean over seeds
            rec["last_attached_load"] = _mean(p, "last_attached_load")[0]
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
# what a job's store says about itself: units, law, surface, Persson's parameters

MAP_MAX_N = 512  # the contact map is recomputed with one solve only up to this grid (a few seconds on one core)


def units(prov: Mapping[str, Any] | None) -> dict[str, str | None]:
    """The store attribute ``units``: JSON ``{"length": "um" | null, "pressure": "MPa" | null}`` (a string or
    the parsed dict of :func:`analysis.report.provenance`). Absent or null: model units (lengths in units of L,
    pressures in units of E*)."""
    raw = (prov or {}).get("units")
    if isinstance(raw, bytes):
        raw = raw.decode("utf-8", "replace")
    if isinstance(raw, str):
        try:
            raw = json.loads(raw)
        except ValueError:
            raw = None
    out: dict[str, str | None] = {"length": None, "pressure": None}
    if isinstance(raw, Mapping):
        for k in out:
            v = raw.get(k)
            out[k] = v.strip() if isinstance(v, str) and v.strip() else None
    return out


class Labels:
    """Axis labels of one job from its units (:func:`units`). With a pressure unit, pressures are drawn as
    stored, in that unit; without, over E* (``scale`` is what a pressure is divided by)."""

    def __init__(self, u: Mapping[str, str | None], *, file_surface: bool = False) -> None:
        self.length_unit, self.pressure_unit = u.get("length"), u.get("pressure")
        self.model_length = "units of the map" if file_surface else "units of L"

    def length(self, what: str) -> str:
        return f"{what} [{self.length_unit}]" if self.length_unit else f"{what} ({self.model_length})"

    def pressure(self, sym: str, what: str = "") -> str:
        lead = f"{what} " if what else ""
        return f"{lead}${sym}$ [{self.pressure_unit}]" if self.pressure_unit else f"{lead}${sym}/E^*$"

    def scale(self, e_star: float) -> float:
        return 1.0 if self.pressure_unit or not (np.isfinite(e_star) and e_star > 0) else float(e_star)

    def value(self, s0: float, e_star: float) -> str:
        """A pressure for a legend: ``sigma0 = 0.01 MPa`` or ``sigma0/E* = 0.01``."""
        v = s0 / self.scale(e_star)
        return (f"$\\sigma_0$ = {v:.3g} {self.pressure_unit}" if self.pressure_unit
                else f"$\\sigma_0/E^*$ = {v:.3g}")

    def gap_density(self) -> str:
        return f"density $P(g)$ [1/{self.length_unit}]" if self.length_unit else "density $P(g)$ (per length)"

    def pressure_density(self) -> str:
        return f"density $P(p)$ [1/{self.pressure_unit}]" if self.pressure_unit else "density $E^*P(p)$"

    def energy(self) -> str:
        if self.length_unit and self.pressure_unit:
            return f"elastic energy per area [{self.pressure_unit} {self.length_unit}]"
        return "elastic energy per area (units of E* L)"


def _spec(prov: Mapping[str, Any]) -> dict[str, Any]:
    import tomllib

    text = prov.get("spec_text", prov.get("spec"))
    try:
        return tomllib.loads(text) if isinstance(text, str) else {}
    except ValueError:
        return {}


def _table(raw: Mapping[str, Any], *keys: str) -> dict[str, Any]:
    t: Any = raw
    for k in keys:
        t = t.get(k, {}) if isinstance(t, Mapping) else {}
    return dict(t) if isinstance(t, Mapping) else {}


def _first(rows: pd.DataFrame, col: str, default: float = math.nan) -> float:
    v = pd.to_numeric(rows[col], errors="coerce").dropna() if col in rows else pd.Series(dtype=float)
    return float(v.iloc[0]) if len(v) else default


def _load_map(surf: Mapping[str, Any], prov: Mapping[str, Any], rows: pd.DataFrame) -> tuple[Any, str | None]:
    """The job's height map, loaded as the sweep does (``gapsweep.sweep.filesurface``) from the spec's surface
    table, the path relative to the job spec (the store's ``spec_dir``, else the store's folder). ``(topo,
    None)`` or ``(None, why not)``; never raises."""
    from gapsweep.sweep import filesurface

    path = str(surf.get("path", ""))
    bases = [Path(str(prov["spec_dir"]))] if prov.get("spec_dir") else []
    if prov.get("path"):
        bases.append(Path(str(prov["path"])).parent)
    for base in bases:
        full = base / path
        if not path or not full.is_file():
            continue
        try:
            table, _ = filesurface.file_surface(dict(surf), base)
            topo = filesurface.load_file_surface(table, full)
        except Exception as e:  # the report says why instead of failing
            why = str(e).replace(str(base.resolve()), "<spec dir>").replace(str(base), "<spec dir>")
            return None, f"the height map `{path}` (relative to the job spec) does not load ({why})"
        # the same map gives the store's h_rms again: from format 5 on the rms of the heights solved (np.std),
        # before it the map's spectral value (map_spectrum, right for its boundaries; now h_rms_spectrum)
        from gapsweep.theory.spectrum import map_spectrum

        topo.periodic = bool(table.get("periodic", topo.periodic))
        h_rms = _first(rows, "h_rms")
        if np.isfinite(_first(rows, "h_rms_spectrum")):
            mine = float(np.std(topo.heights))
        else:
            mine = map_spectrum(topo.heights, topo.length, periodic=topo.periodic).h_rms
        if np.isfinite(h_rms) and not math.isclose(mine, h_rms, rel_tol=1e-6):
            return None, (f"the height map found at `{path}` (relative to the job spec) is not the one the job ran "
                          f"(rms height {mine:.6g}, the store's {h_rms:.6g})")
        return topo, None
    return None, (f"the height map `{path}` (relative to the job spec) was not found next to the job spec or the "
                  "store")


def job_info(job: str, rows: pd.DataFrame, prov: Mapping[str, Any] | None = None) -> dict[str, Any]:
    """What the contact figures need of one job, from its store's attributes (``prov``: one entry of
    :func:`analysis.report.provenance`) and rows: ``units``, ``law``, the spec's Persson options, the file
    surface's map (``heights``, ``length``; None when it cannot be found) and ``notes`` for the report."""
    prov = prov or {}
    raw = _spec(prov)
    surf = _table(raw, "surface")
    theory = _table(raw, "methods", "theory")
    law = str(rows["interaction"].iloc[0]) if "interaction" in rows and len(rows) else \
        str(_table(raw, "interaction").get("kind", "exponential"))
    info: dict[str, Any] = {
        "job": job, "units": units(prov), "law": law, "file": surf.get("kind") == "file",
        "map_path": str(surf["path"]) if surf.get("kind") == "file" and "path" in surf else None,
        "interaction": _table(raw, "interaction"), "surface": surf, "gfmd": _table(raw, "methods", "gfmd"),
        "variant": str(theory.get("persson_variant", "persson2001")),
        "gamma": float(theory.get("persson_gamma", 0.42)),
        "tol": float(_table(raw, "methods", "gfmd").get("tol", 1e-8)),
        "store": prov.get("path"), "heights": None, "length": math.nan, "notes": [], "has_spec": bool(raw)}
    # the body beyond the half-space ([material] thickness, poisson, bottom, hardness: docs/jobs.md): the map is
    # re-solved with it, and Persson's half-space distributions are not drawn against it
    mat = _table(raw, "material")
    info["body"] = {k: mat[k] for k in ("thickness", "poisson", "bottom", "hardness") if k in mat}
    if info["body"]:
        info["notes"].append(f"Job {job}: an elastic layer or a pressure cap ([material] "
                             f"{', '.join(sorted(info['body']))}); Persson's half-space distributions are not drawn.")
    if info["file"]:
        topo, why = _load_map(surf, prov, rows) if raw else (None, "the store holds no job spec")
        if topo is None:
            info["notes"].append(f"Job {job}: {why}; Persson's distributions and the map are left out.")
        else:
            info["heights"], info["length"] = np.asarray(topo.heights, float), tuple(map(float, topo.length))
            info["periodic"] = bool(topo.periodic)
    return info


def _persson_kw(info: Mapping[str, Any], row: Mapping[str, Any]) -> dict[str, Any] | None:
    """Spectrum keywords of ``gapsweep.theory.persson`` for one row: the map's own spectrum (file surface) or the
    self-affine parameters (synthetic); None when the law is not the hard wall or the surface is unknown."""
    if info.get("law") != "hard_wall" or info.get("body"):
        return None
    if info.get("file"):
        return None if info.get("heights") is None else {"heights": info["heights"], "length": info["length"],
                                                         "periodic": info.get("periodic", True)}
    kw = {k: float(row.get(k, math.nan)) for k in ("hurst", "lambda_l", "lambda_s", "length")}
    if not all(np.isfinite(list(kw.values()))):
        return None
    surf = info.get("surface", {})
    for k in ("rms_slope", "rms_height", "c0"):
        if k in surf:
            kw[k] = float(surf[k])
    return kw


# ---------------------------------------------------------------------------------------------------------
# figures


def _xscale(ax: Any, s: np.ndarray) -> None:
    if len(s) and np.all(s > 0):
        ax.set_xscale("log")


def _tidy_log_ticks(fig: Any) -> None:
    """Tick labels of every log axis that cannot overprint (issue 36: matplotlib labels the minor ticks of an
    axis spanning less than a decade, and "3x10^-2" ran into "4x10^-2" on the narrow panels): minor ticks stay,
    unlabelled; the labelled ticks are the decades, else 1-2-5, 1-2-3-5 or 1..9 times the decades (the first
    that puts at least two inside the axis), thinned to at most 3 labels across (x) and 6 up (y); labels are
    plain numbers from 1e-3 to 1e4 (short), powers of ten beyond."""
    from matplotlib import ticker

    for ax in fig.axes:
        for axis, scale, most in ((ax.xaxis, ax.get_xscale(), 3), (ax.yaxis, ax.get_yscale(), 6)):
            if scale != "log":
                continue
            lo, hi = sorted(axis.get_view_interval())
            if not (lo > 0 and np.isfinite(hi) and hi > lo):
                continue
            decades = 10.0 ** np.arange(math.floor(math.log10(lo)) - 1, math.ceil(math.log10(hi)) + 1)
            ticks = np.array([])
            for subs in ((1.0,), (1.0, 2.0, 5.0), (1.0, 2.0, 3.0, 5.0), tuple(range(1, 10))):
                c = np.unique(np.round(np.outer(decades, subs).ravel(), 12))
                ticks = c[(c >= lo * (1 - 1e-9)) & (c <= hi * (1 + 1e-9))]
                if len(ticks) >= 2:
                    break
            if len(ticks) < 2:  # a range narrower than 1..9 x 10^k resolves: plain linear ticks
                ticks = np.asarray([t for t in ticker.MaxNLocator(3).tick_values(lo, hi) if lo <= t <= hi and t > 0])
            step = 1
            while len(ticks[::step]) > most:
                step += 1
            axis.set_major_locator(ticker.FixedLocator(ticks[::step]))
            axis.set_major_formatter(ticker.FuncFormatter(_log_label))
            axis.set_minor_locator(ticker.LogLocator(base=10.0, subs=np.arange(2, 10) * 1.0, numticks=100))
            axis.set_minor_formatter(ticker.NullFormatter())


def _log_label(v: float, _pos: Any = None) -> str:
    """A log-axis tick label: a plain number from 1e-3 to 1e4 ("0.02", "500"), else "10^k" or "m x 10^k"."""
    if not (v > 0 and np.isfinite(v)):
        return ""
    if 1e-3 <= v < 1e4:
        return f"{v:.3g}"
    k = math.floor(math.log10(v) + 1e-9)
    m = v / 10.0 ** k
    if abs(m - 1) < 1e-6:
        return f"$10^{{{k}}}$"
    return f"${m:.2g}\\times10^{{{k}}}$"


def _finish(fig: Any, note: str | None) -> None:
    """Footer line; the legends are inside the axes (placed by each figure); log-axis ticks that do not
    overprint (:func:`_tidy_log_ticks`)."""
    _tidy_log_ticks(fig)
    fh = fig.get_figheight()
    if note:
        fig.text(0.5, 0.01, note, ha="center", va="bottom", fontsize=7.5, color="0.3")
    fig.tight_layout(rect=(0, (0.26 / fh) if note else 0.0, 1, 1))


def _legend(ax: Any, **kw: Any) -> None:
    """A legend inside the axes (never outside the figure, whatever the length of the unit labels)."""
    if ax.get_legend_handles_labels()[0]:
        ax.legend(loc=kw.pop("loc", "best"), fontsize=7.5, framealpha=0.85, **kw)


def _info(info: Mapping[str, Any] | None, job: str, rows: pd.DataFrame) -> Mapping[str, Any]:
    return info if info is not None else job_info(job, rows)


def fig_contact(points: pd.DataFrame, persson: pd.DataFrame, *, job: str, note: str | None = None,
                info: Mapping[str, Any] | None = None):
    """Contact area, mean gap and elastic energy against the applied pressure (one job, finest n): GFMD (mean
    over seeds, standard errors where several) and Persson's theory where the job ran it. Axes in the store's
    units (``info["units"]``) or over E* and L."""
    import matplotlib

    with matplotlib.rc_context(figures.STYLE):
        p = points[points["job"] == job]
        p = p[p["n"] == p["n"].max()].sort_values("sigma0")
        # detached loads (adhesion beyond pull-off: no equilibrium in contact, so no point to draw) are marked
        # by a vertical line, and the pull-off bracket by the last attached load (docs/analysis.md "Contact")
        detached = p[((p["flags"].to_numpy(int) & 2) > 0) & (p["count"] == 0)]
        attached = pd.to_numeric(detached.get("last_attached_load", pd.Series(dtype=float)), errors="coerce")
        attached = attached[np.isfinite(attached.to_numpy(float))]
        p = p[p["count"] > 0]
        info = _info(info, job, p)
        lab = Labels(info["units"], file_surface=bool(info.get("file")))
        th = persson[persson["job"] == job].sort_values("sigma0") if len(persson) else persson
        fig, axes = figures._panels(3, width=3.7, height=3.3)
        ps = lab.scale(_first(p, "e_star", 1.0))
        x = p["sigma0"].to_numpy(float) / ps
        for ax, col, ylabel, tcol, title in (
                (axes[0], "contact_area", "contact area $A/A_0$", "persson_area", "(a) contact area"),
                (axes[1], "mean_gap", lab.length("mean gap $g_0$"), "persson_separation", "(b) mean gap"),
                (axes[2], "elastic_energy", lab.energy(), None, "(c) elastic energy")):
            y = p[col].to_numpy(float)
            ax.errorbar(x, y, yerr=np.nan_to_num(p[f"{col}_sem"].to_numpy(float)), **figures.GFMD)
            jump = (p["flags"].to_numpy(int) & 1) > 0
            if jump.any():  # load-path jumps (adhesion) marked, not hidden
                ax.plot(x[jump], y[jump], ls="none", marker="x", ms=8, color="tab:red",
                        label="jump along the load path")
            if tcol and len(th):
                ax.plot(th["sigma0"].to_numpy(float) / ps, th[tcol].to_numpy(float), **PERSSON)
            for i, s_det in enumerate(detached["sigma0"].to_numpy(float)):
                ax.axvline(s_det / ps, color="tab:red", ls=":", lw=1.2,
                           label="detached (beyond pull-off)" if i == 0 else None)
            if len(attached):
                ax.axvline(float(attached.min()) / ps, color="tab:green", ls="--", lw=1.0,
                           label="last attached load (pull-off bracket)")
            _xscale(ax, np.concatenate([x, detached["sigma0"].to_numpy(float) / ps]))
            if len(y) and np.all(y[np.isfinite(y)] > 0) and col != "mean_gap":
                ax.set_yscale("log")
            ax.set_xlabel(lab.pressure(r"\sigma_0", "pressure"))
            ax.set_ylabel(ylabel)
            ax.set_title(title)
            _legend(ax)
        _finish(fig, note)
    return fig


def _pick(keys: list[float], k: int = MAX_CURVES) -> list[float]:
    if len(keys) <= k:
        return keys
    return [keys[i] for i in np.unique(np.linspace(0, len(keys) - 1, k).round().astype(int))]


def _rows(df: pd.DataFrame, job: str) -> pd.DataFrame:
    """Done GFMD rows of one job, finest n, first seed."""
    g = df[(df["job"] == job) & (df["method"].astype(str) == "gfmd") & (df["status"].astype(str) == "done")]
    return g[(g["n"] == g["n"].max()) & (g["seed"] == g["seed"].min())] if len(g) else g


def fig_distributions(df: pd.DataFrame, hists: Mapping[str, tuple], phists: Mapping[str, tuple], *, job: str,
                      note: str | None = None, info: Mapping[str, Any] | None = None):
    """Gap density of the free points and pressure density of the loaded points of one job's GFMD rows (finest
    n, first seed, up to five pressures), with Persson's distributions (hard wall: ``gapsweep.theory.persson``
    ``gap_distribution`` and ``pressure_distribution``, the surface's own spectrum) dashed in the same colour.

    Both densities are drawn as steps on the store's own bins, on linear axes of gap and pressure: the store
    bins linearly (equal bins from the smallest to the largest value), so a log pressure axis would stretch the
    first bin over decades, and re-binning onto log bins cannot resolve below one stored bin. The pressure
    density spans decades, so its density axis is logarithmic. The atoms (g = 0: the hard wall's contact; p = 0:
    the free surface) are not densities; they are in the report's contact table."""
    import matplotlib
    from matplotlib.lines import Line2D

    with matplotlib.rc_context(figures.STYLE):
        g = _rows(df, job)
        info = _info(info, job, g)
        lab = Labels(info["units"], file_surface=bool(info.get("file")))
        loads = _pick(sorted(set(g["sigma0"].astype(float))))
        fig, axes = figures._panels(2, width=4.6, height=3.6)
        cmap = matplotlib.colormaps["viridis"]
        drawn_p, pmax, gmax, failed = False, [], [], []
        for i, s0 in enumerate(loads):
            row = g[np.isclose(g["sigma0"].to_numpy(float), s0, rtol=1e-9, atol=0.0)].iloc[0]
            col = cmap(0.9 * i / max(len(loads) - 1, 1))
            tid = row["task_id"]
            e_star = float(row.get("e_star", 1.0)) if np.isfinite(row.get("e_star", np.nan)) else 1.0
            ps = lab.scale(e_star)
            kw = _persson_kw(info, row) if s0 > 0 else None
            if tid in hists:
                e, d, _ = hists[tid]
                axes[0].stairs(d, e, color=col, label=lab.value(s0, e_star))
                if np.isfinite(d).any():
                    gmax.append(float(np.nanmax(d)))
                if kw is not None:
                    u = np.linspace(0.0, float(e[-1]), 400)
                    try:
                        dens, _ = persson.gap_distribution(u, s0, gamma=info["gamma"], e_star=e_star, **kw)
                        axes[0].plot(u, dens, color=col, ls="--", lw=1.0)
                        drawn_p = True
                    except Exception as ex:  # a theory that cannot be evaluated is named, not fatal
                        failed.append(f"gap distribution at sigma0 = {s0:g}: {ex}")
            if tid in phists:
                e, d, _atom = phists[tid]
                axes[1].stairs(d * ps, e / ps, color=col, label=lab.value(s0, e_star))
                pos = d[d > 0]
                if len(pos):
                    pmax.append((float(pos.min() * ps), float(pos.max() * ps)))
                if kw is not None:
                    p = np.linspace(max(float(e[0]), 0.0), float(e[-1]), 400)
                    try:
                        dens = persson.pressure_distribution(p, s0, variant=info["variant"], e_star=e_star, **kw)
                        axes[1].plot(p / ps, np.where(dens * ps > 0, dens * ps, np.nan), color=col, ls="--", lw=1.0)
                        drawn_p = True
                    except Exception as ex:
                        failed.append(f"pressure distribution at sigma0 = {s0:g}: {ex}")
        if failed:
            log.warning("Persson's distributions of job %s: %s", job, "; ".join(failed))
        axes[0].set_xlabel(lab.length("gap $g$"))
        axes[0].set_ylabel(lab.gap_density() + " of the free points")
        axes[0].set_title("(a) gap distribution")
        if gmax:  # Persson's gap density diverges (integrably) at g = 0: the GFMD data set the scale
            axes[0].set_ylim(0.0, 1.15 * max(gmax))
        axes[1].set_yscale("log")
        if pmax:  # down to one sample per bin (the store's resolution), at most eight decades
            top = max(x[1] for x in pmax)
            axes[1].set_ylim(max(0.5 * min(x[0] for x in pmax), top * 1e-8), top * 3)
        axes[1].set_xlabel(lab.pressure("p", "local pressure"))
        axes[1].set_ylabel(lab.pressure_density() + " of the loaded points")
        axes[1].set_title("(b) pressure distribution")
        _legend(axes[0])
        style = [Line2D([], [], color="k", lw=1.4, label="GFMD (steps: the store's bins)")]
        if drawn_p:
            style.append(Line2D([], [], color="k", ls="--", lw=1.0, label="Persson's theory"))
        axes[1].legend(handles=style, loc="upper right", fontsize=7.5, framealpha=0.85)
        _finish(fig, note)
    return fig


def _map_row(df: pd.DataFrame, job: str) -> Any:
    """The load of the contact map: a compressive GFMD load whose contact area is nearest 15 % (a map with
    separate spots and clusters), else the first done row."""
    g = _rows(df, job)
    if g.empty:
        return None
    c = g[g["sigma0"].astype(float) > 0] if (g["sigma0"].astype(float) > 0).any() else g
    a = pd.to_numeric(c["contact_area"], errors="coerce").to_numpy(float) if "contact_area" in c else \
        np.full(len(c), np.nan)
    k = int(np.nanargmin(np.abs(a - 0.15))) if np.isfinite(a).any() else 0
    return c.iloc[k]


def map_fields(df: pd.DataFrame, job: str, info: Mapping[str, Any]) -> dict[str, Any]:
    """Height map and contact mask of one job at the load of :func:`_map_row`: the kept fields of that task when
    the store has them, else one ``gapsweep.gfmd.solve`` on the map (N <= ``MAP_MAX_N``), else the height
    map alone. ``{"heights", "length", "mask", "row", "source", "note"}`` (``heights`` None: nothing to draw)."""
    row = _map_row(df, job)
    out: dict[str, Any] = {"heights": info.get("heights"), "length": info.get("length"), "mask": None, "row": row,
                           "source": "", "note": None}
    if row is None:
        return out
    law, rho = info.get("law"), float(row.get("rho", math.nan))
    gap = pressure = None
    if info.get("store"):
        try:  # kept fields (docs/jobs.md keep_fields), when the store has them for this task
            from gapsweep import store as gstore

            kept = gstore.open_fields(info["store"], [str(row["task_id"]).split(":")[-1]])
            ds = next(iter(kept.values()), None)
            if ds is not None and "gap" in ds:
                gap = np.asarray(ds["gap"].values, float)
                pressure = np.asarray(ds["pressure"].values, float) if "pressure" in ds else None
                if "height" in ds:
                    out["heights"] = np.asarray(ds["height"].values, float)
                out["source"] = "the store's kept fields"
        except Exception:  # no kept fields: recompute below
            gap = None
    if out["heights"] is None and not info.get("file") and info.get("has_spec"):
        out["heights"], out["length"], why = _synthetic_heights(info, row)
        if why:
            out["note"] = f"Job {job}: no map figure ({why})."
    h = out["heights"]
    if gap is None and h is not None:
        if h.shape[0] > MAP_MAX_N:
            out["note"] = (f"Job {job}: the contact map is not drawn (N = {h.shape[0]} > {MAP_MAX_N}: one solve "
                           "would not be cheap; keep the fields of one task with `[methods.gfmd] keep_fields`).")
        else:
            from gapsweep import gfmd

            kw: dict[str, Any] = dict(info.get("body") or {})
            if law in ("adhesive", "hard_wall_adhesive"):
                kw.update({"work": float(info["interaction"].get("work", math.nan)), "rho": rho})
            try:
                length = out["length"]
                length = tuple(map(float, length)) if isinstance(length, (tuple, list)) else float(length)
                r = gfmd.solve(h, sigma0=float(row["sigma0"]), interaction=law, e_star=float(row.get("e_star", 1.0)),
                               length=length, tol=float(info.get("tol", 1e-8)), backend="numpy",
                               periodic=bool(info.get("periodic", True)), **kw)
                gap, pressure = np.asarray(r.gap, float), np.asarray(r.pressure, float)
                out["source"] = "one solve with gapsweep.gfmd.solve (cold start)"
            except Exception as ex:
                out["note"] = f"Job {job}: the contact map could not be recomputed ({ex})."
    if gap is not None:
        out["mask"] = ((pressure > 0) if (law == "hard_wall" and pressure is not None)
                       else (gap <= 0) if law == "hard_wall_adhesive" else (gap < rho))
    return out


def _synthetic_heights(info: Mapping[str, Any], row: Any) -> tuple[Any, float, str | None]:
    """The self-affine surface of one row regenerated as the sweep does (``gapsweep.surface.self_affine`` with the
    spec's ``[surface]`` keys and the row's H, seed and n), checked against the store's rms height. ``(heights,
    length, None)`` or ``(None, nan, why not)``."""
    n = int(row.get("n", 0))
    if n > MAP_MAX_N:
        return None, math.nan, f"a self-affine surface of N = {n} > {MAP_MAX_N} is not regenerated"
    surf = dict(info.get("surface", {}))
    kw: dict[str, Any] = {"lambda_l": float(surf.get("lambda_l", 0.25)),
                          "lambda_s": float(surf.get("lambda_s", 2.5e-3)), "length": float(surf.get("length", 1.0)),
                          "amplitudes": str(surf.get("amplitudes", "fixed"))}
    if "lambda_r" in surf:
        kw["lambda_r"] = float(surf["lambda_r"])
    norms = [k for k in ("rms_slope", "rms_height", "c0") if k in surf]
    kw[norms[0] if norms else "rms_slope"] = float(surf[norms[0]]) if norms else 1.0
    try:
        from gapsweep.surfaces import synthetic

        h = np.asarray(synthetic.self_affine(n, float(row["hurst"]), seed=int(row["seed"]), **kw), float)
    except Exception as ex:
        return None, math.nan, f"the self-affine surface could not be regenerated: {ex}"
    h_rms = float(row.get("h_rms", math.nan))
    if np.isfinite(h_rms) and not math.isclose(float(np.std(h)), h_rms, rel_tol=1e-6):
        return None, math.nan, (f"the regenerated surface is not the job's (rms height {float(np.std(h)):.6g}, the "
                                f"store's {h_rms:.6g})")
    return h, kw["length"], None


def fig_map(df: pd.DataFrame, *, job: str, info: Mapping[str, Any], note: str | None = None,
            fields: Mapping[str, Any] | None = None):
    """The height map (a) and the contact map at one load (b, black: in contact by the law's criterion)."""
    import matplotlib

    f = fields if fields is not None else map_fields(df, job, info)
    with matplotlib.rc_context({**figures.STYLE, "axes.grid": False}):
        lab = Labels(info["units"], file_surface=bool(info.get("file")))
        two = f["mask"] is not None
        fig, axes = figures._panels(2 if two else 1, width=3.9, height=3.5)
        h, length = f["heights"], f["length"]
        lx, ly = (float(length[0]), float(length[1])) if isinstance(length, (tuple, list)) else (float(length),) * 2
        ext = (0.0, lx, 0.0, ly)  # a rectangular map keeps its aspect
        im = axes[0].imshow(h.T, origin="lower", extent=ext, cmap="viridis", interpolation="nearest")
        fig.colorbar(im, ax=axes[0], fraction=0.046, pad=0.03).set_label(lab.length("height $h$"))
        axes[0].set_title("(a) height map" + (f": {info['map_path']}" if info.get("map_path") else ""), fontsize=9)
        for ax in axes:
            ax.set_xlabel(lab.length("$x$"))
            ax.set_ylabel(lab.length("$y$"))
        if two:
            row = f["row"]
            m = np.asarray(f["mask"], bool)
            axes[1].imshow(m.T, origin="lower", extent=ext, cmap="Greys", vmin=0, vmax=1, interpolation="nearest")
            e_star = float(row.get("e_star", 1.0))
            axes[1].set_title(f"(b) contact at {lab.value(float(row['sigma0']), e_star)}: $A/A_0$ = {m.mean():.3f}",
                              fontsize=9)
        _finish(fig, " | ".join(x for x in (note, f"contact map: {f['source']}" if two else "") if x))
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


def job_infos(df: pd.DataFrame, prov: Sequence[Mapping[str, Any]] = ()) -> dict[str, dict[str, Any]]:
    """:func:`job_info` of every contact job of ``df`` (``prov`` matched by the store's ``job_name``)."""
    by_job = {str(p.get("job_name", "")): p for p in prov}
    cdf = df[is_contact(df)] if len(df) else df
    return {job: job_info(job, cdf[cdf["job"] == job], by_job.get(job, {}))
            for job in sorted(set(cdf["job"].astype(str)))} if len(cdf) else {}


def plan(df: pd.DataFrame, hists: Mapping[str, tuple], phists: Mapping[str, tuple], points: pd.DataFrame,
         persson: pd.DataFrame, quick: set[str] | frozenset[str] = frozenset(),
         infos: Mapping[str, Mapping[str, Any]] | None = None) -> list[tuple[str, str, Any]]:
    """``[(name, caption, make)]`` of the contact figures, per contact job with finished GFMD rows: the
    quantities against pressure, the distributions, and the height and contact maps (file surfaces). ``infos``:
    :func:`job_infos` (built here without the stores' attributes when None); map notes are added to each
    job's ``notes``."""
    out: list[tuple[str, str, Any]] = []
    infos = dict(infos) if infos is not None else job_infos(df)

    def note(a: pd.DataFrame, job: str) -> str:
        return _note(a, job, job in quick)

    for job in sorted(set(points["job"])) if len(points) else []:
        p = points[(points["job"] == job) & (points["count"] > 0)]
        if p.empty:
            continue
        a = df[df["job"] == job]
        info = infos.get(job) or job_info(job, a)
        law = str(p["interaction"].iloc[0])
        tag = "".join(c if c.isalnum() else "_" for c in job) or "store"
        has_p = len(persson) and (persson["job"] == job).any()
        out.append((f"contact_{tag}", f"Contact area, mean gap and elastic energy against pressure, {law} (job "
                    f"{job}{'; GFMD and Persson side by side' if has_p else ''})",
                    lambda job=job, a=a, info=info: fig_contact(points, persson, job=job, note=note(a, job),
                                                                info=info)))
        tids = set(a[a["method"].astype(str) == "gfmd"]["task_id"])
        if tids & set(hists) or tids & set(phists):
            overlay = law == "hard_wall" and (not info.get("file") or info.get("heights") is not None) \
                and not info.get("body")
            out.append((f"contact_distributions_{tag}", f"Gap and pressure distributions, {law} (job {job}; "
                        + ("Persson's theory dashed" if overlay else "no Persson overlay: "
                           + ("hard-wall theory" if law != "hard_wall" else "half-space theory (layer or cap)"
                              if info.get("body") else "map not found")) + ")",
                        lambda job=job, a=a, info=info: fig_distributions(df, hists, phists, job=job,
                                                                          note=note(a, job), info=info)))
        if leak.has_flow(df, job):  # the flow extension's columns (docs/model.md M8)
            out.append((f"leak_{tag}", f"Leak conductance against pressure, {law} (job {job}; the flow solve on "
                        "the GFMD gaps, Bruggeman and critical junction from their gap histograms)",
                        lambda job=job, a=a, info=info: leak.fig_leak(df, job=job, info=info, note=note(a, job))))
        if info.get("heights") is not None or info.get("store") or (info.get("has_spec") and not info.get("file")):
            f = map_fields(df, job, info)
            if f["note"]:
                info.setdefault("notes", []).append(f["note"])
            if f["heights"] is not None:
                r = f["row"]
                cap = f"Height map{' and contact map' if f['mask'] is not None else ''}, {law} (job {job}"
                if f["mask"] is not None:
                    cap += f"; contact at sigma0 = {float(r['sigma0']):g}, {f['source']}"
                out.append((f"contact_map_{tag}", cap + ")",
                            lambda job=job, a=a, info=info, f=f: fig_map(df, job=job, info=info, note=note(a, job),
                                                                         fields=f)))
    return out
