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
from tests.hooks import gapsweep_test_hooks as hooks

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
    hooks.fail_at(monkeypatch, fail)
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
    # the killed run's lease is stale: reported, and broken only when asked
    with pytest.raises(runner.RunError, match=r"no longer running.*--break-lease"):
        _run(THEORY_JOB, path, resume=True)
    s = _run(THEORY_JOB, path, resume=True, break_lease=True)
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
    # --overwrite replaces an earlier merge of the same job, but never with fewer done rows (issue 31)
    with pytest.raises(store.StoreError, match="done"):
        store.merge(shards[:2], out, overwrite=True)
    assert store.merge(shards, out, overwrite=True)["pending"] == 0
    assert store.diff(out, single) == []


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


_SDE_BINNED_JOB = """
[job]
name = "test-sde-binned"

[grid]
hurst = [0.3]
rho = [2e-2]
sigma0 = [1e-2]
seeds = [3]

[surface]
lambda_l = 0.25
lambda_s = 0.0625
rms_slope = 1.0

[material]
gamma0 = 1e-3

[histogram]
bins = 32
range = {range}

[methods.sde]
samples = 20000
dzeta = 0.05
dtype = "float64"
"""


def test_sde_device_histogram_path_matches_host_path(tmp_path, monkeypatch):
    """SDE tasks above tasks.SDE_HOST_SAMPLES_MAX are binned on the device into SDE_SUB_BINS sub-bins per store
    bin. Same seed = same samples, so against the exact host path (threshold lowered to 1000 here): stored
    densities and counts are identical on the same edges (float64 kernel: no edge rounding ambiguity), the mean
    is within w/2 and the Sheppard-corrected std within w/2 + w/sqrt(12) (w = sub-bin width), min/max are
    sub-bin bounds; samples outside a given range are reported; "auto" uses the SDE's default range."""
    from gapsweep import sde
    from gapsweep.sweep.methods import sde as sde_method

    h_rms = surface.continuum_rms_height(0.3, lambda_l=0.25, lambda_s=0.0625, rms_slope=1.0)
    plan = sde.plan_steps(1e-2, hurst=0.3, h_rms=h_rms, rho=2e-2, gamma0=1e-3, lambda_l=0.25, lambda_s=0.0625,
                          dzeta=0.05)
    g0, sd = plan.g0_end, plan.variance ** 0.5
    calls = []
    real_counts = sde.gap_histogram_counts

    def spy(*a, **k):
        calls.append(k["n"])
        return real_counts(*a, **k)

    monkeypatch.setattr(sde, "gap_histogram_counts", spy)

    def run(rng, binned):
        monkeypatch.setattr(sde_method, "SDE_HOST_SAMPLES_MAX", 1000 if binned else 2**22)
        job = tmp_path / f"j{len(list(tmp_path.iterdir()))}.toml"
        job.write_text(_SDE_BINNED_JOB.format(range=rng))
        path = job.with_suffix(".h5")
        n_calls = len(calls)
        assert _run(job, path)["tasks"] == 1
        assert len(calls) == n_calls + binned  # the path taken
        row = store.read(path).iloc[0]
        return row, store.read_histograms(path)[row.task_id]

    lo, hi = g0 - 8 * sd, g0 + 8 * sd
    exact, (e_x, d_x, c_x) = run(f"[{lo!r}, {hi!r}]", False)
    binned, (e_b, d_b, c_b) = run(f"[{lo!r}, {hi!r}]", True)
    assert exact.status == binned.status == "done" and binned.message == ""
    assert c_x == c_b == 20000
    assert np.array_equal(e_x, e_b) and np.array_equal(d_x, d_b)
    w = (hi - lo) / (32 * sde_method.SDE_SUB_BINS)
    assert abs(binned.mean_gap - exact.mean_gap) <= w / 2
    assert abs(binned.gap_std - exact.gap_std) <= w / 2 + w / 12**0.5
    assert binned.gap_min <= exact.gap_min < binned.gap_min + w * (1 + 1e-9)
    assert binned.gap_max - w * (1 + 1e-9) < exact.gap_max <= binned.gap_max
    assert binned.h_rms == exact.h_rms == h_rms
    # sharper, independent: the same samples binned by numpy on the sub-edges give the row's binned moments
    g = sde.gap_samples(1e-2, hurst=0.3, h_rms=h_rms, rho=2e-2, gamma0=1e-3, lambda_l=0.25, lambda_s=0.0625,
                        dzeta=0.05, n=20000, seed=3, dtype="float64")
    sub = np.linspace(lo, hi, 32 * sde_method.SDE_SUB_BINS + 1)
    n_sub = np.histogram(g, sub)[0]
    centres = 0.5 * (sub[:-1] + sub[1:])
    mean = n_sub @ centres / n_sub.sum()
    std = (n_sub @ (centres - mean) ** 2 / n_sub.sum() - w * w / 12) ** 0.5  # Sheppard
    occ = np.flatnonzero(n_sub)
    assert binned.mean_gap == pytest.approx(mean, rel=1e-12)
    assert binned.gap_std == pytest.approx(std, rel=1e-9)  # Sheppard changes it by ~2e-6 (relative) here
    assert binned.gap_min == pytest.approx(sub[occ[0]], rel=1e-12)
    assert binned.gap_max == pytest.approx(sub[occ[-1] + 1], rel=1e-12)

    # a range that cuts the tails: same binned counts on both paths; the binned row says what it left out
    narrow = f"[{g0 - sd!r}, {g0 + sd!r}]"
    ex_n, (_, d_xn, c_xn) = run(narrow, False)
    bn_n, (_, d_bn, c_bn) = run(narrow, True)
    assert c_xn == c_bn and 0 < c_bn < 20000 and np.array_equal(d_xn, d_bn)
    assert bn_n.status == ex_n.status == "done" and ex_n.mean_gap == exact.mean_gap  # host: all samples
    assert bn_n.message == (f"sde: {20000 - c_bn} of 20000 samples outside the histogram range "
                            "(moments from binned samples)")

    # "auto": the SDE's default range g0 -/+ 6 sd (no repulsion here), nothing outside at 20000 samples
    auto, (e_a, _, c_a) = run('"auto"', True)
    assert np.allclose(e_a[[0, -1]], [g0 - 6 * sd, g0 + 6 * sd], rtol=0, atol=1e-12)
    assert auto.message == "" and c_a == 20000
    w_a = 12 * sd / (32 * sde_method.SDE_SUB_BINS)
    assert abs(auto.mean_gap - exact.mean_gap) <= w_a / 2
    assert abs(auto.gap_std - exact.gap_std) <= w_a / 2 + w_a / 12**0.5


