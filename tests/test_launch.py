"""Several jobs of one launch through one farm (gapsweep.sweep.launch, issue 38), in-process: the joint farm's
numbering and order, and serial launches of two jobs compared with a farm per job -- every store bit-identical
(store.diff: all but wall time and rank), the run records naming the shared farm, device faults and stop
requests reaching every job."""

from __future__ import annotations

import json
from types import SimpleNamespace

import pytest

from gapsweep.sweep import launch
from gapsweep.sweep.schema import Unit
from tests.test_farm import _expected, fakegpu  # noqa: F401 - the fixture

SECOND = """
[job]
name = "farm-second"
[grid]
hurst = [0.5]
rho = [1e-3, 4e-3]
sigma0 = {min = 1e-3, max = 1.0, num = 7, scale = "log"}
seeds = [0, 1, 2]
[surface]
lambda_l = 0.25
lambda_s = 0.04
rms_slope = 1.0
[material]
gamma0 = 1e-3
[methods.theory]
forms = ["paper", "continuum"]
[methods.fakegpu]
"""


def _run(units, todo=None, st=None):
    """A stand-in of a started runner._Run: what Joint reads."""
    tasks = sorted({i for u in units for i in u.tasks})
    return SimpleNamespace(
        comm=None, rank=0, size=1, wmode="serial", works=True, lookahead=2, limit=None, together=False,
        gpu=0, gpu_of=[0], ctx=None, tasks=list(range(len(tasks))), units=units,
        todo=set(tasks) if todo is None else todo, work=list(range(len(units))), st=st,
        stop=SimpleNamespace(stop_file=None), ahead_ok=lambda: [u.gpu for u in units])


def test_joint_numbering_and_largest_first_across_jobs():
    """Task i of job j is offset[j] + i, unit k of job j likewise; the queue is the units of every job by
    estimated cost, largest first, ties in the launch's order; rows and skips map back to the job's own
    indices."""
    a = _run([Unit((0, 1, 2), 30.0, True, "chain"), Unit((3,), 1.0)])
    b = _run([Unit((0, 1), 50.0, True, "chain"), Unit((2, 3), 30.0, True, "chain"), Unit((4,), 0.5)])
    j = launch.Joint([a, b])
    assert j.task_offset == [0, 4] and j.unit_offset == [0, 2]
    assert [u.tasks for u in j.units] == [(0, 1, 2), (3,), (4, 5), (6, 7), (8,)]
    assert j.work == [2, 0, 3, 1, 4]  # 50, 30 (job a first), 30, 1, 0.5
    assert j.owner_task(5) == (1, 1) and j.owner_task(3) == (0, 3) and j.owner_unit(3) == (1, 1)
    assert j.todo == set(range(9)) and j.ahead_ok() == [True, False, True, True, False]
    seen = []
    b.units_of = lambda k, skip: (seen.append((k, skip)), iter([(1, "row")]))[1]
    c = _run([Unit((0,), 1.0)])
    c.ctx = SimpleNamespace(_max=4)
    launch.Joint([_run([Unit((0,), 1.0)]), c, _run([Unit((0,), 1.0)])])
    assert c.ctx._max == 1  # three jobs: the surface caches share one job's budget (4 surfaces)
    assert list(j.units_of(2, frozenset({4}))) == [(5, "row")] and seen == [(0, frozenset({0}))]


def test_joint_farm_refused_for_a_distributed_job_or_different_placements():
    a, b = _run([Unit((0,), 1.0, True)]), _run([Unit((0,), 1.0, True)])
    assert launch.Joint.applies([a, b]) == ""
    b.gpu_of = [None]  # a job without GPU units: no placement of its own, shares the farm
    assert launch.Joint.applies([a, b]) == ""
    b.gpu_of = [1]
    assert "placements differ" in launch.Joint.applies([a, b])
    b.gpu_of, b.together = [0], True
    assert "distributed" in launch.Joint.applies([a, b])


def _two(fakegpu, tmp_path):  # noqa: F811 - the fixture's value
    second = tmp_path / "second.toml"
    second.write_text(SECOND)
    return [fakegpu, second]


