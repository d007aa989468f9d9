"""The contact-mechanics challenge's outputs (docs/challenge.md, "Outputs") for jobs with the challenge's law
(``[interaction] kind = "hard_wall_adhesive"``), from the contact table of :func:`gapsweep.analysis.contact.tables`
and the store's kept fields:

- :func:`load_table`: per job and range ``rho``, along the job's load path: contact area, mean gap and contact
  stiffness ``K = -d sigma0 / d g0`` (central differences of the mean gap against the load on the path's own
  points, one-sided at its ends), with the path named (``order`` of ``[methods.gfmd]``, warm starts);
- :func:`patch_areas`: contact-patch areas of a kept gap field (pixels with ``g = 0``, 4-neighbour clusters
  joined across the periodic edges), and :func:`reference_table` their statistics with the pressure and gap
  distributions' moments at the reference load (the load whose fields the job keeps);
- :func:`tabor_table`: contact area and mean gap against ``rho`` at the reference load, with the Tabor parameter
  ``mu_T = (R work^2 / (E*^2 rho^3))^(1/3)``, ``R = 1/kappa_rms`` (gapsweep.surfaces.challenge.tabor) and the
  resolution measure ``mu_rho``.

:func:`plan` lists the figures, :func:`section` the report's markdown; both leave out what the store lacks (a
note says what)."""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import numpy as np
import pandas as pd

from gapsweep.analysis import figures

__all__ = ["LAW", "fig_loads", "fig_reference", "fig_tabor", "is_challenge", "load_table", "patch_areas", "plan",
           "reference_table", "section", "tabor_table"]

LAW = "hard_wall_adhesive"


def is_challenge(points: pd.DataFrame) -> pd.Series:
    """Rows of the contact table whose job ran the challenge's law."""
    if "interaction" not in points:
        return pd.Series(False, index=points.index)
    return points["interaction"].astype(str) == LAW


def _gfmd(info: Mapping[str, Any]) -> Mapping[str, Any]:
    return info.get("gfmd", {}) if isinstance(info.get("gfmd", {}), Mapping) else {}


def path_text(info: Mapping[str, Any]) -> str:
    """The loading path of a job in words (its ``[methods.gfmd]`` order and warm starts)."""
    g = _gfmd(info)
    order = str(g.get("order", "decreasing"))
    warm = bool(g.get("warm_start", True))
    if not warm:
        return "each load solved on its own from the flat body touching the highest summit (no load path)"
    if order == "increasing":
        return ("loading: loads in increasing order, each started from the previous (lighter) one, the first from "
                "the flat body touching the highest summit")
    return ("unloading: loads in decreasing order, each started from the previous (heavier) one, the first from the "
            "flat body touching the highest summit; tensile loads by continuation from zero load")


def load_table(points: pd.DataFrame, infos: Mapping[str, Mapping[str, Any]] | None = None) -> pd.DataFrame:
    """``job, rho, sigma0, contact_area, mean_gap, stiffness, path`` for the challenge jobs (finest n; means over
    seeds as in the contact table). ``stiffness = -d sigma0/d g0`` by ``numpy.gradient`` on the path's points
    (NaN where a job has fewer than two loads at a rho)."""
    infos = infos or {}
    p = points[is_challenge(points) & (points["count"] > 0)] if len(points) else points
    rows = []
    for job, g in p.groupby("job", sort=True):
        g = g[g["n"] == g["n"].max()]
        for rho, r in g.groupby("rho", sort=True):
            r = r.sort_values("sigma0")
            s, g0 = r["sigma0"].to_numpy(float), r["mean_gap"].to_numpy(float)
            k = -np.gradient(s, g0) if len(s) >= 2 and np.all(np.diff(g0) != 0) else np.full(len(s), np.nan)
            for i in range(len(r)):
                rows.append({"job": job, "rho": float(rho), "n": int(r["n"].iloc[i]), "sigma0": s[i],
                             "hurst": float(r["hurst"].iloc[i]) if "hurst" in r else math.nan,
                             "e_star": float(r["e_star"].iloc[i]) if "e_star" in r else 1.0,
                             "contact_area": float(r["contact_area"].iloc[i]), "mean_gap": g0[i],
                             "stiffness": float(k[i]), "flags": int(r["flags"].iloc[i]),
                             "path": path_text(infos.get(str(job), {}))})
    return pd.DataFrame(rows, columns=["job", "rho", "n", "sigma0", "hurst", "e_star", "contact_area", "mean_gap",
                                       "stiffness", "flags", "path"])


