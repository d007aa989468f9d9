"""Full disks, file-size limits and write errors (docs/reliability.md): a one-line message and a non-zero exit,
never a segfault or a hang; every row done before stays done; after freeing space a resume reaches the
uninterrupted result. Stores allocate all their space at creation, so a disk that fills up during a run does
not touch the row writes. A small tmpfs is mounted where root may; otherwise RLIMIT_FSIZE stands in."""

from __future__ import annotations

import os
import resource
import subprocess
import time
from pathlib import Path

import pytest

from gapsweep import store
from gapsweep.sweep import lease

from .conftest import (
    JOBS,
    WRITERS,
    assert_done_kept,
    assert_only_done_pending,
    done_rows,
    env,
    finish,
    gs,
    gs_popen,
    mpi_cmd,
    needs_mpi,
    one_line_error,
    resume_to_ref,
    wait_done,
)


@pytest.fixture
def small_fs(tmp_path):
    """A 2 MB tmpfs (root) or None."""
    d = tmp_path / "fs"
    d.mkdir()
    if os.geteuid() != 0:
        yield None
        return
    r = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=2m", "tmpfs", str(d)], capture_output=True)
    if r.returncode != 0:
        yield None
        return
    try:
        yield d
    finally:
        subprocess.run(["umount", "-l", str(d)], capture_output=True)


def _fill(d: Path) -> Path:
    """Fill the file system of ``d`` to the last byte (unbuffered writes until ENOSPC)."""
    f = d / "filler"
    fd = os.open(f, os.O_WRONLY | os.O_CREAT | os.O_APPEND)
    try:
        for size in (65536, 4096, 1):
            try:
                while True:
                    os.write(fd, b"\0" * size)
            except OSError:
                pass
    finally:
        os.close(fd)
    return f


def _fsize(limit: int):
    def pre():
        resource.setrlimit(resource.RLIMIT_FSIZE, (limit, limit))
    return pre


def test_full_before_create(tmp_path, refs, small_fs):
    if small_fs is None:
        pytest.skip("cannot mount a tmpfs here (not root)")
    filler = _fill(small_fs)
    path = small_fs / "s.h5"
    p = gs("run", JOBS["hist"], "--store", path, "--mpi", "off", "--progress", "none")
    one_line_error(p, str(path), "No space left")
    assert not path.exists() and lease.read(path) is None
    filler.unlink()
    resume_to_ref(path, refs["hist"], JOBS["hist"])


def test_fsize_limit_at_create(tmp_path, refs):
    """File-size limit below the store's size: creation fails with one line, no file and no lease left."""
    path = tmp_path / "s.h5"
    p = gs("run", JOBS["hist"], "--store", path, "--mpi", "off", "--progress", "none", preexec=_fsize(20_000))
    one_line_error(p, str(path), "nothing was written")
    assert not path.exists() and lease.read(path) is None
    assert [x.name for x in tmp_path.iterdir()] == []  # no temporary file left
    resume_to_ref(path, refs["hist"], JOBS["hist"])


@pytest.mark.parametrize("job", ["theory", "hist"])
def test_disk_fills_during_run(tmp_path, refs, small_fs, job):
    if small_fs is None:
        pytest.skip("cannot mount a tmpfs here (not root)")
    path = small_fs / "s.h5"
    p = gs_popen("run", JOBS[job], "--store", path, "--mpi", "off", "--progress", "none",
                 GAPSWEEP_TEST_DELAY="0.04")
    wait_done(path, 3, p)
    filler = _fill(small_fs)
    seen = done_rows(path)
    rc, _, err = finish(p)
    assert rc in (0, 1), err  # finishes (space was allocated at creation) or stops with a message
    assert "Traceback" not in err
    assert_only_done_pending(path)
    assert_done_kept(seen, path)
    filler.unlink()
    resume_to_ref(path, refs[job], JOBS[job])


def test_resume_on_full_disk(tmp_path, refs, small_fs):
    if small_fs is None:
        pytest.skip("cannot mount a tmpfs here (not root)")
    path = small_fs / "s.h5"
    p = gs("run", JOBS["hist"], "--store", path, "--mpi", "off", "--progress", "none",
           GAPSWEEP_TEST_WRITE_ERROR="8")
    assert p.returncode == 1
    seen = done_rows(path)
    filler = _fill(small_fs)
    p = gs("run", JOBS["hist"], "--store", path, "--mpi", "off", "--progress", "none", "--resume")
    assert p.returncode in (0, 1) and "Traceback" not in p.stderr, p.stderr
    assert_only_done_pending(path)
    assert_done_kept(seen, path)
    filler.unlink()
    resume_to_ref(path, refs["hist"], JOBS["hist"])


