"""The GPU layout of a node (gapsweep.sweep.gpus, issue 38): ranks per GPU by default, the CUDA MPS daemon the run
starts and stops itself (a stand-in ``nvidia-cuda-mps-control`` on the PATH), the fallback to one rank per GPU,
and a GPU worker that makes its own GPU current before any CUDA call (a recording stand-in for cupy with CUDA
12's rule: setting a device opens its context). No GPU needed; no timing asserts."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import types
from pathlib import Path

import numpy as np
import pytest

from gapsweep.sweep import gpus

FAKE_CONTROL = """#!{python}
import os, sys
pipe, log = os.environ["CUDA_MPS_PIPE_DIRECTORY"], os.environ["FAKE_MPS_LOG"]
if sys.argv[1:] == ["-d"]:
    if os.environ.get("FAKE_MPS_FAIL"):
        sys.stderr.write("cannot start the daemon\\n")
        sys.exit(1)
    open(os.path.join(pipe, "control"), "w").close()
    open(log, "a").write("start " + pipe + "\\n")
else:
    open(log, "a").write(sys.stdin.read().strip() + " " + pipe + "\\n")
"""


@pytest.fixture
def fake_mps(tmp_path, monkeypatch):
    """A stand-in nvidia-cuda-mps-control first on the PATH; returns its log (one line per start / command)."""
    bin_dir = tmp_path / "bin"
    bin_dir.mkdir()
    ctl = bin_dir / "nvidia-cuda-mps-control"
    ctl.write_text(FAKE_CONTROL.format(python=sys.executable))
    ctl.chmod(0o755)
    monkeypatch.setenv("PATH", f"{bin_dir}{os.pathsep}{os.environ['PATH']}")
    monkeypatch.setenv("FAKE_MPS_LOG", str(tmp_path / "mps.log"))
    monkeypatch.delenv("CUDA_MPS_PIPE_DIRECTORY", raising=False)
    monkeypatch.setattr(gpus, "mps_processes", lambda: [])
    return tmp_path / "mps.log"


def test_default_ranks_per_gpu():
    """min(K_G, W // G, 48 // G, memory cap) under MPS (K_G: 8 per GPU, as measured), at least 1; 1 without
    MPS."""
    assert gpus.auto_per_gpu(1, 63, True) == 8  # issue 38: 8 per GPU the best one-GPU layout with GPU surfaces
    assert gpus.auto_per_gpu(1, 5, True) == 5  # no more than the working ranks
    assert gpus.auto_per_gpu(2, 63, True) == 8  # two GPUs: 8 per GPU beat 16
    assert gpus.auto_per_gpu(4, 63, True) == 8
    assert gpus.auto_per_gpu(8, 127, True) == 6  # 48 clients per MPS server (issue 26)
    assert gpus.auto_per_gpu(4, 6, True) == 1
    assert gpus.auto_per_gpu(2, 63, True, cap=3) == 3
    assert gpus.auto_per_gpu(4, 63, False) == 1 and gpus.auto_per_gpu(0, 63, True) == 1
    with pytest.raises(ValueError, match=r"ranks-per-gpu: expected an integer in \[1, 48\]"):
        gpus.assign(0, 1, per_gpu=49)


def test_mps_started_and_stopped_when_the_ranks_are_gone(fake_mps):
    """No MPS runs and the control program is there: the node starts a daemon in its own folder, the default is
    8 ranks per GPU (15 working ranks: 8); the watcher quits the daemon and removes the folder once
    the ranks' processes have exited."""
    k, m, note = gpus._node_plan(1, 15, None, gpus.MPS_CLIENTS)
    assert k == 8 and m is not None and "started a daemon" in note
    folder = m.folder
    assert (folder / "pipe" / "control").exists() and m.env["CUDA_MPS_PIPE_DIRECTORY"] == str(folder / "pipe")
    assert fake_mps.read_text().splitlines() == [f"start {folder / 'pipe'}"]
    rank = subprocess.Popen([sys.executable, "-c", "import sys; sys.stdin.read()"], stdin=subprocess.PIPE)
    m.watch([rank.pid, os.getpid() + 10**7])  # the second: an id no process has
    rank.stdin.close()
    rank.wait(timeout=60)
    assert m.watcher.wait(timeout=60) == 0
    assert fake_mps.read_text().splitlines() == [f"start {folder / 'pipe'}", f"quit {folder / 'pipe'}"]
    assert not folder.exists()


def test_watcher_waits_for_a_live_rank(fake_mps):
    """While a rank lives the daemon stays (no quit yet); stop() quits it at once."""
    k, m, _ = gpus._node_plan(2, 31, None, gpus.MPS_CLIENTS)
    assert k == 8
    rank = subprocess.Popen([sys.executable, "-c", "import sys; sys.stdin.read()"], stdin=subprocess.PIPE)
    try:
        m.watch([rank.pid])
        with pytest.raises(subprocess.TimeoutExpired):
            m.watcher.wait(timeout=0.5)
        assert fake_mps.read_text().count("quit") == 0 and m.folder.exists()
    finally:
        rank.stdin.close()
        rank.wait(timeout=60)
    assert m.watcher.wait(timeout=60) == 0 and not m.folder.exists()
    assert fake_mps.read_text().count("quit") == 1


def test_without_mps_one_rank_per_gpu_and_why(fake_mps, monkeypatch, tmp_path):
    # the daemon fails: its folder is removed, one rank per GPU, the note says why
    monkeypatch.setenv("FAKE_MPS_FAIL", "1")
    before = set(Path(os.environ.get("TMPDIR", "/tmp")).glob("gapsweep-mps-*"))
    k, m, note = gpus._node_plan(1, 15, None, gpus.MPS_CLIENTS)
    assert (k, m) == (1, None) and "cannot start the daemon" in note and note.endswith("one rank per GPU")
    assert set(Path(os.environ.get("TMPDIR", "/tmp")).glob("gapsweep-mps-*")) == before
    # an explicit K is kept (time slices), and said so
    k, m, note = gpus._node_plan(1, 15, 4, gpus.MPS_CLIENTS)
    assert (k, m) == (4, None) and "time slices" in note
    monkeypatch.delenv("FAKE_MPS_FAIL")
    # an MPS daemon of someone else runs (its pipe not reachable from here): not started a second time
    monkeypatch.setattr(gpus, "mps_processes", lambda: [4242])
    monkeypatch.setenv("CUDA_MPS_PIPE_DIRECTORY", str(tmp_path / "elsewhere"))
    k, m, note = gpus._node_plan(1, 15, None, gpus.MPS_CLIENTS)
    assert (k, m) == (1, None) and "cannot reach" in note
    assert "start" not in (fake_mps.read_text() if fake_mps.exists() else "")  # never started
    # a running daemon whose control pipe is reachable is used as it is
    (tmp_path / "elsewhere").mkdir()
    (tmp_path / "elsewhere" / "control").touch()
    k, m, note = gpus._node_plan(1, 15, None, gpus.MPS_CLIENTS)
    assert (k, m) == (8, None) and "using the running daemon" in note
    # the daemon starts but a client cannot connect (its server refuses): stopped again, one rank per GPU
    monkeypatch.setattr(gpus, "mps_processes", lambda: [])
    monkeypatch.delenv("CUDA_MPS_PIPE_DIRECTORY")
    monkeypatch.setattr(gpus, "_probe_mps", lambda m: "a client of the daemon failed: cudaErrorMpsServerNotReady")
    k, m, note = gpus._node_plan(1, 15, None, gpus.MPS_CLIENTS)
    assert (k, m) == (1, None) and "cudaErrorMpsServerNotReady" in note
    lines = fake_mps.read_text().splitlines()
    assert lines[-2].startswith("start ") and lines[-1] == "quit " + lines[-2].split()[1]
    assert not Path(lines[-1].split()[1]).exists()
    # no control program at all
    monkeypatch.setattr(gpus, "mps_processes", lambda: [])
    monkeypatch.setattr(gpus.shutil, "which", lambda name: None)
    k, m, note = gpus._node_plan(1, 15, None, gpus.MPS_CLIENTS)
    assert (k, m) == (1, None) and "no nvidia-cuda-mps-control" in note
    # one working rank per GPU or fewer: no MPS needed, none started
    k, m, note = gpus._node_plan(4, 4, None, gpus.MPS_CLIENTS)
    assert (k, m, note) == (1, None, "")


def test_mps_processes_are_found_by_name(tmp_path):
    """A process named nvidia-cuda-mps-control (any user) is seen in /proc."""
    if not Path("/proc/self/comm").exists():
        pytest.skip("no /proc")
    fake = tmp_path / "nvidia-cuda-mps-control"
    shutil.copy(shutil.which("sleep") or "/bin/sleep", fake)
    p = subprocess.Popen([str(fake), "60"])
    try:
        assert _until(lambda: p.pid in gpus.mps_processes())
    finally:
        p.kill()
        p.wait()
    assert p.pid not in gpus.mps_processes()


def _until(cond, timeout: float = 60.0) -> bool:
    """Wait for ``cond()`` (a process's state seen by another one), at most ``timeout`` seconds."""
    import time

    end = time.monotonic() + timeout
    while not cond():
        if time.monotonic() > end:
            return False
        time.sleep(0.05)
    return True


class _FakeCuda:
    """Records cupy's CUDA calls; a context opens on a device when it is set current (CUDA 12) or used."""

    def __init__(self) -> None:
        self.current, self.calls, self.contexts = 0, [], set()

    def module(self) -> types.ModuleType:
        me = self
        cp = types.ModuleType("cupy")

        class runtime:
            @staticmethod
            def getDeviceCount():
                return 4

            @staticmethod
            def getDevice():
                return me.current

            @staticmethod
            def setDevice(i):
                me.calls.append(("setDevice", i))
                me.current = i
                me.contexts.add(i)

        class Device:  # cupy.cuda.Device's rules: enter sets the device, exit sets the previous one back
            def __init__(self, i=None):
                self.id = me.current if i is None else i

            def __enter__(self):
                self.prev = me.current
                if self.prev != self.id:
                    runtime.setDevice(self.id)
                return self

            def __exit__(self, *a):
                if self.prev != self.id:
                    runtime.setDevice(self.prev)

            def use(self):
                runtime.setDevice(self.id)

        def used(f):
            def g(*a, **k):
                me.calls.append((f.__name__, me.current))
                me.contexts.add(me.current)
                return f(*a, **k)
            return g

        class RawModule:
            @used
            def __init__(self, code=None, options=()):
                pass

            def get_function(self, name):
                @used
                def launch(grid, block, args, shared_mem=0):
                    pass
                return launch

        cp.cuda = types.SimpleNamespace(runtime=runtime, Device=Device)
        cp.RawModule = RawModule
        cp.asarray = used(lambda a, dtype=None: np.asarray(a, dtype=dtype))
        cp.empty = used(lambda n, dtype=None: np.zeros(n, dtype=dtype))
        cp.zeros = used(lambda n, dtype=None: np.zeros(n, dtype=dtype))
        cp.asnumpy = used(np.asarray)
        cp.uint64 = np.uint64
        return cp


SDE_JOB = """
[job]
name = "sde-on-gpu-2"
[grid]
hurst = [0.3]
rho = [2e-3]
sigma0 = [1e-2]
seeds = [0]
[surface]
lambda_l = 0.25
lambda_s = 0.0625
[methods.sde]
samples = 1000
device = "cuda"
"""


@pytest.mark.parametrize("select", [True, False])
def test_sde_worker_opens_a_context_on_its_gpu_only(monkeypatch, select):
    """An SDE task on the worker of GPU 2: its first CUDA call makes GPU 2 current, and no context opens on any
    other GPU. Without that selection (the control case) the engine's ``with Device(2)`` sets device 0 back on
    exit and opens a context there: the ~520 MiB per worker on GPU 0 of issue 38."""
    from gapsweep.gapdist import _sde_cuda
    from gapsweep.sweep import spec as specmod
    from gapsweep.sweep.context import Context
    from gapsweep.sweep.methods import sde as sde_method
    from gapsweep.sweep.tasks import expand

    fake = _FakeCuda()
    monkeypatch.setitem(sys.modules, "cupy", fake.module())
    monkeypatch.delenv("GAPSWEEP_SDE_ENGINE", raising=False)
    _sde_cuda._module.cache_clear()
    try:
        t = next(x for x in expand(specmod.loads(SDE_JOB)) if x.method == "sde")
        ctx = Context(gpu=2)
        if not select:
            monkeypatch.setattr(ctx, "select_gpu", lambda: 2)  # the device index only, as before issue 38
        res, _ = sde_method.run_sde(t, ctx)
    finally:
        _sde_cuda._module.cache_clear()
    assert res.status in ("done", "not_converged")  # the stand-in's kernels write zeros: a row all the same
    assert any(c[0] == "__init__" for c in fake.calls)  # the CUDA engine ran (its module was built)
    if select:
        assert fake.calls[0] == ("setDevice", 2)
        assert fake.contexts == {2}
    else:
        assert fake.contexts == {0, 2}


THEORY_AND_SDE = SDE_JOB.replace('name = "sde-on-gpu-2"', 'name = "layout"').replace(
    "sigma0 = [1e-2]", "sigma0 = [1e-3, 1e-2]").replace("seeds = [0]", "seeds = [0, 1]") + (
    '[methods.theory]\nforms = ["paper"]\n')


@pytest.mark.skipif(shutil.which("mpiexec") is None, reason="mpiexec not installed")
def test_farm_default_layout_under_mpi(fake_mps, tmp_path):
    """3 ranks, 1 (mocked) GPU, the default layout, coordinator only coordinating: both workers share the GPU
    under an MPS daemon the run started (the run record says so) and stopped after the ranks left; with
    GAPSWEEP_TRACE each rank wrote its timeline: every unit ran once, and the coordinator handled each ask of
    a worker after it was made (latency >= 0), one handling per ask."""
    import json

    from gapsweep import store
    from tests.mpi.test_mpi import mpirun

    js = tmp_path / "job.toml"
    js.write_text(THEORY_AND_SDE)
    path, trace = tmp_path / "s.h5", tmp_path / "trace"
    p = mpirun(3, ["run", str(js), "--store", str(path), "--writer", "rank0", "--coordinator-works", "no"],
               env={"GAPSWEEP_TEST_GPUS": "1", "GAPSWEEP_TRACE": str(trace), "PATH": os.environ["PATH"],
                    "FAKE_MPS_LOG": str(fake_mps)})
    assert p.returncode in (0, 3, 5), p.stdout + p.stderr  # the SDE rows fail where no CUDA device is: 5 or 3
    rec = json.loads(store.read_attrs(path)["runs"])[-1]
    assert rec["gpus"] == [None, 0, 0] and rec["ranks_per_gpu"] == 2 and "started a daemon" in rec["mps"]
    pipe = Path(fake_mps.read_text().split()[1])
    assert _until(lambda: not pipe.exists())  # the watcher quits the daemon once the three ranks are gone
    lines = fake_mps.read_text().splitlines()
    assert lines == [f"start {pipe}", f"quit {pipe}"]
    recs = {r: json.loads((trace / f"rank{r}.farm0.json").read_text()) for r in range(3)}
    ran = [u[0] for r in (1, 2) for u in recs[r]["units"]]
    assert ran and len(ran) == len(set(ran))
    assert all(u[1] <= u[2] for r in (1, 2) for u in recs[r]["units"])
    for w in (1, 2):
        asks, handled = recs[w]["asks"], recs[0]["handled"][str(w)]
        assert len(asks) == len(handled) >= 2
        assert all(h >= a for a, h in zip(asks, handled))
    assert recs[0]["rows"] == len(store.read(path))
