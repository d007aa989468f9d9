"""Contact laws end to end through the sweep (issue 12 parts 3-4, issue 13 part 1): job specs with
``[surface] kind = "file"`` and ``[interaction] kind``, the store's new columns (format 2), Persson's theory side by
side, the report's contact section; old (format-1) stores still open, resume and merge; task ids of the existing
specs unchanged. The shipped jobs/contact_file.toml runs in a few seconds (N = 256, five pressures)."""

from __future__ import annotations

import hashlib
import math
from pathlib import Path

import h5py
import numpy as np
import pandas as pd
import pytest

from gapsweep import spec, store
from gapsweep.sweep import tasks

ROOT = Path(__file__).resolve().parents[1]
JOB = ROOT / "jobs" / "contact_file.toml"
ADHESION = ROOT / "jobs" / "adhesion_quick.toml"


@pytest.fixture(scope="module")
def contact_store(tmp_path_factory):
    from gapsweep import runner

    path = tmp_path_factory.mktemp("contact") / "contact.h5"
    runner.run(JOB, path, progress="none", mpi="off")
    return path


def _ids_digest(path: Path) -> str:
    ts = tasks.expand(spec.load(path))
    return hashlib.sha256("".join(t.task_id for t in ts).encode()).hexdigest()


def test_existing_specs_keep_their_task_ids():
    # Recorded on main before the contact keys existed (sha256 of the concatenated task ids, and the spec hash).
    assert _ids_digest(ROOT / "jobs" / "fig2.toml").startswith("412a6758735e")
    assert spec.load(ROOT / "jobs" / "fig2.toml").sha256.startswith("187b866da567")
    assert _ids_digest(ROOT / "jobs" / "test_generic.toml").startswith("f7115c51a334")
    assert _ids_digest(ROOT / "jobs" / "fig6.toml").startswith("1a64b8a0ea4e")


def test_file_spec_is_hashed_by_content(tmp_path):
    js = spec.load(JOB)
    assert js.law == "hard_wall" and js.surface["kind"] == "file"
    assert js.grid["hurst"] == [0.0] and js.grid["rho"] == [0.0]  # placeholders: no Hurst exponent, no range
    assert js.methods["gfmd"]["n"] == [256]
    raw = (ROOT / "jobs" / "data" / "rough_tilted_256.npy").read_bytes()
    assert js.surface["sha256"] == hashlib.sha256(raw).hexdigest()
    assert js.surface["length"] == pytest.approx(128.0)
    # the same spec next to a changed map: other task ids
    (tmp_path / "data").mkdir()
    h = np.load(ROOT / "jobs" / "data" / "rough_tilted_256.npy")
    np.save(tmp_path / "data" / "rough_tilted_256.npy", h * 1.01)
    (tmp_path / "c.toml").write_text(JOB.read_text())
    ids_a = {t.task_id for t in tasks.expand(js)}
    ids_b = {t.task_id for t in tasks.expand(spec.load(tmp_path / "c.toml"))}
    assert not ids_a & ids_b


BAD = [
    ('[surface]\nkind = "file"\npath = "nope.npy"\npixel_size = 1.0\n', "surface.path"),
    ('[surface]\nkind = "file"\npath = "bad.txt"\npixel_size = 1.0\n', "surface.path"),
    ('[surface]\nkind = "file"\npath = "ok.npy"\n', "surface.length"),
    ('[surface]\nkind = "file"\npath = "ok.npy"\npixel_size = -1.0\n', "surface.pixel_size"),
    ('[surface]\nkind = "file"\npath = "ok.npy"\npixel_size = 1.0\ndetrend = "cubic"\n', "surface.detrend"),
    ('[surface]\nkind = "file"\npath = "ok.npy"\npixel_size = 1.0\nunit = "furlong"\n', "surface.unit"),
    ('[surface]\nkind = "measured"\n', "surface.kind"),
    ('[interaction]\nkind = "glue"\n', "interaction.kind"),
    ('[interaction]\nkind = "adhesive"\n', "interaction.work"),
    ('[interaction]\nkind = "adhesive"\nwork = -1.0\n', "interaction.work"),
    ('[interaction]\nkind = "hard_wall"\nwork = 1.0\n', "interaction.work"),
]


@pytest.mark.parametrize("extra,key", BAD)
def test_bad_contact_specs_name_the_key(tmp_path, extra, key):
    np.save(tmp_path / "ok.npy", np.random.default_rng(0).normal(size=(32, 32)))
    (tmp_path / "bad.txt").write_text("1 2 x\n3 4\n")
    base = ('[job]\nname = "x"\n[grid]\nsigma0 = [1e-2]\n' + ("hurst = [0.5]\n" if "file" not in extra else "")
            + ("rho = [1e-2]\n" if "hard_wall" not in extra else "")
            + '[methods.gfmd]\n' + ("n = 64\n" if "file" not in extra else ""))
    with pytest.raises(spec.SpecError) as e:
        spec.loads(base + extra, base=tmp_path)
    assert str(e.value).startswith(key), str(e.value)


