"""Issue 31, item 4: no crash on a full disk or under a file-size limit, anywhere. Each case asserts a clean
one-line error and exit 1 (never SIGSEGV / 139), the output removed (no file, no temporary file), the inputs byte
for byte as they were, and no lease left (or, after an MPI abort, one marked ended that the next run takes over
without --break-lease); a run keeps every done row and, once space is freed, a resume reaches the uninterrupted
result.

Before: a run keeping GFMD fields on a disk that filled (serial, mpio and rank-0 writers) and export on a full
disk or under a file-size limit segfaulted after their message (HDF5 closing or releasing a file whose write had
failed), leaving a stale lease. The full disk is a small tmpfs (root; skipped otherwise); the file-size limit is
RLIMIT_FSIZE (Python ignores SIGXFSZ, so a write fails with EFBIG instead of killing the process)."""

from __future__ import annotations

import os
import resource
import subprocess
from pathlib import Path

import pytest

from gapsweep import lease, store

from .conftest import (
    HIST_JOB,
    WRITERS,
    assert_done_kept,
    assert_only_done_pending,
    done_rows,
    env,
    gs,
    mpi_cmd,
    needs_mpi,
    one_line_error,
    wait_gone,
)

FIELDS_JOB = Path(__file__).resolve().parent / "jobs" / "fields.toml"


@pytest.fixture
def tmpfs(tmp_path):
    """Mount a tmpfs of the given size (kB) at a fresh folder; remount(size) resizes it."""
    mounted = []

    def mount(kb: int) -> Path:
        d = tmp_path / f"fs{len(mounted)}"
        d.mkdir()
        if os.geteuid() != 0:
            pytest.skip("a small tmpfs needs root")
        r = subprocess.run(["mount", "-t", "tmpfs", "-o", f"size={kb}k", "tmpfs", str(d)], capture_output=True)
        if r.returncode != 0:
            pytest.skip(f"cannot mount a tmpfs here: {r.stderr.decode().strip()}")
        mounted.append(d)
        return d

    yield mount
    for d in mounted:
        subprocess.run(["umount", "-l", str(d)], capture_output=True)


def _remount(d: Path, kb: int) -> None:
    subprocess.run(["mount", "-o", f"remount,size={kb}k", str(d)], check=True)


def _leave_free(d: Path, kb: int) -> Path:
    """Fill the file system of ``d`` so that ``kb`` kB stay free."""
    st = os.statvfs(d)
    free = st.f_bavail * st.f_frsize
    f = d / "filler"
    f.write_bytes(b"\0" * max(0, free - kb * 1024))
    return f


def _fsize(limit: int):
    def pre():
        resource.setrlimit(resource.RLIMIT_FSIZE, (limit, limit))
    return pre


@pytest.fixture(scope="module")
def fields_ref(tmp_path_factory):
    d = tmp_path_factory.mktemp("fieldsref")
    path = d / "f.h5"
    p = gs("run", FIELDS_JOB, "--store", path, "--mpi", "off", "--progress", "none")
    assert p.returncode == 0, p.stderr
    return path


def _no_crash(rc: int, out: str) -> None:
    assert rc == 1, (rc, out)
    assert "Segmentation fault" not in out and "signal 11" not in out and "Traceback" not in out, out


def _lease_gone_or_ended(path: Path) -> None:
    info = lease.read(path)
    if info is not None and info["alive"] is True:  # mpiexec has returned after MPI_Abort, rank 0 (the holder)
        wait_gone(int(info["pid"]))                 # may still be exiting: wait for that event, then judge
        info = lease.read(path)
    assert info is None or (info["alive"] is False and info.get("interrupted")), info


