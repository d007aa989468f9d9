"""Tests of gapsweep.analysis (docs/analysis.md) on synthetic store frames, and end to end on a quick job."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from gapsweep.analysis import aggregate, compare, dataset, figures, report

ROOT = Path(__file__).resolve().parents[1]
E_STAR, GAMMA0, LL, LS = 1.0, 1e-3, 0.25, 2.5e-3

_COLS = ("task_id", "method", "hurst", "rho", "sigma0", "seed", "n", "status", "message", "mean_gap",
         "mean_gap_paper", "mean_gap_continuum", "mean_gap_discrete", "h_rms", "g_rms", "lambda_l", "lambda_s",
         "gamma0", "e_star", "residual", "iterations", "wall_time", "c1", "c2")


def _row(i: int, method: str, **kw) -> dict:
    r = {c: math.nan for c in _COLS}
    r.update(task_id=f"t{i:04d}", method=method, seed=0, n=0, status="done", message="", lambda_l=LL, lambda_s=LS,
             gamma0=GAMMA0, e_star=E_STAR, g_rms=1.0, iterations=-1)
    r.update(kw)
    return r


def _frame(rows: list[dict]) -> pd.DataFrame:
    return pd.DataFrame(rows, columns=list(_COLS))


# ---------------------------------------------------------------------------------------------------------
# aggregation


def test_aggregate_hand_computed_and_failed_rows_not_averaged():
    h = 0.002
    rows = [_row(i, "gfmd", hurst=0.3, rho=2e-3, sigma0=1e-2, seed=i, n=1024, mean_gap=v, h_rms=h)
            for i, v in enumerate([1.0e-3, 2.0e-3, 4.0e-3])]
    rows += [
        _row(3, "gfmd", hurst=0.3, rho=2e-3, sigma0=1e-2, seed=3, n=1024, status="failed", mean_gap=1.0, h_rms=h,
             message="boom"),
        _row(4, "gfmd", hurst=0.3, rho=2e-3, sigma0=1e-2, seed=4, n=1024, status="not_converged", mean_gap=0.5,
             h_rms=h),
        _row(5, "gfmd", hurst=0.3, rho=2e-3, sigma0=1e-2, seed=5, n=1024, status="pending"),
        _row(6, "gfmd", hurst=0.3, rho=2e-3, sigma0=1e-2, seed=6, n=1024, mean_gap=math.nan, h_rms=h),  # invalid
        # a point where every task failed must still be listed
        _row(7, "gfmd", hurst=0.3, rho=2e-3, sigma0=1e-1, seed=0, n=1024, status="failed", mean_gap=9.0, h_rms=h),
    ]
    agg = aggregate.aggregate_mean_gap(_frame(rows))
    a = agg[np.isclose(agg["sigma0"], 1e-2)].iloc[0]
    vals = np.array([1e-3, 2e-3, 4e-3])
    mean = 7e-3 / 3
    sd = math.sqrt(((vals - mean) ** 2).sum() / 2)
    assert a["count"] == 3
    assert a["mean"] == pytest.approx(mean, rel=1e-12)
    assert a["std"] == pytest.approx(sd, rel=1e-12)
    assert a["sem"] == pytest.approx(sd / math.sqrt(3), rel=1e-12)
    assert a["mean_reduced"] == pytest.approx(mean / h, rel=1e-12)
    assert a["sem_reduced"] == pytest.approx(sd / math.sqrt(3) / h, rel=1e-12)
    assert (a["n_failed"], a["n_not_converged"], a["n_pending"], a["n_invalid"], a["n_total"]) == (1, 1, 1, 1, 7)
    assert a["sigma0_reduced"] == pytest.approx(1e-2)
    b = agg[np.isclose(agg["sigma0"], 1e-1)].iloc[0]
    assert b["count"] == 0 and math.isnan(b["mean"]) and b["n_failed"] == 1
    st = aggregate.status_counts(_frame(rows)).set_index("method")
    assert st.loc["gfmd", ["done", "failed", "not_converged", "pending", "total"]].tolist() == [4, 2, 1, 1, 8]


def test_aggregate_theory_forms_and_single_seed_sem_is_nan():
    rows = [_row(0, "theory", hurst=0.8, rho=1e-3, sigma0=1e-3, mean_gap_paper=2.0, mean_gap_continuum=2.1,
                 h_rms=0.5)]
    agg = aggregate.aggregate_mean_gap(_frame(rows)).set_index("source")
    assert set(agg.index) == {"theory:paper", "theory:continuum"}  # no discrete form computed: not listed
    assert agg.loc["theory:paper", "mean"] == 2.0 and agg.loc["theory:continuum", "mean_reduced"] == pytest.approx(4.2)
    assert math.isnan(agg.loc["theory:paper", "sem"])


def test_bad_input_raises():
    with pytest.raises(TypeError):
        aggregate.aggregate_mean_gap([1, 2])
    with pytest.raises(ValueError, match="status"):
        aggregate.aggregate_mean_gap(pd.DataFrame({"task_id": [1], "method": ["gfmd"]}))
    with pytest.raises(ValueError, match="edges"):
        aggregate.merge_histograms([(np.array([0.0, 0.0, 1.0]), np.ones(2), 10)])
    with pytest.raises(ValueError, match="at least one"):
        aggregate.merge_histograms([])


# ---------------------------------------------------------------------------------------------------------
# histograms


def _hist(samples: np.ndarray, edges: np.ndarray):
    c, e = np.histogram(samples, bins=edges)
    return e, c / (c.sum() * np.diff(e)), int(c.sum())


def test_merge_histograms_same_edges_equals_pooled_samples():
    rng = np.random.default_rng(1)
    edges = np.linspace(-4, 4, 41)
    parts = [rng.normal(size=k) for k in (1000, 3000, 500)]
    parts = [p[(p > -4) & (p < 4)] for p in parts]
    st = aggregate.merge_histograms([_hist(p, edges) for p in parts])
    pooled = _hist(np.concatenate(parts), edges)[1]
    np.testing.assert_allclose(st["density"], pooled, rtol=1e-12, atol=1e-15)
    assert (st["density"] * np.diff(st["edges"])).sum() == pytest.approx(1.0, abs=1e-12)
    assert st["sem_kind"] == "seeds" and st["count"] == sum(len(p) for p in parts) and st["n_hist"] == 3
    assert np.all(st["sem"] >= 0) and np.any(st["sem"] > 0)


def test_merge_histograms_different_edges_conserves_mass_and_mean():
    rng = np.random.default_rng(2)
    a = rng.normal(1.0, 0.5, 20000)
    b = rng.normal(1.2, 0.4, 10000)
    ha = _hist(a, np.linspace(a.min(), a.max(), 33))
    hb = _hist(b, np.linspace(b.min(), b.max(), 17))
    st = aggregate.merge_histograms([ha, hb], bins=50)
    w = np.diff(st["edges"])
    assert (st["density"] * w).sum() == pytest.approx(1.0, abs=1e-12)
    # The pooled mean is conserved up to the within-bin spread of the rebinning (a fraction of a bin width).
    mean = (st.centres * st["density"] * w).sum()
    assert mean == pytest.approx(np.concatenate([a, b]).mean(), abs=0.5 * w.max())
    # One histogram: Poisson errors sqrt(P/(N dx)).
    one = aggregate.merge_histograms([ha])
    np.testing.assert_allclose(one["sem"], np.sqrt(ha[1] / (ha[2] * np.diff(ha[0]))))
    assert one["sem_kind"] == "poisson"


def test_rebin_density_exact_mass_per_interval():
    e = np.array([0.0, 1.0, 3.0])
    d = np.array([0.25, 0.375])  # masses 0.25 and 0.75
    new = np.array([-1.0, 0.5, 2.0, 4.0])
    r = aggregate.rebin_density(e, d, new)
    np.testing.assert_allclose(r * np.diff(new), [0.125, 0.125 + 0.375, 0.375])


def test_histogram_distances_analytic():
    # Two uniform densities on [0,1] and [0.5,1.5]: L1 = 1, KS = 0.5, W1 = shift = 0.5.
    d = compare.histogram_distance([0, 1], [1.0], [0.5, 1.5], [1.0], split=0.75)
    assert d["l1"] == pytest.approx(1.0)
    assert d["ks"] == pytest.approx(0.5)
    assert d["w1"] == pytest.approx(0.5)
    assert d["l1_below"] == pytest.approx(0.5) and d["l1_above"] == pytest.approx(0.5)
    same = compare.histogram_distance([0, 0.5, 1], [1.0, 1.0], [0, 1], [1.0])
    assert same["l1"] == pytest.approx(0, abs=1e-15) and same["w1"] == pytest.approx(0, abs=1e-15)


# ---------------------------------------------------------------------------------------------------------
# synthetic store: theory, GFMD with a known bias, SDE histograms at two C2


def _synthetic(tmp_bias: float = 0.0):
    """Frame + histograms: GFMD = paper theory x (1 - bias(h_rms/rho, sigma0)) with a little noise."""
    from gapsweep import theory
    from gapsweep.surface import continuum_rms_height

    rng = np.random.default_rng(0)
    rows, hists, i = [], {}, 0
    sig = np.geomspace(1e-4, 1.0, 7)
    for hurst, rhos in ((0.3, (2e-3, 1e-3, 5e-4)), (0.8, (5e-3, 2e-3, 1e-3))):
        h = continuum_rms_height(hurst, lambda_l=LL, lambda_s=LS)
        for rho in rhos:
            paper = theory.mean_gap(sig, hurst=hurst, h_rms=h, rho=rho, gamma0=GAMMA0, lambda_l=LL, lambda_s=LS)
            cont = theory.mean_gap(sig, hurst=hurst, h_rms=h, rho=rho, gamma0=GAMMA0, lambda_l=LL, lambda_s=LS,
                                   form="continuum")
            for s, p, c in zip(sig, paper, cont):
                rows.append(_row(i, "theory", hurst=hurst, rho=rho, sigma0=s, mean_gap_paper=p, mean_gap_continuum=c,
                                 h_rms=h))
                i += 1
                bias = 0.005 * (h / rho) * (1e-2 / s) ** 0.3  # grows with h_rms/rho, falls with pressure
                for seed in range(3):
                    rows.append(_row(i, "gfmd", hurst=hurst, rho=rho, sigma0=s, seed=seed, n=1024, h_rms=h,
                                     mean_gap=p - bias * abs(p) + rng.normal(0, 1e-3 * abs(p))))
                    i += 1
    # figures 4/5: H sweep at rho = 2e-3
    for hurst in (0.1, 0.3, 0.5, 0.7, 0.9):
        h = continuum_rms_height(hurst, lambda_l=LL, lambda_s=LS)
        for s in (0.01, 0.1):
            p = float(theory.mean_gap(s, hurst=hurst, h_rms=h, rho=2e-3, gamma0=GAMMA0, lambda_l=LL, lambda_s=LS))
            rows.append(_row(i, "theory", hurst=hurst, rho=2e-3, sigma0=s, mean_gap_paper=p, h_rms=h, seed=0))
            i += 1
            for seed in range(2):
                rows.append(_row(i, "gfmd", hurst=hurst, rho=2e-3, sigma0=s, seed=seed, n=1024, h_rms=h,
                                 mean_gap=p * (1 - 0.01 * hurst / s**0.2) + rng.normal(0, 1e-6)))
                i += 1
    # figure 6: GFMD histograms per seed and SDE at c2 = 0 and 0.5
    h6 = 0.002
    for s in (1e-4, 1e-3, 1e-2):
        g0 = 2e-3 * math.log(GAMMA0 / (2e-3 * s)) + h6**2 / 4e-3
        for seed in range(2):
            x = rng.normal(g0, h6, 4000) + np.where(rng.random(4000) < s * 20, h6, 0.0)
            rows.append(_row(i, "gfmd", hurst=0.3, rho=2e-3, sigma0=s, seed=seed, n=512, h_rms=h6,
                             mean_gap=float(x.mean())))
            hists[f"t{i:04d}"] = _hist(x, np.linspace(x.min(), x.max(), 41))
            i += 1
        for c2, shift in ((0.0, 0.5 * h6), (0.5, 0.05 * h6)):
            x = rng.normal(g0 + shift, h6, 20000)
            rows.append(_row(i, "sde", hurst=0.3, rho=2e-3, sigma0=s, h_rms=h6, c2=c2, mean_gap=float(x.mean())))
            hists[f"t{i:04d}"] = _hist(x, np.linspace(x.min(), x.max(), 41))
            i += 1
    rows.append(_row(i, "sde", hurst=0.3, rho=2e-3, sigma0=1e-1, h_rms=h6, c2=0.5, status="failed", message="x"))
    return _frame(rows), hists


def test_theory_vs_gfmd_errors_and_uncertainty():
    rows = [_row(0, "theory", hurst=0.3, rho=1e-3, sigma0=1e-2, mean_gap_paper=1.1e-3, mean_gap_continuum=1.2e-3,
                 h_rms=2e-3)]
    rows += [_row(1 + k, "gfmd", hurst=0.3, rho=1e-3, sigma0=1e-2, seed=k, n=n, mean_gap=v, h_rms=2e-3)
             for k, (n, v) in enumerate([(512, 5.0e-3), (1024, 0.9e-3), (1024, 1.1e-3)])]
    agg = aggregate.aggregate_mean_gap(_frame(rows))
    cmp = compare.theory_vs_gfmd(agg).set_index("form")
    G, sG = 1.0e-3, 0.1e-3  # finest grid only: values 0.9e-3 and 1.1e-3, sd = 1.414e-4, sem = 1e-4
    assert cmp.loc["paper", "gfmd"] == pytest.approx(G) and cmp.loc["paper", "n"] == 1024
    assert cmp.loc["paper", "rel_err"] == pytest.approx(0.1)
    assert cmp.loc["paper", "rel_err_sem"] == pytest.approx(1.1e-3 * sG / G**2)
    assert cmp.loc["continuum", "rel_err"] == pytest.approx(0.2)
    assert cmp.loc["paper", "red_err"] == pytest.approx(0.1e-3 / 2e-3)
    assert not cmp.loc["paper", "ill_conditioned"]  # |G| = 0.5 h_rms >= 0.25 h_rms


def test_agreement_regions_and_verdicts_on_synthetic_store(tmp_path):
    df, hists = _synthetic()
    agg = aggregate.aggregate_mean_gap(df)
    cmp = compare.theory_vs_gfmd(agg)
    points, summary = compare.agreement_regions(cmp)
    assert set(points["tier"]) <= {"<=1%", "<=5%", "<=10%", ">10%", "ill-conditioned", "no GFMD data"}
    # Built-in bias grows with h_rms/rho: the worst curve has the largest h_rms/rho.
    assert summary["max_abs_rel_err"].idxmax() == summary["h_rms_over_rho"].idxmax()
    hagg = aggregate.aggregate_histograms(df, hists)
    assert all(abs((v["density"] * np.diff(v["edges"])).sum() - 1) < 1e-12 for v in hagg.values())
    dist = compare.histogram_distances(hagg)
    ver = {v["claim"][:30]: v for v in report.verdicts(cmp, dist)}
    assert len(ver) == 7
    # Pressure trend is built in (bias ~ sigma0^-0.3): confirmed; h_rms/rho trend likewise.
    v4 = next(v for k, v in ver.items() if k.startswith("Agreement improves"))
    assert v4["verdict"] == "confirmed", v4
    v5 = next(v for k, v in ver.items() if k.startswith("Agreement worsens"))
    assert v5["verdict"] in ("confirmed", "mostly confirmed"), v5
    v6 = next(v for k, v in ver.items() if "matches GFMD" in v["claim"])
    assert v6["verdict"] == "confirmed" and "best stored C2 = 0.5" in v6["evidence"], v6
    # Empty inputs: every claim says "not enough data".
    empty = report.verdicts(cmp.iloc[0:0], dist.iloc[0:0])
    assert all(v["verdict"] == report.NOT_ENOUGH for v in empty)

    ds = dataset.to_dataset(df)
    assert dict(ds.sizes)["seed"] == 3 and "gfmd_mean_gap" in ds and "theory_paper" in ds and "sde_mean_gap" in ds
    assert ds.attrs["gfmd_n"] == 1024 and ds.attrs["sde_c2"] == 0.0
    sel = ds["gfmd_mean_gap"].sel(hurst=0.3, rho=2e-3, seed=1)
    assert np.isfinite(sel.sel(sigma0=1e-4)).item()


def test_calibrate_c2_recovers_known_c2():
    """A histogram made by the Fokker-Planck solver itself at C2 = 0.3 must calibrate back to C2 ~ 0.3."""
    fp = pytest.importorskip("gapsweep.fokker_planck")
    kw = dict(hurst=0.3, h_rms=2e-3, rho=2e-3, gamma0=GAMMA0, lambda_l=LL, lambda_s=LS, e_star=E_STAR)
    s = 1e-2
    r = fp.solve(s, c2=0.3, **kw)
    m, sd = r.mean(), math.sqrt(r.variance())
    edges = np.linspace(m - 6 * sd, m + 6 * sd, 49)
    dens = r.bin_density(edges)
    dens = dens / (dens * np.diff(edges)).sum()
    st = aggregate.HistogramStats(edges=edges, density=dens, sem=np.zeros_like(dens), sem_kind="seeds", count=10**6,
                                  n_hist=1, h_rms=2e-3, g_rms=1.0, e_star=E_STAR, gamma0=GAMMA0, lambda_l=LL,
                                  lambda_s=LS, mean_gap=math.nan)
    hagg = {("gfmd", 0.3, 2e-3, s, 1024.0, math.nan, ""): st}
    table, models = compare.calibrate_c2(hagg)
    assert table["status"].iloc[0] in ("ok", "at_bound"), table
    assert table["c2"].iloc[0] == pytest.approx(0.3, rel=0.05)
    dist = compare.histogram_distances({**hagg, **models})
    assert dist["method"].tolist() == ["fp_calibrated"] and dist["l1"].iloc[0] < 0.02


def test_report_build_writes_every_figure_and_counts_failures(tmp_path):
    df, hists = _synthetic()
    path = report.build(df, hists, tmp_path)
    text = path.read_text()
    # The synthetic store holds every parameter set of the paper: every paper figure, each panel with data.
    figs = pd.read_csv(tmp_path / "figures.csv").set_index("figure")
    assert set(figs.index) == {name for name, _ in report.FIGURES}
    assert (figs["min_points"] > 0).all(), figs
    for name, _ in report.FIGURES:
        for ext in ("png", "pdf"):
            f = tmp_path / f"{name}.{ext}"
            assert f.is_file() and f.stat().st_size > 1000, f
        assert f"({name}.png)" in text
    assert "## Verdicts on the paper's claims" in text and "(quick job: not a conclusion)" not in text
    for csv in ("status", "mean_gap", "theory_vs_gfmd", "agreement_summary", "hist_distances", "histograms"):
        assert (tmp_path / f"{csv}.csv").stat().st_size > 0
    st = pd.read_csv(tmp_path / "status.csv").set_index("method")
    assert st.loc["sde", "failed"] == 1
    assert "1 failed or unconverged tasks" in text
    assert (tmp_path / "report.html").read_text().count("<img") == len(report.FIGURES)


def test_figures_without_data_still_render(tmp_path):
    empty = aggregate.aggregate_mean_gap(_frame([_row(0, "gfmd", hurst=0.5, rho=1e-3, sigma0=1e-2, mean_gap=1e-3,
                                                      h_rms=1e-3)]))
    for name, fig in (("a", figures.fig_mean_gap_pressure(empty, hurst=0.3)),
                      ("b", figures.fig_mean_gap_hurst(empty, sigma0_reduced=0.01, rho=2e-3)),
                      ("c", figures.fig_gap_distribution({}, hurst=0.3, rho=2e-3))):
        paths = figures.save(fig, tmp_path, name)
        assert all(p.stat().st_size > 0 for p in paths)


# ---------------------------------------------------------------------------------------------------------
# end to end: a quick job into a temporary store, then the report


def _sweep_ready() -> str | None:
    try:
        from gapsweep import runner, store  # noqa: F401
    except ImportError as e:
        return f"gapsweep sweep not importable: {e}"
    return None


QUICK = ("fig2_quick", "fig3_quick", "fig4_5_quick", "fig6_quick")


@pytest.mark.timeout(180)
def test_quick_jobs_end_to_end(tmp_path, capsys):
    why = _sweep_ready()
    if why:
        pytest.skip(why)
    jobs = [ROOT / "jobs" / f"{j}.toml" for j in QUICK]
    missing = [str(j) for j in jobs if not j.is_file()]
    if missing:
        pytest.skip(f"quick job specs missing: {missing}")
    from tests.storekit import cli_run

    stores = []
    for j in jobs:  # `gapsweep run` in this process (cli.main): the process boundary is not under test here
        st = tmp_path / f"{j.stem}.h5"
        rc, _, err = cli_run(capsys, "run", j, "--store", st, "--mpi", "off", "--progress", "none")
        assert rc == 0, err[-2000:]
        stores.append(st)
    out = tmp_path / "report"
    path = report.main(stores, out)
    text = path.read_text()
    figs = pd.read_csv(out / "figures.csv")
    assert (figs["min_points"] > 0).all(), figs
    for name in figs["figure"]:
        assert (out / f"{name}.png").stat().st_size > 1000
        assert (out / f"{name}.pdf").stat().st_size > 1000
    # The quick jobs hold the paper's H, rho and pressures at zeta_s = 16: the paper's figures are drawn, and
    # every verdict is either "not evaluated" or labelled as coming from a quick job, under a warning.
    assert {"fig2", "fig3", "fig4", "fig5", "fig6"} <= set(figs["figure"]), figs
    assert "Warning: quick job(s)" in text
    verdicts = (out / "verdicts.md").read_text()
    rows = [r for r in verdicts.splitlines() if r.startswith("| ") and not r.startswith(("| claim", "| ---"))]
    assert rows and all("(quick job: not a conclusion)" in r or "| not evaluated |" in r for r in rows), rows
    # the stores by their paths relative to the report (here: next to it), never the machine's absolute path
    assert "## Provenance" in text and f"### ../{stores[0].name}" in text and str(tmp_path) not in text
    agg = pd.read_csv(out / "mean_gap.csv")
    assert (agg["source"] == "gfmd").any() and (agg["source"] == "theory:paper").any()
    # Every figure got its own job's data (no "no data" panel): each quick job name appears in the tables.
    assert {"fig2_quick", "fig3_quick", "fig4_5_quick"} <= set(agg["job"])
    dist = pd.read_csv(out / "hist_distances.csv")
    assert set(dist["job"]) == {"fig6_quick"} and (dist["method"] == "fp_calibrated").any()


def test_surface_families_apart_and_both_h_rms():
    # issue 9.5: two jobs at the same (H, rho) with different surfaces (h_rms 2e-3 vs 9e-3) stay two summary rows;
    # theory_vs_gfmd labels which h_rms the theory used and gives the theory at the surfaces' own h_rms too.
    from gapsweep import theory

    rows, i = [], 0
    for job, h_cont, h_surf, bias in (("fig2", 2.0e-3, 2.04e-3, 0.01), ("fig6", 9.0e-3, 9.2e-3, 0.5)):
        for s in (1e-3, 1e-2, 1e-1):
            p = float(theory.mean_gap(s, hurst=0.3, h_rms=h_cont, rho=2e-3, gamma0=GAMMA0, lambda_l=LL, lambda_s=LS))
            rows.append(dict(_row(i, "theory", hurst=0.3, rho=2e-3, sigma0=s, mean_gap_paper=p, h_rms=h_cont),
                             job=job))
            i += 1
            for seed in range(2):
                rows.append(dict(_row(i, "gfmd", hurst=0.3, rho=2e-3, sigma0=s, seed=seed, n=256, h_rms=h_surf,
                                      mean_gap=p * (1 - bias) * (1 + 1e-4 * seed)), job=job))
                i += 1
    df = pd.DataFrame(rows, columns=[*_COLS, "job"])
    cmp = compare.theory_vs_gfmd(aggregate.aggregate_mean_gap(df), forms=("paper",))
    assert set(cmp["theory_h_rms"]) == {"continuum"}
    r = cmp[(cmp["job"] == "fig2") & np.isclose(cmp["sigma0"], 1e-2)].iloc[0]
    assert r["h_rms_theory"] == pytest.approx(2.0e-3) and r["h_rms"] == pytest.approx(2.04e-3)
    want = theory.mean_gap(1e-2, hurst=0.3, h_rms=2.04e-3, rho=2e-3, gamma0=GAMMA0, lambda_l=LL, lambda_s=LS)
    assert r["theory_hsurf"] == pytest.approx(float(want), rel=1e-12)
    assert r["rel_err_hsurf"] == pytest.approx((want - r["gfmd"]) / r["gfmd"], rel=1e-9)
    _points, summary = compare.agreement_regions(cmp)
    assert len(summary) == 2 and set(summary["job"]) == {"fig2", "fig6"}
    small = summary[summary["job"] == "fig2"].iloc[0]
    assert small["max_abs_rel_err"] < 0.02 and small["h_rms_over_rho"] == pytest.approx(1.02)
    assert np.isfinite(small["max_abs_rel_err_hsurf"])
    trend = compare.pressure_trend(cmp)
    assert len(trend) == 2 and set(trend["job"]) == {"fig2", "fig6"}
    assert (trend["points"] == 3).all()


def test_theory_outside_its_domain_is_said_on_the_panel_not_as_raw_warnings(caplog):
    """A figure draws the field theory where the data are (as the paper's figures do); where that is outside the
    theory's validated domain (rho/h_rms < 0.5 here: docs/theory.md, 'Validity') the panel says so and the log
    says why, and no raw PredictorDomainWarning reaches the user's terminal (it did once per curve)."""
    import logging
    import warnings

    from gapsweep.theory.domain import PredictorDomainWarning

    def panel_texts(fig):
        return [t.get_text() for ax in fig.axes for t in ax.texts]

    h = 0.002
    for rho, outside in ((2e-4, True), (4e-3, False)):  # rho/h_rms = 0.1 (outside) and 2 (inside)
        agg = aggregate.aggregate_mean_gap(_frame([_row(i, "gfmd", hurst=0.3, rho=rho, sigma0=s, seed=0, n=1024,
                                                         mean_gap=3e-3, h_rms=h)
                                                    for i, s in enumerate((1e-3, 1e-2, 1e-1))]))
        caplog.clear()
        figures._DOMAIN_LOGGED.clear()
        with warnings.catch_warnings(record=True) as w, caplog.at_level(logging.INFO, "gapsweep.analysis.figures"):
            warnings.simplefilter("always")
            fig = figures.fig_mean_gap_pressure(agg, hurst=0.3)
        assert not [x for x in w if issubclass(x.category, PredictorDomainWarning)]
        assert (figures.OUTSIDE_NOTE in panel_texts(fig)) is outside
        assert any("validated domain" in r.getMessage() for r in caplog.records) is outside
