"""``gapsweep plan`` and ``run`` for jobs with ``[methods.gfmd] distributed = true`` (gapsweep.sweep.collective):
the memory of a solve split over the ranks (gfmd.distributed.solve_memory) per GPU or per rank, refused when it
does not fit, with the number named; the spec's refusals. The runs themselves: tests/mpi/test_collective.py."""

from __future__ import annotations

import pytest

from gapsweep.sweep import budget, collective, runner, spec
from gapsweep.sweep.schema import SpecError

JOB = """
[job]
name = "dist"
[grid]
hurst = [0.8]
rho = [2e-6]
sigma0 = [1e-2]
seeds = [0]
[surface]
lambda_l = 0.25
lambda_s = {ls}
rms_slope = 1.0
[material]
gamma0 = 1e-3
[methods.gfmd]
n = {n}
backend = "{backend}"
distributed = true
"""


def _tasks(tmp_path, n: int, backend: str = "numpy", law: str = ""):
    text = JOB.format(n=n, backend=backend, ls=4.0 / n)
    if law:
        text = text.replace("[material]\ngamma0 = 1e-3", f'[interaction]\nkind = "{law}"\nwork = 1e-3')
    p = tmp_path / "j.toml"
    p.write_text(text)
    s = spec.load(p)
    return s, runner._select(s, None)[0]


def test_gpu_memory_per_gpu_named_and_refused(tmp_path):
    from gapsweep.gfmd.distributed import solve_memory

    _, tasks = _tasks(tmp_path, 65536, "cupy", "adhesive")
    assert collective.is_collective(tasks)
    need = solve_memory((65536, 65536), 4, "adhesive")["bytes_per_rank"] + collective.CUDA_CONTEXT
    # 11 arrays + 3 of scratch of a GPU's 16384 rows: 120 GB, fits one H200 (141 GB) on 4 GPUs
    assert need == pytest.approx(15 * 8 * 16384 * 65536 + 0.5e9)  # 11 arrays + 4 of scratch
    lines = collective.check_memory(tasks, 4, on_gpu_total=141e9, host_total=0)
    assert len(lines) == 1 and "per GPU (4 GPUs" in lines[0]
    with pytest.raises(collective.DoesNotFit, match=r"needs ~\S+ GB per GPU on 2 GPUs, more than this GPU's"):
        collective.check_memory(tasks, 2, on_gpu_total=141e9, host_total=0)


def test_cpu_memory_per_rank_refused(tmp_path, monkeypatch):
    s, tasks = _tasks(tmp_path, 65536)
    with pytest.raises(collective.DoesNotFit, match=r"needs ~\S+ GB per rank for the solve, ~\S+ [GT]B over 4 ranks"):
        collective.check_memory(tasks, 4, host_total=64e9)
    monkeypatch.setattr(budget, "memory_total", lambda: int(64e9))  # a 64 GB machine
    s, tasks = _tasks(tmp_path, 32768)  # the surface per rank fits (34 GB), the slabs of 4 ranks do not
    with pytest.raises(runner.RunError, match=r"needs ~32.\d GB per rank for the solve"):
        runner.plan(s, ranks=4)
    s, tasks = _tasks(tmp_path, 64)
    text = runner.plan(s, ranks=2)
    assert "distributed GFMD:" in text and "per rank for the solve (2 ranks)" in text


def test_synthetic_surface_not_counted_whole_per_rank(tmp_path):
    """A synthetic surface is made in place (each rank its rows, among the solve's arrays): the rank count times
    the solve's slabs and the interpreters is what a node needs, no whole map per rank (it was 4 maps per rank).
    At 32768^2 over 4 ranks: 4 x 32.2 GB of slabs fit 160 GB, which 4 whole maps (4 x 34.4 GB more) did not."""
    from gapsweep.gfmd.distributed import solve_memory

    _, tasks = _tasks(tmp_path, 32768)
    assert budget.task_memory(tasks[0]) == 0.0
    slabs = 4 * solve_memory((32768, 32768), 4, "exponential")["bytes_per_rank"]
    need = slabs + budget.peak_memory(tasks) + 3 * budget.BASE_MEMORY
    lines = collective.check_memory(tasks, 4, host_total=need + 1e6)
    assert "per rank for the solve (4 ranks)" in lines[0]
    with pytest.raises(collective.DoesNotFit, match=r"over 4 ranks, more than this machine's"):
        collective.check_memory(tasks, 4, host_total=need - 1e6)


def test_spec_refusals(tmp_path):
    with pytest.raises(SpecError, match=r"methods\.gfmd\.distributed: expected true or false|distributed"):
        p = tmp_path / "a.toml"
        p.write_text(JOB.format(n=64, backend="numpy", ls=0.0625).replace("distributed = true", 'distributed = "yes"'))
        spec.load(p)
    p = tmp_path / "b.toml"
    p.write_text(JOB.format(n=64, backend="numpy", ls=0.0625) + 'method = "mpcg"\n')
    with pytest.raises(SpecError, match=r"methods\.gfmd\.method"):
        spec.load(p)
    p.write_text(JOB.format(n=64, backend="numpy", ls=0.0625) + 'keep_fields = {fields = ["gap"]}\n')
    s = spec.load(p)  # kept fields are written by rows (tests/mpi/test_collective.py)
    assert s.methods["gfmd"]["distributed"] and s.methods["gfmd"]["keep_fields"]


def test_timeout_and_batch_refused(tmp_path):
    s, _ = _tasks(tmp_path, 64)
    with pytest.raises(runner.RunError, match="--task-timeout and --batch do not apply"):
        runner.run(s, tmp_path / "s.h5", task_timeout=10.0, progress="none", mpi="off")
    assert not (tmp_path / "s.h5").exists()


def test_challenge_law_sized_with_its_pairs(tmp_path):
    """hard_wall_adhesive with distributed = true: sized by gfmd._bounded.memory_plan with the job's L-BFGS pairs
    (``[methods.gfmd.extra] memory``, passed to gfmd.solve): 65536^2 on 4 H200 (141 GB) fits with 2 pairs and is
    refused, naming the number, with the default 10."""
    from gapsweep.gfmd._bounded import memory_plan

    _, tasks = _tasks(tmp_path, 65536, "cupy", "hard_wall_adhesive")
    with pytest.raises(collective.DoesNotFit, match=r"needs ~2\d\d(\.\d)? GB per GPU on 4 GPUs"):
        collective.check_memory(tasks, 4, on_gpu_total=141e9, host_total=0)
    text = (tmp_path / "j.toml").read_text() + "[methods.gfmd.extra]\nmemory = 2\n"
    (tmp_path / "j.toml").write_text(text)
    tasks = runner._select(spec.load(tmp_path / "j.toml"), None)[0]
    lines = collective.check_memory(tasks, 4, on_gpu_total=141e9, host_total=0)
    plan = memory_plan((65536, 65536), 4, memory=2, backend="slab-cupy")["bytes_per_rank"]
    assert len(lines) == 1 and f"{budget.human(plan + collective.CUDA_CONTEXT)} per GPU" in lines[0]
