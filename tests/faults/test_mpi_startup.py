"""MPI start-up errors (docs/reliability.md): any error before the farm starts ends every rank within seconds
with a message; a multi-rank launch with --mpi off is refused; nothing half-written is left."""

from __future__ import annotations

import time

import pytest

from gapsweep.sweep import lease

from .conftest import JOBS, WRITERS, mpirun, needs_mpi

pytestmark = needs_mpi


@pytest.mark.parametrize("writer", WRITERS)
def test_store_dir_cannot_be_created(tmp_path, writer):
    blocker = tmp_path / "file"
    blocker.write_text("x")
    t0 = time.monotonic()
    p = mpirun(2, "run", JOBS["theory"], "--store", blocker / "sub" / "s.h5", "--writer", writer, timeout=90)
    assert time.monotonic() - t0 < 60
    assert p.returncode != 0
    assert "Traceback" not in p.stderr and str(blocker) in p.stderr


def test_mpi_off_under_mpiexec(tmp_path):
    path = tmp_path / "s.h5"
    p = mpirun(2, "run", JOBS["theory"], "--store", path, "--mpi", "off", timeout=90)
    assert p.returncode != 0
    assert "--mpi off" in p.stderr and "Traceback" not in p.stderr
    assert not path.exists() and lease.read(path) is None


@pytest.mark.parametrize("writer", WRITERS)
def test_bad_spec_under_mpiexec(tmp_path, writer):
    job = tmp_path / "bad.toml"
    job.write_text(JOBS["theory"].read_text() + "\n[methods.theory.extra]\nzetta = 1\n")
    t0 = time.monotonic()
    p = mpirun(2, "run", job, "--store", tmp_path / "s.h5", "--writer", writer, timeout=90)
    assert time.monotonic() - t0 < 60
    assert p.returncode == 2 or p.returncode != 0
    assert "methods.theory.extra.zetta" in p.stderr and "Traceback" not in p.stderr


@pytest.mark.parametrize("writer", WRITERS)
def test_error_on_one_rank_before_farm(tmp_path, writer):
    t0 = time.monotonic()
    p = mpirun(2, "run", JOBS["theory"], "--store", tmp_path / "s.h5", "--writer", writer, timeout=90,
               GAPSWEEP_TEST_ABORT_RANK="1")
    assert time.monotonic() - t0 < 60
    assert p.returncode != 0
    assert "injected error on rank 1" in p.stdout + p.stderr


def test_store_leased_under_mpiexec(tmp_path, refs):
    """A live lease refuses an MPI run on every rank (no rank left waiting)."""
    import shutil

    path = tmp_path / "s.h5"
    shutil.copy(refs["theory"], path)
    held = lease.acquire(path)
    try:
        p = mpirun(2, "run", JOBS["theory"], "--store", path, "--overwrite", timeout=90)
        assert p.returncode != 0 and "in use by" in p.stderr
    finally:
        held.release()
    from gapsweep import store

    assert store.diff(path, refs["theory"]) == []
