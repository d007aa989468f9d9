"""Every store layout ever written opens, verifies, resumes and merges (docs/store.md "Formats"), and the
results table cannot change without a new format version.

The fixtures in tests/data/stores were written by the commits that wrote each layout (README.md there): one job,
two theory rows and two Fokker-Planck rows, all done. Their values are the reference: a resume of a fixture
whose rows were set back to pending must reproduce them (the same job, deterministic methods: to 1e-12)."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import h5py
import numpy as np
import pytest

from gapsweep import store
from gapsweep.sweep import methods as registry
from gapsweep.sweep import schema, storecheck

DATA = Path(__file__).resolve().parent / "data" / "stores"
JOB = DATA / "fixture.toml"
# fixture file -> its layout (gapsweep.sweep.schema.LAYOUTS) and the commit that wrote it
FIXTURES = {"format1": ("1", "a678e7c"), "format2": ("2", "449a5c7"), "format3a": ("3a", "ca6983b"),
            "format3b": ("3b", "de98333"), "format3c": ("3c", "6bc25eb"), "format3d": ("3d", "a6b475f"),
            "format4": ("4", "576c959"), "format5": ("5", "4ab0def")}
# The fingerprints of the layouts (schema.Layout.digest: columns, types, offsets, checksum kinds, version). A
# layout once written never changes: never edit a line here; a new layout is a new line with a new version.
FROZEN = {"1": "e37c64403432c69f", "2": "0b19de7ef5d24b33", "3a": "4a4f2341e18342ea", "3b": "bb06a6b192d3bf2c",
          "3c": "d45f8072119c04f1", "3d": "b073084f8d5885f9", "4": "264b0f229dcda8c1",
          "5": "c67791f88e6b88d2"}  # issues 36 and 40: h_rms_spectrum, g_rms_spectrum, algorithm_version


def _copy(name: str, tmp_path: Path) -> Path:
    p = tmp_path / f"{name}.h5"
    shutil.copy(DATA / f"{name}.h5", p)
    return p


def _values(path: Path) -> np.ndarray:
    df = store.read(path)
    return df.sort_values("task_id")[["mean_gap", "h_rms", "g_rms"]].to_numpy()


REFERENCE = None


def _reference() -> np.ndarray:
    global REFERENCE
    if REFERENCE is None:
        REFERENCE = _values(DATA / "format4.h5")
    return REFERENCE


# --- the layout table -------------------------------------------------------------------------------------

def test_layouts_are_frozen_and_the_writer_uses_the_last():
    """A results (or task) table that changes without a new layout and version fails here: the writer's table
    must be the last layout's, whose fingerprint is frozen above; a new layout needs a new version."""
    assert [x.name for x in schema.LAYOUTS] == list(FROZEN)
    for x in schema.LAYOUTS:
        assert x.digest() == FROZEN[x.name], f"layout {x.name} changed: add a new layout and version instead"
    cur = schema.CURRENT_LAYOUT
    assert cur.results == schema.RESULT_DTYPE and cur.version == schema.FORMAT_VERSION and cur.integrity
    # one version per layout from format 4 on (the four layouts of format 3 are history, told apart by tables)
    new = [x.version for x in schema.LAYOUTS if x.version >= 4]
    assert len(new) == len(set(new)) and max(x.version for x in schema.LAYOUTS) == schema.FORMAT_VERSION
    assert len({x.digest() for x in schema.LAYOUTS}) == len(schema.LAYOUTS)


def test_a_new_column_changes_the_fingerprint():
    """The check above can fail: the current layout with one more column (what be10c32 did to format 3) has
    another fingerprint."""
    cur = schema.CURRENT_LAYOUT
    wider = np.dtype([*cur.results.descr, ("new_quantity", "f8")])
    grown = schema.Layout(cur.name, cur.version, wider, cur.row_checksums, cur.integrity, "")
    assert grown.digest() != FROZEN[cur.name]


