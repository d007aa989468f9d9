"""The body's job keys (``[material] thickness, poisson, bottom, hardness``; docs/jobs.md "The body: layer and
hardness"): validated up front naming the key, absent from the task options when not given (older task ids
unchanged), and the shipped jobs layer_quick and plastic_quick run end to end with rows equal to direct solves."""

from __future__ import annotations

from pathlib import Path

import h5py
import numpy as np
import pytest

from gapsweep import gfmd, spec
from gapsweep.sweep import tasks

ROOT = Path(__file__).resolve().parents[1]
BASE = ('[job]\nname = "x"\n[grid]\nhurst = [0.5]\nsigma0 = [1e-2, 2e-2]\n[surface]\nlambda_s = 0.0625\n'
        '[interaction]\nkind = "{law}"\n[methods.gfmd]\nn = 64\n{more}[material]\n')


@pytest.mark.parametrize(("law", "material", "more", "key"), [
    ("hard_wall", "thickness = 0.0\npoisson = 0.3\n", "", "material.thickness"),
    ("hard_wall", "thickness = -1\npoisson = 0.3\n", "", "material.thickness"),
    ("hard_wall", "thickness = 0.1\n", "", "material.poisson"),             # bonded needs nu
    ("hard_wall", "thickness = 0.1\npoisson = 0.5\n", "", "material.poisson"),
    ("hard_wall", "thickness = 0.1\npoisson = 0.3\nbottom = \"glued\"\n", "", "material.bottom"),
    ("hard_wall", "poisson = 0.3\n", "", "material.poisson"),             # a layer key without thickness
    ("hard_wall", "hardness = 0.02\n", "", "material.hardness"),          # not above every sigma0
    ("hard_wall", "hardness = -1.0\n", "", "material.hardness"),
    ("hard_wall", "hardness = 1.0\n", "method = \"pk\"\n[methods.theory]\nforms = [\"persson\"]\n",
     "methods.theory"),                                                   # no theory of a cap: refused
    ("hard_wall", "thickness = 0.1\nbottom = \"slip\"\n", "method = \"mpcg\"\n", "methods.gfmd.method"),
    ("hard_wall", "thickness = 0.1\nbottom = \"slip\"\n", "distributed = true\n", "methods.gfmd.distributed"),
    ("hard_wall", "hardness = 0.05\n", "sigma0 = [0.01, 0.1]\n", "material.hardness"),  # a method's own sigma0
])
def test_bad_body_keys_name_the_key(law: str, material: str, more: str, key: str) -> None:
    with pytest.raises(spec.SpecError) as e:
        spec.loads(BASE.format(law=law, more=more) + material)
    assert str(e.value).startswith(key), str(e.value)


def test_hardness_needs_the_hard_wall() -> None:
    text = BASE.format(law="exponential", more="").replace("hurst = [0.5]", "hurst = [0.5]\nrho = [1e-2]")
    with pytest.raises(spec.SpecError, match=r"^material\.hardness"):
        spec.loads(text + "hardness = 1.0\n")


def test_task_options_carry_the_body_only_when_given() -> None:
    plain = tasks.expand(spec.loads(BASE.format(law="hard_wall", more="")))
    layer = tasks.expand(spec.loads(BASE.format(law="hard_wall", more="") + "thickness = 0.1\nbottom = \"slip\"\n"))
    assert all(t.opt("thickness") is None and t.opt("hardness") is None for t in plain)
    assert all(t.opt("thickness") == 0.1 and t.opt("bottom") == "slip" for t in layer)
    assert {t.task_id for t in plain}.isdisjoint({t.task_id for t in layer})


