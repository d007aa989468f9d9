"""Measured maps through the sweep (issue 20; docs/jobs.md "Measured maps"): the worked example
jobs/measured_map.toml -- a rectangular (192 x 128), tilted, non-periodic map in micrometres with E* in MPa --
solved with free boundaries, Persson's theory from the map's spectrum taken right for a finite map, units in the
store, the dataset and the netCDF export, and no placeholder dimensions. References are independent calls of the
physics (gapsweep.gfmd.solve on the loaded map; theory.spectrum.map_spectrum) and the parent surface's exact rms
slope (0.1, scripts/make_measured_map.py)."""

from __future__ import annotations

import json
import math
from pathlib import Path

import pytest

from gapsweep import gfmd, runner, spec, store
from gapsweep.surfaces import topography

ROOT = Path(__file__).resolve().parents[1]
JOB = ROOT / "jobs" / "measured_map.toml"


@pytest.fixture(scope="module")
def measured(tmp_path_factory):
    path = tmp_path_factory.mktemp("mm") / "mm.h5"
    runner.run(JOB, path, progress="none", mpi="off")
    return path


def _map():
    return topography.load(ROOT / "jobs" / "data" / "measured_tilted_192x128.npz", key="heights", unit="um",
                           pixel_size=0.5, detrend="plane", periodic=False)


def test_rectangular_free_boundary_rows_equal_a_direct_solve(measured):
    df = store.read(measured)
    assert set(df.status) == {"done"} and len(df) == 10
    topo = _map()
    assert topo.shape == (192, 128) and topo.length == pytest.approx((96.0, 64.0))
    g = df[df.method == "gfmd"].set_index("sigma0")
    for s0 in (2.0, 20.0):
        ref = gfmd.solve(topo.heights, sigma0=s0, interaction="hard_wall", e_star=1000.0, length=topo.length,
                         tol=1e-8, backend="numpy", periodic=False)
        # the sweep warm-starts along the chain; both are converged to tol 1e-8
        assert g.mean_gap[s0] == pytest.approx(ref.mean_gap, rel=1e-6)
        assert g.contact_area[s0] == pytest.approx(ref.contact_area, abs=2.0 / topo.heights.size)
    # free boundaries, not periodic: the periodic solve of the same map differs by far more than the tolerance
    per = gfmd.solve(topo.heights, sigma0=20.0, interaction="hard_wall", e_star=1000.0, length=topo.length,
                     tol=1e-8, backend="numpy", periodic=True)
    assert abs(per.mean_gap - g.mean_gap[20.0]) > 1e-3 * abs(g.mean_gap[20.0])


def test_persson_uses_the_maps_own_slope_not_the_edge_jump(measured):
    df = store.read(measured)
    th = df[df.method == "theory"]
    # the parent surface's rms slope is 0.1 (the map is a crop of it, tilted): within 3 %, where the plain FFT of
    # the detrended map counts the edge jump (about 0.125)
    assert th.g_rms_spectrum.iloc[0] == pytest.approx(0.1, rel=0.03)
    from gapsweep.theory import persson
    from gapsweep.theory.spectrum import map_spectrum

    h = _map().heights
    assert map_spectrum(h, (96.0, 64.0), periodic=True).g_rms > 1.15 * th.g_rms_spectrum.iloc[0]  # a plain FFT

    for s0, area in zip(th.sigma0, th.contact_area):
        ref = persson.contact_area(s0, heights=h, length=(96.0, 64.0), e_star=1000.0, periodic=False)
        assert area == pytest.approx(float(ref), rel=1e-12)


def test_units_carried_to_store_dataset_and_netcdf(measured, tmp_path):
    assert json.loads(store.read_attrs(measured)["units"]) == {"length": "um", "pressure": "MPa"}
    pytest.importorskip("xarray")
    ds = store.to_dataset(measured)
    assert set(ds.dims) == {"sigma0"}  # no placeholder hurst = 0, rho = 0 or seed = 0 for a hard-wall map
    assert ds.sigma0.attrs["units"] == "MPa" and ds.gfmd_mean_gap.attrs["units"] == "um"
    assert ds.persson_mean_gap.attrs["units"] == "um" and ds.gfmd_elastic_energy.attrs["units"] == "MPa um"
    assert ds.gfmd_contact_area.attrs["units"] == "1"
    pytest.importorskip("h5netcdf")
    import xarray as xr

    out = store.export_netcdf(measured, tmp_path / "mm.nc")
    with xr.open_dataset(out) as nc:
        assert nc.sigma0.attrs["units"] == "MPa" and nc.gfmd_mean_gap.attrs["units"] == "um"


