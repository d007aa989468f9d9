"""Issue 31, item 4 (the rule): one rule for every command that writes. An output never replaces an input --
through any link: hard link, symlink (compared by device and inode) -- nor a gapsweep store it was not asked to
write; ``--overwrite`` replaces only a file of the command's own kind (gapsweep.sweep.outputs.guard_output):

* ``merge --overwrite``: only an earlier merge output of the same job (spec hash) that holds no done row the new
  merge lacks -- what the Slurm merge job, which always passes ``--overwrite``, meets when it is run again;
* ``export --overwrite``: only a netCDF file gapsweep export wrote;
* ``run --overwrite``: only a gapsweep store (another job's included: the documented way to start again), never
  the job spec or another file.

Before: merge --overwrite replaced another job's finished store, a hard link of its own input shard and plain
HDF5 files (lost data). Every refusal here is one line, exit 1, and leaves the file byte for byte as it was. The
refusals run the CLI in this process (``gs_here``); the commands that write a store run as children (``gs``)."""

from __future__ import annotations

import shutil

import h5py
import pytest

from gapsweep import store

from .conftest import JOBS, THEORY_JOB, gs, gs_here, one_line_error


@pytest.fixture(scope="module")
def shards(tmp_path_factory):
    """The theory job in two shards and their merge."""
    d = tmp_path_factory.mktemp("shards")
    out = []
    for i in range(2):
        p = d / f"s{i}.h5"
        r = gs("run", THEORY_JOB, "--store", p, "--shard", f"{i}/2", "--mpi", "off", "--progress", "none")
        assert r.returncode == 0, r.stderr
        out.append(p)
    merged = d / "merged.h5"
    r = gs("merge", *out, "--out", merged)
    assert r.returncode == 0, r.stderr
    return out, merged


def _target(tmp_path, kind, shards, refs):
    s, merged = shards
    t = tmp_path / "out" / "m.h5"
    t.parent.mkdir()
    if kind == "hardlink-of-shard":
        t.hardlink_to(s[0])
    elif kind == "symlink-to-shard":
        t.symlink_to(s[1])
    elif kind == "other-jobs-store":
        shutil.copyfile(refs["hist"], t)
    elif kind == "other-jobs-merge":
        r = gs("merge", refs["hist"], "--out", t)
        assert r.returncode == 0, r.stderr
    elif kind == "run-store-of-same-job":
        shutil.copyfile(refs["theory"], t)
    elif kind == "plain-hdf5":
        with h5py.File(t, "w") as f:
            f["x"] = [1.0, 2.0]
    elif kind == "text":
        t.write_text("my notes\n")
    elif kind == "merge-with-more-done-rows":
        shutil.copyfile(merged, t)
    return t


REFUSED = {
    "hardlink-of-shard": "is also a shard",
    "symlink-to-shard": "is also a shard",
    "other-jobs-store": "not a merge output",
    "other-jobs-merge": "another job",
    "run-store-of-same-job": "not a merge output",
    "plain-hdf5": "not a gapsweep store",
    "text": "not a gapsweep store",
    "merge-with-more-done-rows": "done row",
}


@pytest.mark.parametrize("kind", list(REFUSED))
def test_merge_overwrite_refuses_what_it_did_not_write(tmp_path, capsys, refs, shards, kind):
    s, _ = shards
    t = _target(tmp_path, kind, shards, refs)
    before = t.read_bytes()
    inputs = [x.read_bytes() for x in s]
    # the merge with fewer shards: the earlier merge holds done rows this one lacks
    args = [s[0]] if kind == "merge-with-more-done-rows" else [s[0], s[1]]
    p = gs_here(capsys, "merge", *args, "--out", t, "--overwrite")
    one_line_error(p, REFUSED[kind])
    assert t.read_bytes() == before
    assert [x.read_bytes() for x in s] == inputs
    assert sorted(x.name for x in t.parent.iterdir()) == ["m.h5"]  # no temporary file, no lease left


def test_merge_overwrite_replaces_its_own_earlier_merge(tmp_path, refs, shards):
    """The Slurm merge job run again (it always passes --overwrite): the earlier merge of the same job, with
    only the first shard merged, is replaced by the merge of both."""
    s, merged = shards
    t = tmp_path / "m.h5"
    assert gs("merge", s[0], "--out", t).returncode == 0
    p = gs("merge", *s, "--out", t, "--overwrite")
    assert p.returncode == 0, p.stderr
    assert store.diff(t, merged) == []
    p = gs("merge", *s, "--out", t, "--overwrite")  # and again, the same rows
    assert p.returncode == 0, p.stderr


EXPORT_REFUSED = {
    "hardlink-of-input": "is the input",
    "plain-hdf5": "not a netCDF file written by gapsweep export",
    "text": "not a netCDF file written by gapsweep export",
    "other-store": "gapsweep store",
}


@pytest.mark.parametrize("kind", list(EXPORT_REFUSED))
def test_export_overwrite_refuses_what_it_did_not_write(tmp_path, capsys, refs, kind):
    src = tmp_path / "in" / "s.h5"
    src.parent.mkdir()
    shutil.copyfile(refs["theory"], src)
    t = tmp_path / "out.nc"
    if kind == "hardlink-of-input":
        t.hardlink_to(src)
    elif kind == "plain-hdf5":
        with h5py.File(t, "w") as f:
            f["x"] = [1.0]
    elif kind == "text":
        t.write_text("notes\n")
    else:
        shutil.copyfile(refs["hist"], t)
    before, inp = t.read_bytes(), src.read_bytes()
    p = gs_here(capsys, "export", src, "--out", t, "--overwrite")
    one_line_error(p, "export --out", EXPORT_REFUSED[kind])
    assert t.read_bytes() == before and src.read_bytes() == inp


RUN_REFUSED = {
    "the-job-spec": "is the input",
    "hardlink-of-the-job-spec": "is the input",
    "plain-hdf5": "not a gapsweep store",
    "text": "not a gapsweep store",
}


@pytest.mark.parametrize("kind", list(RUN_REFUSED))
def test_run_overwrite_refuses_what_it_did_not_write(tmp_path, capsys, kind):
    job = tmp_path / "job.toml"
    shutil.copyfile(JOBS["theory"], job)
    t = tmp_path / "s.h5"
    if kind == "the-job-spec":
        t = job
    elif kind == "hardlink-of-the-job-spec":
        t.hardlink_to(job)
    elif kind == "plain-hdf5":
        with h5py.File(t, "w") as f:
            f["x"] = [1.0]
    else:
        t.write_text("notes\n")
    before = t.read_bytes()
    p = gs_here(capsys, "run", job, "--store", t, "--overwrite", "--mpi", "off", "--progress", "none")
    one_line_error(p, "run --store", RUN_REFUSED[kind])
    assert t.read_bytes() == before and job.read_bytes() == JOBS["theory"].read_bytes()


def test_run_overwrite_replaces_another_jobs_store(tmp_path, refs):
    """run --overwrite onto a store of another job: the documented way to start again (its own kind)."""
    t = tmp_path / "s.h5"
    shutil.copyfile(refs["hist"], t)
    p = gs("run", JOBS["theory"], "--store", t, "--overwrite", "--mpi", "off", "--progress", "none")
    assert p.returncode == 0, p.stderr
    assert store.diff(t, refs["theory"]) == []
