"""Issue 31, item 5: repair where the data allow it, and no damage reported that is not there.

* ``--resume`` re-runs every damaged row, histogram rows included: before, a theory, SDE or Fokker-Planck row
  whose NaN histogram (or pressure histogram) was damaged stayed damaged after the resume (5 of 5), because a
  row without a histogram never wrote its NaN rows again.
* A damaged task id (a pending row's, a done row's, one that is no longer UTF-8) or run-record list (attribute
  ``runs``) is rebuilt from the spec by ``--resume``, keeping every verified done row (a done row whose results
  verify against the spec's task row stays done, not re-run); status, merge and ``--skip-damaged`` work on such
  a store. Before, each blocked status, resume, merge and --skip-damaged; the only remedy offered,
  ``--overwrite``, discarded the done rows.
* A reader of a store being written never reports damage that is not there: a row run again (a timed-out row)
  is first marked pending, so a reader -- or a kill -- between its new payload and its new status sees it
  pending, not "damaged"; a row that does not match is read again before it is called damaged (a torn read of a
  compound row under mpio)."""

from __future__ import annotations

import json
import shutil

import h5py
import numpy as np
import pytest

from gapsweep import store
from gapsweep.sweep import runner, storecheck
from gapsweep.sweep.schema import STATUS
from gapsweep.sweep.store import reseal

from .conftest import JOBS, gs, gs_here, one_line_error


def _copy(refs, name, tmp_path):
    p = tmp_path / f"{name}.h5"
    shutil.copyfile(refs[name], p)
    return p


def _resume(job, path):
    runner.run(job, path, resume=True, mpi="off", progress="none")


HIST_SETS = ["histograms/edges", "histograms/density", "histograms/pressure_edges", "histograms/pressure_density"]


@pytest.mark.parametrize("value", ["one", "nan-payload"])
@pytest.mark.parametrize("ds", HIST_SETS)
@pytest.mark.parametrize("method", ["theory", "sde", "fokker_planck"])
def test_resume_repairs_damaged_histogram_rows(tmp_path, refs, method, ds, value):
    path = _copy(refs, "hist", tmp_path)
    i = int(np.flatnonzero(store.read(path).method == method)[0])
    with h5py.File(path, "r+") as f:
        a = f[ds][i]
        if value == "one":
            a[:] = 1.0
        else:  # another NaN: the same value to a reader, other bytes
            a.view("u8")[:] = 0x7FF8000000000001
        f[ds][i] = a
    assert store.read(path).status[i] == "damaged"
    _resume(JOBS["hist"], path)
    assert store.diff(path, refs["hist"]) == []
    assert set(store.read(path).status) == {"done"}


def _set_task_id(path, i, raw: bytes):
    with h5py.File(path, "r+") as f:
        t = f["tasks"][i]
        t["task_id"] = raw
        f["tasks"][i] = t


@pytest.fixture
def partial(tmp_path):
    """The theory job stopped by a write error after 5 rows: done and pending rows."""
    path = tmp_path / "p.h5"
    p = gs("run", JOBS["theory"], "--store", path, "--mpi", "off", "--progress", "none",
           GAPSWEEP_TEST_WRITE_ERROR="6")
    assert p.returncode == 1, p.stderr
    return path


def _flip(raw: bytes, kind: str) -> bytes:
    return (raw[:3] + bytes([raw[3] ^ 0x01]) + raw[4:]) if kind == "bit" else (b"\xff\xfe" + raw[2:])


@pytest.mark.parametrize("kind", ["bit", "not-utf8"])
@pytest.mark.parametrize("row", ["pending", "done"])
def test_damaged_task_id_rebuilt_keeping_done_rows(tmp_path, refs, partial, row, kind, capsys):
    path = partial
    df = store.read(path)
    i = int(np.flatnonzero(df.status == row)[0])
    with h5py.File(path, "r") as f:
        raw = bytes(f["tasks"][i]["task_id"])
    before = df[df.status == "done"].set_index("task_id")
    _set_task_id(path, i, _flip(raw, kind))
    p = gs_here(capsys, "status", path)
    assert p.returncode == 0 and "Traceback" not in p.stderr, p.stderr
    if row == "done":
        assert "damaged" in p.stdout
        p = gs_here(capsys, "merge", path, "--out", tmp_path / "m.h5")  # refused, naming the damage
        one_line_error(p, "damaged")
        p = gs_here(capsys, "merge", path, "--out", tmp_path / "m2.h5", "--skip-damaged")
        assert p.returncode == 0, p.stderr
    p = gs("run", JOBS["theory"], "--store", path, "--mpi", "off", "--progress", "none", "--resume")
    assert p.returncode == 0, p.stderr
    assert store.diff(path, refs["theory"]) == []
    after = store.read(path).set_index("task_id")
    # every done row kept as it was -- the one with the damaged id too: its results verify against the spec's
    # task row, so it is not run again (same wall time)
    for tid, r in before.iterrows():
        assert after.loc[tid, "status"] == "done"
        assert after.loc[tid, "wall_time"] == r["wall_time"], tid


