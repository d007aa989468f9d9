"""The farm's scheduling rules (gapsweep.sweep.farm), in-process: no MPI, no GPU, no subprocess. Each test
drives a Farm with events as the runner would and checks the dispatches against the rules of the module
docstring (docs/architecture.md, "The farm")."""

from __future__ import annotations

import pytest

from gapsweep.sweep.farm import DeviceFault, Farm, Worker, device_fault
from tests.hooks import gapsweep_test_hooks as hooks

# units 0..5, largest first; 0, 1, 3 need a GPU
GPU = [True, True, False, True, False, False]


def farm(workers: dict[int, Worker], order=range(6), gpu=GPU) -> Farm:
    return Farm(gpu, list(order), workers)


def test_gpu_worker_takes_gpu_units_first_cpu_worker_cpu_units_only():
    f = farm({1: Worker(gpu=0), 2: Worker()})
    assert f.request(2) == [(2, 2)]  # the first CPU unit, although 0 and 1 are larger
    assert f.request(1) == [(1, 0)]
    assert f.request(1, 0) == [(1, 1)]
    assert f.request(1, 1) == [(1, 3)]
    assert f.request(1, 3) == [(1, 4)]  # no GPU unit left: the GPU worker helps with the CPU units
    assert f.request(2, 2) == [(2, 5)]
    assert f.workers[2].state == "busy" and f.workers[2].units == [5]
    # nothing queued; worker 1 holds nothing that 2 could run: 2 stops, 1 then stops too
    assert f.request(2, 5) == [(2, None)]
    assert f.request(1, 4) == [(1, None)]
    assert not f.busy() and f.left == [] and f.no_gpu == ""


def test_coordinator_thread_takes_from_the_tail():
    f = farm({0: Worker(tail=True), 1: Worker()}, gpu=[False] * 6)
    assert f.request(0) == [(0, 5)]
    assert f.request(1) == [(1, 0)]
    assert f.request(0, 5) == [(0, 4)]


def test_without_any_gpu_worker_any_worker_takes_gpu_units():
    f = farm({1: Worker(), 2: Worker()})
    assert [f.request(1), f.request(2)] == [[(1, 0)], [(2, 1)]]


def test_units_ahead_for_gpu_workers_after_every_worker_holds_one():
    f = farm({1: Worker(gpu=0, ahead=2), 2: Worker(gpu=1, ahead=2), 3: Worker(ahead=2)})
    # the one it runs, and one ahead: GPU units 1 and 3 are queued, one is left for the other GPU worker
    assert f.request(1) == [(1, 0), (1, 1)]
    assert f.request(2) == [(2, 3)]  # no GPU unit left to hold ahead (CPU units are not held ahead)
    assert f.request(3) == [(3, 2)]
    assert f.request(1, 0) == []  # CPU units are not held ahead
    assert f.workers[1].units == [1] and f.workers[1].unit == 1


def test_units_ahead_leave_one_for_every_other_gpu_worker_and_only_where_ok():
    workers = {w: Worker(gpu=w, ahead=4) for w in range(4)}
    f = farm(workers, order=range(16), gpu=[True] * 16)
    assert [k for _, k in f.request(0)] == [0, 1, 2, 3, 4]  # 11 remain for the 3 others
    f = farm({w: Worker(gpu=w, ahead=4) for w in range(4)}, order=range(6), gpu=[True] * 6)
    assert [k for _, k in f.request(0)] == [0, 1, 2]  # 3 remain, one for each of the others
    assert [k for _, k in f.request(1)] == [3]
    f = Farm([True] * 4, range(4), {0: Worker(gpu=0, ahead=4)}, ahead_ok=[True, False, True, False])
    assert [k for _, k in f.request(0)] == [0, 2]  # 1 and 3 have nothing to make ahead: taken one at a time


def test_a_cpu_worker_holds_one_unit():
    f = farm({1: Worker(ahead=3)}, gpu=[False] * 6)
    assert f.request(1) == [(1, 0)]


def test_a_worker_holding_nothing_is_served_before_units_ahead():
    f = farm({1: Worker(gpu=0, ahead=3), 2: Worker(gpu=1, ahead=3)}, order=[0, 1, 2, 3], gpu=[True] * 4)
    f.workers[2].started = True  # asked already, its request is being handled in the same dispatch
    assert f.request(1) == [(1, 0), (2, 1), (1, 2)]  # 3 stays queued for 2's next request