def _resume_after_room(d: Path, path: Path, ref: Path, seen: dict) -> None:
    _remount(d, 8192)
    p = gs("run", FIELDS_JOB, "--store", path, "--mpi", "off", "--progress", "none", "--resume")
    assert p.returncode == 0, p.stderr
    assert_done_kept(seen, path)
    assert store.diff(path, ref) == []
    want = sorted(x.name for x in (ref.parent / (ref.name + ".fields")).iterdir())
    assert sorted(x.name for x in (path.parent / (path.name + ".fields")).iterdir()) == want


def test_kept_fields_fill_the_disk_serial(tmpfs, fields_ref):
    """The store fits, the second task's fields do not: one line naming the fields folder, exit 1."""
    d = tmpfs(300)
    path = d / "f.h5"
    p = gs("run", FIELDS_JOB, "--store", path, "--mpi", "off", "--progress", "none")
    _no_crash(p.returncode, p.stderr)
    one_line_error(p, "kept fields", "No space left", "--resume")
    assert lease.read(path) is None
    assert_only_done_pending(path)
    seen = done_rows(path)
    assert seen  # some rows were done before the disk filled
    assert not [x for x in d.rglob(".*tmp*")]
    _resume_after_room(d, path, fields_ref, seen)


@needs_mpi
@pytest.mark.parametrize("writer", WRITERS)
def test_kept_fields_fill_the_disk_mpi(tmpfs, fields_ref, writer):
    d = tmpfs(300)
    path = d / "f.h5"
    p = subprocess.run(mpi_cmd(2, "run", FIELDS_JOB, "--store", path, "--writer", writer, "--progress", "none"),
                       env=env(), capture_output=True, text=True, timeout=300)
    out = p.stdout + p.stderr
    _no_crash(p.returncode, out)
    assert "No space left" in out
    _lease_gone_or_ended(path)
    assert_only_done_pending(path)
    seen = done_rows(path)
    _resume_after_room(d, path, fields_ref, seen)  # without --break-lease


@pytest.mark.parametrize("free_kb", [4, 20, 36])
def test_merge_export_report_on_full_disk(tmpfs, refs, free_kb):
    d = tmpfs(512)
    src = d / "s.h5"
    src.write_bytes(refs["hist"].read_bytes())
    _leave_free(d, free_kb)
    before = src.read_bytes()
    failed = 0
    for args, needle in ((["merge", src, "--out", d / "m.h5"], "merge --out"),
                         (["export", src, "--out", d / "e.nc"], "export --out"),
                         (["report", src, "--out", d / "rep"], "report --out")):
        p = gs(*args)
        if p.returncode == 0:  # it fitted: then it is complete
            assert Path(args[-1]).exists()
            continue
        failed += 1
        _no_crash(p.returncode, p.stderr)
        one_line_error(p, needle, "No space left")
        assert not Path(args[-1]).exists()
        assert lease.read(args[-1]) is None
    assert failed  # the space left is below what each writes: at least one command meets the full disk
    assert src.read_bytes() == before
    assert sorted(x.name for x in d.iterdir() if x.name not in ("m.h5", "e.nc", "rep")) == ["filler", "s.h5"]


@pytest.mark.parametrize("limit", [4096, 20_000, 30_000])
def test_merge_export_report_under_file_size_limit(tmp_path, refs, limit):
    src = tmp_path / "s.h5"
    src.write_bytes(refs["hist"].read_bytes())
    before = src.read_bytes()
    failed = 0
    for args, needle in ((["merge", src, "--out", tmp_path / "m.h5"], "merge --out"),
                         (["export", src, "--out", tmp_path / "e.nc"], "export --out"),
                         (["report", src, "--out", tmp_path / "rep"], "report --out")):
        p = gs(*args, preexec=_fsize(limit))
        if p.returncode == 0:
            continue
        failed += 1
        _no_crash(p.returncode, p.stderr)
        one_line_error(p, needle, "too large")  # "File too large" (HDF5 1.10) or "file too large" (HDF5 2.0)
        assert not Path(args[-1]).exists()
    assert failed  # the limit is below what each writes: at least one command meets it
    assert src.read_bytes() == before
    assert sorted(x.name for x in tmp_path.iterdir() if x.name not in ("m.h5", "e.nc", "rep")) == ["s.h5"]



