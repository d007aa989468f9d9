"""The report of a sweep that is not the paper's (jobs/test_generic.toml: H = 0.5/0.7, rho/L = 4e-3/8e-3,
zeta_s = 16): figures chosen from the store's axes, every panel with data, no verdict on the paper's claims,
and the CLI's manners around it (no silent overwrite)."""

from __future__ import annotations

import shutil
from pathlib import Path

import pandas as pd
import pytest

from tests.storekit import cli_run

ROOT = Path(__file__).resolve().parents[1]
JOB = ROOT / "jobs" / "test_generic.toml"


@pytest.fixture(scope="module")
def generic_store(tmp_path_factory):
    from gapsweep import runner

    path = tmp_path_factory.mktemp("generic") / "generic.h5"
    runner.run(JOB, path, progress="none", mpi="off")
    return path


@pytest.fixture(scope="module")
def generic_report(generic_store, tmp_path_factory):
    """The report of the generic store, built once by ``gapsweep report STORE --out DIR`` into a new folder (the
    CLI's first build: exit 0). The tests read it; the overwrite test works on a copy."""
    from gapsweep import cli

    out = tmp_path_factory.mktemp("generic_report") / "report"
    rc = cli.main(["report", str(generic_store), "--out", str(out)])
    assert rc == 0
    return out


@pytest.mark.timeout(300)
def test_generic_report_has_no_blank_figure(generic_report):
    out = generic_report
    text = (out / "report.md").read_text()
    figs = pd.read_csv(out / "figures.csv")
    # One pressure figure per H (a panel per rho), the gap distribution at (0.5, 8e-3), the agreement map.
    names = set(figs["figure"])
    assert {"gap_vs_pressure_test-generic_H0.5", "gap_vs_pressure_test-generic_H0.7", "fig_agreement"} <= names, names
    assert any(n.startswith("gap_distribution_test-generic_H0.5_rho0.008") for n in names), names
    assert not names & {"fig2", "fig3", "fig4", "fig5", "fig6"}  # not the paper's parameter sets
    assert (figs["min_points"] > 0).all(), figs
    assert figs.loc[figs["figure"] == "gap_vs_pressure_test-generic_H0.5", "panels"].item() == 2
    for name in names:
        for ext in ("png", "pdf"):
            assert (out / f"{name}.{ext}").stat().st_size > 1000
        assert f"({name}.png)" in text
    # No PNG that the manifest does not list (a stale or blank figure).
    assert {p.stem for p in out.glob("*.png")} == names
    assert "Not evaluated: no job in these stores holds one of the paper's parameter sets" in text
    assert "| confirmed |" not in text and "not confirmed" not in text
    assert "Symbols:" in text


@pytest.mark.timeout(120)
def test_cli_report_refuses_to_overwrite(generic_store, generic_report, tmp_path, capsys):
    # the first `gapsweep report` into a new folder (exit 0) is the module's generic_report; a copy of that
    # folder (its manifest with it) is the report already in --out
    out = tmp_path / "rep"
    shutil.copytree(generic_report, out)
    cmd = ["report", generic_store, "--out", out]
    before = (out / "report.md").stat().st_mtime_ns
    rc, _, err = cli_run(capsys, *cmd)
    assert rc != 0 and "--overwrite" in err
    assert (out / "report.md").stat().st_mtime_ns == before  # untouched
    rc, _, err = cli_run(capsys, *cmd, "--overwrite")
    assert rc == 0, err[-2000:]
    assert (out / "report.md").stat().st_mtime_ns != before


@pytest.mark.parametrize("mask", [0o022, 0o002, 0o077])
def test_report_folder_mode_follows_the_umask(tmp_path, monkeypatch, mask):
    """The report folder gets the mode of a plain ``mkdir`` under the umask (0755 under 022, 0775 under 002,
    0700 under 077); the old one was made by mkdtemp and stayed 0700 for everyone (issue 40). A replaced report
    keeps its folder's mode. The store reading and figure drawing are stood in for: only the folder is tested."""
    import os
    import stat

    from gapsweep.analysis import report

    monkeypatch.setattr(report, "load", lambda paths: (None, {}, {}))
    monkeypatch.setattr(report, "load_pressure", lambda paths: {})
    monkeypatch.setattr(report, "build", lambda df, h, out, prov, phists=None: (out / "report.md").write_text("r"))
    old = os.umask(mask)
    try:
        out = tmp_path / "sub" / "rep"
        report.main([tmp_path / "x.h5"], out)
        ref = tmp_path / "plain"
        ref.mkdir()
    finally:
        os.umask(old)
    assert stat.S_IMODE(out.stat().st_mode) == stat.S_IMODE(ref.stat().st_mode) == 0o777 & ~mask
    out.chmod(0o750)
    report.main([tmp_path / "x.h5"], out, overwrite=True)
    assert stat.S_IMODE(out.stat().st_mode) == 0o750


def test_generic_figures_say_quick_only_for_quick_jobs(monkeypatch):
    """The footer of a per-job figure (mean gap against pressure, against H) warns "QUICK JOB" only for a quick
    job. (Before, the per-job figures passed their "job ..." label as the quick flag, so every one of them said
    QUICK JOB, a full job's included.)"""
    from gapsweep.analysis import figures, report

    rows = [{"job": job, "source": "gfmd", "count": 3, "n": 64, "hurst": h, "rho": 4e-3, "sigma0": s,
             "sigma0_reduced": s} for job in ("full", "smoke") for h in (0.5, 0.6, 0.7) for s in (1e-3, 1e-2, 1e-1)]
    agg = pd.DataFrame(rows)
    notes: dict[str, str] = {}
    monkeypatch.setattr(figures, "fig_mean_gap_pressure", lambda a, *, hurst, rhos, note: note)
    monkeypatch.setattr(figures, "fig_mean_gap_hurst", lambda a, *, sigma0_reduced, rho, rtol, note: note)
    plan = report.plan_figures(agg, {}, pd.DataFrame(), {}, {"smoke"})
    for name, _, make in plan:
        notes[name] = make()
    assert {n.split("_")[1] for n in notes} == {"vs"} and len(notes) == 8, sorted(notes)
    for name, note in notes.items():
        job = "smoke" if "_smoke_" in name else "full"
        assert f"job {job}" in note, (name, note)
        assert (figures.QUICK_NOTE in note) == (job == "smoke"), (name, note)
