"""Checksums of everything a reader trusts (issue 31 item 1; docs/reliability.md "Checksums"): one flipped bit in
any attribute of a format-4 store (units, spec text and hash, format version, run records, provenance) or in a
task id is found on open by status, --resume, merge, export and report, and named in one line. Before format 4
attributes were not checked at all (a flipped bit exported every length unit as ``om``; flips in spec_sha256 or
format_version surfaced as "written for another job spec") and a task id flip in a pending row blocked every
command with a misleading message: each case here fails on the old code.

Older formats carry no attribute checksums: ``status`` says they are not verified (tests/test_store_formats.py).

``status``, ``merge``, ``export`` and ``report`` run in this process (``gs_here``: ``cli.main``, its exit code and
output) except where the whole stderr of a process is asserted (one line only: a refused ``status``) or every
command of a sequence must log damage that is logged once per store and process; the runs (``--resume``) stay
child processes."""

from __future__ import annotations

import h5py
import pytest

from gapsweep import store
from tests.storekit import copy_store, flip_attr

from .conftest import ROOT, gs, gs_here, one_line_error

JOB = ROOT / "tests" / "faults" / "jobs" / "units.toml"
# every attribute a format-4 store of this job has (test_every_attribute_is_listed keeps the list complete)
ATTRS = ("created", "finished", "format", "format_version", "gapsweep_version", "git_commit", "job_name", "runs",
         "shard", "spec_sha256", "spec_text", "units", "versions")
# the attributes whose damage still refuses the store (the layout and the shard; issue 40 item 1)
REFUSED = ("format", "format_version", "shard")


@pytest.fixture(scope="module")
def ref(tmp_path_factory):
    path = tmp_path_factory.mktemp("integrity") / "u.h5"
    p = gs("run", JOB, "--store", path, "--mpi", "off", "--progress", "none")
    assert p.returncode == 0, p.stderr
    return path


def flip_task_id(path, row: int) -> None:
    """Flip one bit of the task id of ``row`` in /tasks (hex digits stay ASCII)."""
    with h5py.File(path, "r+") as f:
        t = f["tasks"][...]
        tid = bytearray(t["task_id"][row])
        tid[3] ^= 1
        t["task_id"][row] = bytes(tid)
        f["tasks"][...] = t


def test_every_attribute_is_listed(ref):
    with h5py.File(ref, "r") as f:
        assert set(f.attrs) - {"integrity"} == set(ATTRS)


@pytest.mark.parametrize("name", ATTRS)
def test_flipped_attribute_is_named_by_status(ref, tmp_path, name, capsys):
    path = copy_store(ref, tmp_path)
    flip_attr(path, name)
    before = path.read_bytes()
    # a refusal is asserted to be the process's only stderr line: a child process; else in process
    p = gs("status", path, timeout=60) if name in REFUSED else gs_here(capsys, "status", path)
    if name not in REFUSED:  # the rows are not affected: status goes on and names the damage (issue 40 item 1;
        # --resume or `gapsweep repair` mends it: tests/test_store_damage.py)
        assert f"attribute '{name}' fails its checksum" in p.stdout + p.stderr, p.stdout + p.stderr
        assert p.returncode == 0 and f"{name!r}" in p.stdout, p.stdout + p.stderr
    else:
        err = one_line_error(p, str(path), f"attribute {name!r} fails its checksum")
        assert len([x for x in err.splitlines() if x.strip()]) == 1, err
    assert path.read_bytes() == before  # a reader changes nothing
    if name not in REFUSED:  # the rows read as they are (issue 31 item 5, issue 40 item 1)
        assert len(store.read(path)) > 0
        return
    with pytest.raises(store.StoreError, match=f"attribute '{name}' fails its checksum"):
        store.read(path)


