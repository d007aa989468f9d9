"""Contact reports a reader could put in a paper (issue 20 items 6 and 7, report half): for hard-wall and adhesion
stores, bins that fit their axes, Persson's distributions overlaid, legends inside the axes in every unit system,
the height and contact maps, nothing of the seed paper's claims and no empty CSV in a contact-only report, axis
labels from the store attribute ``units``, and no absolute machine path in what the report writes. Structure
only, never pixels."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import h5py
import numpy as np
import pandas as pd
import pytest

ROOT = Path(__file__).resolve().parents[1]
JOB = ROOT / "jobs" / "contact_file.toml"
ADHESION = ROOT / "jobs" / "adhesion_quick.toml"
SI = {"length": "um", "pressure": "MPa"}


@pytest.fixture(scope="module")
def stores(tmp_path_factory):
    from gapsweep import runner

    d = tmp_path_factory.mktemp("contact_report")
    out = {}
    for name, job in (("hard_wall", JOB), ("adhesive", ADHESION)):
        out[name] = d / f"{name}.h5"
        runner.run(job, out[name], progress="none", mpi="off")
    return out


def _copy(src: Path, dst: Path, **attrs) -> Path:
    """A copy of a store with attributes set (None: removed -- a store of model units, no `units`)."""
    shutil.copy(src, dst)
    with h5py.File(dst, "r+") as f:
        for k, v in attrs.items():
            if v is None:
                f.attrs.pop(k, None)
            else:
                f.attrs[k] = v
    return dst


def _figures(path: Path) -> dict:
    """The contact figures of one store, built as the report builds them."""
    from gapsweep.analysis import contact, report

    df, hists, prov = report.load([path])
    points, persson = contact.tables(df)
    extra = (contact.job_infos(df, prov),) if hasattr(contact, "job_infos") else ()  # (the old plan had none)
    plan = contact.plan(df, hists, report.load_pressure([path]), points, persson, set(), *extra)
    return {name.split("_" + "".join(c if c.isalnum() else "_" for c in prov[0]["job_name"]))[0]: make()
            for name, _, make in plan}


def _steps(ax) -> list[np.ndarray]:
    return [np.asarray(p.get_data().edges, float) for p in ax.patches if hasattr(p, "get_data")]


def _assert_bins_fit_the_axis(fig) -> None:
    """Every histogram drawn as steps has bins of equal width on its own x axis: log-spaced on a log axis,
    equal on a linear one (a linear bin on a log axis shows as a plateau over decades)."""
    seen = 0
    for ax in fig.axes:
        for e in _steps(ax):
            seen += 1
            w = np.diff(np.log(e)) if ax.get_xscale() == "log" else np.diff(e)
            np.testing.assert_allclose(w, w[0], rtol=1e-6, err_msg=f"{ax.get_title()}: {ax.get_xscale()} axis")
    assert seen


def _assert_legends_inside(fig) -> None:
    """Each panel with labelled data has its own legend, and it lies inside the panel."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    canvas = FigureCanvasAgg(fig)
    canvas.draw()
    r = canvas.get_renderer()
    assert not fig.legends, "a figure legend outside the panels"
    for ax in fig.axes:
        if ax.get_label() == "<colorbar>":
            continue
        labelled = [lab for lab in ax.get_legend_handles_labels()[1] if not lab.startswith("_")]
        leg = ax.get_legend()
        if not labelled and leg is None:
            continue
        assert leg is not None, ax.get_title()
        lb, ab = leg.get_window_extent(r), ax.get_window_extent(r)
        assert lb.x0 >= ab.x0 - 1 and lb.x1 <= ab.x1 + 1 and lb.y0 >= ab.y0 - 1 and lb.y1 <= ab.y1 + 1, ax.get_title()


@pytest.mark.timeout(300)
@pytest.mark.parametrize("law", ["hard_wall", "adhesive"])
@pytest.mark.parametrize("units", [None, SI])
def test_figures_bins_legends_and_units(stores, tmp_path, law, units):
    path = _copy(stores[law], tmp_path / "s.h5", units=None if units is None else json.dumps(units))
    figs = _figures(path)
    dist = figs["contact_distributions"]
    _assert_bins_fit_the_axis(dist)
    for f in figs.values():
        _assert_legends_inside(f)
    assert {"contact", "contact_distributions", "contact_map"} <= set(figs), set(figs)
    gap_ax, p_ax = dist.axes[:2]
    xlabels = [ax.get_xlabel() for f in figs.values() for ax in f.axes]
    if units is None:
        assert "E^*" in p_ax.get_xlabel() and "units of the map" in gap_ax.get_xlabel()
        assert not any("[" in x for x in xlabels)
    else:
        assert p_ax.get_xlabel().endswith("[MPa]") and gap_ax.get_xlabel().endswith("[um]")
        assert figs["contact"].axes[1].get_ylabel() == "mean gap $g_0$ [um]"
        assert all("E^*" not in x for x in xlabels)
    # Persson's distributions (dashed) drawn for the hard wall only, on both panels
    dashed = [[ln for ln in ax.get_lines() if ln.get_linestyle() == "--" and np.isfinite(ln.get_ydata()).any()]
              for ax in (gap_ax, p_ax)]
    if law == "hard_wall":
        assert all(len(d) == 5 for d in dashed), [len(d) for d in dashed]
    else:
        assert not any(dashed)
    # the contact map: the height image and a contact mask with the stored contact area at that load
    cmap = figs["contact_map"]
    imgs = [ax.get_images() for ax in cmap.axes if ax.get_label() != "<colorbar>"]
    assert [len(i) for i in imgs] == [1, 1]
    mask = np.asarray(imgs[1][0].get_array(), float)
    assert mask.shape == (256, 256) and set(np.unique(mask)) <= {0.0, 1.0}
    from gapsweep import store

    df = store.read(path)
    areas = df[(df["method"] == "gfmd") & (df["status"] == "done")]["contact_area"].to_numpy(float)
    assert np.min(np.abs(areas - mask.mean())) < 5e-3


