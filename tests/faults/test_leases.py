"""Issue 31, item 2: a second writer is refused whatever its environment. The first writer holds the store's
lease in a process with one ``$TMPDIR`` / ``$GAPSWEEP_LEASE_DIR``; the second comes with its own (as Slurm gives
each job), through a hard link, a symlink, a symlinked folder or a bind mount, with ``HDF5_USE_FILE_LOCKING=FALSE``
(what the Slurm scripts set). It must be refused with one line and leave the store byte for byte as it was. The
holder is a separate process that has taken the lease and waits on its standard input: no timing involved.

Before: the identity lease lived only in the per-process lease folder and the path lease was keyed by the path,
so the second run was admitted (4 of 4 tries, rows went back to pending). Now the holder also locks the store
file itself (``lease.FileLock``).

Item 5 (last point): a stale lease with any content -- a huge or non-numeric pid, a non-object, a host that is
not a string -- is reported and broken by ``--break-lease`` (before: a traceback, and the store blocked)."""

from __future__ import annotations

import json
import os
import shutil
import socket
import subprocess
import sys

import pytest

from gapsweep import lease, store

from .conftest import JOBS, env, gs, one_line_error

HOLD = ("import sys; from gapsweep import lease; h = lease.acquire(sys.argv[1]); print('held', flush=True); "
        "sys.stdin.read(); h.release()")