def patch_areas(contact: np.ndarray, pixel_area: float = 1.0, periodic: bool = True) -> np.ndarray:
    """Areas of the contact patches of the boolean map ``contact``: 4-neighbour clusters (scipy.ndimage.label),
    joined across opposite edges when ``periodic``; sorted, largest first, in units of ``pixel_area``."""
    from scipy import ndimage

    mask = np.asarray(contact, bool)
    lab, n = ndimage.label(mask)
    if n == 0:
        return np.zeros(0)
    parent = np.arange(n + 1)

    def find(a: int) -> int:
        while parent[a] != a:
            parent[a] = parent[parent[a]]
            a = parent[a]
        return a

    if periodic:
        for a, b in ((lab[0, :], lab[-1, :]), (lab[:, 0], lab[:, -1])):
            for x, y in zip(a[(a > 0) & (b > 0)], b[(a > 0) & (b > 0)]):
                rx, ry = find(int(x)), find(int(y))
                if rx != ry:
                    parent[max(rx, ry)] = min(rx, ry)
    roots = np.array([find(i) for i in range(n + 1)])
    sizes = np.bincount(roots[lab[mask]], minlength=n + 1)
    sizes = sizes[sizes > 0]
    return np.sort(sizes)[::-1].astype(float) * pixel_area


def _kept(info: Mapping[str, Any], task_id: str) -> Mapping[str, np.ndarray] | None:
    if not info.get("store"):
        return None
    try:
        from gapsweep import store as gstore

        kept = gstore.open_fields(info["store"], [task_id.split(":")[-1]])
        ds = next(iter(kept.values()), None)
        if ds is None or "gap" not in ds:
            return None
        return {k: np.asarray(ds[k].values, float) for k in ("gap", "pressure", "height") if k in ds}
    except Exception:  # no kept fields (or no xarray): the report says so
        return None


def reference_fields(df: pd.DataFrame, job: str, info: Mapping[str, Any]) -> list[dict[str, Any]]:
    """The kept fields of a challenge job's done GFMD rows (finest n, first seed): ``[{rho, sigma0, gap,
    pressure, row}]`` (empty without kept fields)."""
    g = df[(df["job"] == job) & (df["method"].astype(str) == "gfmd") & (df["status"].astype(str) == "done")]
    if g.empty:
        return []
    g = g[(g["n"] == g["n"].max()) & (g["seed"] == g["seed"].min())]
    out = []
    for _, row in g.sort_values(["rho", "sigma0"]).iterrows():
        f = _kept(info, str(row["task_id"]))
        if f is not None:
            out.append({"rho": float(row["rho"]), "sigma0": float(row["sigma0"]), **f, "row": row})
    return out


def _box(info: Mapping[str, Any]) -> tuple[float, float]:
    surf = info.get("surface", {}) if isinstance(info.get("surface", {}), Mapping) else {}
    length = surf.get("length", 1.0)
    lx, ly = (length, length) if not isinstance(length, (list, tuple)) else length
    return float(lx), float(ly)