@pytest.mark.parametrize("job", ["layer_quick", "plastic_quick"])
def test_shipped_body_jobs_match_direct_solves(job: str, tmp_path: Path) -> None:
    from gapsweep import runner
    from gapsweep.sweep.context import Context

    path = ROOT / "jobs" / f"{job}.toml"
    out = tmp_path / "s.h5"
    runner.run(path, out, progress="none", mpi="off")
    js = spec.load(path)
    ts = [t for t in tasks.expand(js) if t.method == "gfmd"]
    with h5py.File(out) as f:
        res = f["results"][...]
        ids = [x.decode() for x in f["tasks"]["task_id"]]
    assert (res["status"] == 1).all()
    row = {i: r for i, r in zip(ids, res)}
    ctx = Context()
    for t in ts[:2]:
        h = ctx.surface(t, t.n)
        m = js.material
        kw = {k: m[k] for k in ("thickness", "poisson", "bottom", "hardness") if k in m}
        r = gfmd.solve(h, sigma0=t.sigma0, interaction="hard_wall", length=t.surface_params()["length"], tol=1e-8,
                       **kw)
        assert row[t.task_id]["mean_gap"] == pytest.approx(r.mean_gap, rel=1e-6)
        assert row[t.task_id]["contact_area"] == pytest.approx(r.contact_area, abs=2.0 / h.size)
    if job == "plastic_quick":  # contact area at least sigma0 / H
        sig = np.array([t.sigma0 for t in ts])
        area = np.array([row[t.task_id]["contact_area"] for t in ts])
        assert np.all(area >= sig / js.material["hardness"] - 1e-12)
    # the report: the contact map re-solved with the body, no Persson half-space overlay
    from gapsweep.analysis import contact, report

    df, _, prov = report.load([out])
    cdf = df[contact.is_contact(df)]
    info = contact.job_infos(cdf, prov)[js.name]
    assert info["body"] == {k: js.material[k] for k in ("thickness", "poisson", "bottom", "hardness")
                            if k in js.material}
    assert any("Persson's half-space distributions are not drawn" in n for n in info["notes"])
    f = contact.map_fields(cdf, js.name, info)
    r = f["row"]
    h = ctx.surface(next(t for t in ts if t.task_id == str(r["task_id"]).split(":")[-1]), int(r["n"]))
    direct = gfmd.solve(h, sigma0=float(r["sigma0"]), interaction="hard_wall", tol=1e-8, **info["body"])
    np.testing.assert_array_equal(f["mask"], direct.pressure > 0)
    half = gfmd.solve(h, sigma0=float(r["sigma0"]), interaction="hard_wall", tol=1e-8)
    assert not np.array_equal(f["mask"], half.pressure > 0)  # the body changes the map: the check can fail


PLASTIC_JOB = """
[job]
name = "plastic-cols"
[grid]
hurst = 0.7
sigma0 = [4e-3, 1.5e-2]
seeds = [3]
[surface]
lambda_l = 0.5
lambda_s = 0.1
rms_slope = 0.1
[interaction]
kind = "hard_wall"
[methods.gfmd]
n = 40
tol = 1e-9
backend = "numpy"
{material}"""
PLASTIC_COLUMNS = ("plastic_area", "plastic_displacement_mean", "plastic_displacement_max")