class Holder:
    """A process that holds the lease of ``path`` (taken through ``path``) until :meth:`stop`."""

    def __init__(self, path, tmp) -> None:
        e = env(TMPDIR=str(tmp / "tmp-a"), GAPSWEEP_LEASE_DIR=str(tmp / "leases-a"), HDF5_USE_FILE_LOCKING="FALSE")
        (tmp / "tmp-a").mkdir(exist_ok=True)
        self.p = subprocess.Popen([sys.executable, "-c", HOLD, str(path)], env=e, stdin=subprocess.PIPE,
                                  stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        line = self.p.stdout.readline()
        assert line.strip() == "held", self.p.stderr.read()

    def stop(self) -> None:
        self.p.stdin.close()
        assert self.p.wait(timeout=60) == 0


def _other_env(tmp):
    (tmp / "tmp-b").mkdir(exist_ok=True)
    return {"TMPDIR": str(tmp / "tmp-b"), "GAPSWEEP_LEASE_DIR": str(tmp / "leases-b"),
            "HDF5_USE_FILE_LOCKING": "FALSE"}


def _bind_file(src, dst) -> bool:
    if os.geteuid() != 0:
        return False
    dst.touch()
    return subprocess.run(["mount", "--bind", str(src), str(dst)], capture_output=True).returncode == 0


def _other_path(tmp, path, how):
    if how == "same-path":
        return path, None
    if how == "hardlink":
        other = tmp / "elsewhere" / "hard.h5"  # another folder: another path lease
        other.parent.mkdir()
        other.hardlink_to(path)
        return other, None
    if how == "symlink":
        other = tmp / "link.h5"
        other.symlink_to(path)
        return other, None
    if how == "symlinked-folder":
        (tmp / "alias").symlink_to(path.parent)
        return tmp / "alias" / path.name, None
    other = tmp / "mnt.h5"
    if not _bind_file(path, other):
        pytest.skip("bind mounts need root and mount permission")
    return other, other


@pytest.fixture
def partial(tmp_path, refs):
    """A store with some rows done and some pending (a write error stopped its run), and a byte copy of it."""
    path = tmp_path / "store" / "s.h5"
    path.parent.mkdir()
    p = gs("run", JOBS["theory"], "--store", path, "--mpi", "off", "--progress", "none",
           GAPSWEEP_TEST_WRITE_ERROR="6")
    assert p.returncode == 1, p.stderr
    copy = tmp_path / "copy.h5"
    shutil.copyfile(path, copy)
    return path, copy


@pytest.mark.parametrize("second", ["--overwrite", "--resume"])
@pytest.mark.parametrize("how", ["same-path", "hardlink", "symlink", "symlinked-folder", "bind-mount"])
def test_second_writer_other_environment_refused(tmp_path, refs, partial, how, second):
    path, copy = partial
    holder = Holder(path, tmp_path)
    mounted = None
    try:
        other, mounted = _other_path(tmp_path, path, how)
        p = gs("run", JOBS["theory"], "--store", other, "--mpi", "off", "--progress", "none", second,
               **_other_env(tmp_path))
        one_line_error(p, "in use by", "alive")
        # even --break-lease never takes a live writer's store
        p = gs("run", JOBS["theory"], "--store", other, "--mpi", "off", "--progress", "none", "--resume",
               "--break-lease", **_other_env(tmp_path))
        one_line_error(p, "in use by")
    finally:
        if mounted is not None:
            subprocess.run(["umount", str(mounted)], check=False)
        holder.stop()
    assert path.read_bytes() == copy.read_bytes()  # untouched
    p = gs("run", JOBS["theory"], "--store", path, "--mpi", "off", "--progress", "none", "--resume")
    assert p.returncode == 0, p.stderr
    assert store.diff(path, refs["theory"]) == []


@pytest.mark.parametrize("how", ["same-path", "hardlink"])
def test_merge_onto_leased_store_refused(tmp_path, refs, partial, how):
    """merge --out onto a store another process writes (through any path, any environment) is refused."""
    path, copy = partial
    holder = Holder(path, tmp_path)
    try:
        other, _ = _other_path(tmp_path, path, how)
        p = gs("merge", refs["theory"], "--out", other, "--overwrite", **_other_env(tmp_path))
        one_line_error(p, "in use by")
    finally:
        holder.stop()
    assert path.read_bytes() == copy.read_bytes()


def test_file_lock_is_per_file(tmp_path):
    """The lock inside the file: a second description of the same inode (a hard link in another folder) is
    refused while the first holds it, and gets it once the first releases it; another file is independent."""
    a = tmp_path / "a.h5"
    a.write_bytes(b"x")
    (tmp_path / "d").mkdir()
    b = tmp_path / "d" / "b.h5"
    b.hardlink_to(a)
    c = tmp_path / "c.h5"
    c.write_bytes(b"y")
    one, two = lease.FileLock(), lease.FileLock()
    assert one.take(a) is True
    assert two.take(b) is False and lease.locked(b)
    assert two.take(c) is True
    one.release()
    assert two.take(b) is True and not lease.locked(c)
    two.release()
    assert not lease.locked(a) and a.read_bytes() == b"x"  # a lock never writes the file


BAD_LEASES = {
    "huge-pid": {"pid": 10**30},
    "negative-pid": {"pid": -7},
    "non-numeric-pid": {"pid": "abc"},
    "float-pid": {"pid": 1e300},
    "no-pid": {},
    "host-not-a-string": {"host": ["x"], "pid": 1},
    "not-an-object": None,
    "not-json": "garbage",
    "deep-json": "[" * 100000,
}


@pytest.mark.parametrize("kind", list(BAD_LEASES))
def test_stale_lease_with_any_content_breakable(tmp_path, refs, partial, kind):
    """A lease file with any content blocks the store with a one-line message naming --break-lease, and
    --break-lease takes it over (before: a huge or non-numeric pid gave a traceback even with --break-lease)."""
    path, _ = partial
    v = BAD_LEASES[kind]
    if isinstance(v, dict):
        text = json.dumps({"host": socket.gethostname(), "run_id": "r0", "started": "?", **v})
    elif v is None:
        text = "[1, 2]"
    else:
        text = v
    lease.lease_path(path).write_text(text)
    p = gs("run", JOBS["theory"], "--store", path, "--mpi", "off", "--progress", "none", "--resume")
    one_line_error(p, "--break-lease")
    p = gs("status", path)
    assert p.returncode == 0 and "Traceback" not in p.stderr, p.stderr
    p = gs("run", JOBS["theory"], "--store", path, "--mpi", "off", "--progress", "none", "--resume",
           "--break-lease")
    assert p.returncode == 0, p.stderr
    assert store.diff(path, refs["theory"]) == []
    assert not lease.lease_path(path).exists()


def _dead_holder_lease(path) -> None:
    """A lease of ``path`` whose holder (a child process that exited without releasing it, as one SIGKILLed does)
    is gone: waited for with ``wait()``, no timing involved."""
    code = "import os, sys; from gapsweep import lease; lease.acquire(sys.argv[1]); os._exit(0)"
    subprocess.run([sys.executable, "-c", code, str(path)], env=env(), check=True)
    assert lease.read(path)["alive"] is False


def test_dead_holder_that_never_created_the_store_is_taken_over(tmp_path, caplog):
    """A run killed at start-up (mpiexec SIGKILLs its ranks 1 s after forwarding a signal; a loaded machine
    outlasts that) between taking the lease and creating the store leaves a lease with nothing behind it: the
    next run takes it over by itself and says so (it asked for --break-lease before: seen in a loaded suite run)."""
    import logging

    path = tmp_path / "s.h5"
    _dead_holder_lease(path)
    with caplog.at_level(logging.INFO, "gapsweep"):
        held = lease.acquire(path)
    try:
        assert "is gone and never created the store" in caplog.text
    finally:
        held.release()
    assert lease.read(path) is None


def test_dead_holder_of_an_existing_store_still_needs_break_lease(tmp_path, refs):
    """... but a store that exists is what a lease protects: a dead holder that did not record its interruption
    in it is still broken only with --break-lease (one line naming the holder)."""
    path = tmp_path / "s.h5"
    shutil.copy(refs["theory"], path)
    _dead_holder_lease(path)
    with pytest.raises(lease.LeaseError, match="--break-lease"):
        lease.acquire(path)
    lease.acquire(path, break_lease=True).release()