def test_result_columns_are_the_plugins_columns():
    """Every result column is filled by the sweep itself or declared by a method plug-in (``columns``; the
    registry refuses a column that is not in the table): the layout is what the plug-ins declare."""
    declared = set(schema.COMMON_RESULTS)
    for m in registry.all_methods().values():
        declared |= set(m.columns)
    assert set(schema.FLOAT_RESULTS + schema.INT_RESULTS) == declared


# --- the fixtures -----------------------------------------------------------------------------------------

@pytest.mark.parametrize("name", list(FIXTURES))
def test_fixture_reads_and_verifies(name, tmp_path):
    """Each layout is recognised as itself, reads with the same values, and ``status`` says what it verifies."""
    layout, commit = FIXTURES[name]
    p = _copy(name, tmp_path)
    attrs = store.read_attrs(p)
    assert attrs["git_commit"].startswith(commit)  # written by the commit the README names
    with store.open_read(p) as f:
        rep = storecheck.check(f, p)
    assert rep.layout.name == layout and rep.damaged == [] and rep.rerun == []
    assert np.allclose(_values(p), _reference(), rtol=1e-12, atol=0)
    text = store.status(p)
    assert ("no attribute checksums" in text) == (layout not in ("4", "5"))
    assert ("no row checksums" in text) == (rep.layout.row_checksums != "column")
    assert f"format {layout}" in text or layout in ("4", "5")
    assert len(store.read_histograms(p)) == 2  # the Fokker-Planck rows


@pytest.mark.parametrize("name", list(FIXTURES))
def test_fixture_resumes_in_its_own_layout(name, tmp_path):
    """Rows set back to pending are run again into the store's own layout (no column added or dropped), to
    the fixture's values; a format-4 store's checksums stay valid through the new run record."""
    from gapsweep import runner

    p = _copy(name, tmp_path)
    with h5py.File(p, "r+") as f:
        dtype = f["results"].dtype
        r = f["results"][...]
        r["status"][[1, 3]] = schema.STATUS["pending"]
        f["results"][...] = r
    runner.run(JOB, p, resume=True, progress="none", mpi="off")
    with store.open_read(p) as f:
        assert f["results"].dtype == dtype
        rep = storecheck.check(f, p)
    assert rep.layout.name == FIXTURES[name][0] and rep.damaged == []
    assert (store.read(p)["status"] == "done").all()
    assert np.allclose(_values(p), _reference(), rtol=1e-12, atol=0)
    assert len(json.loads(store.read_attrs(p)["runs"])) == 2


def test_fixtures_merge(tmp_path):
    """All layouts merged into one store (format 4): no conflict, every row done with the fixtures' values; and
    each layout merged alone."""
    shards = [_copy(n, tmp_path) for n in FIXTURES]
    out = tmp_path / "merged.h5"
    counts = store.merge(shards, out, on_conflict="first")
    assert counts["done"] == 4 and counts["conflicts"] == 0
    with store.open_read(out) as f:
        assert storecheck.check(f, out).layout is schema.CURRENT_LAYOUT
    assert np.allclose(_values(out), _reference(), rtol=1e-12, atol=0)
    for s in shards:
        one = tmp_path / f"one-{s.name}"
        assert store.merge([s], one)["done"] == 4
        assert np.allclose(_values(one), _reference(), rtol=1e-12, atol=0)


@pytest.mark.parametrize("name", ["format1", "format3b", "format3d", "format4", "format5"])
def test_fixture_exports(name, tmp_path):
    pytest.importorskip("xarray")
    pytest.importorskip("netCDF4")
    from gapsweep.sweep.dataset import export_netcdf

    out = export_netcdf(_copy(name, tmp_path), tmp_path / "x.nc")
    assert out.stat().st_size > 0


def test_unknown_layout_is_one_line(tmp_path):
    """A format-3d table under format_version 7 (a newer gapsweep, or a damaged attribute of a store without
    attribute checksums): refused in one line naming both."""
    p = _copy("format3d", tmp_path)
    with h5py.File(p, "r+") as f:
        f.attrs["format_version"] = 7
    with pytest.raises(store.StoreError, match=r"format_version 7 with a /results table of format 3d"):
        store.read(p)