def test_device_fault_requeues_for_another_gpu_worker_and_skips_recorded_rows():
    f = farm({1: Worker(gpu=0), 2: Worker(gpu=1), 3: Worker()})
    assert f.request(1) == [(1, 0)]
    assert f.request(2) == [(2, 1)]
    f.row(0, 10)  # unit 0 recorded one row before its device failed
    assert f.fault(1, "CUDARuntimeError: cudaErrorDevicesUnavailable") == [(1, 2)]  # 1 goes on with CPU work
    assert f.workers[1].lost and not f.workers[1].has_gpu and f.workers[1].epoch == 1
    assert f.queue[0] == 0 and f.skip(0) == frozenset({10})  # back at the head, its recorded row skipped
    assert f.request(2, 1) == [(2, 0)]  # the other GPU worker takes it
    assert f.request(3) == [(3, 4)]
    assert f.request(1, 2) == [(1, 5)]
    assert f.request(2, 0) == [(2, 3)]
    assert f.faults == [(1, 0, "CUDARuntimeError: cudaErrorDevicesUnavailable")]


def test_device_fault_requeues_every_unit_held_in_order():
    f = farm({1: Worker(gpu=0, ahead=2), 2: Worker(gpu=1)}, order=[0, 1, 3, 2], gpu=GPU)
    assert f.request(1) == [(1, 0), (1, 1)]  # one ahead: GPU unit 3 is left for worker 2
    assert f.request(2) == [(2, 3)]
    assert f.fault(1, "out of memory") == [(1, 2)]  # 1 (CPU now) takes the CPU unit
    assert list(f.queue) == [0, 1]  # both units it held, at the head, in their order
    assert f.request(2, 3) == [(2, 0)]


def test_worker_waits_while_a_unit_it_could_run_is_in_flight():
    """GPU worker 2 finds the queue empty while worker 1 runs a GPU unit: it waits (the unit may come back),
    takes it when 1's device fails, and everybody stops once it is done."""
    f = farm({1: Worker(gpu=0), 2: Worker(gpu=1)}, order=[0], gpu=[True])
    assert f.request(1) == [(1, 0)]
    assert f.request(2) == []
    assert f.workers[2].state == "waiting"
    # 1 (a CPU worker now) can run nothing queued or held elsewhere: it stops; 2 takes the unit back
    assert f.fault(1, "out of memory") == [(2, 0), (1, None)]
    assert f.workers[1].state == "stopped" and f.workers[2].state == "busy"
    assert f.request(2, 0) == [(2, None)]
    assert not f.busy()


def test_cpu_worker_stops_while_only_gpu_units_are_in_flight():
    f = farm({1: Worker(gpu=0), 2: Worker()}, order=[0, 1], gpu=[True, True])
    assert f.request(1) == [(1, 0)]
    assert f.request(2) == [(2, None)]  # GPU units only: a CPU worker is not needed


def test_no_gpu_left_leaves_gpu_units_pending_and_finishes_cpu_units():
    f = farm({1: Worker(gpu=0), 2: Worker()})
    assert f.request(2) == [(2, 2)]
    assert f.request(1) == [(1, 0)]
    f.row(0, 7)
    out = f.fault(1, "CUDARuntimeError: cudaErrorDevicesUnavailable: all CUDA-capable devices are busy")
    assert sorted(f.left) == [0, 1, 3] and f.skip(0) == frozenset({7})
    assert f.no_gpu.startswith("no GPU left (GPU 0: CUDARuntimeError")
    assert out == [(1, 4)]  # the CPU units still run
    assert [f.request(2, 2), f.request(1, 4)] == [[(2, 5)], [(1, None)]]
    assert f.request(2, 5) == [(2, None)] and not f.busy()


def test_stop_request_empties_the_queue_and_a_late_fault_is_not_requeued():
    f = farm({1: Worker(gpu=0), 2: Worker(gpu=1), 3: Worker()})
    assert f.request(1) == [(1, 0)]
    assert f.request(3) == [(3, 2)]
    assert f.stop() == []  # nobody waits yet
    assert f.request(2) == [(2, None)]
    assert f.fault(1, "out of memory") == [(1, None)]
    assert 0 not in f.queue and len(f.queue) == 0
    assert f.request(3, 2) == [(3, None)] and not f.busy()