def reference_table(df: pd.DataFrame, infos: Mapping[str, Mapping[str, Any]]) -> tuple[pd.DataFrame, dict]:
    """Per challenge job and kept task: the contact-patch statistics (count, mean, largest area, the area-weighted
    mean) and the moments of the pressure in contact and of the gap off contact; and ``{(job, rho, sigma0):
    (patch areas, pressures in contact, gaps off contact)}`` for the figures."""
    rows, data = [], {}
    for job, info in infos.items():
        if info.get("law") != LAW:
            continue
        lx, ly = _box(info)
        for f in reference_fields(df, job, info):
            gap, pres = f["gap"], f.get("pressure")
            nx, ny = gap.shape
            areas = patch_areas(gap <= 0, (lx / nx) * (ly / ny))
            p_in = pres[gap <= 0] if pres is not None else np.zeros(0)
            g_off = gap[gap > 0]
            data[(job, f["rho"], f["sigma0"])] = (areas, p_in, g_off)
            tot = float(areas.sum()) if areas.size else 0.0
            rows.append({"job": job, "rho": f["rho"], "sigma0": f["sigma0"], "contact_area": float(np.mean(gap <= 0)),
                         "patches": int(areas.size), "mean_patch_area": float(areas.mean()) if areas.size else math.nan,
                         "largest_patch_area": float(areas.max()) if areas.size else math.nan,
                         "area_weighted_patch_area": float((areas**2).sum() / tot) if tot > 0 else math.nan,
                         "mean_contact_pressure": float(p_in.mean()) if p_in.size else math.nan,
                         "rms_contact_pressure": float(np.sqrt(np.mean(p_in**2))) if p_in.size else math.nan,
                         "mean_free_gap": float(g_off.mean()) if g_off.size else math.nan,
                         "path": path_text(info)})
    return pd.DataFrame(rows), data


def tabor_table(loads: pd.DataFrame, ref: pd.DataFrame, infos: Mapping[str, Mapping[str, Any]]) -> pd.DataFrame:
    """Contact area and mean gap against the range ``rho`` at each job's reference load (the kept-fields load,
    else the load of the most ranges), with the Tabor parameter and ``mu_rho`` (module docstring)."""
    from gapsweep.surfaces import challenge as ch

    rows = []
    for job, g in loads.groupby("job", sort=True):
        info = infos.get(str(job), {})
        s_ref = float(ref[ref["job"] == job]["sigma0"].iloc[0]) if len(ref) and (ref["job"] == job).any() else \
            float(g["sigma0"].value_counts().idxmax())
        at = g[np.isclose(g["sigma0"].to_numpy(float), s_ref, rtol=1e-9)].sort_values("rho")
        surf = info.get("surface", {}) if isinstance(info.get("surface", {}), Mapping) else {}
        inter = info.get("interaction", {}) if isinstance(info.get("interaction", {}), Mapping) else {}
        work = float(inter.get("work", math.nan))
        e_star = float(g["e_star"].iloc[0]) if np.isfinite(g["e_star"].iloc[0]) else 1.0
        radius = math.nan
        try:
            lam_l = float(surf.get("lambda_l", 0.25))
            radius = 1.0 / ch.rms_curvature(float(g["hurst"].iloc[0]), lambda_l=lam_l,
                                            lambda_s=float(surf.get("lambda_s", 2.5e-3)),
                                            lambda_r=float(surf["lambda_r"]) if "lambda_r" in surf else None,
                                            rms_slope=float(surf.get("rms_slope", 1.0)))
        except (TypeError, ValueError, ZeroDivisionError):
            pass
        lx, _ = _box(info)
        for _, r in at.iterrows():
            rho = float(r["rho"])
            rows.append({"job": job, "sigma0": s_ref, "rho": rho,
                         "tabor": ch.tabor(work, rho, e_star, radius) if math.isfinite(radius) else math.nan,
                         "mu_rho": ch.mu_rho(work, rho, e_star, lx / float(r["n"])) if math.isfinite(work) else
                         math.nan,
                         "contact_area": float(r["contact_area"]), "mean_gap": float(r["mean_gap"]),
                         "path": r["path"]})
    return pd.DataFrame(rows)


def _dress(ax: Any, xlabel: str, ylabel: str, title: str) -> None:
    """Axis labels, panel title and a small legend: the same dress on every panel of the challenge figures."""
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    ax.set_title(title)
    ax.legend(fontsize=7)


