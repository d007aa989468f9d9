"""Issue 40 item 5: ``--reuse`` carries kept fields and copies only rows of the current algorithm.

* Every method plug-in declares ``ALGORITHM_VERSION``, stored per row (results column ``algorithm_version``, store
  format 5; a row of an older store has none: -1, unknown). ``--reuse`` copies a row only when its version is the
  plug-in's current one; ``--reuse-older`` copies the others too, and the run record and ``gapsweep status`` name
  them. Before, rows were keyed by the task alone: a row of an older solver was copied as current.
* A reused GFMD row whose task keeps fields brings its fields file: the store (and its ``.fields`` folder) equals
  one computed from scratch; a source without the file does not lend the row. Before, the fields were left
  behind.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import h5py
import numpy as np
import pytest

from gapsweep import store
from gapsweep.sweep import methods as registry
from gapsweep.sweep.fields import fields_dir
from tests.storekit import run_job, small_job

ROOT = Path(__file__).resolve().parents[1]
THEORY = ROOT / "tests" / "data" / "stores" / "fixture.toml"  # two theory and two Fokker-Planck rows


def _gfmd_job(seeds: str) -> str:
    """Two loads of GFMD keeping the gap and pressure at sigma0 = 1e-2, on the seeds ``seeds`` (a TOML array)."""
    return small_job("reuse-fields", seeds=seeds, methods="""
[methods.gfmd]
n = 64
backend = "numpy"
keep_fields = { fields = ["gap", "pressure"], sigma0 = [1e-2] }
""")


@pytest.fixture(scope="module")
def theory(tmp_path_factory):
    d = tmp_path_factory.mktemp("reuse-version")
    run_job(THEORY, d / "src.h5")
    return d


def test_rows_carry_the_algorithm_version(theory):
    df = store.read(theory / "src.h5")
    for m, g in df.groupby("method"):
        assert (g.algorithm_version == registry.get(m).algorithm_version).all()
    import importlib

    for m in registry.all_methods():  # each plug-in module declares it, and its method carries it
        mod = importlib.import_module(type(registry.get(m)).__module__)
        assert isinstance(mod.ALGORITHM_VERSION, int) and registry.get(m).algorithm_version == mod.ALGORITHM_VERSION


def test_rows_of_another_version_are_run_again(theory, tmp_path, monkeypatch, capsys):
    """The theory plug-in's version bumped: its rows are not copied (run again, now with version 2); with
    --reuse-older they are copied, named in the run record and by status."""
    monkeypatch.setattr(registry.get("theory"), "algorithm_version", 2)
    out = tmp_path / "a.h5"
    s = run_job(THEORY, out, reuse=[theory / "src.h5"])
    assert s["todo"] == 2  # the two theory rows ran; the Fokker-Planck rows (same version) were copied
    df = store.read(out)
    assert (df[df.method == "theory"].algorithm_version == 2).all()
    run = json.loads(store.read_attrs(out)["runs"])[-1]
    assert list(run["reused"].values()) == [2] and "reused_older" not in run
    out2 = tmp_path / "b.h5"
    s = run_job(THEORY, out2, reuse=[theory / "src.h5"], reuse_older=True)
    assert s["todo"] == 0
    run = json.loads(store.read_attrs(out2)["runs"])[-1]
    assert list(run["reused"].values()) == [4] and list(run["reused_older"].values()) == [2]
    text = store.status(out2)
    assert "--reuse-older" in text and "2 theory row(s) computed by version(s) [1] (current 2)" in text, text
    assert store.diff(out2, theory / "src.h5") == []  # the copied rows are the source's, version included


def test_rows_without_a_version_count_as_older(theory, tmp_path):
    """A format-4 store (before the column) lends no row unless --reuse-older; status calls them unknown."""
    old = ROOT / "tests" / "data" / "stores" / "format4.h5"
    s = run_job(THEORY, tmp_path / "a.h5", reuse=[old])
    assert s["todo"] == 4
    s = run_job(THEORY, tmp_path / "b.h5", reuse=[old], reuse_older=True)
    assert s["todo"] == 0
    text = store.status(tmp_path / "b.h5")
    assert "row(s) of unknown algorithm version" in text and "--reuse-older" in text


def _fields(path: Path) -> dict[str, dict[str, np.ndarray]]:
    out = {}
    for f in sorted(fields_dir(path).glob("*.nc")):
        with h5py.File(f, "r") as h:
            out[f.name] = {k: h[k][...] for k in ("gap", "pressure")}
    return out


def test_reuse_carries_kept_fields(tmp_path):
    small, big = tmp_path / "small.toml", tmp_path / "big.toml"
    small.write_text(_gfmd_job("[0]"))
    big.write_text(_gfmd_job("[0, 1]"))
    run_job(small, tmp_path / "small.h5")
    run_job(big, tmp_path / "fresh.h5")
    assert len(_fields(tmp_path / "small.h5")) == 1 and len(_fields(tmp_path / "fresh.h5")) == 2
    s = run_job(big, tmp_path / "reused.h5", reuse=[tmp_path / "small.h5"])
    assert s["todo"] == 2  # seed 1 ran, seed 0 was copied with its fields file
    assert store.diff(tmp_path / "reused.h5", tmp_path / "fresh.h5") == []
    a, b = _fields(tmp_path / "reused.h5"), _fields(tmp_path / "fresh.h5")
    assert a.keys() == b.keys()
    for k in a:
        for v in ("gap", "pressure"):
            np.testing.assert_array_equal(a[k][v], b[k][v])
    # a source without the fields file of a row that keeps fields does not lend that row
    src = tmp_path / "nofields.h5"
    shutil.copy(tmp_path / "small.h5", src)
    s = run_job(big, tmp_path / "again.h5", reuse=[src])
    assert s["todo"] == 3 and len(_fields(tmp_path / "again.h5")) == 2