@pytest.mark.parametrize("grid,more,key", [
    ("hurst = [0.5]\nrho = [1e-2]\n", "", "grid.rho"),                      # hard wall has no range
    ("rho = [1e-2]\n", "", "grid.hurst"),                                 # missing for a self-affine surface
    ("hurst = [0.5]\nsigma0 = [-1e-3]\n", "", "grid.sigma0"),             # tensile only with adhesion
    ("hurst = [0.5]\n", "[methods.sde]\n", "methods.sde"),                # SDE models exponential repulsion
    ("hurst = [0.5]\n", "[methods.theory]\nforms = [\"paper\"]\n", "methods.theory.forms[0]"),
    ("hurst = [0.5]\n", "[material]\ngamma0 = 1e-3\n", "material.gamma0"),
])
def test_hard_wall_spec_errors(grid, more, key):
    text = ('[job]\nname = "x"\n[grid]\n' + grid + ("sigma0 = [1e-2]\n" if "sigma0" not in grid else "")
            + '[surface]\nlambda_s = 0.0625\n[interaction]\nkind = "hard_wall"\n[methods.gfmd]\nn = 64\n' + more)
    with pytest.raises(spec.SpecError) as e:
        spec.loads(text)
    assert str(e.value).startswith(key), str(e.value)


def test_file_surface_grid_is_the_map(tmp_path):
    np.save(tmp_path / "m.npy", np.random.default_rng(0).normal(size=(32, 32)))
    head = '[job]\nname = "x"\n[grid]\nsigma0 = [1e-2]\n{g}[surface]\nkind = "file"\npath = "m.npy"\npixel_size = 1.0\n'
    tail = '[interaction]\nkind = "hard_wall"\n[methods.gfmd]\n'
    for g, t, key in (("", "n = 64\n", "methods.gfmd.n"), ("hurst = [0.5]\n", "", "grid.hurst"),
                      ("seeds = [0, 1]\n", "", "grid.seeds")):
        with pytest.raises(spec.SpecError) as e:
            spec.loads(head.format(g=g) + tail + t, base=tmp_path)
        assert str(e.value).startswith(key), str(e.value)
    # rectangular maps are taken (issue 20): solved on their own nx x ny grid, box [Lx, Ly]
    np.save(tmp_path / "r.npy", np.random.default_rng(1).normal(size=(32, 16)))
    js = spec.loads(head.format(g="").replace("m.npy", "r.npy") + tail, base=tmp_path)
    assert js.methods["gfmd"]["n"] == [32] and js.surface["shape"] == [32, 16] and js.surface["length"] == [32, 16]


def test_cli_refuses_a_bad_file_spec_and_writes_nothing(tmp_path, capsys):
    """In this process (``cli.main``): a refusal at validation, no process boundary under test."""
    from gapsweep import cli

    (tmp_path / "j.toml").write_text(JOB.read_text().replace("rough_tilted_256.npy", "missing.npy"))
    out = tmp_path / "s.h5"
    rc = cli.main(["run", str(tmp_path / "j.toml"), "--store", str(out), "--mpi", "off"])
    err = capsys.readouterr().err
    assert rc == 2, err
    assert "surface.path" in err
    assert not out.exists() and not list(tmp_path.glob("*.h5*"))


