"""Serial runs of the sweep (gapsweep.runner): results equal direct solver calls, failure isolation, no-op
re-runs, refusal to mix jobs, a real kill -9 with resume, shards + merge equal a single run."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from gapsweep import runner, spec, store, surface, theory

ROOT = Path(__file__).resolve().parent.parent
THEORY_JOB = ROOT / "jobs" / "test_theory.toml"
MIXED_JOB = ROOT / "jobs" / "test_mixed.toml"


def _run(job, path, **kw):
    kw.setdefault("progress", "none")
    kw.setdefault("mpi", "off")
    return runner.run(job, path, **kw)


@pytest.fixture(scope="module")
def theory_ref(tmp_path_factory):
    path = tmp_path_factory.mktemp("ref") / "theory.h5"
    s = _run(THEORY_JOB, path)
    assert s["done"] == s["tasks"] == 48
    return path


def test_theory_rows_equal_direct_calls(theory_ref):
    """The sweep calls the public theory functions with the spec's parameters (independent recomputation)."""
    js = spec.load(THEORY_JOB)
    df = store.read(theory_ref)
    assert set(df.status) == {"done"}
    sp = js.surface
    for row in df.itertuples():
        h_rms = surface.continuum_rms_height(row.hurst, lambda_l=sp["lambda_l"], lambda_s=sp["lambda_s"])
        kw = dict(hurst=row.hurst, h_rms=h_rms, rho=row.rho, gamma0=1e-3, lambda_l=0.25, lambda_s=sp["lambda_s"])
        assert row.h_rms == h_rms
        assert row.mean_gap_paper == theory.mean_gap(row.sigma0, **kw)
        assert row.mean_gap_continuum == theory.mean_gap(row.sigma0, form="continuum", **kw)
        assert row.mean_gap == row.mean_gap_paper
        h = surface.self_affine(64, row.hurst, lambda_l=0.25, lambda_s=sp["lambda_s"], rms_slope=1.0,
                                seed=row.seed)
        assert row.mean_gap_discrete == theory.mean_gap_discrete(row.sigma0, h, rho=row.rho, gamma0=1e-3,
                                                                 lambda_l=0.25)
    # fixed amplitudes (M2): the discrete form depends on |h~|^2 only, so both seeds agree to rounding
    a = df[(df.seed == 0)].mean_gap_discrete.to_numpy()
    b = df[(df.seed == 1)].mean_gap_discrete.to_numpy()
    assert np.allclose(a, b, rtol=1e-10, atol=0)


def test_failure_isolation_and_rerun_noop(tmp_path, monkeypatch, theory_ref):
    fail = spec.load(THEORY_JOB).grid["sigma0"][2]
    monkeypatch.setenv("GAPSWEEP_TEST_FAIL", repr(fail))
    path = tmp_path / "f.h5"
    s = _run(THEORY_JOB, path)
    assert s["failed"] == 8 and s["done"] == 40
    df, ref = store.read(path), store.read(theory_ref)
    bad = df.sigma0 == fail
    assert set(df[bad].status) == {"failed"}
    assert all("injected failure" in m for m in df[bad].message)
    assert np.all(np.isnan(df[bad].mean_gap))
    assert np.array_equal(df[~bad].mean_gap.to_numpy(), ref[~bad].mean_gap.to_numpy())
    # a finished job (failures are finished too) is a no-op, with or without --resume; the file is untouched
    before = path.read_bytes()
    assert _run(THEORY_JOB, path)["mode"] == "noop"
    assert _run(THEORY_JOB, path, resume=True)["mode"] == "noop"
    assert path.read_bytes() == before


def test_refuses_other_job_and_unfinished_store(tmp_path):
    path = tmp_path / "s.h5"
    _run(THEORY_JOB, path)
    other = tmp_path / "other.toml"
    other.write_text(THEORY_JOB.read_text().replace("num = 6", "num = 5"))
    with pytest.raises(runner.RunError, match="another job spec"):
        _run(other, path, resume=True)
    s = _run(other, path, overwrite=True)
    assert s["mode"] == "create" and s["done"] == 40
    # an unfinished store needs --resume
    with h5py_rw(path) as f:
        r = f["results"][...]
        r["status"][:3] = 0
        f["results"][...] = r
    with pytest.raises(runner.RunError, match="--resume"):
        _run(other, path)
    assert _run(other, path, resume=True)["todo"] == 3