def test_plastic_columns_are_plug_in_columns(tmp_path: Path) -> None:
    """The cap's columns are declared by the GFMD plug-in alone (docs/store.md "Plug-in columns"): none is a
    built-in column or named in sweep/schema.py; a job with ``hardness`` stores them, equal to a direct solve's
    plastic set (counted here from its pressure, not read from its ``plastic_area``), in the xarray view and the
    netCDF export; the same job without ``hardness`` keeps the built-in table, and both keep the spec hashes and
    task ids they had before the columns existed (computed with gapsweep at the merge of issue 43, b075681)."""
    from gapsweep import runner, store
    from gapsweep.surface import self_affine
    from gapsweep.sweep import methods, schema

    builtin = set(schema.FLOAT_RESULTS) | set(schema.INT_RESULTS) | set(schema.RESULT_DTYPE.names)
    assert builtin.isdisjoint(PLASTIC_COLUMNS)
    assert "plastic" not in (ROOT / "gapsweep" / "sweep" / "schema.py").read_text()
    assert set(PLASTIC_COLUMNS) <= set(methods.get("gfmd").own_columns)

    plain = spec.loads(PLASTIC_JOB.format(material=""))
    capped = spec.loads(PLASTIC_JOB.format(material="[material]\nhardness = 0.04\n"))
    assert methods.job_columns(plain) == []
    assert methods.job_columns(capped) == [(k, "float") for k in PLASTIC_COLUMNS]
    assert plain.sha256 == "ebb14479206cede479b7dbfa54f5dc9ebc11b26172a46738015e0dfb0cc61cf5"
    assert capped.sha256 == "aed957a19d88258e1f9ee97a84c56ebbe12347c017d25e0431574cb9e594e15b"
    assert sorted(t.task_id for t in tasks.expand(plain)) == ["301fed0cacd68c9e", "8014f32faddaee03"]
    assert sorted(t.task_id for t in tasks.expand(capped)) == ["3b049c97a8eb7477", "630b40d42b77d705"]

    for js, name in ((plain, "plain"), (capped, "capped")):
        p = tmp_path / f"{name}.toml"  # the job without the cap renamed: the report holds both
        p.write_text(js.text.replace('"plastic-cols"', '"plastic-cols-elastic"') if js is plain else js.text)
        runner.run(p, tmp_path / f"{name}.h5", mpi="off", progress="none")
    with h5py.File(tmp_path / "plain.h5", "r") as f:
        assert f["results"].dtype == schema.RESULT_DTYPE and schema.PLUGIN_COLUMNS not in f.attrs
    assert not set(PLASTIC_COLUMNS) & set(store.read(tmp_path / "plain.h5").columns)

    df = store.read(tmp_path / "capped.h5").sort_values("sigma0")
    assert (df.status == "done").all()
    h = self_affine(40, 0.7, seed=3, lambda_l=0.5, lambda_s=0.1, rms_slope=0.1)
    H = 0.04
    for _, row in df.iterrows():
        r = gfmd.solve(h, sigma0=row.sigma0, interaction="hard_wall", hardness=H, tol=1e-9)
        plastic = r.pressure >= H
        assert row.plastic_area == np.count_nonzero(plastic) / h.size
        # u_pl = -(g0 + u - h) on the plastic set: from the displacement and the mean gap of the elastic set
        g = r.displacement - h
        g0 = -g[(r.pressure > 0) & ~plastic].mean()
        u_pl = np.where(plastic, -(g0 + g), 0.0)
        assert row.plastic_displacement_mean == pytest.approx(u_pl.mean(), rel=1e-6)
        assert row.plastic_displacement_max == pytest.approx(u_pl.max(), rel=1e-6)
    assert 0 < df.plastic_area.iloc[0] < df.plastic_area.iloc[1] <= df.contact_area.iloc[1]
    assert df.plastic_displacement_mean.iloc[0] < df.plastic_displacement_mean.iloc[1]

    pytest.importorskip("xarray")
    import xarray as xr

    nc = store.export_netcdf(tmp_path / "capped.h5", tmp_path / "capped.nc")
    with xr.open_dataset(nc) as back:
        np.testing.assert_array_equal(back["gfmd_plastic_area"].squeeze().values, df.plastic_area.to_numpy())
        assert back["gfmd_plastic_displacement_mean"].attrs["reference_unit"] == "L"
        assert "p = H" in back["gfmd_plastic_area"].attrs["long_name"]

    # the report: the cap's columns in the contact table, and in the capped job's figure the plastic area, the
    # rigid-plastic limit sigma0/H and the curves of the job without the cap (found by its spec)
    from gapsweep.analysis import contact, report

    rdf, _, prov = report.load([tmp_path / "capped.h5", tmp_path / "plain.h5"])
    cdf = rdf[contact.is_contact(rdf)]
    points, persson = contact.tables(cdf)
    infos = contact.job_infos(cdf, prov)
    assert infos["plastic-cols"]["uncapped"] == "plastic-cols-elastic"
    assert "uncapped" not in infos["plastic-cols-elastic"]
    pc = points[points.job == "plastic-cols"].sort_values("sigma0")
    np.testing.assert_array_equal(pc.plastic_area.to_numpy(), df.plastic_area.to_numpy())
    fig = contact.fig_contact(points, persson, job="plastic-cols", info=infos["plastic-cols"])
    lines = {ln.get_label(): ln for ax in fig.axes[:2] for ln in ax.get_lines()}
    free = store.read(tmp_path / "plain.h5").sort_values("sigma0")
    gap_line = next(ln for ln in fig.axes[1].get_lines() if ln.get_label().startswith("without the cap"))
    np.testing.assert_array_equal(gap_line.get_ydata(), free.mean_gap.to_numpy())
    assert not np.allclose(gap_line.get_ydata(), df.mean_gap.to_numpy())  # the cap changes the mean gap
    np.testing.assert_allclose(lines[r"rigid-plastic limit $\sigma_0/H$"].get_ydata(), df.sigma0.to_numpy() / H)
    caps = [c for _, c, _ in contact.plan(cdf, {}, {}, points, persson, infos=infos)]
    assert any("without the cap (job plastic-cols-elastic)" in c for c in caps)


