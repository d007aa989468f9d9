"""Standard data (gapsweep.dataset via gapsweep.store): a store opened by path as an xarray.Dataset with CF
attributes and seed-independent theory broadcast over seeds, the netCDF4 export read back by xarray and by
netCDF4-python, the tolerant diff, and the kept GFMD fields of chosen tasks."""

from __future__ import annotations

import shutil
import subprocess
from pathlib import Path

import h5py
import numpy as np
import pytest

from gapsweep import dataset, runner, store
from gapsweep.spec import SpecError, loads

xr = pytest.importorskip("xarray")
pytest.importorskip("h5netcdf")

ROOT = Path(__file__).resolve().parents[1]
KEEP = 'keep_fields = { fields = ["gap", "pressure"], sigma0 = [1e-2], seeds = [0] }\n'


def _spec_with_fields() -> str:
    text = (ROOT / "jobs" / "test_mixed.toml").read_text()
    assert 'backend = "numpy"\n' in text
    return text.replace('backend = "numpy"\n', 'backend = "numpy"\n' + KEEP, 1)


@pytest.fixture(scope="module")
def mixed(tmp_path_factory):
    d = tmp_path_factory.mktemp("ds")
    job = d / "mixed_fields.toml"
    job.write_text(_spec_with_fields())
    path = d / "mixed.h5"
    runner.run(job, path, progress="none", mpi="off")
    return path


def test_to_dataset_by_path_cf_attrs_and_theory_broadcast(mixed):
    ds = store.to_dataset(mixed)
    assert set(ds.dims) == {"hurst", "rho", "sigma0", "seed"} and ds.sizes["seed"] == 2
    # Seed-independent theory has no seed dimension, so GFMD - theory is defined at every seed with GFMD data.
    assert "seed" not in ds["theory_paper"].dims and "seed" in ds["theory_discrete"].dims
    diff = ds["gfmd_mean_gap"] - ds["theory_paper"]
    n_gfmd = int(np.isfinite(ds["gfmd_mean_gap"]).sum())
    assert n_gfmd == 6 and int(np.isfinite(diff).sum()) == n_gfmd
    for name, var in {**ds.data_vars, **ds.coords}.items():
        assert var.attrs.get("units"), name
        assert var.attrs.get("long_name"), name
    st = ds["gfmd_status"]
    assert st.dtype == np.int8 and st.attrs["flag_meanings"].split() == ["pending", "done", "failed", "not_converged"]
    assert int((st == 1).sum()) == 6
    assert ds.attrs["Conventions"].startswith("CF-") and ds.attrs["gapsweep_job_name"] == "test-mixed"
    assert len(ds.attrs["gapsweep_spec_sha256"]) == 64 and "versions" in "".join(ds.attrs)
    # The analysis wrapper opens it by path too.
    from gapsweep.analysis import dataset as adataset

    assert adataset.to_dataset(mixed)["gfmd_mean_gap"].equals(ds["gfmd_mean_gap"])


def test_export_netcdf_opens_in_xarray_and_netcdf4(mixed, tmp_path):
    out = store.export_netcdf(mixed, tmp_path / "mixed.nc")
    ds = store.to_dataset(mixed)
    back = xr.open_dataset(out, engine="h5netcdf")
    np.testing.assert_array_equal(back["gfmd_mean_gap"].values, ds["gfmd_mean_gap"].values)
    np.testing.assert_array_equal(back["gfmd_status"].values, ds["gfmd_status"].values)
    assert back["theory_paper"].attrs["long_name"] == ds["theory_paper"].attrs["long_name"]
    back.close()
    nc4 = pytest.importorskip("netCDF4")
    with nc4.Dataset(out) as f:
        assert f.data_model == "NETCDF4" and "gfmd_mean_gap" in f.variables
        assert f.variables["sigma0"].long_name.startswith("applied mean pressure")
    if shutil.which("ncdump"):
        r = subprocess.run(["ncdump", "-h", str(out)], capture_output=True, text=True)
        assert r.returncode == 0 and "gfmd_mean_gap" in r.stdout
    with pytest.raises(FileExistsError, match="--overwrite"):
        store.export_netcdf(mixed, out)


def test_diff_with_tolerance(mixed, tmp_path):
    b = tmp_path / "b.h5"
    shutil.copy(mixed, b)
    assert store.diff(mixed, b) == []
    with h5py.File(b, "r+") as f:
        r = f["results"][...]
        i = int(np.flatnonzero(np.isfinite(r["mean_gap"]))[0])
        r["mean_gap"][i] *= 1 + 4e-15  # what summing in another order does
        f["results"][...] = r
    exact = store.diff(mixed, b)
    assert len(exact) == 1 and "results.mean_gap differs in 1 rows" in exact[0]
    assert store.diff(mixed, b, rtol=1e-12) == []
    with h5py.File(b, "r+") as f:
        r = f["results"][...]
        r["mean_gap"][i] *= 1 + 1e-6
        f["results"][...] = r
    loose = store.diff(mixed, b, rtol=1e-12)
    assert len(loose) == 1 and "mean_gap" in loose[0] and "max |diff|" in loose[0]
    with pytest.raises(ValueError, match="rtol"):
        store.diff(mixed, b, rtol=-1.0)


