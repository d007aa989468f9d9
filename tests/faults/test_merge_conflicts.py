"""Merges of overlapping shards (docs/reliability.md): conflicting rows are refused unless a resolution is
named; a failed row never beats a done one, whichever shard comes first; damaged shards give one line. The merges
of valid shards run in this process (``gs_here``: ``cli.main``, its exit code and output); the merge of a truncated
file stays a child process (what HDF5's C library prints goes to the process's stderr)."""

from __future__ import annotations

import shutil

import h5py
import numpy as np
import pytest

from gapsweep import store

from .conftest import gs, gs_here, one_line_error


def _set(path, i, **cols):
    """Give row ``i`` other results, as another run of the shard would have written them (checksums resealed:
    a conflict between two valid rows, not a damaged row)."""
    from gapsweep.sweep.store import reseal

    with h5py.File(path, "r+") as h:
        r = h["results"][...]
        for k, v in cols.items():
            r[k][i] = v
        h["results"][...] = r
        reseal(h)


@pytest.fixture
def pair(tmp_path, refs):
    a, b = tmp_path / "a.h5", tmp_path / "b.h5"
    shutil.copy(refs["hist"], a)
    shutil.copy(refs["hist"], b)
    return a, b


def test_identical_overlap_merges(tmp_path, refs, pair, capsys):
    a, b = pair
    p = gs_here(capsys, "merge", a, b, "--out", tmp_path / "m.h5")
    assert p.returncode == 0, p.stderr
    assert store.diff(tmp_path / "m.h5", refs["hist"]) == []


def test_conflicting_done_rows_refused(tmp_path, refs, pair, capsys):
    a, b = pair
    _set(b, 3, mean_gap=1.2345)
    out = tmp_path / "m.h5"
    p = gs_here(capsys, "merge", a, b, "--out", out)
    one_line_error(p, "conflicting", "--on-conflict")
    assert not out.exists()
    for how, want in (("first", a), ("last", b)):
        p = gs_here(capsys, "merge", a, b, "--out", out, "--overwrite", "--on-conflict", how)
        assert p.returncode == 0, p.stderr
        assert store.diff(out, want) == []


@pytest.mark.parametrize("order", ["failed-first", "done-first"])
@pytest.mark.parametrize("worse", ["failed", "not_converged"])
def test_failed_never_beats_done(tmp_path, refs, pair, order, worse, capsys):
    a, b = pair
    _set(a, 4, status=store.STATUS[worse], mean_gap=np.nan, message=b"boom")
    shards = [a, b] if order == "failed-first" else [b, a]
    for how in ("error", "first", "last"):
        out = tmp_path / f"m-{how}.h5"
        p = gs_here(capsys, "merge", *shards, "--out", out, "--on-conflict", how)
        assert p.returncode == 0, p.stderr
        assert store.diff(out, refs["hist"]) == []


def test_conflicting_failed_rows_refused(tmp_path, pair, capsys):
    a, b = pair
    _set(a, 4, status=store.STATUS["failed"], message=b"one")
    _set(b, 4, status=store.STATUS["failed"], message=b"two")
    p = gs_here(capsys, "merge", a, b, "--out", tmp_path / "m.h5")
    one_line_error(p, "conflicting")


def test_damaged_shard(tmp_path, pair):
    a, b = pair
    b.write_bytes(b.read_bytes()[:1000])
    p = gs("merge", a, b, "--out", tmp_path / "m.h5")
    one_line_error(p, str(b))
    assert not (tmp_path / "m.h5").exists()