def test_layer_on_a_free_boundary_file_surface_is_refused_with_why(tmp_path: Path) -> None:
    """A non-periodic file surface with a layer: refused at validation naming the key, saying why (no validated
    real-space kernel of the layer) and what to do instead; the same map periodic is accepted."""
    np.save(tmp_path / "m.npy", np.random.default_rng(0).normal(size=(32, 32)) * 1e-3)
    text = ('[job]\nname = "x"\n[grid]\nsigma0 = [1e-2]\n[surface]\nkind = "file"\npath = "m.npy"\n'
            'pixel_size = 1.0\nperiodic = {periodic}\n[interaction]\nkind = "hard_wall"\n[methods.gfmd]\n'
            '[material]\nthickness = 4.0\npoisson = 0.3\n')
    with pytest.raises(spec.SpecError) as e:
        spec.loads(text.format(periodic="false"), base=tmp_path)
    msg = str(e.value)
    assert msg.startswith("material.thickness") and "real-space Green's function" in msg
    assert "surface.periodic = true" in msg
    assert spec.loads(text.format(periodic="true"), base=tmp_path).material["thickness"] == 4.0


def test_persson_theory_runs_on_a_layer_job(tmp_path: Path) -> None:
    """``[methods.theory] forms = ["persson"]`` on a layer job: the rows are gapsweep.theory.persson_layer's
    contact area and mean separation with the job's layer (not the half-space's); the field theory on a layer
    and any theory with a pressure cap are refused naming the key."""
    from gapsweep import runner, store
    from gapsweep.theory import persson, persson_layer

    text = ('[job]\nname = "layer-persson"\n[grid]\nhurst = [0.8]\nsigma0 = [3e-3, 2e-2]\n[surface]\n'
            'lambda_l = 0.5\nlambda_s = 0.125\nrms_slope = 0.1\n[interaction]\nkind = "hard_wall"\n'
            '[material]\nthickness = 0.03\nbottom = "slip"\n[methods.gfmd]\nn = 64\ntol = 1e-8\n'
            '[methods.theory]\nforms = ["persson"]\n')
    p = tmp_path / "j.toml"
    p.write_text(text)
    runner.run(p, tmp_path / "s.h5", mpi="off", progress="none")
    df = store.read(tmp_path / "s.h5")
    th = df[df.method == "theory"].sort_values("sigma0")
    assert (th.status == "done").all() and len(th) == 2
    kw = dict(hurst=0.8, lambda_l=0.5, lambda_s=0.125, rms_slope=0.1)
    for _, row in th.iterrows():
        u = persson_layer.mean_separation(row.sigma0, thickness=0.03, bottom="slip", **kw)
        a = persson_layer.contact_area(row.sigma0, thickness=0.03, bottom="slip", **kw)
        assert row.mean_gap_persson == pytest.approx(u, rel=1e-12) and row.contact_area == pytest.approx(a, rel=1e-12)
        assert row.mean_gap_persson > 1.2 * persson.mean_separation(row.sigma0, **kw)  # the layer, not the half-space
    with pytest.raises(spec.SpecError, match=r"^methods\.theory\.forms"):
        spec.loads(text.replace('forms = ["persson"]', 'forms = ["paper"]').replace(
            'kind = "hard_wall"', 'kind = "exponential"').replace("hurst = [0.8]", "hurst = [0.8]\nrho = [1e-3]"))