@pytest.mark.parametrize("name", ["format_version", "runs"])
def test_flipped_attribute_refused_by_every_command(ref, tmp_path, name, capsys):
    """resume, merge, export and report refuse the store naming the attribute; nothing is written. Damage the
    rows survive is the exception (run records, issue 31 item 5; provenance and the spec's attributes, issue 40
    item 1: tests/test_store_damage.py): every command names the damage and goes on, the store untouched
    (--resume rebuilds them: test_resume_rebuilds_damaged_run_records)."""
    pytest.importorskip("xarray")
    path = copy_store(ref, tmp_path)
    flip_attr(path, name)
    before = path.read_bytes()
    need = f"attribute {name!r} fails its checksum"
    resume = [] if name == "runs" else [["run", JOB, "--store", path, "--resume", "--mpi", "off", "--progress", "none"]]
    for cmd in (*resume, ["merge", path, "--out", tmp_path / "m.h5"],
                ["export", path, "--out", tmp_path / "x.nc"],
                ["report", path, "--out", tmp_path / "rep"]):
        # a refusal in this process; a run, and the damage the rows survive (logged once per store and process:
        # each command must say it, as each of a user's commands does), in a child process
        p = gs(*cmd, timeout=120) if cmd[0] == "run" or name == "runs" else gs_here(capsys, *cmd)
        if name == "runs":
            assert p.returncode == 0 and need in p.stderr and "Traceback" not in p.stderr, (cmd, p.stderr)
        else:
            one_line_error(p, str(path), need)
    assert path.read_bytes() == before
    made = [] if name != "runs" else ["m.h5", "rep", "x.nc"]
    assert sorted(x.name for x in tmp_path.iterdir()) == sorted(["s.h5", *made])


def test_flipped_integrity_record_is_named(ref, tmp_path, capsys):
    """Named by status, which goes on (issue 40 item 1: the rows verify on their own checksums)."""
    path = copy_store(ref, tmp_path)
    flip_attr(path, "integrity")
    p = gs_here(capsys, "status", path)
    assert p.returncode == 0 and "attribute 'integrity'" in p.stdout and "damaged" in p.stdout, p.stdout + p.stderr


def test_removed_attribute_is_named(ref, tmp_path, capsys):
    """An attribute gone (e.g. `units`: the store would read as model units) is named, not taken as absent."""
    path = copy_store(ref, tmp_path)
    with h5py.File(path, "r+") as f:
        del f.attrs["units"]
    p = gs_here(capsys, "status", path)  # named, and status goes on (a spec attribute: issue 40 item 1)
    assert p.returncode == 0 and "attribute 'units' is missing" in p.stderr and "'units'" in p.stdout, p.stderr


@pytest.mark.parametrize("status", ["done", "pending"])
def test_flipped_task_id(ref, tmp_path, status, capsys):
    """One bit in a task id, of a done or a pending row: ``status`` names /tasks (and goes on: the other rows
    are readable), merge, export and report refuse the store in one line, ``merge --skip-damaged`` leaves the row
    out; --resume restores the id from the job and re-runs that row (the store then reads and merges). The old
    code refused a pending row's flip everywhere as "written for another job spec", --resume included."""
    pytest.importorskip("xarray")
    path = copy_store(ref, tmp_path)
    if status == "pending":
        with h5py.File(path, "r+") as f:
            r = f["results"][...]
            r["status"][1] = 0
            f["results"][...] = r
    flip_task_id(path, 1)
    need = "table '/tasks' (task ids and parameters) fails its checksum"
    p = gs_here(capsys, "status", path)
    assert p.returncode == 0 and need in p.stdout and "--resume restores it" in p.stdout, p.stdout + p.stderr
    for cmd in (["merge", path, "--out", tmp_path / "m.h5"], ["export", path, "--out", tmp_path / "x.nc"],
                ["report", path, "--out", tmp_path / "rep"]):
        one_line_error(gs_here(capsys, *cmd), str(path), need)
    p = gs_here(capsys, "merge", path, "--out", tmp_path / "m.h5", "--skip-damaged")
    assert p.returncode == 0, p.stderr
    assert (store.read(tmp_path / "m.h5")["status"] == "done").sum() == 1  # row 1 left out (pending or damaged)
    (tmp_path / "m.h5").unlink()
    p = gs("run", JOB, "--store", path, "--resume", "--mpi", "off", "--progress", "none", timeout=120)
    assert p.returncode == 0, p.stderr
    assert store.diff(path, ref) == []
    assert (store.read(path)["status"] == "done").all()
    assert gs_here(capsys, "merge", path, "--out", tmp_path / "m.h5").returncode == 0


def test_resume_rebuilds_damaged_run_records(ref, tmp_path, capsys):
    """A flipped bit in `runs`: status names it, --resume starts a new list of run records (the rows are not
    affected) and the store verifies again."""
    path = copy_store(ref, tmp_path)
    flip_attr(path, "runs")
    p = gs_here(capsys, "status", path)
    assert "attribute 'runs' fails its checksum" in p.stdout + p.stderr
    p = gs("run", JOB, "--store", path, "--resume", "--mpi", "off", "--progress", "none", timeout=120)
    assert p.returncode == 0, p.stderr
    assert gs_here(capsys, "status", path).returncode == 0
    assert store.diff(path, ref) == []