@pytest.mark.timeout(300)
def test_contact_store_holds_every_quantity(contact_store):
    from gapsweep import gfmd, topography

    df = store.read(contact_store)
    assert (df["status"] == "done").all(), df[["method", "status", "message"]]
    gf = df[df["method"] == "gfmd"].sort_values("sigma0")
    th = df[df["method"] == "theory"].sort_values("sigma0")
    assert len(gf) == 5 and len(th) == 5
    for col in ("mean_gap", "contact_area", "elastic_energy", "contact_atom", "pressure_atom", "residual"):
        assert np.isfinite(gf[col]).all(), col
    assert (gf["flags"] == 0).all()
    # hard wall: contact (p > 0) is the atom at g = 0, the complement of the free surface's atom at p = 0
    np.testing.assert_allclose(gf["contact_atom"], gf["contact_area"], rtol=0, atol=1e-12)
    np.testing.assert_allclose(gf["contact_area"] + gf["pressure_atom"], 1.0, rtol=0, atol=1e-12)
    assert np.all(np.diff(gf["contact_area"].to_numpy()) > 0) and np.all(np.diff(gf["mean_gap"].to_numpy()) < 0)
    assert np.all(np.diff(gf["elastic_energy"].to_numpy()) > 0)
    # histograms: gap density of the free points integrates to 1 - atom, pressure density of the loaded ones to
    # the contact area
    hg, hp = store.read_histograms(contact_store), store.read_pressure_histograms(contact_store)
    for _, row in gf.iterrows():
        e, d, _ = hg[row.task_id]
        assert float(np.sum(d * np.diff(e))) == pytest.approx(1 - row.contact_atom, abs=1e-9)
        e, d, atom = hp[row.task_id]
        assert atom == pytest.approx(row.pressure_atom)
        assert float(np.sum(d * np.diff(e))) == pytest.approx(row.contact_area, abs=1e-9)
        # local pressures are compressive and average to sigma0 over the whole surface
        c = 0.5 * (e[1:] + e[:-1])
        assert e[0] > 0 and float(np.sum(c * d * np.diff(e))) == pytest.approx(row.sigma0, rel=0.05)
    # the same answer as gapsweep.gfmd.solve on the map loaded by hand (one solve, cold start)
    topo = topography.load(ROOT / "jobs" / "data" / "rough_tilted_256.npy", pixel_size=0.5, unit="um",
                           detrend="plane")
    row = gf.iloc[2]
    r = gfmd.solve(topo.heights, sigma0=row.sigma0, interaction="hard_wall", length=topo.length[0], tol=1e-10,
                   backend="numpy")
    assert r.mean_gap == pytest.approx(row.mean_gap, rel=1e-6)
    assert r.contact_area == pytest.approx(row.contact_area, abs=2 / 256**2)
    assert r.elastic_energy == pytest.approx(row.elastic_energy, rel=1e-6)
    # Persson's theory of the map's own spectrum: a contact area and a mean separation at every pressure
    from gapsweep.theory import persson

    want = persson.contact_area(th["sigma0"].to_numpy(), heights=topo.heights, length=topo.length[0])
    np.testing.assert_allclose(th["contact_area"], want, rtol=1e-12)
    assert np.isfinite(th["mean_gap_persson"]).all() and (th["mean_gap"] == th["mean_gap_persson"]).all()


@pytest.mark.timeout(300)
def test_contact_report_has_data_in_every_figure(contact_store, tmp_path):
    from gapsweep.analysis import report

    out = tmp_path / "rep"
    text = report.main([contact_store], out).read_text()
    figs = pd.read_csv(out / "figures.csv")
    names = set(figs["figure"])
    assert {"contact_contact_file", "contact_distributions_contact_file"} <= names, names
    assert (figs["min_points"] > 0).all(), figs
    assert {p.stem for p in out.glob("*.png")} == names
    for n in names:
        assert (out / f"{n}.png").stat().st_size > 1000
    side = pd.read_csv(out / "contact_vs_persson.csv")
    assert len(side) == 5 and np.isfinite(side[["area_dev", "gap_dev"]].to_numpy()).all()
    summ = pd.read_csv(out / "contact_vs_persson_summary.csv")
    assert set(summ["quantity"]) == {"contact area", "mean separation"}
    assert "GFMD and Persson's theory side by side" in text
    # no field-theory figure for a hard-wall job (it has no rho, no gamma0)
    assert not any(n.startswith("gap_vs_pressure") for n in names)


@pytest.mark.timeout(300)
def test_adhesion_records_jumps_and_detachment(tmp_path):
    from gapsweep import runner

    path = tmp_path / "ad.h5"
    runner.run(ADHESION, path, progress="none", mpi="off")
    df = store.read(path).sort_values("sigma0", ascending=False)
    done = df[df["status"] == "done"]
    assert len(done) >= 5 and np.isfinite(done[["contact_area", "elastic_energy", "mean_gap"]].to_numpy()).all()
    assert np.isnan(done["contact_atom"]).all()  # no atom at g = 0 for a smooth law
    det = df[(df["flags"] & tasks.FLAG_DETACHED) > 0]
    assert len(det) and (det["status"] == "not_converged").all() and (det["sigma0"] < 0).all()
    assert det["message"].str.contains("detached").all()
    assert not (done["flags"] & tasks.FLAG_DETACHED).any()
    jumps = df[(df["flags"] & tasks.FLAG_JUMP) > 0]
    assert jumps["message"].str.startswith("jump along the load path").all()
    # compressive loads: contact area grows with load along the path
    pos = done[done["sigma0"] > 0]
    assert np.all(np.diff(pos["contact_area"].to_numpy()) < 0)