@pytest.mark.parametrize("exc, fault", [
    (type("CUDARuntimeError", (RuntimeError,), {})("cudaErrorDevicesUnavailable: all CUDA-capable devices are "
                                                    "busy or unavailable"), True),
    (type("OutOfMemoryError", (MemoryError,), {})("Out of memory allocating 1,073,741,824 bytes"), True),
    (type("CUDADriverError", (RuntimeError,), {})("CUDA_ERROR_CONTEXT_IS_DESTROYED: context is destroyed"), True),
    (type("CudaSupportError", (ImportError,), {})("Error at driver init"), True),
    (RuntimeError("cudaErrorMpsMaxClientsReached: maximum number of clients reached"), True),
    (DeviceFault("injected"), True),
    (type("CUDARuntimeError", (RuntimeError,), {})("cudaErrorInvalidValue: invalid argument"), False),
    (MemoryError("host memory"), False),
    (ValueError("sigma0 must be > 0"), False),
    (RuntimeError("the solver diverged"), False),
    (RuntimeError("Warp CUDA error 2: out of memory (in function alloc_device)"), True),
])
def test_device_fault_classification(exc, fault):
    assert bool(device_fault(exc)) is fault
    if fault:
        assert type(exc).__name__ in device_fault(exc)


def test_device_fault_found_in_the_cause_chain():
    try:
        try:
            raise type("CUDARuntimeError", (RuntimeError,), {})("cudaErrorMemoryAllocation: out of memory")
        except RuntimeError as inner:
            raise ValueError("while making the histogram") from inner
    except ValueError as e:
        assert device_fault(e).startswith("CUDARuntimeError: cudaErrorMemoryAllocation")


# ---------------------------------------------------------------------------------------------------------
# the runner with a fake GPU (tests/fakegpu.py), in-process: serial runs


@pytest.fixture
def fakegpu(monkeypatch, tmp_path):
    """The test-only method ``fakegpu`` registered for this test (removed after it), one visible GPU, the job."""
    import importlib.util
    import sys
    from pathlib import Path

    from gapsweep.sweep.methods import base

    mod = sys.modules.get("fakegpu")
    if mod is None:
        spec = importlib.util.spec_from_file_location("fakegpu", Path(__file__).with_name("fakegpu.py"))
        mod = importlib.util.module_from_spec(spec)
        sys.modules["fakegpu"] = mod
        spec.loader.exec_module(mod)
    else:
        base.register(mod.FakeGPU)
    mod._ran.clear()
    hooks.gpus(monkeypatch, 1)
    monkeypatch.delenv("FAKEGPU_BROKEN", raising=False)
    job = tmp_path / "farm.toml"
    job.write_text(mod.JOB)
    yield job
    base._REGISTRY.pop("fakegpu", None)


def _expected(df):
    """fakegpu's closed form along each chain (pressures in decreasing order)."""
    import math

    out = {}
    for _, c in df[df.method == "fakegpu"].groupby(["hurst", "rho", "seed"]):
        g = 0.0
        for r in c.sort_values("sigma0", ascending=False).itertuples():
            g = g + math.log(r.sigma0) * (r.seed + 1) + r.hurst * r.rho  # as fakegpu adds
            out[r.task_id] = g
    return out


def test_serial_run_with_a_working_gpu(fakegpu, tmp_path):
    from gapsweep import runner, store

    s = runner.run(fakegpu, tmp_path / "s.h5", mpi="off", progress="none")
    assert s["pending"] == 0 and s["unfinished"] == 0 and s["failed"] == 0
    df = store.read(tmp_path / "s.h5")
    assert set(df.status) == {"done"} and (df.method == "fakegpu").sum() == 16
    want = _expected(df)
    got = df[df.method == "fakegpu"].set_index("task_id").mean_gap
    assert all(got[k] == v for k, v in want.items())


