"""Two runs on one store (docs/reliability.md, "Exclusive access"): the lease refuses the second writer
whatever HDF5_USE_FILE_LOCKING says and for every writer; the first run finishes to the uninterrupted result."""

from __future__ import annotations

import pytest

from gapsweep import lease, store

from .conftest import (
    JOBS,
    WRITERS,
    finish,
    gs,
    gs_popen,
    mpi_cmd,
    needs_mpi,
    one_line_error,
    wait_done,
)

SECOND = {
    "plain": ["--progress", "none"],
    "overwrite": ["--overwrite", "--progress", "none"],
    "resume": ["--resume", "--progress", "none"],
    "break-lease-of-live-run": ["--resume", "--break-lease", "--progress", "none"],
}


@pytest.mark.parametrize("locking", ["default", "FALSE"])
@pytest.mark.parametrize("second", list(SECOND))
def test_second_serial_run_refused(tmp_path, refs, second, locking):
    path = tmp_path / "s.h5"
    kw = {"GAPSWEEP_TEST_DELAY": "0.1"}
    if locking == "FALSE":
        kw["HDF5_USE_FILE_LOCKING"] = "FALSE"
    first = gs_popen("run", JOBS["theory"], "--store", path, "--mpi", "off", "--progress", "none", **kw)
    assert wait_done(path, 3, first) >= 3
    p = gs("run", JOBS["theory"], "--store", path, "--mpi", "off", *SECOND[second], **kw)
    assert first.poll() is None  # the premise: the first run was still writing
    one_line_error(p, "in use by", "alive")
    rc, _, err = finish(first)
    assert rc == 0, err
    assert store.diff(path, refs["theory"]) == []
    assert lease.read(path) is None  # released


def test_merge_onto_running_store_refused(tmp_path, refs):
    path = tmp_path / "s.h5"
    first = gs_popen("run", JOBS["theory"], "--store", path, "--mpi", "off", "--progress", "none",
                     GAPSWEEP_TEST_DELAY="0.1")
    assert wait_done(path, 3, first) >= 3
    p = gs("merge", refs["theory"], "--out", path, "--overwrite")
    assert first.poll() is None
    one_line_error(p, "in use by")
    rc, _, err = finish(first)
    assert rc == 0, err
    assert store.diff(path, refs["theory"]) == []


@needs_mpi
@pytest.mark.parametrize("writer", WRITERS)
def test_second_run_during_mpi_run_refused(tmp_path, refs, writer):
    """An mpio (or rank-0) MPI run holds the lease through rank 0: a serial --overwrite and a second MPI-less
    --resume are refused; the MPI run finishes to the uninterrupted result."""
    import subprocess

    from .conftest import env

    path = tmp_path / "s.h5"
    first = subprocess.Popen(mpi_cmd(2, "run", JOBS["theory"], "--store", path, "--writer", writer, "--progress",
                                     "none"), env=env(GAPSWEEP_TEST_DELAY="0.3", HDF5_USE_FILE_LOCKING="FALSE"),
                             stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    assert wait_done(path, 3, first) >= 3
    for extra in (["--overwrite"], ["--resume"]):
        p = gs("run", JOBS["theory"], "--store", path, "--mpi", "off", "--progress", "none", *extra,
               HDF5_USE_FILE_LOCKING="FALSE")
        assert first.poll() is None
        one_line_error(p, "in use by")
    rc, _, err = finish(first, timeout=120)
    assert rc == 0, err
    assert store.diff(path, refs["theory"]) == []
