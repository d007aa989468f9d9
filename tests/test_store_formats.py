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
            "format4": ("4", "576c959")}
# The fingerprints of the layouts (schema.Layout.digest: columns, types, offsets, checksum kinds, version). A
# layout once written never changes: never edit a line here; a new layout is a new line with a new version.
FROZEN = {"1": "e37c64403432c69f", "2": "0b19de7ef5d24b33", "3a": "4a4f2341e18342ea", "3b": "bb06a6b192d3bf2c",
          "3c": "d45f8072119c04f1", "3d": "b073084f8d5885f9", "4": "264b0f229dcda8c1",
          "5": "653ac3490dcb004c"}  # issue 40 item 5: the column algorithm_version


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
    assert ("no attribute checksums" in text) == (layout != "4")
    assert ("no row checksums" in text) == (rep.layout.row_checksums != "column")
    assert f"format {layout}" in text or layout == "4"
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


@pytest.mark.parametrize("name", ["format1", "format3b", "format3d", "format4"])
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