def test_serial_device_fault_leaves_gpu_rows_pending_then_resume_completes(fakegpu, tmp_path, monkeypatch, caplog):
    """The GPU fails at its second task: the first row of that chain stays done, every other GPU row pending,
    every CPU row done, one 'no GPU left' line, the run record says why; --resume with a working GPU finishes
    the store, equal to an undisturbed run."""
    import json
    import logging

    from gapsweep import runner, store

    ref = tmp_path / "ref.h5"
    runner.run(fakegpu, ref, mpi="off", progress="none")
    path = tmp_path / "s.h5"
    monkeypatch.setenv("FAKEGPU_BROKEN", "0@1")
    with caplog.at_level(logging.WARNING, logger="gapsweep"):
        s = runner.run(fakegpu, path, mpi="off", progress="none")
    assert s["done"] == s["todo"] - 15 and s["pending"] == 15 and s["failed"] == 0 and s["unfinished"] == 15
    df = store.read(path)
    assert (df[df.method == "theory"].status == "done").all()
    gpu = df[df.method == "fakegpu"]
    assert (gpu.status == "done").sum() == 1 and (gpu.status == "pending").sum() == 15
    lines = [r.getMessage() for r in caplog.records if "no GPU left" in r.getMessage()]
    assert len(lines) == 1 and "cudaErrorDevicesUnavailable" in lines[0] and "15 GPU task(s) left pending" in lines[0]
    run = json.loads(store.read_attrs(path)["runs"])[-1]
    assert "no GPU left" in run["stopped"] and run["pending"] == 15 and "GPU 0" in run["device_faults"][0]
    text = store.status(path)
    assert "pending: 15 row(s)" in text and "--resume" in text
    monkeypatch.delenv("FAKEGPU_BROKEN")
    s = runner.run(fakegpu, path, mpi="off", progress="none", resume=True)
    assert s["todo"] == 15 and s["done"] == 15 and s["unfinished"] == 0
    assert store.diff(path, ref) == []


def test_cli_exit_codes_partial_failure_and_pending(fakegpu, tmp_path, monkeypatch, capsys):
    """Exit 5 (documented in docs/running.md) for a run that leaves rows failed or pending, with one line naming
    the counts; 3 stays 'every task failed'; 0 only when every row is done."""
    from gapsweep import cli

    path = tmp_path / "s.h5"
    monkeypatch.setenv("FAKEGPU_BROKEN", "0")
    assert cli.main(["run", str(fakegpu), "--store", str(path), "--mpi", "off", "--progress", "none"]) == 5
    err = capsys.readouterr().err
    assert "16 row(s) not done (0 failed, 16 pending)" in err and "--resume" in err
    monkeypatch.delenv("FAKEGPU_BROKEN")
    hooks.fail_at(monkeypatch, 1.0)  # the first pressure of every GPU chain fails
    assert cli.main(["run", str(fakegpu), "--store", str(path), "--resume", "--mpi", "off"]) == 5
    err = capsys.readouterr().err
    assert "(4 failed, 0 pending)" in err
    # nothing left to run, but the store keeps failed rows: still not 0
    hooks.fail_at(monkeypatch)  # no task fails any more
    assert cli.main(["run", str(fakegpu), "--store", str(path), "--resume", "--mpi", "off"]) == 5
    ok = tmp_path / "ok.h5"
    assert cli.main(["run", str(fakegpu), "--store", str(ok), "--mpi", "off", "--progress", "none"]) == 0


# ---------------------------------------------------------------------------------------------------------
# layout of a node (gapsweep plan) and no CUDA context outside the GPU workers


@pytest.mark.parametrize("node, job, want", [
    ((4, 64, 48, 200), None, (64, 4, 59, False)),  # 4 GPUs, 64 cores: coordinator, 4 GPU workers, 59 CPU ranks
    ((4, 64, 48, 16), None, (21, 4, 16, False)),  # no more CPU ranks than CPU units
    ((4, 64, 2, 0), None, (3, 2, 0, False)),  # no more GPU workers than GPU units
    ((0, 64, 0, 100), None, (64, 0, 63, False)),  # a CPU node
    ((2, 2, 10, 10), None, (2, 2, 0, True)),  # 2 cores: the coordinator works (and drives GPU 0)
    ((0, 2, 0, 1), None, (1, 0, 1, True)),  # one unit: one process
])
def test_layout(node, job, want):
    from gapsweep.sweep.gpus import layout

    lay = layout(*node)
    assert (lay.ranks, lay.gpu_workers, lay.cpu_workers, lay.coordinator_works) == want
    assert lay.ranks == lay.gpu_workers + lay.cpu_workers + (0 if lay.coordinator_works else 1)


def test_layout_args_name_the_coordinator_only_where_the_default_differs():
    from gapsweep.sweep.gpus import Layout

    assert Layout(64, 4, 59, False).args() == "mpiexec -n 64 --bind-to none gapsweep run ..."
    assert Layout(4, 1, 2, False).args().endswith("--coordinator-works no")
    assert Layout(1, 0, 1, True).args().startswith("gapsweep run")


class Touched(BaseException):
    """Raised by the stand-in cupy: something imported or used it (not caught by `except Exception`)."""