def _to_format1(path: Path) -> None:
    """Rewrite a store as format 1 (before the issue-12 columns and the pressure histograms)."""
    with h5py.File(path, "r+") as f:
        r = f["results"][...]
        old = np.zeros(r.shape, dtype=store.RESULT_DTYPE_V1)
        for k in old.dtype.names:
            old[k] = r[k]
        del f["results"], f["histograms/pressure_edges"], f["histograms/pressure_density"]
        f.create_dataset("results", data=old)
        f.attrs["format_version"] = 1
        del f.attrs["integrity"]  # format 1 had no attribute checksums


@pytest.mark.timeout(300)
def test_format1_store_opens_resumes_and_merges(tmp_path):
    from gapsweep import runner

    job = ROOT / "jobs" / "test_theory.toml"
    a = tmp_path / "a.h5"
    runner.run(job, a, progress="none", mpi="off")
    _to_format1(a)
    df = store.read(a)
    assert np.isnan(df["contact_area"]).all() and (df["flags"] == -1).all()
    assert store.read_pressure_histograms(a) == {}
    with h5py.File(a, "r+") as f:  # make two rows pending: resume must fill them in the old format
        res = f["results"][...]
        res["status"][:2] = 0
        f["results"][...] = res
    runner.run(job, a, resume=True, progress="none", mpi="off")
    after = store.read(a)
    assert (after["status"] == "done").all()
    with h5py.File(a, "r") as f:
        assert f["results"].dtype == store.RESULT_DTYPE_V1
    b = tmp_path / "b.h5"
    runner.run(job, b, progress="none", mpi="off")
    merged = tmp_path / "m.h5"
    store.merge([a, b], merged, on_conflict="first")
    m = store.read(merged)
    assert (m["status"] == "done").all() and np.isfinite(m["mean_gap"]).all()
    assert store.diff(a, b) != [] and any("only in" in x for x in store.diff(a, b))
    ds = store.to_dataset(a)
    assert "theory_paper" in ds


def test_half_pressure_histograms_is_a_damaged_store(contact_store, tmp_path):
    import shutil

    p = tmp_path / "d.h5"
    shutil.copy(contact_store, p)
    with h5py.File(p, "r+") as f:
        del f["histograms/pressure_density"]
    with pytest.raises(store.StoreError, match="pressure"):
        store.read(p)


def test_dataset_carries_the_contact_columns(contact_store):
    pytest.importorskip("xarray")
    ds = store.to_dataset(contact_store)
    for name in ("gfmd_contact_area", "gfmd_elastic_energy", "gfmd_contact_atom", "gfmd_pressure_atom",
                 "persson_contact_area", "persson_mean_gap"):
        assert name in ds, name
        assert ds[name].attrs["units"] and ds[name].attrs["long_name"]
    assert "seed" not in ds["persson_contact_area"].dims
    assert ds["gfmd_elastic_energy"].attrs["reference_unit"] == "E* L"
    assert math.isfinite(float(ds["gfmd_contact_area"].sel(sigma0=1e-2).squeeze()))


@pytest.mark.timeout(300)
def test_merge_of_file_surface_shards(tmp_path):
    """A file-surface job's shards merge (the merge re-reads the spec next to the map: spec_dir attribute)."""
    from gapsweep import runner

    shards = []
    for i in range(2):
        p = tmp_path / f"s{i}.h5"
        runner.run(JOB, p, shard=(i, 2), progress="none", mpi="off")
        shards.append(p)
    out = tmp_path / "m.h5"
    counts = store.merge(shards, out)
    assert counts["done"] == 10
    assert store.read_attrs(out)["spec_dir"] == str(JOB.resolve().parent)  # jobs/*.toml link to gapsweep/jobs


def test_file_surface_with_a_pair_size_runs(tmp_path):
    """A box given as a pair: the task's surface cache key must stay hashable (lists as tuples)."""
    rng = np.random.default_rng(3)
    np.save(tmp_path / "m.npy", rng.normal(size=(32, 32)))
    js = spec.loads('[job]\nname = "x"\n[grid]\nsigma0 = [0.05, 0.1]\n[surface]\nkind = "file"\npath = "m.npy"\n'
                    'length = [16.0, 16.0]\n[interaction]\nkind = "hard_wall"\n[methods.gfmd]\nbackend = "numpy"\n',
                    base=tmp_path)
    ts = tasks.expand(js)
    units = tasks.make_units(ts)
    out = [r for u in units for _, r in tasks.run_unit(ts, u, tasks.Context())]
    assert [r.status for r in out] == ["done", "done"], [r.message for r in out]
    assert all(0 < r.values["contact_area"] < 1 for r in out)