def _footnote(fig: Any, note: str | None) -> None:
    """The provenance line at the bottom left, when there is one."""
    if note:
        fig.text(0.01, 0.01, note, fontsize=7)


def fig_loads(loads: pd.DataFrame, *, job: str, note: str | None = None):
    """(a) contact area, (b) mean gap and (c) contact stiffness against the load, one curve per range rho."""
    import matplotlib

    with matplotlib.rc_context(figures.STYLE):
        t = loads[loads["job"] == job]
        fig, axes = figures._panels(3, width=3.7, height=3.3)
        for rho, r in t.groupby("rho", sort=True):
            r = r.sort_values("sigma0")
            x = r["sigma0"].to_numpy(float)
            for ax, col in zip(axes, ("contact_area", "mean_gap", "stiffness")):
                ax.plot(x, r[col].to_numpy(float), marker="o", ms=4, mfc="none", label=f"rho = {rho:g}")
        for ax, ylab, title in zip(axes, ("contact area $A/A_0$", "mean gap $g_0$", r"$K = -d\sigma_0/dg_0$"),
                                   ("(a) contact area", "(b) mean gap", "(c) contact stiffness")):
            x = t["sigma0"].to_numpy(float)
            if len(x) and np.all(x > 0):
                ax.set_xscale("log")
            _dress(ax, r"load $\sigma_0$", ylab, title)
        axes[0].set_yscale("log")
        _footnote(fig, note)
    return fig


