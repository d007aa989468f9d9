"""gapsweep.sweep.resume in-process: what a run does with its store, as a truth table over the store's state
(none, finished, half finished, a failed row, another job's, not a store, a damaged task row, another axis
order) and the flags (none, --resume, --overwrite). The stores are made here: the two-task ``units`` job run once,
and stores created with a chosen subset of its rows (copied or failed); no subprocess."""

from __future__ import annotations

from pathlib import Path

import h5py
import pytest

from gapsweep.sweep import resume, runner
from gapsweep.sweep import spec as specmod
from tests.storekit import UNITS_JOB, partial_store, run_job

SPEC = runner._load(UNITS_JOB)
TASKS = runner._select(SPEC, None)[0]
FLAGS = {"none": (False, False), "resume": (True, False), "overwrite": (False, True)}


@pytest.fixture(scope="module")
def stores(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    d = tmp_path_factory.mktemp("decide")
    done = d / "done.h5"
    assert run_job(UNITS_JOB, done)["done"] == 2
    other = d / "other.toml"
    other.write_text(UNITS_JOB.read_text().replace("gamma0 = 1e-3", "gamma0 = 2e-3"))
    (d / "text.h5").write_text("not a store\n")
    return {"absent": d / "absent.h5", "done": done, "half": partial_store(d / "half.h5", done, copy=(0,)),
            "failed": partial_store(d / "failed.h5", done, copy=(0,), failed=(1,)),
            "other": (run_job(other, d / "other.h5"), d / "other.h5")[1], "text": d / "text.h5"}


# (state, flag) -> (mode, rows to run, failed rows not run again) or the start of the RunError's message
TABLE = {
    ("absent", "none"): ("create", [0, 1], 0),
    ("absent", "resume"): ("create", [0, 1], 0),
    ("absent", "overwrite"): ("create", [0, 1], 0),
    ("done", "none"): ("noop", [], 0),
    ("done", "resume"): ("noop", [], 0),
    ("done", "overwrite"): ("create", [0, 1], 0),
    ("half", "none"): "exists with 1 of 2 tasks pending: pass --resume",
    ("half", "resume"): ("resume", [1], 0),
    ("half", "overwrite"): ("create", [0, 1], 0),
    ("failed", "none"): ("noop", [], 1),  # a failed row is finished: counted as unfinished, not run again
    ("failed", "resume"): ("noop", [], 1),
    ("failed", "overwrite"): ("create", [0, 1], 0),
    ("other", "none"): "was written for another job spec or shard",
    ("other", "resume"): "was written for another job spec or shard",
    ("other", "overwrite"): ("create", [0, 1], 0),
    ("text", "none"): "it is not a gapsweep store: choose another --store",
    ("text", "resume"): "it is not a gapsweep store: choose another --store",
    ("text", "overwrite"): ("create", [0, 1], 0),  # the output rule (runner._guard_store) refuses it before
}


@pytest.mark.parametrize(("state", "flag"), sorted(TABLE))
def test_decision_truth_table(stores: dict[str, Path], state: str, flag: str) -> None:
    want = TABLE[state, flag]
    res, over = FLAGS[flag]
    if isinstance(want, str):
        with pytest.raises(resume.RunError, match=want):
            resume.decide(stores[state], SPEC, TASKS, "", res, over)
    else:
        assert resume.decide(stores[state], SPEC, TASKS, "", res, over) == want
    assert not stores["absent"].exists()  # deciding writes nothing


def test_another_shard_is_refused(stores: dict[str, Path]) -> None:
    with pytest.raises(resume.RunError, match="another job spec or shard"):
        resume.decide(stores["done"], SPEC, TASKS, "0/2", True, False)


def test_damaged_task_row_of_a_done_row_is_kept(stores: dict[str, Path], tmp_path: Path) -> None:
    """A done row whose task row alone is damaged (one bit of its sigma0) verifies against the job's task row:
    it stays done (nothing to run) and ``--resume`` restores the task row; a plain run is refused, naming the
    table that fails its checksum."""
    p = tmp_path / "s.h5"
    p.write_bytes(stores["done"].read_bytes())
    with h5py.File(p, "r+") as f:
        row = f["tasks"][1]
        row["sigma0"] = row["sigma0"] * (1 + 2**-40)
        f["tasks"][1] = row
    assert resume.decide(p, SPEC, TASKS, "", True, False) == ("resume", [], 0)
    with pytest.raises(resume.RunError, match=r"table '/tasks' .* fails its checksum"):
        resume.decide(p, SPEC, TASKS, "", False, False)


def test_axis_order_and_description_do_not_strand_a_store(stores: dict[str, Path]) -> None:
    """The same job with sigma0's values reversed and a new description: its hash differs, its tasks are the
    store's; the store's row order is the permutation that maps its rows to the new expansion."""
    text = UNITS_JOB.read_text().replace("sigma0 = [1e-2, 1e-1]", "sigma0 = [1e-1, 1e-2]") \
        .replace('name = "faults-units"', 'name = "faults-units"\ndescription = "corrected"')
    spec = specmod.loads(text)
    tasks = runner._select(spec, None)[0]
    assert spec.sha256 != SPEC.sha256 and resume.task_key(spec) == resume.task_key(SPEC)
    order = resume.stored_order(stores["done"], spec, tasks, "", False)
    assert order is not None and [tasks[i].task_id for i in order] == [t.task_id for t in TASKS]
    assert resume.stored_order(stores["done"], spec, tasks, "", True) is None  # --overwrite: no order kept
    ordered = resume.store_order(tasks, [], order)[0]
    assert resume.decide(stores["done"], spec, ordered, "", False, False, reordered=True) == ("noop", [], 0)
    with pytest.raises(resume.RunError, match="another job spec"):  # the hash differs: not reordered, refused
        resume.decide(stores["done"], spec, ordered, "", False, False)
    assert resume.stored_order(stores["other"], spec, tasks, "", False) is None  # another job: no order


def test_no_room_for_a_new_store(stores: dict[str, Path], monkeypatch: pytest.MonkeyPatch) -> None:
    from gapsweep.sweep import budget

    monkeypatch.setattr(budget, "disk_free", lambda p: 10)
    with pytest.raises(resume.RunError, match=r"needs ~.*, only 10 B free there"):
        resume.decide(stores["absent"], SPEC, TASKS, "", False, False)
    assert not stores["absent"].exists()
