"""Plug-in columns (docs/store.md "Plug-in columns") and the flow extension of the GFMD method
(gapsweep.sweep.methods.flow): a job with ``[methods.gfmd] flow = ...`` stores leak rate, conductance and the
percolating flag in columns that no edit of the schema declared, equal to gapsweep.flow.solve on the same GFMD
gap; jobs without it keep the built-in table (layout 5) and their task ids; such stores validate, resume and
merge; a damaged declaration is refused."""

from __future__ import annotations

import json

import h5py
import numpy as np
import pytest

from gapsweep import flow, gfmd, spec, store, surface
from gapsweep.sweep import methods, runner, schema

JOB = """
[job]
name = "flow-test"
[grid]
hurst = 0.8
sigma0 = [2e-3, 3e-2, 0.3]
[surface]
lambda_l = 0.5
lambda_s = 0.125
rms_slope = 0.1
[interaction]
kind = "hard_wall"
[histogram]
bins = 40
[methods.gfmd]
n = 32
tol = 1e-8
backend = "numpy"
{flow}
"""


def _job(tmp_path, flow_line):
    p = tmp_path / "job.toml"
    p.write_text(JOB.format(flow=flow_line))
    return p


def test_flow_columns_in_the_store(tmp_path):
    job = _job(tmp_path, "flow = { viscosity = 2.0, pressure_drop = 3.0, axis = 0 }")
    js = spec.load(job)
    assert methods.job_columns(js)[:4] == [("leak_rate", "float"), ("conductance", "float"),
                                           ("conductance_ratio", "float"), ("percolating", "int")]
    runner.run(job, tmp_path / "s.h5", mpi="off", progress="none")
    df = store.read(tmp_path / "s.h5").sort_values("sigma0")
    assert (df.status == "done").all()
    # the same numbers from the physics alone: the GFMD gap of each load, then flow.solve
    h = surface.self_affine(32, 0.8, seed=0, lambda_l=0.5, lambda_s=0.125, rms_slope=0.1)
    for _, row in df.iterrows():
        r = gfmd.solve(h, sigma0=row.sigma0, interaction="hard_wall", tol=1e-8)
        f = flow.solve(r.gap, axis=0, viscosity=2.0, pressure_drop=3.0)
        assert row.leak_rate == pytest.approx(f.leak_rate, rel=1e-6, abs=1e-300)
        assert row.conductance == pytest.approx(f.conductance, rel=1e-6, abs=1e-300)
        assert row.percolating == int(f.percolating)
        assert row.contact_area == pytest.approx(r.contact_area, abs=1e-12)
    assert df.percolating.iloc[0] == 1 and df.leak_rate.iloc[0] > df.leak_rate.iloc[1]
    assert df.percolating.iloc[-1] == 0 and df.leak_rate.iloc[-1] == 0.0  # 0.3 E*: sealed
    with h5py.File(tmp_path / "s.h5", "r") as f:
        assert json.loads(f.attrs[schema.PLUGIN_COLUMNS])[0] == ["leak_rate", "float"]
        assert schema.layout_of(f.attrs["format_version"], f["results"].dtype, False, True).name == "5"
    # the xarray view and the netCDF export carry them (the flag as 0/1, its long name from the plug-in)
    pytest.importorskip("xarray")
    ds = store.to_dataset(tmp_path / "s.h5")
    lr = ds["gfmd_leak_rate"].squeeze().values
    np.testing.assert_array_equal(lr, df.leak_rate.to_numpy())
    assert list(ds["gfmd_percolating"].squeeze().values) == list(df.percolating.astype(float))
    assert "contact seals" in ds["gfmd_percolating"].attrs["long_name"]
    nc = store.export_netcdf(tmp_path / "s.h5", tmp_path / "s.nc")
    import xarray as xr

    with xr.open_dataset(nc) as back:
        np.testing.assert_array_equal(back["gfmd_conductance"].squeeze().values, df.conductance.to_numpy())
    # resume (nothing to do) and merge keep the columns
    runner.run(job, tmp_path / "s.h5", mpi="off", progress="none", resume=True)
    store.merge([tmp_path / "s.h5"], tmp_path / "m.h5")
    assert store.diff(tmp_path / "s.h5", tmp_path / "m.h5") == []
    assert list(store.read(tmp_path / "m.h5").leak_rate) == list(store.read(tmp_path / "s.h5").leak_rate)


