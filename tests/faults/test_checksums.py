"""Row checksums (store format 3, docs/store.md "Checksums"; issue 19 item 2): a changed byte anywhere in a
written row -- a result value, a task parameter, a histogram, a status byte, swapped task rows, NaN histogram
edges -- is found by `status` (naming the rows), re-run by `--resume` (which restores the reference store), and
refused by `merge` and `export` unless `--skip-damaged`. Stores without checksums (formats 1 and 2) still open.
Each damage below passed every check of the code before checksums. ``status``, ``merge`` and ``export`` run in this
process (``gs_here``: ``cli.main``, its exit code and output); the runs stay child processes."""

from __future__ import annotations

import shutil

import h5py
import numpy as np
import pytest

from gapsweep import store

from .conftest import JOBS, gs, gs_here, one_line_error


def _rows(h, method):
    return [i for i, m in enumerate(h["tasks"].fields("method")[...]) if m.decode() == method]


def _value(p):  # a done theory row's mean gap, one bit of the mantissa
    with h5py.File(p, "r+") as h:
        i = _rows(h, "theory")[1]
        r = h["results"][i]
        r["mean_gap"] = np.nextafter(r["mean_gap"], np.inf)
        h["results"][i] = r
    return [i]


def _param(p):  # a done row's sigma0 in /tasks
    with h5py.File(p, "r+") as h:
        i = _rows(h, "sde")[0]
        t = h["tasks"][i]
        t["sigma0"] = t["sigma0"] * (1 + 1e-12)
        h["tasks"][i] = t
    return [i]


def _hist(p):  # one bin of an SDE histogram (still positive, finite: the old check passes it)
    with h5py.File(p, "r+") as h:
        i = _rows(h, "sde")[2]
        d = h["histograms/density"][i]
        k = int(np.argmax(d))
        d[k] *= 1.01
        h["histograms/density"][i] = d
    return [i]


def _status(p):  # a done row's status byte says not_converged (a known code: the old check passes it)
    with h5py.File(p, "r+") as h:
        i = _rows(h, "theory")[0]
        r = h["results"][i]
        r["status"] = 3
        h["results"][i] = r
    return [i]


def _swap(p):  # two rows of /tasks swapped
    with h5py.File(p, "r+") as h:
        i, j = _rows(h, "sde")[:2]
        a, b = h["tasks"][i], h["tasks"][j]
        h["tasks"][i], h["tasks"][j] = b, a
    return [i, j]


def _nan_edges(p):  # NaN edges of a done row's histogram (density kept)
    with h5py.File(p, "r+") as h:
        i = _rows(h, "fokker_planck")[0]
        e = h["histograms/edges"][i]
        e[:] = np.nan
        h["histograms/edges"][i] = e
    return [i]


DAMAGE = {"value": _value, "task-parameter": _param, "histogram": _hist, "status-byte": _status,
          "swapped-task-rows": _swap, "nan-histogram-edges": _nan_edges}


@pytest.mark.parametrize("damage", list(DAMAGE))
def test_damage_found_by_status_and_repaired_by_resume(tmp_path, refs, damage, capsys):
    path = tmp_path / "s.h5"
    shutil.copy(refs["hist"], path)
    rows = DAMAGE[damage](path)
    p = gs_here(capsys, "status", path)
    assert p.returncode == 0, p.stderr
    assert "damaged row" in p.stdout or "without a complete result" in p.stdout, p.stdout
    assert str(rows[0]) in p.stdout, p.stdout
    p = gs("run", JOBS["hist"], "--store", path, "--resume", "--mpi", "off")
    assert p.returncode == 0, p.stderr
    # a damaged task row whose results verify against the spec's task row is restored, not run again (issue 31)
    rerun = 0 if damage in ("task-parameter", "swapped-task-rows") else len(rows)
    assert f"{rerun} of " in p.stdout, p.stdout
    assert store.diff(path, refs["hist"]) == []
    p = gs_here(capsys, "status", path)
    assert "damaged" not in p.stdout, p.stdout


