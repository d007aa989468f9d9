"""``gapsweep run --reuse OTHER.h5`` (issue 28): rows of the same tasks (task id = content hash) that another
store holds ``done`` with a verified checksum are copied instead of run; the result equals a store computed from
scratch (every column but wall time, rank and checksum), the run record names the source, merge and export take
the rows like any other; a damaged source row is not taken."""

from __future__ import annotations

import json
from pathlib import Path

import h5py
import numpy as np
import pytest

from gapsweep import runner, store
from gapsweep.sweep import merge

ROOT = Path(__file__).resolve().parent.parent
JOB = ROOT / "jobs" / "test_theory.toml"
# the same job with a third seed: the rows of seeds 0 and 1 are the same tasks (same ids)
BIGGER = JOB.read_text().replace("seeds = [0, 1]", "seeds = [0, 1, 2]")


def _run(job, path, **kw):
    return runner.run(job, path, progress="none", mpi="off", **kw)


@pytest.fixture(scope="module")
def stores(tmp_path_factory):
    d = tmp_path_factory.mktemp("reuse")
    (d / "big.toml").write_text(BIGGER)
    _run(JOB, d / "small.h5")
    _run(d / "big.toml", d / "fresh.h5")
    return d


def test_reused_rows_equal_fresh_ones(stores, tmp_path):
    out = tmp_path / "big.h5"
    s = _run(stores / "big.toml", out, reuse=[stores / "small.h5"])
    assert s["tasks"] == 72 and s["todo"] == 24 and s["done"] == 24  # only seed 2 was run
    assert store.diff(out, stores / "fresh.h5") == []
    df = store.read(out)
    assert (df.status == "done").all()  # checksums verify: no row reads as damaged
    run = json.loads(store.read_attrs(out)["runs"])[-1]
    assert run["reused"] == {str((stores / "small.h5").absolute()): 48}
    m = tmp_path / "merged.h5"
    counts = merge.merge([out], m)
    assert counts["done"] == 72 and store.diff(m, stores / "fresh.h5") == []
    xr = pytest.importorskip("xarray")
    pytest.importorskip("h5netcdf")
    from gapsweep.sweep import dataset

    nc = dataset.export_netcdf(out, tmp_path / "big.nc")
    assert xr.open_dataset(nc).sizes  # opens


def test_damaged_source_row_is_run_again(stores, tmp_path):
    src = tmp_path / "small.h5"
    src.write_bytes((stores / "small.h5").read_bytes())
    with h5py.File(src, "r+") as f:  # one finished row changed after it was written: its checksum fails
        r = f["results"][3]
        r["mean_gap"] = r["mean_gap"] * 1.5
        f["results"][3] = r
    out = tmp_path / "big.h5"
    s = _run(stores / "big.toml", out, reuse=[src])
    assert s["todo"] == 25  # seed 2 and the damaged row
    assert store.diff(out, stores / "fresh.h5") == []
    assert json.loads(store.read_attrs(out)["runs"])[-1]["reused"] == {str(src.absolute()): 47}


def test_reuse_of_the_store_itself_refused(stores, tmp_path):
    out = tmp_path / "x.h5"
    _run(JOB, out, resume=False)
    with h5py.File(out, "r+") as f:
        r = f["results"][...]
        r["status"][:5] = 0
        f["results"][...] = r
    with pytest.raises(runner.RunError, match="the store being written"):
        _run(JOB, out, resume=True, reuse=[out])
    assert int(np.sum(store.read(out).status == "pending")) == 5  # nothing changed
