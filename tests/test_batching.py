"""Batched GFMD in the sweep (gapsweep.batching) on the CPU: which units batch, stores of batched and unbatched
sweeps equal to round-off (same statuses, messages, iteration counts), resume and injected failures inside a
batch; the GPU-per-rank policy (gapsweep.gpus) with mocked GPU counts, serial and under mpiexec (2 ranks, 1 GPU).
"""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest

from gapsweep import runner, spec, store
from gapsweep.sweep import batching, gpus, tasks
from tests.hooks import gapsweep_test_hooks as hooks

JOB = """
[job]
name = "batching"
[grid]
hurst = [0.3]
rho = [0.02, 0.004]
sigma0 = [1e-3, 1e-2, 1e-1]
seeds = [0, 1]
[surface]
lambda_l = 0.25
lambda_s = 0.125
[histogram]
bins = 16
[methods.theory]
forms = ["paper", "discrete"]
n = [32, 64]
[methods.gfmd]
n = [32, 64]
tol = 1e-9
backend = "numpy"
"""
# rho = 0.004 < dx = 1/64, 1/32: under-resolved (a warning in those rows' messages)


def _units(text: str, mode: str) -> tuple[list[tasks.Task], list[tasks.Unit]]:
    ts = tasks.expand(spec.loads(text))
    return ts, batching.batch_units(ts, tasks.make_units(ts), mode=mode)


def test_which_units_batch() -> None:
    cupy_job = JOB.replace('backend = "numpy"', 'backend = "cupy"').replace("n = [32, 64]\ntol", "n = [64, 2048]\ntol")
    ts, us = _units(cupy_job, "auto")
    batch = [u for u in us if u.kind == "batch"]
    assert len(batch) == 1 and len(batch[0].chains) == 4  # 2 rho x 2 seeds at n = 64
    assert all(ts[i].n == 64 and ts[i].method == "gfmd" for i in batch[0].tasks)
    assert all(len(c) == 3 and [ts[i].sigma0 for i in c] == [1e-1, 1e-2, 1e-3] for c in batch[0].chains)
    assert batch[0].gpu and sorted(batch[0].tasks) == sorted(i for c in batch[0].chains for i in c)
    assert sum(u.kind == "chain" and ts[u.tasks[0]].n == 2048 for u in us) == 4  # N > 1024: one by one
    # every task is in exactly one unit, in every mode
    for mode in batching.MODES:
        _, uu = _units(cupy_job, mode)
        assert sorted(i for u in uu for i in u.tasks) == list(range(len(ts)))
    assert not any(u.kind == "batch" for u in _units(cupy_job, "off")[1])
    assert not any(u.kind == "batch" for u in _units(JOB, "auto")[1])  # CPU backend: not in auto
    assert sum(u.kind == "batch" for u in _units(JOB, "all")[1]) == 2  # one per grid size
    # theory tasks with the discrete form: one set per surface (spectrum once), 2 seeds x 2 n
    sets = [u for u in us if u.kind == "set"]
    assert len(sets) == 4 and all(len({(ts[i].seed, ts[i].n) for i in u.tasks}) == 1 for u in sets)
    with pytest.raises(ValueError, match="batch mode"):
        batching.batch_units(ts, us, mode="yes")
    # at most BATCH_CHAINS chains per batch unit
    _, us2 = _units(JOB.replace("seeds = [0, 1]", "seeds = {start = 0, count = 20}"), "all")
    sizes = sorted(len(u.chains) for u in us2 if u.kind == "batch")
    assert sizes == [8, 8, batching.BATCH_CHAINS, batching.BATCH_CHAINS]


def _rows(path) -> dict:
    with store.open_read(path) as f:
        return {"t": f["tasks"][...], "r": f["results"][...], "d": f["histograms"]["density"][...]}


def test_batched_sweep_equals_unbatched(tmp_path, monkeypatch) -> None:
    js = tmp_path / "job.toml"
    js.write_text(JOB)
    hooks.fail_at(monkeypatch, 0.01)  # the middle pressure of every chain fails
    a, b = tmp_path / "off.h5", tmp_path / "all.h5"
    runner.run(js, a, progress="none", mpi="off", batch="off")
    s = runner.run(js, b, progress="none", mpi="off", batch="all")
    failed = int((_rows(a)["t"]["sigma0"] == 1e-2).sum())  # every method's rows at sigma0 = 0.01
    assert s["done"] > 0 and s["failed"] == failed == 16
    assert json.loads(store.read_attrs(b)["runs"])[-1]["batch_units"] == 2
    ra, rb = _rows(a), _rows(b)
    assert (ra["t"]["task_id"] == rb["t"]["task_id"]).all()
    for k in ("status", "message", "iterations", "count"):
        assert (ra["r"][k] == rb["r"][k]).all(), k
    gf = ra["t"]["method"] == b"gfmd"
    msgs = {m.decode() for m in rb["r"]["message"][gf]}
    assert any(m.startswith("warning: UnderResolvedWarning: rho/dx") for m in msgs)
    assert any(m.startswith("RuntimeError: injected failure") for m in msgs)
    for k in ("mean_gap", "gap_std", "gap_min", "gap_max", "h_rms", "g_rms", "residual"):
        x, y = ra["r"][k][gf], rb["r"][k][gf]
        same = (x == y) | (np.isnan(x) & np.isnan(y))
        # the residual (<= tol = 1e-9) is itself at round-off level: within 1e-3 tol
        tol = 1e-12 if k == "residual" else 1e-12 * np.abs(x) + 1e-15
        assert np.all(same | (np.abs(x - y) <= tol)), k
    assert np.array_equal(np.isnan(ra["d"]), np.isnan(rb["d"]))  # rows without a histogram (theory, failed)
    assert np.nanmax(np.abs(ra["d"] - rb["d"])) <= 1e-9 * np.nanmax(ra["d"])
    assert store.diff(a, b, rtol=1e-10, atol=1e-12) == []


