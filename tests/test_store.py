"""The HDF5 store (gapsweep.store, docs/store.md): preallocated rows, round trip of results and histograms,
status text, diff, merge refusals, attributes."""

from __future__ import annotations

import json
from pathlib import Path

import h5py
import numpy as np
import pytest

from gapsweep import spec, store
from gapsweep.sweep import provenance, tasks
from gapsweep.sweep.tasks import TaskResult

JOB = """
[job]
name = "st"
[grid]
hurst = [0.3]
rho = [2e-3]
sigma0 = [1e-2, 1e-1]
seeds = [0, 1]
[surface]
lambda_s = 0.0625
[histogram]
bins = 5
[methods.theory]
[methods.gfmd]
n = 64
"""


def _new(path: Path, text: str = JOB):
    js = spec.loads(text)
    ts = tasks.expand(js)
    st = store.Store.create(path, ts, provenance.store_attrs(js), js.histogram["bins"])
    return js, ts, st


def test_preallocated_pending_rows_and_round_trip(tmp_path):
    path = tmp_path / "s.h5"
    js, ts, st = _new(path)
    assert st.n_tasks == 6 and st.bins == 5
    df = store.read(path)  # readable while open for writing
    assert list(df.task_id) == [t.task_id for t in ts]
    assert set(df.status) == {"pending"} and df.mean_gap.isna().all() and (df.iterations == -1).all()
    edges = np.linspace(0.0, 1.0, 6)
    dens = np.array([0.5, 1.5, 1.0, 1.0, 1.0])
    st.write(3, TaskResult("not_converged", "gfmd: max_iter", {"mean_gap": 0.25, "iterations": 7, "rank": 2},
                           (edges, dens, 4096)))
    st.write(0, TaskResult("failed", "x" * 1000))
    with pytest.raises(store.StoreError, match="bins"):
        st.write(1, TaskResult("done", "", {}, (edges[:3], dens[:2], 1)))
    st.close()
    df = store.read(path)
    assert df.status.tolist()[:4] == ["failed", "pending", "pending", "not_converged"]
    assert df.message[0] == "x" * store.MESSAGE_LEN  # truncated, not an error
    r = df.iloc[3]
    assert (r.mean_gap, r.iterations, r["count"], r["rank"], r.message) == (0.25, 7, 4096, 2, "gfmd: max_iter")
    assert (r.method, r.hurst, r.rho, r.sigma0, r.n, r.gamma0, r.e_star, r.lambda_s) == (
        ts[3].method, 0.3, 2e-3, ts[3].sigma0, 64, 1e-3, 1.0, 0.0625)
    h = store.read_histograms(path)
    assert list(h) == [ts[3].task_id]
    e, d, c = h[ts[3].task_id]
    assert np.array_equal(e, edges) and np.array_equal(d, dens) and c == 4096
    assert store.read_histograms(path, task_ids=[ts[0].task_id]) == {}
    attrs = store.read_attrs(path)
    assert attrs["spec_text"] == JOB and attrs["spec_sha256"] == js.sha256 and attrs["job_name"] == "st"
    v = json.loads(attrs["versions"])
    assert v["h5py"] == h5py.__version__ and v["hdf5"] == h5py.version.hdf5_version and "numpy" in v
    text = store.status(path)
    assert "6 tasks" in text and "not_converged: " in text and "gfmd: max_iter" in text


def test_default_file_format_has_no_write_flag(tmp_path):
    """Earliest superblock (version 0): no 'file open for write' flag that would need h5clear after a crash."""
    path = tmp_path / "s.h5"
    _, _, st = _new(path)
    st.f.flush()
    raw = path.read_bytes()[:9]
    assert raw[:8] == b"\x89HDF\r\n\x1a\n" and raw[8] == 0  # superblock version 0
    st.close()