def test_resumed_old_layout_keeps_its_h_rms_meaning():
    """Format 5 changed what a file map's h_rms and g_rms are (the heights solved; the spectrum's moved to
    h_rms_spectrum, g_rms_spectrum). A row written into an older layout (a resumed store) keeps that layout's
    meaning, the spectrum's, so one column holds one quantity within a store; a synthetic surface's row (no
    spectral columns) is written as it is."""
    from gapsweep.sweep.schema import TaskResult

    res = TaskResult("done", "", {"mean_gap": 0.5, "h_rms": 1.0, "g_rms": 3.0, "h_rms_spectrum": 2.0,
                                  "g_rms_spectrum": 4.0})
    new = store.result_row(res, schema.RESULT_DTYPE)[0]
    assert (new["h_rms"], new["g_rms"], new["h_rms_spectrum"], new["g_rms_spectrum"]) == (1.0, 3.0, 2.0, 4.0)
    for layout in schema.LAYOUTS[:-1]:
        old = store.result_row(res, layout.results)[0]
        assert (old["h_rms"], old["g_rms"], old["mean_gap"]) == (2.0, 4.0, 0.5), layout.name
    synthetic = TaskResult("done", "", {"h_rms": 1.0, "g_rms": 3.0, "h_rms_spectrum": float("nan"),
                                        "g_rms_spectrum": float("nan")})
    assert store.result_row(synthetic, schema.LAYOUTS[-2].results)[0]["h_rms"] == 1.0


def test_old_file_map_store_reads_and_merges_into_format5_meaning(tmp_path):
    """format4_filemap.h5 was written by bb77f13 (layout 4) from filemap.toml: a mean-detrended non-periodic crop,
    GFMD and Persson rows whose h_rms, g_rms are the map's spectral moments. It still reads as written; merged
    into a format-5 store, those values move to h_rms_spectrum, g_rms_spectrum, and h_rms, g_rms become those
    of the heights solved (computed from the map), as a format-5 run writes them."""
    from gapsweep.surfaces import topography
    from gapsweep.sweep.context import _rms_and_spectrum

    p = tmp_path / "old.h5"
    shutil.copy(DATA / "format4_filemap.h5", p)
    for name in ("filemap.toml", "filemap_crop.npy"):
        shutil.copy(DATA / name, tmp_path / name)
    with h5py.File(p, "r+") as f:  # the map next to the copy (the fixture names the folder it was written in)
        f.attrs["spec_dir"] = str(tmp_path)
        store.seal_attrs(f)
    assert store.read_attrs(p)["git_commit"].startswith("bb77f13")
    old = store.read(p).sort_values("task_id")
    assert set(old.status) == {"done"} and len(old) == 4
    topo = topography.load(tmp_path / "filemap_crop.npy", unit="um", pixel_size=0.5, detrend="mean",
                           periodic=False)
    h, g, hs, gs = _rms_and_spectrum(topo.heights, {"kind": "file", "length": list(topo.length),
                                                    "periodic": False})
    assert np.allclose(old.h_rms, hs, rtol=1e-12) and np.allclose(old.g_rms, gs, rtol=1e-12)  # the old meaning
    assert abs(h / hs - 1) > 0.1  # and it differs from the new one
    out = tmp_path / "merged.h5"
    assert store.merge([p], out)["done"] == 4
    new = store.read(out).sort_values("task_id")
    assert np.allclose(new.h_rms, h, rtol=1e-12) and np.allclose(new.g_rms, g, rtol=1e-12)
    assert np.allclose(new.h_rms_spectrum, old.h_rms, rtol=0) and np.allclose(new.g_rms_spectrum, old.g_rms, rtol=0)
    assert np.array_equal(new.mean_gap.to_numpy(), old.mean_gap.to_numpy())
    assert np.isclose(float(np.std(topo.heights)), h, rtol=1e-12)
