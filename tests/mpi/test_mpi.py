"""The sweep under ``mpiexec`` (launched here as subprocesses; skipped without mpiexec/mpi4py): stores from 1, 2
and 4 ranks are identical in content for the parallel-HDF5 (mpio) and the rank-0 writer; a rank killed with
kill -9 loses only its in-flight tasks and --resume completes the store; a rank failing inside the collective
part aborts the job instead of hanging; re-running a finished job under MPI is a no-op."""

from __future__ import annotations

import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from gapsweep import runner, store
from tests.mpi.mpirun import ENV

ROOT = Path(__file__).resolve().parents[2]
THEORY_JOB = ROOT / "jobs" / "test_theory.toml"
MIXED_JOB = ROOT / "jobs" / "test_mixed.toml"

pytestmark = pytest.mark.skipif(shutil.which("mpiexec") is None, reason="mpiexec not installed")


def _have_mpi4py() -> bool:
    try:
        import mpi4py  # noqa: F401
    except ImportError:
        return False
    return True


def _h5py_mpi() -> bool:
    import h5py

    return bool(h5py.get_config().mpi)


WRITERS = [pytest.param("mpio", marks=pytest.mark.skipif(not _h5py_mpi(), reason="h5py without MPI")), "rank0"]


def mpirun(n: int, args: list[str], env: dict[str, str] | None = None, timeout: float = 120,
           popen: bool = False):
    if not _have_mpi4py():
        pytest.skip("mpi4py not installed")
    # oversubscription via OMPI_MCA_rmaps_base_oversubscribe (Open MPI); MPICH needs no flag and rejects one
    cmd = ["mpiexec", "-n", str(n), sys.executable, "-m", "gapsweep", *args]
    e = dict(os.environ, **ENV, **(env or {}))
    if any(k.startswith("GAPSWEEP_TEST_") for k in e):  # fault injection from outside the package
        from tests.hooks.gapsweep_test_hooks import pythonpath

        e["PYTHONPATH"] = pythonpath(os.pathsep.join([str(Path(__file__).resolve().parents[2]),
                                                      e.get("PYTHONPATH", "")]))
    if popen:
        return subprocess.Popen(cmd, env=e, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    return subprocess.run(cmd, env=e, capture_output=True, text=True, timeout=timeout)


@pytest.fixture(scope="module")
def refs(tmp_path_factory):
    d = tmp_path_factory.mktemp("mpiref")
    out = {}
    for name, job in (("theory", THEORY_JOB), ("mixed", MIXED_JOB)):
        out[name] = d / f"{name}.h5"
        runner.run(job, out[name], progress="none", mpi="off")
    return out


@pytest.mark.parametrize("writer", WRITERS)
@pytest.mark.parametrize("ranks", [2, 4])
def test_ranks_give_identical_store(tmp_path, refs, writer, ranks):
    path = tmp_path / "s.h5"
    p = mpirun(ranks, ["run", str(MIXED_JOB), "--store", str(path), "--writer", writer, "--progress", "log"])
    assert p.returncode == 0, p.stdout + p.stderr
    assert store.diff(path, refs["mixed"]) == []
    attrs = store.read_attrs(path)
    assert f'"mpi_size": {ranks}' in attrs["runs"] and f'"writer": "{writer}"' in attrs["runs"]
    assert "finished" in p.stderr
    # a finished job is a no-op under MPI too
    before = path.read_bytes()
    p = mpirun(ranks, ["run", str(MIXED_JOB), "--store", str(path), "--resume", "--writer", writer])
    assert p.returncode == 0, p.stdout + p.stderr
    assert "nothing to do" in p.stderr
    assert path.read_bytes() == before


@pytest.mark.parametrize("writer", WRITERS)
def test_kill9_rank_then_resume(tmp_path, refs, writer):
    path, pids = tmp_path / "k.h5", tmp_path / "pids"
    pids.mkdir()
    env = {"GAPSWEEP_TEST_DELAY": "0.05", "GAPSWEEP_TEST_PIDDIR": str(pids)}
    # rank 0 only coordinates, so that the killed worker is the one running tasks
    p = mpirun(2, ["run", str(THEORY_JOB), "--store", str(path), "--writer", writer, "--progress", "none",
                   "--coordinator-works", "no"], env=env, popen=True)
    try:
        t0, done = time.monotonic(), 0
        while time.monotonic() - t0 < 60 and done < 8:
            time.sleep(0.1)
            if path.exists() and (pids / "rank1.pid").exists():
                try:
                    done = int((store.read(path).status == "done").sum())
                except Exception:
                    pass
        os.kill(int((pids / "rank1.pid").read_text()), signal.SIGKILL)
        p.communicate(timeout=60)
    finally:
        if p.poll() is None:
            p.kill()
            p.wait()
    assert p.returncode != 0
    df = store.read(path)  # readable after the kill, no h5clear
    n_done = int((df.status == "done").sum())
    assert 8 <= n_done < len(df)
    assert set(df.status) == {"done", "pending"}
    q = mpirun(2, ["run", str(THEORY_JOB), "--store", str(path), "--resume", "--writer", writer, "--break-lease"])
    assert q.returncode == 0, q.stdout + q.stderr
    assert f"resume, {len(df) - n_done} of {len(df)} tasks run" in q.stdout
    assert store.diff(path, refs["theory"]) == []


@pytest.mark.parametrize("writer", WRITERS)
def test_rank_error_in_collective_aborts(tmp_path, writer):
    path = tmp_path / "a.h5"
    t0 = time.monotonic()
    p = mpirun(2, ["run", str(THEORY_JOB), "--store", str(path), "--writer", writer],
               env={"GAPSWEEP_TEST_ABORT_RANK": "1"}, timeout=90)
    assert p.returncode != 0
    assert "injected error on rank 1" in p.stdout + p.stderr
    assert time.monotonic() - t0 < 60