@pytest.fixture
def no_cupy(monkeypatch):
    """cupy replaced by a module whose every use raises Touched; budget.gpu_memory_total likewise."""
    import sys
    import types

    from gapsweep.sweep import budget

    class Bomb(types.ModuleType):
        def __getattr__(self, name):
            raise Touched(f"cupy.{name}")

    monkeypatch.setitem(sys.modules, "cupy", Bomb("cupy"))
    monkeypatch.setattr(budget, "gpu_memory_total", lambda: (_ for _ in ()).throw(Touched("gpu_memory_total")))


def test_plan_and_a_coordinators_work_touch_no_cuda(fakegpu, no_cupy, monkeypatch, tmp_path):
    """`plan` and a run's start (the resource check, the run record with the SDE engine on CUDA) read GPUs only
    through nvidia-smi: cupy is never used and no CUDA context made (issue 26: 0.25 s per rank, serially)."""
    from gapsweep import runner
    from gapsweep.sweep import gpus, provenance
    from gapsweep.sweep import spec as specmod

    hooks.gpus(monkeypatch, 4)
    monkeypatch.setattr(gpus, "query", lambda: [{"index": str(i), "uuid": f"GPU-{i}", "name": "NVIDIA H200",
                                                 "memory": 150 * 10**9} for i in range(4)])
    text = runner.plan(fakegpu)
    assert "4 GPU(s) (NVIDIA H200, 150.0 GB)" in text and "1 GPU worker(s)" not in text
    assert "layout here:" in text and "4 GPU worker(s)" in text
    sde = specmod.loads(open(fakegpu).read() + "[methods.sde]\nsamples = 1000\ndevice = \"cuda\"\n")
    extras = provenance.run_extras(sde, gpu_ranks=[None, 0], batch="off", batch_units=0)
    assert extras["sde_engine"] in ("cuda", "warp")
    s = runner.run(fakegpu, tmp_path / "s.h5", mpi="off", progress="none")
    assert s["unfinished"] == 0


def test_gpu_memory_check_reads_nvidia_smi(fakegpu, monkeypatch):
    """A GPU job that does not fit the visible GPUs' memory (from nvidia-smi) is refused before anything runs."""
    import sys

    from gapsweep import runner
    from gapsweep.sweep import gpus

    fake = sys.modules["fakegpu"].FakeGPU
    monkeypatch.setattr(fake, "gpu_memory", lambda self, t: 30e9, raising=False)
    monkeypatch.setattr(gpus, "query", lambda: [{"index": "0", "uuid": "GPU-0", "name": "small", "memory": 16 * 2**30}])
    with pytest.raises(runner.RunError, match=r"GPU tasks need ~30.5 GB per GPU, more than this GPU's 17.2 GB"):
        runner.plan(fakegpu)


def test_prefetched_surface_is_the_same_bits():
    """A surface made ahead on a host thread (Context.prefetch) is the one made on the spot, bit for bit, and is
    used (not made twice)."""
    import numpy as np

    from gapsweep import spec as specmod
    from gapsweep.sweep.context import Context
    from gapsweep.sweep.tasks import expand

    job = __import__("pathlib").Path(__file__).resolve().parents[1] / "jobs" / "test_theory.toml"
    t = next(x for x in expand(specmod.load(job)) if x.n > 0)
    ctx = Context()
    ctx.ahead(2)
    try:
        ctx.prefetch(t, 256)
        assert len(ctx._ahead) == 1
        h = ctx.surface(t, 256)
        assert not ctx._ahead and ctx.surface(t, 256) is h and t.n > 0
        rms = ctx.surface_rms(t, 256)
    finally:
        ctx.close()
    fresh = Context()
    assert np.array_equal(h, fresh.surface(t, 256)) and rms == fresh.surface_rms(t, 256)


def test_without_gpu_workers_a_device_fault_does_not_loop():
    """No worker had a GPU: GPU units go to any worker; one whose device fails takes no more; when none is left
    the GPU units are left pending (no endless requeue to the same worker)."""
    f = farm({1: Worker(), 2: Worker()}, order=[0, 1, 2], gpu=[True, True, False])
    assert [f.request(1), f.request(2)] == [[(1, 0)], [(2, 1)]]
    assert f.fault(1, "cudaErrorNoDevice: no CUDA-capable device is detected") == [(1, 2)]
    assert f.fault(2, "cudaErrorNoDevice: no CUDA-capable device is detected") == [(2, None)]
    assert sorted(f.left) == [0, 1] and f.no_gpu.startswith("no GPU left (worker 1: cudaErrorNoDevice")
    assert f.request(1, 2) == [(1, None)] and not f.busy()