def h5py_rw(path):
    import h5py

    return h5py.File(path, "r+")


def test_kill9_then_resume_equals_uninterrupted(tmp_path, theory_ref):
    """A real kill -9 mid-run: the store stays readable, holds only finished rows, and --resume completes it
    to the same content as an uninterrupted run."""
    path = tmp_path / "k.h5"
    env = dict(os.environ, GAPSWEEP_TEST_DELAY="0.05")
    cmd = [sys.executable, "-m", "gapsweep", "run", str(THEORY_JOB), "--store", str(path), "--progress", "none",
           "--mpi", "off"]
    p = subprocess.Popen(cmd, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        t0 = time.monotonic()
        done = 0
        while time.monotonic() - t0 < 60 and done < 10:
            time.sleep(0.1)
            if path.exists():
                try:
                    done = int((store.read(path).status == "done").sum())
                except Exception:
                    pass  # the file is being created
        os.kill(p.pid, signal.SIGKILL)
    finally:
        p.wait(timeout=30)
    assert p.returncode == -signal.SIGKILL
    df = store.read(path)  # readable without h5clear
    n_done = int((df.status == "done").sum())
    assert 10 <= n_done < 48
    assert set(df.status) == {"done", "pending"}
    assert store.read_attrs(path)["runs"].count('"finished": null') == 1
    s = _run(THEORY_JOB, path, resume=True)
    assert s["mode"] == "resume" and s["todo"] == 48 - n_done and s["done"] == s["todo"]
    assert store.diff(path, theory_ref) == []


def test_shards_merge_equal_single_run(tmp_path):
    """All methods (theory, GFMD chains, SDE, FP) through three shards + merge == one run, histograms included."""
    single = tmp_path / "single.h5"
    _run(MIXED_JOB, single)
    shards = []
    for i in range(3):
        s = _run(MIXED_JOB, tmp_path / "shard{i}.h5", shard=(i, 3))
        shards.append(s["store"])
        assert s["tasks"] > 0
    assert sum(len(store.read(p)) for p in shards) == len(store.read(single))
    out = tmp_path / "merged.h5"
    counts = store.merge(shards, out)
    assert counts["pending"] == 0
    assert store.diff(out, single) == []
    with pytest.raises(store.StoreError, match="exists"):
        store.merge(shards, out)
    assert store.merge(shards[:2], out, overwrite=True)["pending"] > 0


def test_mixed_job_rows(tmp_path):
    """GFMD rows equal a direct solver call (first task of a chain: no warm start); histograms integrate to 1."""
    from gapsweep import gfmd

    path = tmp_path / "m.h5"
    _run(MIXED_JOB, path)
    df = store.read(path)
    assert set(df.method) == {"theory", "gfmd", "sde", "fokker_planck"}
    assert not (df.status == "pending").any()
    g = df[(df.method == "gfmd") & (df.seed == 1)].sort_values("sigma0", ascending=False).iloc[0]
    h = surface.self_affine(64, 0.3, lambda_l=0.25, lambda_s=0.0625, rms_slope=1.0, seed=1)
    res = gfmd.solve(h, sigma0=g.sigma0, gamma0=1e-3, rho=2e-2, tol=1e-6, backend="numpy")
    assert g.status == ("done" if res.converged else "not_converged")
    assert g.mean_gap == res.mean_gap and g.iterations == res.iterations
    hist = store.read_histograms(path)
    expected_count = {"gfmd": 64 * 64, "sde": 2000, "fokker_planck": 0}
    method = dict(zip(df.task_id, df.method))
    for tid, (edges, dens, count) in hist.items():
        assert count == expected_count[method[tid]]
        assert len(edges) == 33 and len(dens) == 32
        assert np.sum(dens * np.diff(edges)) == pytest.approx(1.0, abs=1e-9), tid
    with_hist = set(df[df.method != "theory"].task_id[df.status == "done"])
    assert with_hist <= set(hist)