def test_spec_keys_of_measured_maps():
    text = JOB.read_text()
    js = spec.loads(text, base=JOB.parent)
    assert js.surface["periodic"] is False and js.surface["length"] == [96.0, 64.0]
    assert js.surface["shape"] == [192, 128] and js.units() == {"length": "um", "pressure": "MPa"}
    assert js.methods["gfmd"]["n"] == [192]
    # the file's edges decide when the spec does not: this map is not periodic
    js2 = spec.loads(text.replace("periodic = false\n", ""), base=JOB.parent)
    assert js2.surface["periodic"] is False
    js3 = spec.loads(text.replace("periodic = false\n", "periodic = true\n"), base=JOB.parent)
    assert js3.surface["periodic"] is True and js3.sha256 != js.sha256
    with pytest.raises(spec.SpecError, match=r"methods\.gfmd\.seeds"):
        spec.loads(text.replace('backend = "numpy"\n', 'backend = "numpy"\nseeds = [0, 1]\n'), base=JOB.parent)
    with pytest.raises(spec.SpecError, match=r"material\.pressure_unit"):
        spec.loads(text.replace('pressure_unit = "MPa"', 'pressure_unit = "psi"'), base=JOB.parent)
    with pytest.raises(spec.SpecError, match=r"surface\.periodic"):
        spec.loads(text.replace("periodic = false", 'periodic = "no"'), base=JOB.parent)


def test_kept_fields_of_a_rectangular_map_carry_its_axes_and_units(tmp_path):
    pytest.importorskip("xarray")
    pytest.importorskip("h5netcdf")
    job = tmp_path / "mm.toml"
    text = JOB.read_text().replace('path = "data/', f'path = "{ROOT / "jobs" / "data"}/')
    job.write_text(text.replace('backend = "numpy"\n', 'backend = "numpy"\nkeep_fields = { fields = ["gap", '
                                '"pressure"], sigma0 = [5.0] }\n'))
    path = tmp_path / "mm.h5"
    runner.run(job, path, progress="none", mpi="off")
    (f,) = store.open_fields(path).values()
    assert f.gap.shape == (192, 128) and f.x.size == 192 and f.y.size == 128
    assert f.x[-1] == pytest.approx(96.0 - 0.25) and f.y[-1] == pytest.approx(64.0 - 0.25)
    assert f.gap.attrs["units"] == "um" and f.pressure.attrs["units"] == "MPa"
    assert f.attrs["interaction"] == "hard_wall"
    assert math.isclose(float(f.pressure.mean()), 5.0, rel_tol=1e-6)


def test_stored_h_rms_is_that_of_the_heights_solved(tmp_path):
    """issue 36 item 2: a map's ``h_rms`` and ``g_rms`` columns are those of the heights GFMD solves (after
    detrending), not the spectrum's moments, which have their own columns ``h_rms_spectrum`` and
    ``g_rms_spectrum`` (theory.spectrum.map_spectrum, what Persson's theory uses). A crop of a surface with
    roughness up to its whole box, mean-detrended, not periodic: there the two h_rms differ by ~1.8x."""
    import numpy as np

    from gapsweep.surface import self_affine
    from gapsweep.theory.spectrum import map_spectrum

    h = self_affine(256, 0.8, lambda_l=1.0, lambda_s=4 / 256, seed=2)[:64, :48] * 100.0  # um
    np.save(tmp_path / "crop.npy", h)
    job = tmp_path / "crop.toml"
    job.write_text('[job]\nname = "crop"\n[grid]\nsigma0 = [2.0]\n[surface]\nkind = "file"\npath = "crop.npy"\n'
                   'unit = "um"\npixel_size = 0.390625\ndetrend = "mean"\nperiodic = false\n[interaction]\n'
                   'kind = "hard_wall"\n[material]\ne_star = 1000.0\npressure_unit = "MPa"\n[methods.gfmd]\n'
                   'tol = 1e-8\nbackend = "numpy"\n[methods.theory]\nforms = ["persson"]\n')
    path = tmp_path / "crop.h5"
    runner.run(job, path, progress="none", mpi="off")
    df = store.read(path)
    assert set(df.status) == {"done"}
    solved = topography.load(tmp_path / "crop.npy", unit="um", pixel_size=0.390625, detrend="mean",
                             periodic=False)
    ms = map_spectrum(solved.heights, solved.length, periodic=False)
    h_solved = float(np.std(solved.heights))
    dx, dy = solved.pixel_size
    g_solved = math.sqrt(np.mean((np.diff(solved.heights, axis=0) / dx) ** 2)
                         + np.mean((np.diff(solved.heights, axis=1) / dy) ** 2))
    assert h_solved > 1.3 * ms.h_rms  # the case the item is about: the two differ
    for _, row in df.iterrows():  # the GFMD row and the Persson row alike
        assert row.h_rms == pytest.approx(h_solved, rel=1e-12)
        assert row.g_rms == pytest.approx(g_solved, rel=1e-12)
        assert row.h_rms_spectrum == pytest.approx(ms.h_rms, rel=1e-12)
        assert row.g_rms_spectrum == pytest.approx(ms.g_rms, rel=1e-12)
    rec = json.loads(store.read_attrs(path)["surface_map"])
    assert rec["h_rms"] == pytest.approx(h_solved, rel=1e-12) and rec["g_rms"] == pytest.approx(g_solved, rel=1e-12)
    # the report finds the map again by its rms height (the new h_rms), and draws it
    from gapsweep.analysis import contact, report

    df, _, prov = report.load([path])
    info = contact.job_infos(df, prov)["crop"]
    assert not any("not the one the job ran" in n for n in info.get("notes", [])), info.get("notes")
    assert info.get("heights") is not None and np.array_equal(info["heights"], solved.heights)