def test_without_flow_the_store_is_the_builtin_table(tmp_path):
    """Switched off (or absent): no plug-in column, the task ids of the job without the key, layout 5."""
    a, b = spec.load(_job(tmp_path, "")), spec.loads(JOB.format(flow="flow = false"))
    assert methods.job_columns(a) == [] and a.sha256 == b.sha256
    runner.run(_job(tmp_path, ""), tmp_path / "p.h5", mpi="off", progress="none")
    with h5py.File(tmp_path / "p.h5", "r") as f:
        assert f["results"].dtype == schema.RESULT_DTYPE and schema.PLUGIN_COLUMNS not in f.attrs
    assert "leak_rate" not in store.read(tmp_path / "p.h5").columns


def test_damaged_declaration_is_refused(tmp_path):
    job = _job(tmp_path, "flow = true")
    runner.run(job, tmp_path / "s.h5", mpi="off", progress="none")
    with h5py.File(tmp_path / "s.h5", "r+") as f:  # a new declaration without its checksum
        f.attrs[schema.PLUGIN_COLUMNS] = json.dumps([["leak_rate", "int"]])
    with pytest.raises(store.StoreError, match="plugin_columns"):
        store.read(tmp_path / "s.h5")


@pytest.mark.parametrize("line, match", [
    ("flow = 3", r"methods\.gfmd\.flow"), ("flow = { viscosity = 0.0 }", r"methods\.gfmd\.flow\.viscosity"),
    ("flow = { axis = 2 }", r"methods\.gfmd\.flow\.axis"), ("flow = { mu = 1.0 }", r"methods\.gfmd\.flow\.mu"),
])
def test_bad_flow_options(line, match):
    with pytest.raises(spec.SpecError, match=match):
        spec.loads(JOB.format(flow=line))


def test_plugin_column_dtypes():
    d = schema.results_dtype([("leak_rate", "float"), ("percolating", "int")])
    assert schema.plugin_columns_of(d) == [("leak_rate", "float"), ("percolating", "int")]
    assert d.names[:len(schema.RESULT_DTYPE.names)] == schema.RESULT_DTYPE.names
    assert all(schema.plugin_columns_of(x.results) == [] for x in schema.LAYOUTS)
    assert schema.layout_of(3, d, False, False) is None  # plug-in columns came with format 5
    assert schema.plugin_columns_of(np.dtype([("status", "i1")])) is None
    from gapsweep.sweep.store import empty_results

    r = empty_results(2, d)
    assert np.isnan(r["leak_rate"]).all() and (r["percolating"] == -1).all()
    from gapsweep.sweep.methods import base

    class Bad(base.Method):
        name = "bad_cols"
        own_columns = {"mean_gap": schema.Column("float", "x")}  # noqa: RUF012
    with pytest.raises(ValueError, match="column of the store itself"):
        base.register(Bad)
    assert "bad_cols" not in base._REGISTRY


def test_flow_on_a_measured_map_with_free_boundaries(tmp_path):
    """The shipped leakage_measured job at one load: a non-periodic map in um and MPa, GFMD with free boundaries,
    the flow with closed sides along axis 0; the row equals flow.solve(periodic=False) on the same gap, in the
    job's units (mu = 1e-9 MPa s, dp = 0.1 MPa)."""
    from gapsweep import jobs, topography

    text = jobs.path("leakage_measured").read_text().replace("sigma0 = [1.0, 2.0, 3.0, 5.0, 7.0, 10.0, 14.0, 20.0]",
                                                            "sigma0 = [5.0]")
    assert "sigma0 = [5.0]" in text
    folder = jobs.path("leakage_measured").parent  # the map lives beside the shipped job
    p = tmp_path / "job.toml"
    p.write_text(text.replace('path = "data/', f'path = "{folder}/data/'))
    runner.run(p, tmp_path / "m.h5", mpi="off", progress="none")
    row = store.read(tmp_path / "m.h5").query("method == 'gfmd'").iloc[0]
    assert row.status == "done" and row.percolating == 1
    topo = topography.load(folder / "data" / "measured_tilted_192x128.npz", key="heights", unit="um",
                           pixel_size=0.5, detrend="plane")
    r = gfmd.solve(topo, sigma0=5.0, e_star=1000.0, interaction="hard_wall", tol=1e-8)
    f = flow.solve(r.gap, length=topo.length, axis=0, viscosity=1e-9, pressure_drop=0.1, periodic=False)
    assert not topo.periodic and row.leak_rate == pytest.approx(f.leak_rate, rel=1e-6)
    assert row.conductance == pytest.approx(f.leak_rate * topo.length[0] / 0.1, rel=1e-6)