def test_resume_under_fsize_limit(tmp_path, refs):
    path = tmp_path / "s.h5"
    p = gs("run", JOBS["hist"], "--store", path, "--mpi", "off", "--progress", "none",
           GAPSWEEP_TEST_WRITE_ERROR="8")
    assert p.returncode == 1
    seen = done_rows(path)
    size = path.stat().st_size
    p = gs("run", JOBS["hist"], "--store", path, "--mpi", "off", "--progress", "none", "--resume",
           preexec=_fsize(size))
    assert p.returncode in (0, 1) and "Traceback" not in p.stderr and p.returncode >= 0, p.stderr
    assert_only_done_pending(path)
    assert_done_kept(seen, path)
    resume_to_ref(path, refs["hist"], JOBS["hist"])


@pytest.mark.parametrize("k", [1, 7, 15])
def test_write_error_serial(tmp_path, refs, k):
    """A write error (ENOSPC injected between a row's histogram and its status): one line, exit 1, the rows
    before stay done, the lease is released, and a resume completes the store."""
    path = tmp_path / "s.h5"
    p = gs("run", JOBS["hist"], "--store", path, "--mpi", "off", "--progress", "none",
           GAPSWEEP_TEST_WRITE_ERROR=str(k))
    one_line_error(p, str(path), "No space left", "--resume")
    df = store.read(path)
    assert int((df.status == "done").sum()) == k - 1
    assert_only_done_pending(path)
    assert lease.read(path) is None
    p = gs("run", JOBS["hist"], "--store", path, "--mpi", "off", "--progress", "none", "--resume")
    assert p.returncode == 0, p.stderr
    assert store.diff(path, refs["hist"]) == []


@needs_mpi
@pytest.mark.parametrize("writer", WRITERS)
def test_write_error_mpi(tmp_path, refs, writer):
    """A write error on a rank under mpiexec aborts every rank within seconds (no deadlock)."""
    path = tmp_path / "s.h5"
    t0 = time.monotonic()
    p = subprocess.run(mpi_cmd(2, "run", JOBS["hist"], "--store", path, "--writer", writer, "--progress", "none"),
                       env=env(GAPSWEEP_TEST_WRITE_ERROR="3"), capture_output=True, text=True, timeout=120)
    assert time.monotonic() - t0 < 60
    assert p.returncode != 0
    assert "No space left" in p.stdout + p.stderr
    assert_only_done_pending(path)
    resume_to_ref(path, refs["hist"], JOBS["hist"])


def _skip_unless_mpi_starts_under_fsize(limit: int) -> None:
    """Skip where the MPI library itself cannot start under the file-size limit: the case tests gapsweep's
    handling of a store that cannot be created, not the transport. Open MPI starts; the MPICH wheel's UCX
    transport backs its shared memory by files larger than the limit and dies in MPI_Init (issue 19: the
    plain-user run of scripts/test.sh failed here with the transport's message instead of gapsweep's)."""
    import sys

    probe = ["mpiexec", "-n", "2", "prlimit", f"--fsize={limit}", sys.executable, "-c",
             "from mpi4py import MPI; MPI.COMM_WORLD.Barrier()"]
    try:
        p = subprocess.run(probe, env=env(), capture_output=True, text=True, timeout=60)
    except subprocess.TimeoutExpired:
        pytest.skip(f"MPI does not start under a {limit}-byte file-size limit (the probe hung)")
    if p.returncode != 0:
        why = next((x for x in (p.stderr + p.stdout).splitlines() if x.strip()), f"exit {p.returncode}")
        pytest.skip(f"this MPI's transport cannot start under a {limit}-byte file-size limit: {why[:200]}")


@needs_mpi
@pytest.mark.parametrize("writer", WRITERS)
def test_fsize_limit_mpi_create(tmp_path, refs, writer):
    """Creation under a file-size limit of the ranks (not of mpiexec, whose own files need room): every rank
    ends with a message, no hang, no store."""
    import shutil
    import sys

    if shutil.which("prlimit") is None:
        pytest.skip("prlimit not installed")
    _skip_unless_mpi_starts_under_fsize(20000)
    path = tmp_path / "s.h5"
    cmd = ["mpiexec", "-n", "2", "prlimit", "--fsize=20000", sys.executable, "-m", "gapsweep", "run", str(JOBS["hist"]),
           "--store", str(path), "--writer", writer, "--progress", "none"]
    t0 = time.monotonic()
    p = subprocess.run(cmd, env=env(), capture_output=True, text=True, timeout=120)
    assert time.monotonic() - t0 < 60
    assert p.returncode != 0
    assert "nothing was written" in p.stdout + p.stderr
    assert not path.exists()
    resume_to_ref(path, refs["hist"], JOBS["hist"])