@pytest.mark.timeout(300)
def test_contact_only_report_has_no_paper_claims_no_empty_csv_no_absolute_path(stores, tmp_path):
    from gapsweep.analysis import report

    work = tmp_path / "stores"
    work.mkdir()
    paths = [_copy(stores["hard_wall"], work / "cf.h5"), _copy(stores["adhesive"], work / "ad.h5")]
    for i, p in enumerate(([paths[0]], paths)):
        out = tmp_path / f"rep{i}"
        text = report.main(p, out).read_text()
        assert "paper" not in text.lower(), [ln for ln in text.splitlines() if "paper" in ln.lower()]
        assert not (out / "verdicts.md").exists()
        csvs = sorted(out.glob("*.csv"))
        assert {c.stem for c in csvs} >= {"contact", "status", "figures"}
        for c in csvs:
            assert len(pd.read_csv(c)) > 0, c.name
        assert not {"mean_gap", "theory_vs_gfmd", "agreement_summary", "calibration"} & {c.stem for c in csvs}
        figs = set(pd.read_csv(out / "figures.csv")["figure"])
        assert {"contact_contact_file", "contact_distributions_contact_file", "contact_map_contact_file"} <= figs
        assert {p.stem for p in out.glob("*.png")} == figs
        # paths relative to the store or the spec, never the machine's
        for f in [*out.glob("*.md"), *out.glob("*.html"), *csvs]:
            body = f.read_text()
            for absolute in (str(tmp_path), str(ROOT), str(ROOT.resolve())):
                assert absolute not in body, (f.name, absolute)
        assert "data/rough_tilted_256.npy" in text
    assert "Warning: quick job(s) adhesion-quick" in text


@pytest.mark.timeout(300)
def test_missing_map_is_said_not_fatal(stores, tmp_path):
    from gapsweep.analysis import report

    path = _copy(stores["hard_wall"], tmp_path / "moved.h5", spec_dir=str(tmp_path / "gone"))
    out = tmp_path / "rep"
    text = report.main([path], out).read_text()
    assert "data/rough_tilted_256.npy` (relative to the job spec) was not found" in text
    figs = set(pd.read_csv(out / "figures.csv")["figure"])
    assert "contact_distributions_contact_file" in figs and "contact_map_contact_file" not in figs
    assert "no Persson overlay" in pd.read_csv(out / "figures.csv").set_index("figure").loc[
        "contact_distributions_contact_file", "caption"]


def test_large_map_skips_the_solve_with_a_note():
    from gapsweep.analysis import contact

    df = pd.DataFrame({"job": "big", "method": "gfmd", "status": "done", "n": 600, "seed": 0, "sigma0": [0.01],
                       "contact_area": [0.2], "task_id": ["t0"], "rho": 0.0, "e_star": 1.0,
                       "interaction": "hard_wall"})
    info = {"heights": np.zeros((600, 600)), "length": 1.0, "law": "hard_wall", "interaction": {}, "store": None,
            "units": {"length": None, "pressure": None}, "file": True, "map_path": "big.npy"}
    f = contact.map_fields(df, "big", info)
    assert f["mask"] is None and "N = 600 > 512" in f["note"]
    fig = contact.fig_map(df, job="big", info=info, fields=f)
    assert len([ax for ax in fig.axes if ax.get_label() != "<colorbar>"]) == 1


def test_units_attribute_parsing():
    from gapsweep.analysis import contact

    assert contact.units({}) == {"length": None, "pressure": None}
    assert contact.units({"units": json.dumps({"length": "um", "pressure": None})}) == {"length": "um",
                                                                                        "pressure": None}
    assert contact.units({"units": SI}) == SI
    assert contact.units({"units": "not json"}) == {"length": None, "pressure": None}


SYNTHETIC = """[job]
name = "hw-synthetic"
[grid]
hurst = [0.7]
sigma0 = [1e-2, 3e-2, 1e-1]
[surface]
lambda_l = 0.25
lambda_s = 0.0625
rms_slope = 1.0
[interaction]
kind = "hard_wall"
[histogram]
bins = 32
[methods.gfmd]
n = 64
tol = 1e-8
backend = "numpy"
"""


@pytest.mark.timeout(300)
def test_self_affine_hard_wall_gets_persson_and_a_regenerated_map(tmp_path):
    from gapsweep import runner, store

    (tmp_path / "syn.toml").write_text(SYNTHETIC)
    path = tmp_path / "syn.h5"
    runner.run(tmp_path / "syn.toml", path, progress="none", mpi="off")
    figs = _figures(path)
    assert set(figs) == {"contact", "contact_distributions", "contact_map"}
    _assert_bins_fit_the_axis(figs["contact_distributions"])
    for ax in figs["contact_distributions"].axes[:2]:
        assert len([ln for ln in ax.get_lines() if ln.get_linestyle() == "--"]) == 3
    imgs = [ax.get_images() for ax in figs["contact_map"].axes if ax.get_label() != "<colorbar>"]
    mask = np.asarray(imgs[1][0].get_array(), float)
    df = store.read(path)
    areas = df[df["method"] == "gfmd"]["contact_area"].to_numpy(float)
    assert mask.shape == (64, 64) and np.min(np.abs(areas - mask.mean())) < 2 / 64**2
