"""Several jobs of one launch through one MPI farm (gapsweep.sweep.launch, issue 38), on the CPU with the fake GPU
method of tests/fakegpu.py: 4 ranks, 2 (fake) GPUs, two jobs -- every store equals the serial store of its job
(one farm each), with either writer, also when a GPU fails mid-chain; the farm's trace (GAPSWEEP_TRACE) shows
one farm for the launch with ``--farm together`` and one per job with ``--farm each``."""

from __future__ import annotations

import json
import sys

import pytest

from tests.mpi.test_farm_faults import FAKE, WRITERS, _have_mpi, fake
from tests.test_launch import SECOND

pytestmark = pytest.mark.skipif(not _have_mpi(), reason="mpiexec or mpi4py not installed")


@pytest.fixture(scope="module")
def jobs(tmp_path_factory):
    sys.path.insert(0, str(FAKE.parent))
    try:
        import fakegpu
    finally:
        sys.path.pop(0)
    d = tmp_path_factory.mktemp("launchjobs")
    (d / "one.toml").write_text(fakegpu.JOB)
    (d / "two.toml").write_text(SECOND)
    refs = []
    for name in ("one", "two"):
        p = fake(1, "run", d / f"{name}.toml", "--store", d / f"ref_{name}.h5", "--mpi", "off", "--progress",
                 "none", GAPSWEEP_TEST_GPUS="1")
        assert p.returncode == 0, p.stderr
        refs.append(d / f"ref_{name}.h5")
    return [d / "one.toml", d / "two.toml"], refs


@pytest.mark.parametrize("writer", WRITERS)
def test_two_jobs_one_mpi_farm(tmp_path, jobs, writer):
    """One farm for both jobs, GPU 1 failing after two tasks: both stores equal the serial ones, each run record
    names the other store and the device fault; one trace file per rank (one farm)."""
    from gapsweep import store

    specs, refs = jobs
    out = [tmp_path / "a.h5", tmp_path / "b.h5"]
    trace = tmp_path / "trace"
    p = fake(4, "run", *specs, "--store", out[0], "--store", out[1], "--writer", writer, "--progress", "none",
             "--lookahead", "1", "--coordinator-works", "no", FAKEGPU_BROKEN="1@2",
             GAPSWEEP_TRACE=str(trace))
    assert p.returncode == 0, p.stdout + p.stderr
    for s, r in zip(out, refs):
        assert store.diff(s, r) == []
    recs = [json.loads(store.read_attrs(s)["runs"])[-1] for s in out]
    assert recs[0]["farm"] == {"together_with": [str(out[1])]} and recs[1]["farm"] == {"together_with": [str(out[0])]}
    assert all(len(r["device_faults"]) == 1 and "GPU 1" in r["device_faults"][0] for r in recs)
    names = sorted(f.name for f in trace.glob("rank*.json"))
    assert names == [f"rank{r}.farm0.json" for r in range(4)]
    from gapsweep.sweep import spec as specmod
    from gapsweep.sweep import tasks

    total = sum(len(tasks.make_units(tasks.expand(specmod.load(j)))) for j in specs)
    units = [u for f in trace.glob("rank*.json") for u in json.loads(f.read_text())["units"]]
    assert all(0 <= u[5] <= u[2] - u[1] + 1e-3 for u in units)  # the rows' writing and sending: part of the unit
    ran = [u[0] for u in units]
    # every unit of both jobs ran once, but the one GPU 1 failed in (it ran again on another worker)
    assert set(ran) == set(range(total)) and len(ran) == total + 1


def test_farm_each_one_trace_per_job(tmp_path, jobs):
    from gapsweep import store

    specs, refs = jobs
    out = [tmp_path / "a.h5", tmp_path / "b.h5"]
    trace = tmp_path / "trace"
    p = fake(3, "run", *specs, "--store", out[0], "--store", out[1], "--farm", "each", "--progress", "none",
             GAPSWEEP_TRACE=str(trace))
    assert p.returncode == 0, p.stdout + p.stderr
    assert all(store.diff(s, r) == [] for s, r in zip(out, refs))
    assert sorted(f.name for f in trace.glob("rank*.json")) == sorted(
        f"rank{r}.farm{k}.json" for r in range(3) for k in range(2))
    assert "farm" not in json.loads(store.read_attrs(out[0])["runs"])[-1]