def test_two_jobs_one_farm_equal_to_one_farm_each(fakegpu, tmp_path):  # noqa: F811
    """A serial launch of two jobs (GPU chains and CPU theory tasks): one farm gives the stores of a farm per
    job bit for bit, the rows of the chains are fakegpu's closed form, each run record names the other store."""
    from gapsweep import store

    jobs = _two(fakegpu, tmp_path)
    each = [tmp_path / "e1.h5", tmp_path / "e2.h5"]
    one = [tmp_path / "t1.h5", tmp_path / "t2.h5"]
    se = launch.run_jobs(jobs, each, farm="each", mpi="off", progress="none")
    st = launch.run_jobs(jobs, one, farm="together", mpi="off", progress="none")
    for a, b, x, y in zip(each, one, se, st):
        assert store.diff(b, a) == []
        assert (x["done"], x["todo"], x["unfinished"]) == (y["done"], y["todo"], y["unfinished"]) and y["done"] > 0
        df = store.read(b)
        got = df[df.method == "fakegpu"].set_index("task_id").mean_gap
        assert all(got[k] == v for k, v in _expected(df).items())
    r1, r2 = (json.loads(store.read_attrs(p)["runs"])[-1] for p in one)
    assert r1["farm"] == {"together_with": [str(one[1])]} and r2["farm"] == {"together_with": [str(one[0])]}
    assert "farm" not in json.loads(store.read_attrs(each[0])["runs"])[-1]
    # a second launch finds nothing to do in either store
    again = launch.run_jobs(jobs, one, farm="together", mpi="off", progress="none", resume=True)
    assert [s["mode"] for s in again] == ["noop", "noop"]


def test_device_fault_in_a_joint_farm_leaves_each_jobs_gpu_rows_pending(fakegpu, tmp_path, monkeypatch):  # noqa: F811
    """The only GPU fails at its second task: no GPU left; each job's GPU rows not run stay pending and its run
    record says so; every CPU row of both jobs is done; --resume with a working GPU gives the undisturbed
    stores."""
    from gapsweep import store

    jobs = _two(fakegpu, tmp_path)
    ref = [tmp_path / "r1.h5", tmp_path / "r2.h5"]
    launch.run_jobs(jobs, ref, farm="each", mpi="off", progress="none")
    out = [tmp_path / "f1.h5", tmp_path / "f2.h5"]
    monkeypatch.setenv("FAKEGPU_BROKEN", "0@1")
    sums = launch.run_jobs(jobs, out, farm="together", mpi="off", progress="none")
    assert sum(s["done"] for s in sums) > 0 and sum(s["pending"] for s in sums) == 16 + 42 - 1
    for s, p in zip(sums, out):
        df = store.read(p)
        assert (df[df.method == "theory"].status == "done").all()
        assert s["pending"] == (df.status == "pending").sum() > 0
        rec = json.loads(store.read_attrs(p)["runs"])[-1]
        assert "no GPU left" in rec["stopped"] and rec["pending"] == s["pending"] and "GPU 0" in rec["device_faults"][0]
    monkeypatch.delenv("FAKEGPU_BROKEN")
    launch.run_jobs(jobs, out, farm="together", mpi="off", progress="none", resume=True)
    assert all(store.diff(p, r) == [] for p, r in zip(out, ref))


def test_a_stop_file_of_one_job_stops_the_launch_and_every_store_says_so(fakegpu, tmp_path, monkeypatch):  # noqa: F811
    """The stop file of the second store appears during the first GPU task: the serial launch stops (Interrupted)
    and both stores record the interruption with their own counts; --resume finishes both."""
    from gapsweep import store
    from gapsweep.sweep.limits import Interrupted

    jobs = _two(fakegpu, tmp_path)
    out = [tmp_path / "s1.h5", tmp_path / "s2.h5"]
    mod = __import__("sys").modules["fakegpu"]
    real = mod.FakeGPU.run

    def run(self, t, ctx, prev):
        (tmp_path / "s2.h5.stop").touch()
        return real(self, t, ctx, prev)

    monkeypatch.setattr(mod.FakeGPU, "run", run)
    with pytest.raises(Interrupted):
        launch.run_jobs(jobs, out, farm="together", mpi="off", progress="none")
    for p in out:
        rec = json.loads(store.read_attrs(p)["runs"])[-1]
        assert rec.get("interrupted") and rec["finished"] is None
    monkeypatch.setattr(mod.FakeGPU, "run", real)
    sums = launch.run_jobs(jobs, out, farm="together", mpi="off", progress="none", resume=True)
    assert all(s["unfinished"] == 0 for s in sums)
    assert all((store.read(p).status == "done").all() for p in out)


def test_bad_farm_mode_and_store_count():
    with pytest.raises(ValueError, match="--farm: expected one of together, each"):
        launch.run_jobs(["a", "b"], ["x", "y"], farm="both")
    with pytest.raises(ValueError, match="one store per job"):
        launch.run_jobs(["a", "b"], ["x"])
    with pytest.raises(ValueError, match="a store path is given twice"):
        launch.run_jobs(["a", "b"], ["x.h5", "./x.h5"])