@pytest.mark.parametrize("bad", ["not-json", "not-a-list", "list-of-numbers", "not-utf8"])
def test_damaged_run_records_rebuilt(tmp_path, refs, partial, bad, capsys):
    path = partial
    value = {"not-json": "[{\"started\": ", "not-a-list": "{\"a\": 1}", "list-of-numbers": "[1, 2]",
             "not-utf8": np.bytes_(b"\xff\xfe[]")}[bad]
    with h5py.File(path, "r+") as f:
        f.attrs["runs"] = value
    p = gs_here(capsys, "status", path)
    assert p.returncode == 0 and "run records" in p.stdout, (p.stdout, p.stderr)
    p = gs_here(capsys, "status", path, "--finished")
    assert p.returncode == 4 and "Traceback" not in p.stderr, p.stderr
    p = gs_here(capsys, "merge", path, "--out", tmp_path / "m.h5")
    assert p.returncode == 0, p.stderr
    p = gs("run", JOBS["theory"], "--store", path, "--mpi", "off", "--progress", "none", "--resume")
    assert p.returncode == 0, p.stderr
    assert store.diff(path, refs["theory"]) == []
    runs = json.loads(store.read_attrs(path)["runs"])
    assert "rebuilt" in runs[0] and runs[-1]["finished"]


def _make_timed_out(path, i):
    """Row ``i`` recorded as a timed-out failure (no histogram, sealed: its checksum matches), as --task-timeout
    leaves it."""
    with h5py.File(path, "r+") as f:
        for k in HIST_SETS:
            f[k][i] = np.full(f[k].shape[1], np.nan)
        r = f["results"][i]
        r["status"] = STATUS["failed"]
        r["message"] = b"timeout: task exceeded its time limit of 1 s (run again by --resume)"
        f["results"][i] = r
        reseal(f)


def test_row_being_rewritten_is_not_damaged(tmp_path, refs):
    """A timed-out SDE row is run again; the resume is killed between the row's new histogram and its new
    status (the moment a reader of a running store can meet). The row reads pending, not damaged; a resume
    completes the store. Before: "damaged" (its old failed status beside its new histogram)."""
    path = _copy(refs, "hist", tmp_path)
    i = int(np.flatnonzero(store.read(path).method == "sde")[0])
    _make_timed_out(path, i)
    assert store.read(path).status[i] == "failed"
    p = gs("run", JOBS["hist"], "--store", path, "--mpi", "off", "--progress", "none", "--resume",
           GAPSWEEP_TEST_KILL_AT_WRITE="1")
    assert p.returncode == -9, p.stderr
    df = store.read(path)
    assert df.status[i] == "pending" and "damaged" not in set(df.status)
    p = gs("run", JOBS["hist"], "--store", path, "--mpi", "off", "--progress", "none", "--resume",
           "--break-lease")
    assert p.returncode == 0, p.stderr
    assert store.diff(path, refs["hist"]) == []


class _Torn:
    """An h5py file whose first whole-table read of /results shows row ``i`` torn (half of a row write, as a
    reader under mpio may see it); later reads show the row as written."""

    def __init__(self, f, i):
        self.f, self.i, self.first = f, i, True

    @property
    def attrs(self):
        return self.f.attrs

    def __contains__(self, k):
        return k in self.f

    def __getitem__(self, k):
        ds = self.f[k]
        if k != "results":
            return ds
        outer = self

        class View:
            def __getattr__(self, a):
                return getattr(ds, a)

            def fields(self, name):
                return ds.fields(name)

            def __getitem__(self, sel):
                v = ds[sel]
                if sel is Ellipsis and outer.first:
                    outer.first = False
                    v = v.copy()
                    v["mean_gap"][outer.i] += 1.0  # the new value, the old checksum
                return v

        return View()


def test_torn_read_is_read_again(refs):
    with h5py.File(refs["hist"], "r") as f:
        assert storecheck.check(_Torn(f, 3), "x").damaged == []
        # a row that really changed stays damaged: every read shows the same bytes
        r = f["results"][...]
        r["mean_gap"][5] += 1.0

        class Changed(_Torn):
            def __getitem__(self, k):
                if k == "results":
                    class V:
                        dtype = f["results"].dtype
                        shape = f["results"].shape

                        def fields(self, name):
                            return f["results"].fields(name)

                        def __getitem__(self, sel):
                            return r[sel]

                    return V()
                return self.f[k]

        assert storecheck.check(Changed(f, 0), "x").damaged == [5]