def test_kept_fields_readable_and_physical(mixed):
    fields = store.open_fields(mixed)
    df = store.read(mixed)
    kept = df[(df.method == "gfmd") & np.isclose(df.sigma0, 1e-2) & (df.seed == 0)]
    assert set(fields) == set(kept.task_id) and len(fields) == 1
    tid = kept.task_id.iloc[0]
    f = fields[tid]
    assert set(f.data_vars) == {"gap", "pressure"} and f["gap"].dims == ("x", "y") and f["gap"].shape == (64, 64)
    assert f["gap"].attrs["long_name"] and f["gap"].attrs["units"] == "1"
    # docs/model.md M3: the mean gap is the mean of the gap field; the mean pressure carries the load.
    assert float(f["gap"].mean()) == pytest.approx(float(kept.mean_gap.iloc[0]), rel=1e-12)
    assert float(f["pressure"].mean()) == pytest.approx(1e-2, rel=1e-4)
    with h5py.File(dataset.fields_dir(mixed) / f"{tid}.nc", "r") as h:
        assert h["gap"].compression == "gzip" and h["gap"].chunks is not None


def test_keep_fields_spec_errors():
    text = (ROOT / "jobs" / "test_mixed.toml").read_text()
    bad = text.replace('backend = "numpy"\n', 'backend = "numpy"\nkeep_fields = { fields = ["stress"] }\n', 1)
    with pytest.raises(SpecError, match=r"keep_fields\.fields\[0\].*gap"):
        loads(bad)
    bad = text.replace('backend = "numpy"\n', 'backend = "numpy"\nkeep_fields = { fields = ["gap"], sigma = [1] }\n')
    with pytest.raises(SpecError, match="sigma"):
        loads(bad)


def test_kept_fields_write_error_stops_the_run_with_the_row_pending(tmp_path):
    """A file where the .fields folder should be: the solved row must not become a permanent 'failed' row; the
    run exits 1 (store failure) and --resume finishes it once the folder can be written (issue 19 item 5)."""
    import subprocess
    import sys

    job = tmp_path / "mixed_fields.toml"
    job.write_text(_spec_with_fields())
    path = tmp_path / "m.h5"
    dataset.fields_dir(path).write_text("not a folder")
    p = subprocess.run([sys.executable, "-m", "gapsweep", "run", str(job), "--store", str(path), "--mpi", "off",
                        "--progress", "none"], capture_output=True, text=True, timeout=300)
    assert p.returncode == 1, p.stdout + p.stderr
    assert "kept fields" in p.stderr and "Traceback" not in p.stderr
    df = store.read(path)
    assert "failed" not in set(df.status)
    kept = df[(df.method == "gfmd") & np.isclose(df.sigma0, 1e-2) & (df.seed == 0)]
    assert (kept.status == "pending").all()
    dataset.fields_dir(path).unlink()
    p = subprocess.run([sys.executable, "-m", "gapsweep", "run", str(job), "--store", str(path), "--mpi", "off",
                        "--progress", "none", "--resume"], capture_output=True, text=True, timeout=300)
    assert p.returncode == 0, p.stderr
    assert set(store.read(path).status) == {"done"} and len(store.open_fields(path)) == 1


def test_overwrite_with_another_spec_removes_the_old_fields(tmp_path, mixed):
    import shutil

    path = tmp_path / "m.h5"
    shutil.copy(mixed, path)
    shutil.copytree(dataset.fields_dir(mixed), dataset.fields_dir(path))
    (dataset.fields_dir(path) / "notes.txt").write_text("mine")  # not the run's: must stay
    assert len(store.open_fields(path)) == 1
    runner.run(ROOT / "jobs" / "test_mixed.toml", path, progress="none", mpi="off", overwrite=True)
    assert store.open_fields(path) == {}
    assert (dataset.fields_dir(path) / "notes.txt").read_text() == "mine"


def test_cf_units_angstrom_is_not_ampere():
    """A job in Angstrom ("A") gets the UDUNITS spelling "angstrom" in the dataset (CF "A" is the ampere)."""
    xr = pytest.importorskip("xarray")
    from gapsweep.sweep.dataset import apply_units
    from gapsweep.sweep.fields import _length_units, cf_unit

    assert cf_unit("A") == "angstrom" and cf_unit("MPa A") == "MPa angstrom" and cf_unit("um") == "um"
    assert _length_units({"length_unit": "A"}) == {"units": "angstrom"}
    ds = xr.Dataset({"g": ("x", [1.0], {"units": "1", "reference_unit": "L"}),
                     "e": ("x", [1.0], {"units": "1", "reference_unit": "E* L"})})
    ds = apply_units(ds, {"length": "A", "pressure": "MPa"})
    assert ds.g.attrs["units"] == "angstrom" and ds.e.attrs["units"] == "MPa angstrom"