def test_flow_enters_cost_and_memory_estimates():
    from gapsweep.sweep import tasks

    on, off = spec.loads(JOB.format(flow="flow = true")), spec.loads(JOB.format(flow=""))
    ton, toff = tasks.expand(on)[0], tasks.expand(off)[0]
    g = methods.get("gfmd")
    assert g.cost(ton) == pytest.approx(g.cost(toff) + 3e-5 * 32 * 32)
    assert g.memory(ton) > g.memory(toff)
    assert ton.task_id != toff.task_id and ton.opt("ext.flow") and toff.opt("ext.flow") is None


def test_a_method_declares_columns_for_some_jobs_only(tmp_path):
    """A method's own columns may depend on the job (Method.job_own_columns): here a theory-like toy method adds
    a column only for the hard-wall law; its values reach the store and the view, other jobs keep the built-in
    table."""
    from gapsweep.sweep.methods import base

    class Toy(base.Method):
        name = "toy_cols"
        order = 50
        own_columns = {"toy_area": schema.Column("float", "a toy quantity"),  # noqa: RUF012
                       "toy_flag": schema.Column("int", "a toy flag")}

        def job_own_columns(self, spec):
            return dict(self.own_columns) if spec.law == "hard_wall" else {}

        def expand(self, spec):
            yield from base.grid_tasks(spec, self.name, seeds=[0], with_hist=False)

        def cost(self, t):
            return 1e-4

        def run(self, t, ctx, prev):
            return schema.TaskResult("done", "", {"toy_area": 2 * t.sigma0, "toy_flag": 1}), None

    base.register(Toy)
    try:
        text = JOB.format(flow="").replace("[methods.gfmd]\nn = 32\ntol = 1e-8\nbackend = \"numpy\"\n",
                                           "[methods.toy_cols]\n")
        p = tmp_path / "job.toml"
        p.write_text(text)
        assert methods.job_columns(spec.load(p)) == [("toy_area", "float"), ("toy_flag", "int")]
        runner.run(p, tmp_path / "t.h5", mpi="off", progress="none")
        df = store.read(tmp_path / "t.h5")
        assert list(df.toy_area) == [2 * s for s in df.sigma0] and list(df.toy_flag) == [1, 1, 1]
        exp = spec.loads(text.replace('[interaction]\nkind = "hard_wall"\n', "").replace(
            "hurst = 0.8\n", "hurst = 0.8\nrho = 0.01\n"))
        assert methods.job_columns(exp) == []
    finally:
        base._REGISTRY.pop("toy_cols", None)


def test_unconverged_flow_makes_the_row_not_converged(tmp_path, monkeypatch):
    """A flow solve that stops short of its tolerance is never stored as done: the row is not_converged and its
    message says why (here forced: Jacobi CG with one iteration); a sealed row (nothing to solve) stays done."""
    import gapsweep.flow

    orig = gapsweep.flow.solve
    monkeypatch.setattr(gapsweep.flow, "solve", lambda *a, **k: orig(*a, **{**k, "solver": "cg", "max_iter": 1}))
    runner.run(_job(tmp_path, "flow = true"), tmp_path / "u.h5", mpi="off", progress="none")
    df = store.read(tmp_path / "u.h5").sort_values("sigma0")
    leaks = df[df.percolating == 1]
    assert len(leaks) >= 1 and (leaks.status == "not_converged").all()
    assert leaks.message.str.startswith("flow: flow solve not converged").all()
    sealed = df[df.percolating == 0]
    assert len(sealed) >= 1 and (sealed.status == "done").all()


def test_report_has_the_leak_figure(tmp_path):
    """`gapsweep report` of a store with the flow columns draws conductance against load with the two
    estimates (analysis/leak.py); its table holds the store's own means over seeds."""
    from gapsweep.analysis import leak, report

    runner.run(_job(tmp_path, "flow = true"), tmp_path / "s.h5", mpi="off", progress="none")
    out = tmp_path / "rep"
    text = report.main([tmp_path / "s.h5"], out).read_text()
    import pandas as pd

    figs = set(pd.read_csv(out / "figures.csv")["figure"])
    assert "leak_flow_test" in figs and (out / "leak_flow_test.png").is_file() and "Leak conductance" in text
    df = store.read(tmp_path / "s.h5").assign(job="flow-test")
    t = leak.table(df, "flow-test")
    g = df[df.method == "gfmd"].sort_values("sigma0")
    np.testing.assert_array_equal(t.conductance.to_numpy(), g.conductance.to_numpy())
    assert not leak.has_flow(df.drop(columns=["conductance"]), "flow-test")
