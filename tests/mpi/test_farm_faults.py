"""Device faults in the MPI farm (docs/running.md, "When a GPU fails"), on the CPU with the fake GPU method of
tests/fakegpu.py (launched as ``mpiexec -n N python tests/fakegpu.py run ...``; ``GAPSWEEP_TEST_GPUS`` gives the
ranks their GPUs, ``FAKEGPU_BROKEN`` breaks some): a failed device loses no row and changes no result; when no
GPU is left the GPU rows stay pending, the run says so in one line and exits 5, and --resume finishes the store;
a run with failed rows exits 5 too (issue 31: 11 done and 1 failed under mpiexec -n 3 exited 0)."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from tests.mpi import mpirun

ROOT = Path(__file__).resolve().parents[2]
FAKE = ROOT / "tests" / "fakegpu.py"
ENV = {**mpirun.ENV, "GAPSWEEP_TEST_GPUS": "2"}


def _have_mpi() -> bool:
    try:
        import mpi4py  # noqa: F401
    except ImportError:
        return False
    return shutil.which("mpiexec") is not None


def _h5py_mpi() -> bool:
    import h5py

    return bool(h5py.get_config().mpi)


pytestmark = pytest.mark.skipif(not _have_mpi(), reason="mpiexec or mpi4py not installed")
WRITERS = [pytest.param("mpio", marks=pytest.mark.skipif(not _h5py_mpi(), reason="h5py without MPI")), "rank0"]


def fake(n: int, *args, **env: str) -> subprocess.CompletedProcess:
    """``gapsweep ARGS`` with the fake GPU method, under ``mpiexec -n n`` (n = 1: one process, no MPI)."""
    e = {k: v for k, v in os.environ.items() if not k.startswith(("GAPSWEEP_TEST_", "FAKEGPU_"))}
    from tests.hooks.gapsweep_test_hooks import pythonpath

    # with the fault injection of tests/hooks (GAPSWEEP_TEST_GPUS, GAPSWEEP_TEST_FAIL act through it)
    e.update(ENV, PYTHONPATH=pythonpath(os.pathsep.join([str(ROOT), e.get("PYTHONPATH", "")])), **env)
    if e.pop("FAKE_UNSET_CUDA", None):  # every GPU of the node visible: nvidia-smi says which
        e.pop("CUDA_VISIBLE_DEVICES", None)
    cmd = [sys.executable, str(FAKE), *map(str, args)]
    if n > 1:
        cmd = ["mpiexec", "-n", str(n), *cmd]
    return subprocess.run(cmd, env=e, capture_output=True, text=True, timeout=180)


@pytest.fixture(scope="module")
def job(tmp_path_factory):
    sys.path.insert(0, str(FAKE.parent))
    try:
        import fakegpu
    finally:
        sys.path.pop(0)
    d = tmp_path_factory.mktemp("farmjob")
    (d / "farm.toml").write_text(fakegpu.JOB)
    p = fake(1, "run", d / "farm.toml", "--store", d / "ref.h5", "--mpi", "off", "--progress", "none",
             GAPSWEEP_TEST_GPUS="1")
    assert p.returncode == 0, p.stderr
    return d / "farm.toml", d / "ref.h5"


def _runs(path):
    from gapsweep import store

    return json.loads(store.read_attrs(path)["runs"])


@pytest.mark.parametrize("writer", WRITERS)
def test_one_gpu_fails_no_row_lost(tmp_path, job, writer):
    """4 ranks, 2 GPUs (ranks 0 and 1), GPU 1 fails after two tasks (mid-chain): its unit goes back and is
    finished on GPU 0 (the two recorded rows kept); the store equals the one-GPU store; exit 0."""
    spec, ref = job
    path = tmp_path / "s.h5"
    p = fake(4, "run", spec, "--store", path, "--writer", writer, "--progress", "log", "--lookahead", "0",
             FAKEGPU_BROKEN="1@2", FAKEGPU_BARRIER=str(tmp_path))
    assert p.returncode == 0, p.stdout + p.stderr
    from gapsweep import store

    assert store.diff(path, ref) == []
    df = store.read(path)
    assert set(df.status) == {"done"}
    run = _runs(path)[-1]
    assert run["gpus"] == [0, 1, None, None]
    assert len(run["device_faults"]) == 1 and run["device_faults"][0].startswith("rank 1 (GPU 1): CUDARuntimeError")
    assert "stopped" not in run and "GPU 1 failed" in p.stderr and "no GPU left" not in p.stderr
    ranks = df[df.method == "fakegpu"]["rank"]
    assert set(ranks) == {0, 1}  # GPU rows only on the GPU workers
    assert (ranks == 1).sum() == 2  # the two rows GPU 1 recorded before it failed


@pytest.mark.parametrize("writer", WRITERS)
def test_no_gpu_left_rows_pending_exit_5_then_resume(tmp_path, job, writer):
    """3 ranks, both GPUs refuse every task (a full MPS server): the CPU rows are done, every GPU row stays
    pending, one 'no GPU left' line, exit 5; status names the rows and --resume; --resume with working GPUs
    completes the store, equal to the one-GPU store."""
    spec, ref = job
    path = tmp_path / "s.h5"
    p = fake(3, "run", spec, "--store", path, "--writer", writer, FAKEGPU_BROKEN="0,1")
    assert p.returncode == 5, p.stdout + p.stderr
    assert p.stderr.count("no GPU left") == 1 and "16 GPU task(s) left pending" in p.stderr
    assert "16 row(s) not done (0 failed, 16 pending)" in p.stderr and "Traceback" not in p.stderr
    from gapsweep import store

    df = store.read(path)
    assert set(df[df.method == "theory"].status) == {"done"}
    assert set(df[df.method == "fakegpu"].status) == {"pending"}
    st = fake(1, "status", path)
    assert st.returncode == 0 and "pending: 16 row(s)" in st.stdout and "--resume" in st.stdout
    assert "no GPU left" in st.stdout  # the run record says how the run ended
    assert fake(1, "status", path, "--finished").returncode == 4
    p = fake(3, "run", spec, "--store", path, "--writer", writer, "--resume")
    assert p.returncode == 0, p.stdout + p.stderr
    assert store.diff(path, ref) == []


@pytest.mark.parametrize("writer", WRITERS)
def test_gpus_fail_mid_run_with_units_held_ahead(tmp_path, job, writer):
    """4 ranks, coordinator only coordinating: GPU workers 1 and 2 hold units ahead (--lookahead 2) and each
    device fails at its fourth task, wherever the schedule puts it: every row is done with its undisturbed
    value or pending, none failed or lost; exit 5; --resume completes the one-GPU store."""
    spec, ref = job
    path = tmp_path / "s.h5"
    p = fake(4, "run", spec, "--store", path, "--writer", writer, "--coordinator-works", "no", "--lookahead", "2",
             FAKEGPU_BROKEN="0@3,1@3")
    from gapsweep import store

    df, want = store.read(path), store.read(ref)
    assert (df.status != "failed").all()
    done = df.status == "done"
    assert df[done].mean_gap.equals(want[done].mean_gap)
    pending = int((~done).sum())
    assert pending > 0 and set(df[~done].method) == {"fakegpu"}
    assert p.returncode == 5 and p.stderr.count("no GPU left") == 1, p.stdout + p.stderr
    assert f"{pending} row(s) not done (0 failed, {pending} pending)" in p.stderr
    p = fake(4, "run", spec, "--store", path, "--writer", writer, "--resume")
    assert p.returncode == 0, p.stdout + p.stderr
    assert store.diff(path, ref) == []


def test_partial_failure_exits_nonzero(tmp_path, job):
    """Issue 31: some rows done, some failed under mpiexec -n 3 exits 5 (not 0, not 3) with the counts."""
    spec, _ = job
    path = tmp_path / "s.h5"
    p = fake(3, "run", spec, "--store", path, GAPSWEEP_TEST_FAIL="1.0")
    assert p.returncode == 5, p.stdout + p.stderr
    assert "row(s) not done (6 failed, 0 pending)" in p.stderr


@pytest.mark.parametrize("ranks", [2, 4])
def test_gpus_looked_up_once_per_node_whatever_the_rank_count(tmp_path, job, ranks):
    """Start-up does not grow with the rank count: rank 0 reads the GPUs' memory and one rank per node counts
    the GPUs, through nvidia-smi (no CUDA context), 2 ranks or 4. A fake nvidia-smi on PATH logs its calls."""
    spec, ref = job
    bin_dir = tmp_path / "bin"
    bin_dir.mkdir()
    calls = tmp_path / "calls"
    smi = bin_dir / "nvidia-smi"
    smi.write_text(f"""#!/bin/sh
echo "$@" >> {calls}
case "$*" in
  -L*) echo "GPU 0: Fake (UUID: GPU-0)"; echo "GPU 1: Fake (UUID: GPU-1)";;
  *) echo "0, GPU-0, Fake, 81559"; echo "1, GPU-1, Fake, 81559";;
esac
""")
    smi.chmod(0o755)
    path = tmp_path / "s.h5"
    p = fake(ranks, "run", spec, "--store", path, GAPSWEEP_TEST_GPUS="",
             PATH=f"{bin_dir}{os.pathsep}{os.environ['PATH']}", FAKE_UNSET_CUDA="1")
    assert p.returncode == 0, p.stdout + p.stderr
    # rank 0's memory check (plan's and run's) and one GPU count for the node
    assert calls.read_text().splitlines() == ["--query-gpu=index,uuid,name,memory.total --format=csv,noheader,nounits",
                                              "-L"]
    from gapsweep import store

    assert _runs(path)[-1]["gpus"][:2] == [0, 1] and store.diff(path, ref) == []