def fig_reference(data: Mapping[tuple, tuple], *, job: str, note: str | None = None):
    """At the reference load: (a) the number density of contact-patch areas (log bins), (b) the density of the
    pressure in contact, (c) the density of the gap off contact; one curve per kept task."""
    import matplotlib

    with matplotlib.rc_context(figures.STYLE):
        fig, axes = figures._panels(3, width=3.7, height=3.3)
        for (j, rho, s0), (areas, p_in, g_off) in sorted(data.items()):
            if j != job:
                continue
            lab = f"rho = {rho:g}, sigma0 = {s0:g}"
            if areas.size:
                bins = np.geomspace(areas.min(), areas.max() * 1.0001, max(3, min(20, areas.size // 2 + 2)))
                cnt, edges = np.histogram(areas, bins=bins)
                mid = np.sqrt(edges[1:] * edges[:-1])
                axes[0].loglog(mid[cnt > 0], (cnt / np.diff(edges))[cnt > 0], marker="o", ms=4, mfc="none",
                               label=lab)
            for ax, v in ((axes[1], p_in), (axes[2], g_off)):
                if v.size:
                    d, e = np.histogram(v, bins=40, density=True)
                    ax.step(0.5 * (e[1:] + e[:-1]), d, where="mid", label=lab)
        for ax, xl, yl, title in ((axes[0], "patch area $A$", "number density $n(A)$", "(a) contact patches"),
                                  (axes[1], "pressure in contact $p$", "$P(p)$", "(b) pressure in contact"),
                                  (axes[2], "gap off contact $g$", "$P(g)$", "(c) gap off contact")):
            _dress(ax, xl, yl, title)
        _footnote(fig, note)
    return fig


def fig_tabor(tab: pd.DataFrame, *, job: str, note: str | None = None):
    """Contact area and mean gap against the range rho (top axis: the Tabor parameter) at the reference load."""
    import matplotlib

    with matplotlib.rc_context(figures.STYLE):
        t = tab[tab["job"] == job].sort_values("rho")
        fig, axes = figures._panels(2, width=3.7, height=3.3)
        for ax, col, yl, title in ((axes[0], "contact_area", "contact area $A/A_0$", "(a) contact area"),
                                   (axes[1], "mean_gap", "mean gap $g_0$", "(b) mean gap")):
            ax.plot(t["rho"].to_numpy(float), t[col].to_numpy(float), marker="o", ms=5, mfc="none",
                    label=f"sigma0 = {float(t['sigma0'].iloc[0]):g}" if len(t) else None)
            ax.set_xscale("log")
            _dress(ax, r"range $\rho$ (Tabor $\mu_T$ in the table)", yl, title)
        _footnote(fig, note)
    return fig


def plan(df: pd.DataFrame, points: pd.DataFrame, infos: Mapping[str, Mapping[str, Any]],
         quick: set[str] | frozenset[str] = frozenset()) -> tuple[list[tuple[str, str, Any]], dict[str, pd.DataFrame]]:
    """``([(name, caption, make)], tables)`` of the challenge jobs (empty when there are none). Tables:
    ``challenge_loads``, ``challenge_reference``, ``challenge_tabor``."""
    loads = load_table(points, infos)
    if loads.empty:
        return [], {}
    ref, data = reference_table(df, infos)
    tab = tabor_table(loads, ref, infos)
    out: list[tuple[str, str, Any]] = []
    for job in sorted(set(loads["job"])):
        slug = str(job).replace("-", "_")
        warn = "quick job: CI size, not the challenge's numbers" if job in quick else None
        path = str(loads[loads["job"] == job]["path"].iloc[0])
        out.append((f"challenge_loads_{slug}", f"Challenge outputs against load (job {job}; {path})",
                    lambda j=job, w=warn: fig_loads(loads, job=j, note=w)))
        if any(k[0] == job for k in data):
            out.append((f"challenge_reference_{slug}", f"Challenge distributions at the reference load (job {job}; "
                        f"{path})", lambda j=job, w=warn: fig_reference(data, job=j, note=w)))
        if len(tab) and (tab["job"] == job).sum() >= 2:
            out.append((f"challenge_tabor_{slug}", f"Contact area and mean gap against the range rho (job {job}; "
                        f"{path})", lambda j=job, w=warn: fig_tabor(tab, job=j, note=w)))
    return out, {"challenge_loads": loads, "challenge_reference": ref, "challenge_tabor": tab}


def section(tables: Mapping[str, pd.DataFrame], md_table: Any) -> list[str]:
    """Markdown of the challenge section from :func:`plan`'s tables (``md_table``: the report's table writer)."""
    loads = tables.get("challenge_loads", pd.DataFrame())
    if loads.empty:
        return []
    md = ["## The contact-mechanics challenge's outputs", "",
          "Jobs with the challenge's law (a hard wall with exponential adhesion, docs/challenge.md). Contact "
          "stiffness K = -d sigma0/d g0 by central differences along the load path; contact patches are 4-neighbour "
          "clusters of g = 0 pixels joined across the periodic edges; the Tabor parameter uses R = 1/kappa_rms of the "
          "spectrum (docs/challenge.md). Each table names its loading path. Full tables: `challenge_loads.csv`, "
          "`challenge_reference.csv`, `challenge_tabor.csv`.", ""]
    for job in sorted(set(loads["job"])):
        md += [f"### Job {job}", "", f"Loading path: {loads[loads['job'] == job]['path'].iloc[0]}.", ""]
        md += [md_table(loads[loads["job"] == job], ["rho", "n", "sigma0", "contact_area", "mean_gap", "stiffness",
                                                    "flags"])]
        ref = tables.get("challenge_reference", pd.DataFrame())
        if len(ref) and (ref["job"] == job).any():
            md += ["At the reference load (kept fields):", "",
                   md_table(ref[ref["job"] == job], ["rho", "sigma0", "contact_area", "patches", "mean_patch_area",
                                                     "largest_patch_area", "area_weighted_patch_area",
                                                     "mean_contact_pressure", "mean_free_gap"])]
        else:
            md += ["_No kept fields: no contact-patch sizes (keep them with `[methods.gfmd] keep_fields`)._", ""]
        tab = tables.get("challenge_tabor", pd.DataFrame())
        if len(tab) and (tab["job"] == job).any():
            md += ["Against the range rho at the reference load:", "",
                   md_table(tab[tab["job"] == job], ["sigma0", "rho", "tabor", "mu_rho", "contact_area", "mean_gap"])]
    return md
