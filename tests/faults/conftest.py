"""Helpers of the fault-injection suite (docs/reliability.md): real `gapsweep` processes, real signals, real
full disks. Every case asserts that nothing done was lost and that a resume reaches the uninterrupted result."""

from __future__ import annotations

import contextlib
import os
import shutil
import signal
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest

from gapsweep import store
from tests.mpi.mpirun import ENV as MPI_ENV

ROOT = Path(__file__).resolve().parents[2]
THEORY_JOB = ROOT / "jobs" / "test_theory.toml"
HIST_JOB = Path(__file__).resolve().parent / "jobs" / "hist.toml"


def env(**kw: str) -> dict[str, str]:
    """The child's environment: no inherited GAPSWEEP_TEST_*, the fault injection of tests/hooks on PYTHONPATH."""
    from tests.hooks.gapsweep_test_hooks import pythonpath

    e = {k: v for k, v in os.environ.items() if not k.startswith("GAPSWEEP_TEST_")}
    e.update(MPI_ENV)
    e["PYTHONPATH"] = pythonpath(os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")]))
    e.update(kw)
    return e


def gs_cmd(*args: str) -> list[str]:
    return [sys.executable, "-m", "gapsweep", *map(str, args)]


def gs(*args: str, timeout: float = 120, preexec=None, **envkw: str) -> subprocess.CompletedProcess:
    """Run ``gapsweep ARGS`` (serial: --mpi off is the caller's choice) and wait."""
    return subprocess.run(gs_cmd(*args), env=env(**envkw), capture_output=True, text=True, timeout=timeout,
                          preexec_fn=preexec)


def gs_here(capsys, *args: str, **envkw: str) -> subprocess.CompletedProcess:
    """``gapsweep ARGS`` in this process, for the refusals of bad input where no process boundary is under test
    (issue 41: one interpreter start per case cost ~1.5 s): ``cli.main`` with the output captured by pytest's
    ``capsys``, returned as a CompletedProcess (exit code, stdout, stderr) for :func:`one_line_error`. ``envkw``:
    environment variables set for the call only (GAPSWEEP_TEST_* hooks need a child: use :func:`gs`)."""
    from gapsweep import cli

    assert not any(k.startswith("GAPSWEEP_TEST_") for k in envkw), "fault hooks live in a child process: use gs()"
    saved = {k: os.environ.get(k) for k in envkw}
    os.environ.update(envkw)
    try:
        try:
            rc = cli.main([str(a) for a in args])
        except SystemExit as e:  # argparse's usage errors exit 2
            rc = e.code if isinstance(e.code, int) else 1
    finally:
        for k, v in saved.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v
    out = capsys.readouterr()
    return subprocess.CompletedProcess([str(a) for a in args], rc, out.out, out.err)


def gs_popen(*args: str, preexec=None, **envkw: str) -> subprocess.Popen:
    return subprocess.Popen(gs_cmd(*args), env=env(**envkw), stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True, preexec_fn=preexec)


def have_mpi() -> bool:
    if shutil.which("mpiexec") is None:
        return False
    try:
        import mpi4py  # noqa: F401
    except ImportError:
        return False
    return True


def h5py_mpi() -> bool:
    import h5py

    return bool(h5py.get_config().mpi)


needs_mpi = pytest.mark.skipif(not have_mpi(), reason="mpiexec or mpi4py not installed")
WRITERS = [pytest.param("mpio", marks=pytest.mark.skipif(not h5py_mpi(), reason="h5py without MPI")), "rank0"]


def mpi_cmd(n: int, *args: str) -> list[str]:
    return ["mpiexec", "-n", str(n), *gs_cmd(*args)]


def mpirun(n: int, *args: str, timeout: float = 120, **envkw: str) -> subprocess.CompletedProcess:
    return subprocess.run(mpi_cmd(n, *args), env=env(**envkw), capture_output=True, text=True, timeout=timeout)


def one_line_error(p: subprocess.CompletedProcess, *needles: str) -> str:
    """The process failed with a clean message: non-zero exit, no traceback, the message names the needles."""
    err = p.stderr
    assert p.returncode not in (0, None), (p.returncode, p.stdout, err)
    assert p.returncode > 0, f"killed by signal {-p.returncode}: {err}"
    assert "Traceback" not in err, err
    lines = [x for x in err.splitlines() if x.startswith("gapsweep")]
    assert lines, err
    for n in needles:
        assert n in err, (n, err)
    return err


def done_rows(path: Path) -> dict[str, tuple]:
    """{task_id: (row values without volatile columns, histogram)} of the done rows of a store."""
    df = store.read(path)
    hist = store.read_histograms(path)
    out = {}
    cols = [c for c in df.columns if c not in ("wall_time", "rank")]
    for row in df[df.status == "done"][cols].itertuples(index=False):
        r = row._asdict()
        h = hist.get(r["task_id"])
        out[r["task_id"]] = (r, h)
    return out


def assert_done_kept(before: dict[str, tuple], path: Path) -> None:
    """Every row done in ``before`` is still done in ``path`` with the same values and histogram."""
    after = done_rows(path)
    missing = set(before) - set(after)
    assert not missing, f"{len(missing)} done rows lost"
    for tid, (r, h) in before.items():
        r2, h2 = after[tid]
        for k, v in r.items():
            assert (v == r2[k]) or (isinstance(v, float) and np.isnan(v) and np.isnan(r2[k])), (tid, k, v, r2[k])
        if h is not None:
            assert np.array_equal(h[1], h2[1], equal_nan=True), tid


def assert_only_done_pending(path: Path) -> None:
    assert set(store.read(path).status) <= {"done", "pending"}


def wait_done(path: Path, n: int, proc: subprocess.Popen | None = None, timeout: float = 60) -> int:
    """Wait until ``path`` has at least ``n`` done rows (or the process ended); returns the count seen."""
    t0, done = time.monotonic(), 0
    while time.monotonic() - t0 < timeout and done < n:
        if proc is not None and proc.poll() is not None:
            break
        time.sleep(0.05)
        if path.exists():
            try:
                done = int((store.read(path).status == "done").sum())
            except Exception:
                pass  # being created
    return done


HOOKS = Path(__file__).resolve().parent / "hooks"


class Hold:
    """A barrier in a child run (tests/faults/hooks/sitecustomize.py): ``env()`` gives the environment that makes
    the process stop at ``k`` -- right after its ``k``-th store row write (a number), or at a point of its start
    ("import", "lease", "create", "opened") -- until :meth:`release` or a SIGINT/SIGTERM (or, after a row write,
    the store's stop file); :meth:`wait` returns once a process has got there. Nothing depends on how fast either
    side runs."""

    def __init__(self, folder: Path, k: int | str) -> None:
        self.folder, self.k = Path(folder), k
        self.folder.mkdir(parents=True, exist_ok=True)

    def env(self, **kw: str) -> dict[str, str]:
        from tests.hooks.gapsweep_test_hooks import pythonpath

        # this barrier first, then the suite's fault injection (tests/hooks, chained by this sitecustomize)
        path = os.pathsep.join([str(HOOKS), pythonpath(os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")]))])
        return {"FAULTS_HOLD": f"{self.folder}:{self.k}", "PYTHONPATH": path, **kw}

    def wait(self, proc: subprocess.Popen, timeout: float = 300) -> None:
        """Until a process of the run holds at its point; fails if the run ended first (or never got there:
        ``timeout`` only bounds a broken run, it decides nothing in a working one)."""
        self._await(proc, "reached-*", f"its hold point {self.k}", timeout, filled=False)

    def signalled(self, proc: subprocess.Popen, timeout: float = 300) -> int:
        """With ``env(FAULTS_HOLD_SIGNALS="n")``: wait until the held process has recorded its first signal
        (it then stays at the hold point until its n-th); returns that signal's number."""
        return int(self._await(proc, "signalled-*", "recording its signal", timeout, filled=True).read_text())

    def _await(self, proc: subprocess.Popen, pattern: str, what: str, timeout: float, filled: bool) -> Path:
        """The first file matching ``pattern`` in the folder once there (``filled``: once it has content)."""
        t0 = time.monotonic()
        while not (marks := [m for m in self.folder.glob(pattern) if not filled or m.read_text()]):
            if proc.poll() is not None:
                raise AssertionError(f"the run ended (exit {proc.returncode}) before {what}: "
                                     f"{proc.stderr.read() if proc.stderr else ''}")
            if time.monotonic() - t0 > timeout:
                raise AssertionError(f"{what}: not reached within {timeout} s")
            time.sleep(0.01)
        return marks[0]

    def release(self) -> None:
        (self.folder / "release").touch()


def kill(proc: subprocess.Popen, sig: int = signal.SIGKILL) -> None:
    try:
        os.kill(proc.pid, sig)
    except ProcessLookupError:
        pass


@contextlib.contextmanager
def reaped(proc: subprocess.Popen) -> Iterator[subprocess.Popen]:
    """``with reaped(p): ...``: ``p`` is killed and waited for on the way out if it still runs (a failing assert
    leaves no process behind)."""
    try:
        yield proc
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()


def finish(proc: subprocess.Popen, timeout: float = 60) -> tuple[int, str, str]:
    try:
        out, err = proc.communicate(timeout=timeout)
    except subprocess.TimeoutExpired:
        proc.kill()
        out, err = proc.communicate()
        raise AssertionError("process hung") from None
    return proc.returncode, out, err


@pytest.fixture(scope="session")
def refs(tmp_path_factory) -> dict[str, Path]:
    """Uninterrupted serial runs of the two jobs of the suite."""
    d = tmp_path_factory.mktemp("faultref")
    out = {}
    for name, job in (("theory", THEORY_JOB), ("hist", HIST_JOB)):
        out[name] = d / f"{name}.h5"
        p = gs("run", job, "--store", out[name], "--mpi", "off", "--progress", "none")
        assert p.returncode == 0, p.stderr
    return out


JOBS = {"theory": THEORY_JOB, "hist": HIST_JOB}


def resume_to_ref(path: Path, ref: Path, job: Path, *extra: str) -> None:
    """Resume (breaking a stale lease) and compare with the uninterrupted store."""
    p = gs("run", job, "--store", path, "--resume", "--mpi", "off", "--progress", "none", "--break-lease", *extra)
    assert p.returncode == 0, p.stderr
    assert store.diff(path, ref) == []


def wait_gone(pid: int, limit: float = 60.0) -> None:
    """Wait until process ``pid`` has exited (gone, or a zombie): an event, polled; ``limit`` only bounds a hang."""
    import os
    import time

    t0 = time.monotonic()
    while time.monotonic() - t0 < limit:
        try:
            os.kill(pid, 0)
            state = open(f"/proc/{pid}/stat").read().rsplit(")", 1)[1].split()[0]
        except (ProcessLookupError, FileNotFoundError, IndexError):
            return
        if state in ("Z", "X"):
            return
        time.sleep(0.05)
