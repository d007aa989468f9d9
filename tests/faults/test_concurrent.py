"""Two runs on one store (docs/reliability.md, "Exclusive access"): the lease refuses the second writer
whatever HDF5_USE_FILE_LOCKING says and for every writer; the first run finishes to the uninterrupted result.

The first run holds after its third row write (conftest.Hold, a barrier) until the second process has been
refused: the premise "the first run is still writing" is made true, not hoped for (on a loaded machine the first
run used to finish before the second had started)."""

from __future__ import annotations

import pytest

from gapsweep import lease, store

from .conftest import (
    JOBS,
    WRITERS,
    Hold,
    finish,
    gs,
    gs_popen,
    mpi_cmd,
    needs_mpi,
    one_line_error,
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
    path, hold = tmp_path / "s.h5", Hold(tmp_path / "hold", 3)
    kw = {"HDF5_USE_FILE_LOCKING": "FALSE"} if locking == "FALSE" else {}
    first = gs_popen("run", JOBS["theory"], "--store", path, "--mpi", "off", "--progress", "none", **hold.env(**kw))
    hold.wait(first)
    p = gs("run", JOBS["theory"], "--store", path, "--mpi", "off", *SECOND[second], **kw)
    assert first.poll() is None  # the premise: the first run is still writing (held)
    one_line_error(p, "in use by", "alive")
    hold.release()
    rc, _, err = finish(first)
    assert rc == 0, err
    assert store.diff(path, refs["theory"]) == []
    assert lease.read(path) is None  # released


def test_merge_onto_running_store_refused(tmp_path, refs):
    path, hold = tmp_path / "s.h5", Hold(tmp_path / "hold", 3)
    first = gs_popen("run", JOBS["theory"], "--store", path, "--mpi", "off", "--progress", "none", **hold.env())
    hold.wait(first)
    p = gs("merge", refs["theory"], "--out", path, "--overwrite")
    assert first.poll() is None
    one_line_error(p, "in use by")
    hold.release()
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

    path, hold = tmp_path / "s.h5", Hold(tmp_path / "hold", 3)
    first = subprocess.Popen(mpi_cmd(2, "run", JOBS["theory"], "--store", path, "--writer", writer, "--progress",
                                     "none"), env=env(**hold.env(HDF5_USE_FILE_LOCKING="FALSE")),
                             stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    hold.wait(first)
    for extra in (["--overwrite"], ["--resume"]):
        p = gs("run", JOBS["theory"], "--store", path, "--mpi", "off", "--progress", "none", *extra,
               HDF5_USE_FILE_LOCKING="FALSE")
        assert first.poll() is None
        one_line_error(p, "in use by")
    hold.release()
    rc, _, err = finish(first, timeout=120)
    assert rc == 0, err
    assert store.diff(path, refs["theory"]) == []


def _bind_file(src, dst) -> bool:
    """Bind-mount the file ``src`` at ``dst`` (another mount path of one file); False where not permitted."""
    import os
    import subprocess

    if os.geteuid() != 0:
        return False
    dst.touch()
    return subprocess.run(["mount", "--bind", str(src), str(dst)], capture_output=True).returncode == 0


@pytest.mark.parametrize("locking", ["default", "FALSE"])
@pytest.mark.parametrize("how", ["symlink", "symlinked-folder", "hardlink", "bind-mount"])
def test_second_run_through_another_path_refused(tmp_path, refs, how, locking):
    """Issue 19 item 6: a second run through a symlink, a hard link or a bind mount of the same store is refused
    (the lease is keyed by the file: resolved path and device/inode), with HDF5 locking on or off; the first
    run finishes to the uninterrupted result. The old lease, keyed by the path as typed, let the hard link and
    the bind mount run beside the first (done rows went back to pending)."""
    import subprocess

    path, hold = tmp_path / "s.h5", Hold(tmp_path / "hold", 3)
    kw = {"HDF5_USE_FILE_LOCKING": "FALSE"} if locking == "FALSE" else {}
    first = gs_popen("run", JOBS["theory"], "--store", path, "--mpi", "off", "--progress", "none", **hold.env(**kw))
    mounted = None
    try:
        hold.wait(first)
        if how == "symlink":
            other = tmp_path / "link.h5"
            other.symlink_to(path)
        elif how == "symlinked-folder":
            (tmp_path / "alias").symlink_to(tmp_path)
            other = tmp_path / "alias" / "s.h5"
        elif how == "hardlink":
            other = tmp_path / "hard.h5"
            other.hardlink_to(path)
        else:
            other = tmp_path / "mnt.h5"
            if not _bind_file(path, other):
                first.kill()
                first.wait()
                pytest.skip("bind mounts need root and mount permission")
            mounted = other
        p = gs("run", JOBS["theory"], "--store", other, "--mpi", "off", "--resume", "--progress", "none", **kw)
        assert first.poll() is None  # the premise: the first run is still writing (held)
        one_line_error(p, "in use by", "alive")
    finally:
        hold.release()
        if mounted is not None:
            subprocess.run(["umount", str(mounted)], check=False)
    rc, _, err = finish(first)
    assert rc == 0, err
    assert store.diff(path, refs["theory"]) == []
    assert lease.read(path) is None and lease.identity_path(path) is not None
    assert not lease.identity_path(path).exists()  # released with the path lease