def test_batched_resume_finishes_partial_store(tmp_path, monkeypatch) -> None:
    js = tmp_path / "job.toml"
    js.write_text(JOB.replace("n = [32, 64]\ntol", "n = [32]\ntol"))
    ref = tmp_path / "ref.h5"
    runner.run(js, ref, progress="none", mpi="off", batch="off")
    part = tmp_path / "part.h5"
    with monkeypatch.context() as m:
        hooks.fail_at(m, 0.001)  # the chains' last step fails ...
        runner.run(js, part, progress="none", mpi="off", batch="all")
    # ... a failed row is final; mark them pending as a crash would leave them, and resume batched
    import h5py

    with h5py.File(part, "r+") as f:
        r = f["results"][...]
        r["status"][r["status"] == tasks.STATUS["failed"]] = tasks.STATUS["pending"]
        f["results"][...] = r
    s = runner.run(js, part, progress="none", mpi="off", batch="all", resume=True)
    assert s["todo"] == 12 and s["done"] == 12  # 4 GFMD chain ends (chains re-run from their start), 8 theory
    assert store.diff(part, ref, rtol=1e-10, atol=1e-12) == []


def test_gpu_job_variants_match_the_figure_jobs() -> None:
    """jobs/gpu/fig*.toml are the figure jobs with GFMD on the GPU and nothing else changed."""
    from pathlib import Path

    root = Path(__file__).resolve().parents[1] / "jobs"
    for j in ("fig2", "fig3", "fig4_5", "fig6"):
        a, b = spec.load(root / f"{j}.toml"), spec.load(root / "gpu" / f"{j}.toml")
        assert b.methods["gfmd"].pop("backend") == "cupy" and a.methods["gfmd"].pop("backend") == "auto"
        assert (a.name, a.grid, a.surface, a.material, a.histogram, a.methods) == \
            (b.name, b.grid, b.surface, b.material, b.histogram, b.methods)


def test_gpu_policy() -> None:
    assert [gpus.assign(r, 1) for r in range(3)] == [0, None, None]  # default: one rank per GPU
    assert [gpus.assign(r, 1, per_gpu=2) for r in range(3)] == [0, 0, None]  # two ranks share it
    assert [gpus.assign(r, 4) for r in range(5)] == [0, 1, 2, 3, None]
    assert [gpus.assign(r, 2, per_gpu=2) for r in range(5)] == [0, 1, 0, 1, None]
    assert gpus.assign(None, 4) is None and gpus.assign(0, 0) is None
    with pytest.raises(ValueError, match="ranks-per-gpu"):
        gpus.assign(0, 1, per_gpu=0)


def test_gpu_count(monkeypatch) -> None:
    monkeypatch.setenv("CUDA_VISIBLE_DEVICES", "0,3")
    assert gpus.visible_count() == 2
    monkeypatch.setenv("CUDA_VISIBLE_DEVICES", "-1")
    assert gpus.visible_count() == 0
    hooks.gpus(monkeypatch, 8)
    assert gpus.visible_count() == 8
    assert gpus.rank_gpu(None, True) == 0


SDE_GPU_JOB = """
[job]
name = "gpuroute"
[grid]
hurst = [0.3]
rho = [2e-3]
sigma0 = [1e-3, 1e-2]
seeds = [0, 1]
[surface]
lambda_l = 0.25
lambda_s = 0.0625
[methods.theory]
forms = ["paper"]
[methods.sde]
samples = 100
device = "cuda"
"""


@pytest.mark.skipif(shutil.which("mpiexec") is None, reason="mpiexec not installed")
@pytest.mark.parametrize("per_gpu, works, expect", [(1, "yes", [0, None]), (2, "yes", [0, 0]), (1, "no", [None, 0])])
def test_two_ranks_one_mocked_gpu(tmp_path, per_gpu, works, expect) -> None:
    """2 ranks, 1 (mocked) GPU: the record says which rank got it; GPU units (SDE on cuda) ran only there."""
    from tests.mpi.test_mpi import mpirun

    js = tmp_path / "job.toml"
    js.write_text(SDE_GPU_JOB)
    path = tmp_path / "s.h5"
    p = mpirun(2, ["run", str(js), "--store", str(path), "--writer", "rank0", "--ranks-per-gpu", str(per_gpu),
                   "--coordinator-works", works], env={"GAPSWEEP_TEST_GPUS": "1"})
    assert p.returncode in (0, 3, 5), p.stdout + p.stderr  # the SDE rows may fail (no CUDA device here): 5 or 3
    rec = json.loads(store.read_attrs(path)["runs"])[-1]
    assert rec["gpus"] == expect
    r = _rows(path)
    sde = r["t"]["method"] == b"sde"
    assert set(r["r"]["rank"][sde]) <= {k for k, g in enumerate(expect) if g is not None}
    assert (r["r"]["status"][sde] != tasks.STATUS["pending"]).all()


def test_run_unit_runs_every_kind_once() -> None:
    """tasks.run_unit (the library entry) runs chains, sets and batch units; every task yields one row."""
    ts, us = _units(JOB.replace("n = [32, 64]\ntol", "n = [32]\ntol"), "all")
    assert {u.kind for u in us} >= {"batch", "set"}
    ctx = tasks.Context()
    seen = [i for u in us for i, res in tasks.run_unit(ts, u, ctx) if res.status == "done"]
    assert sorted(seen) == list(range(len(ts)))