def test_diff_and_merge_refusals(tmp_path):
    a, b = tmp_path / "a.h5", tmp_path / "b.h5"
    for p in (a, b):
        _, _, st = _new(p)
        st.write(1, TaskResult("done", "", {"mean_gap": 1.0, "wall_time": 0.1 if p == a else 0.2}))
        st.close()
    assert store.diff(a, b) == []  # wall time is not content
    with h5py.File(b, "r+") as f:
        r = f["results"][...]
        r["mean_gap"][1] = np.nextafter(1.0, 2.0)
        f["results"][...] = r
    assert store.diff(a, b) == ["results.mean_gap differs in 1 rows (first: [1])"]
    c = tmp_path / "c.h5"
    _, _, st = _new(c, JOB.replace("bins = 5", "bins = 6"))
    st.close()
    with pytest.raises(store.StoreError, match="different job specs"):
        store.merge([a, c], tmp_path / "m.h5")
    with pytest.raises(store.StoreError, match="no shard"):
        store.merge([], tmp_path / "m.h5")
    with pytest.raises(FileNotFoundError):
        store.read(tmp_path / "none.h5")
    with h5py.File(tmp_path / "plain.h5", "w"):
        pass
    with pytest.raises(store.StoreError, match="not a gapsweep store"):
        store.read(tmp_path / "plain.h5")


def test_git_commit_outside_a_checkout_is_unknown(monkeypatch):
    """A tree copied without .git (compute node): `git rev-parse` fails and prints 'HEAD'; record 'unknown',
    or the commit given in GAPSWEEP_GIT_COMMIT."""
    import subprocess

    from gapsweep.sweep import provenance

    monkeypatch.delenv("GAPSWEEP_GIT_COMMIT", raising=False)
    monkeypatch.setattr(subprocess, "run", lambda *a, **k: subprocess.CompletedProcess(a, 128, "HEAD\n", "fatal"))
    provenance.git_commit.cache_clear()  # read once per process
    assert provenance.git_commit() == "unknown"
    monkeypatch.setenv("GAPSWEEP_GIT_COMMIT", "0ee057e")
    provenance.git_commit.cache_clear()
    assert provenance.git_commit() == "0ee057e"
    provenance.git_commit.cache_clear()


def test_lease_exclusive_stale_and_broken(tmp_path):
    import os
    import subprocess
    import sys

    from gapsweep.sweep import lease

    path = tmp_path / "s.h5"
    held = lease.acquire(path)
    info = lease.read(path)
    assert info["pid"] == os.getpid() and info["alive"] is True
    with pytest.raises(lease.LeaseError, match="in use by"):
        lease.acquire(path)
    with pytest.raises(lease.LeaseError, match="in use by"):
        lease.acquire(path, break_lease=True)  # a live holder on this host is never broken
    held.release()
    assert lease.read(path) is None
    # a lease of a process that has exited is stale: reported, broken only when asked -- where the store exists
    # (a holder that never created the store is taken over: tests/faults/test_leases.py)
    path.write_bytes(b"")
    code = f"from gapsweep.sweep import lease; lease.acquire({str(path)!r})"
    subprocess.run([sys.executable, "-c", code], check=True)
    assert lease.read(path)["alive"] is False
    with pytest.raises(lease.LeaseError, match=r"no longer running.*--break-lease"):
        lease.acquire(path)
    with lease.acquire(path, break_lease=True) as mine:
        assert lease.read(path)["run_id"] == mine.run_id
    assert lease.read(path) is None


def test_storecheck_structural_and_row_problems(tmp_path):
    from gapsweep.sweep import storecheck

    js = spec.loads(JOB)
    ts = tasks.expand(js)
    path = tmp_path / "s.h5"
    st = store.Store.create(path, ts, provenance.store_attrs(js), js.histogram["bins"])
    st.close()
    with h5py.File(path, "r") as f:
        rep = storecheck.check(f, path)
    assert rep.rerun == [] and rep.n_tasks == len(ts)
    with h5py.File(path, "r+") as f:
        r = f["results"][...]
        r["status"][0] = 9  # unknown code
        r["status"][1] = 1  # done without a result
        f["results"][...] = r
    with h5py.File(path, "r") as f:
        rep = storecheck.check(f, path)
        assert rep.unknown_status == [0] and rep.done_incomplete == [1]
        assert storecheck.incomplete_rows(f, path) == list(range(len(ts)))
    with h5py.File(path, "r+") as f:
        del f["histograms/edges"]
    with pytest.raises(store.StoreError, match=r"s\.h5: dataset /histograms/edges missing"):
        store.read(path)