@pytest.mark.parametrize("ranks", [1, 2])
def test_several_jobs_in_one_launch(tmp_path, ranks):
    """`gapsweep run JOB1 JOB2 --store S1 --store S2` (issue 22 item 6: start-up paid once): each store equals
    that of its job run alone; a job list whose second spec is invalid runs nothing."""
    root = Path(__file__).resolve().parents[1]
    jobs = [root / "jobs" / "test_theory.toml", root / "tests" / "faults" / "jobs" / "hist.toml"]
    env = {**os.environ, "OMPI_ALLOW_RUN_AS_ROOT": "1", "OMPI_ALLOW_RUN_AS_ROOT_CONFIRM": "1",
           "OMPI_MCA_rmaps_base_oversubscribe": "1"}
    base = [sys.executable, "-m", "gapsweep", "run"]
    if ranks > 1:
        import shutil

        if shutil.which("mpiexec") is None:
            pytest.skip("no mpiexec")
        base = ["mpiexec", "-n", str(ranks), *base]
    both = [str(tmp_path / "a.h5"), str(tmp_path / "b.h5")]
    p = subprocess.run([*base, *map(str, jobs), "--store", both[0], "--store", both[1], "--progress", "none"],
                       env=env, capture_output=True, text=True, timeout=300)
    assert p.returncode == 0, p.stderr
    for job, s in zip(jobs, both):
        alone = tmp_path / f"alone-{Path(s).name}"
        runner.run(job, alone, progress="none", mpi="off")
        assert store.diff(s, alone) == []
    bad = tmp_path / "bad.toml"
    bad.write_text(jobs[0].read_text().replace("rms_slope = 1.0", "rms_slope = -1.0"))
    p = subprocess.run([sys.executable, "-m", "gapsweep", "run", str(jobs[0]), str(bad), "--store",
                        str(tmp_path / "c.h5"), "--store", str(tmp_path / "d.h5"), "--mpi", "off"],
                       env=env, capture_output=True, text=True, timeout=300)
    assert p.returncode == 2 and "surface.rms_slope" in p.stderr
    assert not (tmp_path / "c.h5").exists() and not (tmp_path / "d.h5").exists()
    p = subprocess.run([sys.executable, "-m", "gapsweep", "run", str(jobs[0]), str(jobs[1]), "--store",
                        str(tmp_path / "c.h5"), "--mpi", "off"], env=env, capture_output=True, text=True, timeout=60)
    assert p.returncode == 2 and "one store per job" in p.stderr
