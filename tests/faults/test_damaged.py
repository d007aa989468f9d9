"""Damaged stores (docs/reliability.md): every command on a truncated, zero-byte, partial or inconsistent store
exits with one line naming the file and the problem, never a traceback; row-level damage (unknown status code,
a done row without its histogram or result) is reported by `status` and repaired by `--resume`."""

from __future__ import annotations

import shutil

import h5py
import numpy as np
import pytest

from gapsweep import store

from .conftest import JOBS, gs, one_line_error


def _zero(p):
    p.write_bytes(b"")


def _truncate(p):
    b = p.read_bytes()
    p.write_bytes(b[: len(b) // 3])


def _garbage_header(p):
    b = bytearray(p.read_bytes())
    b[:64] = b"\x17" * 64
    p.write_bytes(bytes(b))


def _text(p):
    p.write_text("not a store\n")


def _del(name):
    def f(p):
        with h5py.File(p, "r+") as h:
            del h[name]
    return f


def _wrong_dtype(p):
    with h5py.File(p, "r+") as h:
        n = h["results"].shape[0]
        del h["results"]
        h.create_dataset("results", data=np.zeros(n, dtype="f8"))


def _short_results(p):
    with h5py.File(p, "r+") as h:
        r = h["results"][...]
        del h["results"]
        h.create_dataset("results", data=r[: len(r) // 2])


def _no_format(p):
    with h5py.File(p, "r+") as h:
        del h.attrs["format"]


def _no_spec(p):
    with h5py.File(p, "r+") as h:
        del h.attrs["spec_text"]


STRUCTURAL = {
    "zero-byte": (_zero, "empty file"),
    "truncated": (_truncate, "truncated or damaged"),
    "garbage-header": (_garbage_header, "not a readable HDF5 file"),
    "text-file": (_text, "not a readable HDF5 file"),
    "no-results": (_del("results"), "/results missing"),
    "no-density": (_del("histograms/density"), "/histograms/density missing"),
    "no-tasks": (_del("tasks"), "/tasks missing"),
    "results-wrong-dtype": (_wrong_dtype, "/results has dtype"),
    "results-shorter": (_short_results, "different lengths"),
    "no-format-attribute": (_no_format, "attribute 'format' is missing"),  # format 4: its checksums say so
    "no-spec-attribute": (_no_spec, "spec_text"),
}
COMMANDS = ["status", "resume", "merge", "report"]


@pytest.mark.parametrize("command", COMMANDS)
@pytest.mark.parametrize("damage", list(STRUCTURAL))
def test_structural_damage(tmp_path, refs, damage, command):
    path = tmp_path / "s.h5"
    shutil.copy(refs["hist"], path)
    fn, words = STRUCTURAL[damage]
    fn(path)
    before = path.read_bytes()
    if command == "status":
        p = gs("status", path)
    elif command == "resume":
        p = gs("run", JOBS["hist"], "--store", path, "--resume", "--mpi", "off")
    elif command == "merge":
        p = gs("merge", path, "--out", tmp_path / "m.h5")
    else:
        p = gs("report", path, "--out", tmp_path / "rep")
    one_line_error(p, str(path), words)
    assert path.read_bytes() == before  # untouched
    assert not (tmp_path / "m.h5").exists()


def _unknown_status(p):
    with h5py.File(p, "r+") as h:
        r = h["results"][...]
        r["status"][[2, 5]] = 7
        h["results"][...] = r


def _done_no_hist(p):
    with h5py.File(p, "r+") as h:
        ids = [x.decode() for x in h["tasks"].fields("method")[...]]
        i = ids.index("sde")
        d = h["histograms/density"][...]
        d[i] = np.nan
        d[i + 1] = 0.0
        h["histograms/density"][...] = d


def _done_nan_result(p):
    with h5py.File(p, "r+") as h:
        r = h["results"][...]
        r["mean_gap"][0] = np.nan
        h["results"][...] = r


ROWS = {"unknown-status": (_unknown_status, "unknown status code", 2),
        "done-without-histogram": (_done_no_hist, "without a complete result", 2),
        "done-with-nan-result": (_done_nan_result, "without a complete result", 1)}


@pytest.mark.parametrize("damage", list(ROWS))
def test_row_damage_reported_and_repaired(tmp_path, refs, damage):
    path = tmp_path / "s.h5"
    shutil.copy(refs["hist"], path)
    fn, words, n = ROWS[damage]
    fn(path)
    p = gs("status", path)
    assert p.returncode == 0 and words in p.stdout, p.stdout + p.stderr
    p = gs("run", JOBS["hist"], "--store", path, "--mpi", "off", "--progress", "none")
    one_line_error(p, "--resume")  # incomplete rows are pending work, not a finished store
    p = gs("run", JOBS["hist"], "--store", path, "--resume", "--mpi", "off")
    assert p.returncode == 0, p.stderr
    assert f"{n} of " in p.stdout
    assert store.diff(path, refs["hist"]) == []