@pytest.mark.parametrize("damage", ["value", "histogram", "status-byte"])
def test_merge_and_export_refuse_damaged_rows_unless_told(tmp_path, refs, damage, capsys):
    path = tmp_path / "s.h5"
    shutil.copy(refs["hist"], path)
    DAMAGE[damage](path)
    p = gs_here(capsys, "merge", path, "--out", tmp_path / "m.h5")
    one_line_error(p, str(path), "damaged row")
    assert not (tmp_path / "m.h5").exists()
    p = gs_here(capsys, "merge", path, "--out", tmp_path / "m.h5", "--skip-damaged")
    assert p.returncode == 0, p.stderr
    assert "1 damaged" in p.stdout
    df = store.read(tmp_path / "m.h5")
    assert (df.status == "pending").sum() == 1 and "damaged" not in set(df.status)
    pytest.importorskip("xarray")
    pytest.importorskip("h5netcdf")
    p = gs_here(capsys, "export", path, "--out", tmp_path / "s.nc")
    one_line_error(p, str(path), "damaged row")
    assert not (tmp_path / "s.nc").exists()
    p = gs_here(capsys, "export", path, "--out", tmp_path / "s.nc", "--skip-damaged")
    assert p.returncode == 0 and (tmp_path / "s.nc").is_file(), p.stderr


def test_merge_sees_a_conflict_in_the_pressure_histogram_alone(tmp_path, capsys):
    """Two shards whose done rows differ only in a pressure histogram (issue 19 item 3)."""
    from gapsweep.sweep import merge as mergemod

    job = tmp_path / "hw.toml"
    job.write_text("""
[job]
name = "hw"
[interaction]
kind = "hard_wall"
[grid]
hurst = 0.8
sigma0 = [0.05, 0.1]
[surface]
lambda_l = 0.25
lambda_s = 0.0625
rms_slope = 1.0
[histogram]
bins = 8
[methods.gfmd]
n = 48
backend = "numpy"
""")
    a, b = tmp_path / "a.h5", tmp_path / "b.h5"
    p = gs("run", job, "--store", a, "--mpi", "off", "--progress", "none")
    assert p.returncode == 0, p.stderr
    shutil.copy(a, b)
    with h5py.File(b, "r+") as h:  # change one pressure bin, and keep the row's checksum valid
        from gapsweep.sweep.store import reseal

        d = h["histograms/pressure_density"][...]
        d[0, int(np.nanargmax(d[0]))] *= 1.5
        h["histograms/pressure_density"][...] = d
        reseal(h)
    assert gs_here(capsys, "status", b).stdout.count("damaged") == 0
    with pytest.raises(store.StoreError, match="conflicting"):
        mergemod.merge([a, b], tmp_path / "m.h5")
    assert mergemod.merge([a, b], tmp_path / "m.h5", on_conflict="first")["conflicts"] == 1


def test_store_without_checksums_still_opens(tmp_path, refs, capsys):
    """A format-2 store (its results table without error_estimate and checksum) opens, reads and resumes;
    `status` says its rows are not verified."""
    from gapsweep.sweep.schema import RESULT_DTYPE_V2

    path = tmp_path / "s.h5"
    shutil.copy(refs["hist"], path)
    with h5py.File(path, "r+") as h:
        r = h["results"][...]
        old = np.zeros(r.shape, dtype=RESULT_DTYPE_V2)
        for k in RESULT_DTYPE_V2.names:
            old[k] = r[k]
        del h["results"]
        h.create_dataset("results", data=old)
        h.attrs["format_version"] = 2
        del h.attrs["integrity"]  # format 2 had no attribute checksums
    p = gs_here(capsys, "status", path)
    assert p.returncode == 0 and "no row checksums" in p.stdout, p.stdout + p.stderr
    # the same rows; only format 3's new columns are missing
    d = store.diff(path, refs["hist"])
    assert d and all("only in the second store" in x for x in d), d


def test_results_as_a_group_is_a_one_line_error(tmp_path, refs, capsys):
    path = tmp_path / "s.h5"
    shutil.copy(refs["hist"], path)
    with h5py.File(path, "r+") as h:
        del h["results"]
        h.create_group("results")
    for cmd in (("status", path), ("merge", path, "--out", tmp_path / "m.h5")):
        one_line_error(gs_here(capsys, *cmd), str(path), "/results is a group")
