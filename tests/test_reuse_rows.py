"""gapsweep.sweep.reuse in-process, on the two-task ``units`` job: which rows of a source store are taken (done,
checksum verified, same bins, current algorithm version unless ``older``; first source wins), the run record's
entry, and the copy into a store (rows and kept-fields files) that then equals the source. No subprocess; the
end-to-end ``gapsweep run --reuse`` is tests/test_reuse.py and tests/test_store_reuse.py."""

from __future__ import annotations

from pathlib import Path

import h5py
import numpy as np
import pytest

from gapsweep.sweep import methods as registry
from gapsweep.sweep import reuse, runner, store
from gapsweep.sweep.fields import fields_dir
from gapsweep.sweep.store import Store
from tests.storekit import UNITS_JOB, partial_store, run_job

SPEC = runner._load(UNITS_JOB)
TASKS = runner._select(SPEC, None)[0]
BINS = SPEC.histogram["bins"]


@pytest.fixture(scope="module")
def src(tmp_path_factory: pytest.TempPathFactory) -> Path:
    p = tmp_path_factory.mktemp("reuse-rows") / "src.h5"
    assert run_job(UNITS_JOB, p)["done"] == 2
    return p


def test_done_rows_of_the_same_tasks_are_taken(src: Path, tmp_path: Path) -> None:
    got = reuse.reusable_rows([src], tmp_path / "new.h5", TASKS, [0, 1], BINS)
    assert sorted(got) == [0, 1]
    with h5py.File(src, "r") as f:
        for i, (where, row, hists, older) in got.items():
            assert where == str(src.absolute()) and older is False
            assert row.tobytes() == f["results"][i].tobytes()
            assert np.array_equal(hists[1], f["histograms/density"][i], equal_nan=True)
    only = reuse.reusable_rows([src], tmp_path / "new.h5", TASKS, [1], BINS)  # only what is to run
    assert sorted(only) == [1]
    assert reuse.reused_record(got) == {"reused": {str(src.absolute()): 2}}
    assert reuse.reused_record({}) == {}


def test_first_source_wins_and_pending_rows_are_not_taken(src: Path, tmp_path: Path) -> None:
    half = partial_store(tmp_path / "half.h5", src, copy=(1,))  # row 0 pending, row 1 done
    got = reuse.reusable_rows([half, src], tmp_path / "new.h5", TASKS, [0, 1], BINS)
    assert {i: v[0] for i, v in got.items()} == {0: str(src.absolute()), 1: str(half.absolute())}
    assert reuse.reused_record(got) == {"reused": {str(half.absolute()): 1, str(src.absolute()): 1}}
    failed = partial_store(tmp_path / "failed.h5", src, failed=(0, 1))  # failed rows are never copied
    assert reuse.reusable_rows([failed], tmp_path / "new.h5", TASKS, [0, 1], BINS) == {}


def test_rows_that_do_not_verify_or_fit_are_not_taken(src: Path, tmp_path: Path) -> None:
    bad = tmp_path / "bad.h5"
    bad.write_bytes(src.read_bytes())
    with h5py.File(bad, "r+") as f:  # one finished row changed after it was written: its checksum fails
        row = f["results"][0]
        row["mean_gap"] = row["mean_gap"] + 1.0
        f["results"][0] = row
    assert sorted(reuse.reusable_rows([bad], tmp_path / "new.h5", TASKS, [0, 1], BINS)) == [1]
    assert reuse.reusable_rows([src], tmp_path / "new.h5", TASKS, [0, 1], BINS + 1) == {}  # other bins
    with pytest.raises(ValueError, match="that is the store being written"):
        reuse.reusable_rows([src], src, TASKS, [0, 1], BINS)


def test_older_algorithm_version_only_with_older(src: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    method = registry.get(TASKS[0].method)
    monkeypatch.setattr(method, "algorithm_version", method.algorithm_version + 1)
    assert reuse.reusable_rows([src], tmp_path / "new.h5", TASKS, [0, 1], BINS) == {}
    got = reuse.reusable_rows([src], tmp_path / "new.h5", TASKS, [0, 1], BINS, older=True)
    assert sorted(got) == [0, 1] and all(v[3] for v in got.values())
    s = str(src.absolute())
    assert reuse.reused_record(got) == {"reused": {s: 2}, "reused_older": {s: 2}}


def test_copied_rows_equal_the_source_with_their_fields(src: Path, tmp_path: Path) -> None:
    """Rows copied into a store whose rows are pending: the store then equals the source (every column but
    wall time and rank; checksums verify), and a kept-fields file of the source comes along."""
    tid = TASKS[1].task_id
    fdir = fields_dir(src)
    fdir.mkdir(exist_ok=True)
    (fdir / f"{tid}.nc").write_bytes(b"fields of task 1")
    try:
        dest = partial_store(tmp_path / "dest.h5", src)
        got = reuse.reusable_rows([src], dest, TASKS, [0, 1], BINS)
        st = Store.open(dest)
        try:
            reuse.copy_reused(st, got, TASKS)
        finally:
            st.close()
    finally:
        (fdir / f"{tid}.nc").unlink()
        fdir.rmdir()
    assert store.diff(dest, src) == []
    assert (store.read(dest).status == "done").all()
    assert (fields_dir(dest) / f"{tid}.nc").read_bytes() == b"fields of task 1"
    assert [p.name for p in fields_dir(dest).iterdir()] == [f"{tid}.nc"]  # no temporary file left


def test_a_row_that_keeps_fields_comes_only_with_its_file(tmp_path: Path) -> None:
    """GFMD at two loads keeping the fields at sigma0 = 1e-2 only: that task wants its fields file, the other
    not; a source without the file lends only the other row."""
    from gapsweep.sweep import spec as specmod
    from tests.storekit import small_job

    job = tmp_path / "f.toml"
    job.write_text(small_job("reuse-fields", methods="""
[methods.gfmd]
n = 64
backend = "numpy"
keep_fields = { fields = ["gap"], sigma0 = [1e-2] }
"""))
    tasks = runner._select(specmod.load(job), None)[0]
    keep = [i for i, t in enumerate(tasks) if t.sigma0 == 1e-2]
    assert sorted(t.sigma0 for t in tasks) == [1e-2, 5e-2] and len(keep) == 1
    assert [reuse.wants_fields(t) for t in tasks] == [i in keep for i in range(2)]
    assert not any(reuse.wants_fields(t) for t in TASKS)  # the units job keeps no fields
    s = tmp_path / "s.h5"
    assert run_job(job, s)["done"] == 2
    bins = specmod.load(job).histogram["bins"]
    assert sorted(reuse.reusable_rows([s], tmp_path / "n.h5", tasks, [0, 1], bins)) == [0, 1]
    reuse.fields_file(s, tasks[keep[0]].task_id).unlink()
    assert sorted(reuse.reusable_rows([s], tmp_path / "n.h5", tasks, [0, 1], bins)) == [1 - keep[0]]