@needs_mpi
@pytest.mark.parametrize("writer", WRITERS)
def test_mpi_run_without_fields_on_a_disk_too_small_for_its_record(tmpfs, refs, writer):
    """Without kept fields every row's space is allocated at creation: on a disk with room for the store but
    not for the run record's growth probe, the MPI run writes every row, says the record was not updated, and
    ends cleanly (no crash, lease released)."""
    d = tmpfs(200)
    path = d / "h.h5"
    p = subprocess.run(mpi_cmd(2, "run", HIST_JOB, "--store", path, "--writer", writer, "--progress", "none"),
                       env=env(), capture_output=True, text=True, timeout=300)
    out = p.stdout + p.stderr
    assert p.returncode == 0, out
    assert "run record was not updated" in out and "Traceback" not in out, out
    assert lease.read(path) is None
    assert store.diff(path, refs["hist"]) == []


def test_partial_field_files_removed_on_resume(tmp_path):
    """Under MPI a rank killed by another rank's MPI_Abort may leave its kept-field file half written under its
    temporary name; a resume (holding the lease) removes such files and nothing else."""
    from gapsweep.sweep.fields import remove_partial

    d = tmp_path / "s.h5.fields"
    d.mkdir()
    partial = d / ".0123456789abcdef.4242.tmp"
    partial.write_bytes(b"\x89HDF half")
    kept = [d / "0123456789abcdef.nc", d / ".notes.tmp", d / "mine.txt"]
    for f in kept:
        f.write_text("x")
    assert remove_partial(d) == 1
    assert not partial.exists() and all(f.exists() for f in kept)


@needs_mpi
@pytest.mark.parametrize("writer", WRITERS)
def test_distributed_kept_fields_fill_the_disk(tmpfs, tmp_path, writer):
    """A job whose GFMD tasks span both ranks (``distributed = true``) keeps fields written by rows (mpio, or rank 0
    receiving row chunks) on a disk that fills: no crash, the error names the full disk, every row done or
    pending, no half-written field file under its final name; once space is freed a resume finishes with one
    complete field file per GFMD task (read back by store.open_fields) and no temporary file left."""
    job = tmp_path / "dist_fields.toml"
    job.write_text(FIELDS_JOB.read_text().replace('backend = "numpy"\n', 'backend = "numpy"\ndistributed = true\n'))
    d = tmpfs(300)
    path = d / "f.h5"
    p = subprocess.run(mpi_cmd(2, "run", job, "--store", path, "--writer", writer, "--progress", "none"),
                       env=env(), capture_output=True, text=True, timeout=300)
    out = p.stdout + p.stderr
    assert p.returncode != 0 and "Segmentation fault" not in out and "signal 11" not in out, out
    assert "No space left" in out, out
    _lease_gone_or_ended(path)
    assert_only_done_pending(path)
    seen = done_rows(path)
    fdir = d / "f.h5.fields"
    for f in fdir.glob("*.nc"):  # what is there under its final name is complete
        assert set(store.open_fields(path, [f.stem])[f.stem].data_vars) == {"gap", "pressure", "displacement",
                                                                            "height"}
    _remount(d, 8192)
    p = subprocess.run(mpi_cmd(2, "run", job, "--store", path, "--writer", writer, "--progress", "none",
                               "--resume"), env=env(), capture_output=True, text=True, timeout=300)
    assert p.returncode == 0, p.stdout + p.stderr
    assert_done_kept(seen, path)
    df = store.read(path)
    assert set(df.status) == {"done"}
    ids = set(df.task_id[df.method == "gfmd"])
    assert {f.stem for f in fdir.glob("*.nc")} == ids and len(ids) == 6
    assert not list(fdir.glob(".*"))
    assert all(ds.gap.shape == (64, 64) for ds in store.open_fields(path).values())
