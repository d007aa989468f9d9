"""kill -9 at random points (docs/reliability.md, "Crashes"): the store stays readable, holds only done and
pending rows, every row seen done stays done with the same values, and a resume (breaking the stale lease)
reaches the uninterrupted result."""

from __future__ import annotations

import random
import signal
import subprocess
import time

import pytest

from gapsweep import store
from gapsweep.sweep import lease

from .conftest import (
    JOBS,
    WRITERS,
    Hold,
    assert_done_kept,
    assert_only_done_pending,
    done_rows,
    env,
    finish,
    gs_popen,
    kill,
    mpi_cmd,
    needs_mpi,
    reaped,
    resume_to_ref,
)


@pytest.mark.parametrize("job", ["theory", "hist"])
@pytest.mark.parametrize("seed", [1, 2, 3])
def test_kill9_serial_random_time(tmp_path, refs, job, seed):
    path = tmp_path / "s.h5"
    delay = random.Random(seed).uniform(0.05, 1.5)
    p = gs_popen("run", JOBS[job], "--store", path, "--mpi", "off", "--progress", "none",
                 GAPSWEEP_TEST_DELAY="0.03")
    time.sleep(delay)
    seen = done_rows(path) if path.exists() else {}
    kill(p)
    finish(p)
    if path.exists():
        assert_only_done_pending(path)
        assert_done_kept(seen, path)
    resume_to_ref(path, refs[job], JOBS[job])


@pytest.mark.parametrize("k", [1, 5, 12])
def test_kill9_between_payload_and_status(tmp_path, refs, k):
    """Killed after a row's histogram and before its status: that row is pending (never a done row without
    its histogram); a resume completes it."""
    path = tmp_path / "s.h5"
    p = gs_popen("run", JOBS["hist"], "--store", path, "--mpi", "off", "--progress", "none",
                 GAPSWEEP_TEST_KILL_AT_WRITE=str(k))
    rc, _, _ = finish(p)
    assert rc == -signal.SIGKILL
    df = store.read(path)
    assert int((df.status == "done").sum()) == k - 1
    assert_only_done_pending(path)
    assert lease.read(path)["alive"] is False  # stale: reported, broken only when asked
    resume_to_ref(path, refs["hist"], JOBS["hist"])


def test_kill9_during_creation(tmp_path, refs):
    """Killed right after start: no store, or a complete one (created under a temporary name)."""
    for delay in (0.3, 0.6, 0.9):
        path = tmp_path / f"s{delay}.h5"
        p = gs_popen("run", JOBS["theory"], "--store", path, "--mpi", "off", "--progress", "none",
                     GAPSWEEP_TEST_DELAY="0.05")
        time.sleep(delay)
        kill(p)
        finish(p)
        if path.exists():
            assert_only_done_pending(path)
        resume_to_ref(path, refs["theory"], JOBS["theory"])


@needs_mpi
@pytest.mark.parametrize("writer", WRITERS)
@pytest.mark.parametrize("victim", ["rank0", "rank1", "mpiexec"])
def test_kill9_mpi(tmp_path, refs, writer, victim):
    path, pids, hold = tmp_path / "k.h5", tmp_path / "pids", Hold(tmp_path / "hold", 6)
    pids.mkdir()
    p = subprocess.Popen(mpi_cmd(2, "run", JOBS["theory"], "--store", path, "--writer", writer, "--progress",
                                 "none"), env=env(**hold.env(GAPSWEEP_TEST_PIDDIR=str(pids))),
                         stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    with reaped(p):
        hold.wait(p)  # a rank holds after its 6th row: the kill meets a run that has not finished
        seen = done_rows(path)
        if victim == "mpiexec":
            kill(p)
        else:
            import os

            os.kill(int((pids / f"{victim}.pid").read_text()), signal.SIGKILL)
        hold.release()  # a surviving rank goes on (and is stopped by mpiexec)
        rc, _, _ = finish(p, timeout=60)  # never a hang
    assert rc != 0
    # Killing mpiexec -9 can orphan the ranks, which go on: while rank 0 lives its lease refuses every other
    # run; wait until it has finished or died.
    t0 = time.monotonic()
    while (held := lease.read(path)) is not None and held["alive"] and time.monotonic() - t0 < 90:
        time.sleep(0.2)
    assert held is None or not held["alive"]
    assert_only_done_pending(path)
    assert_done_kept(seen, path)
    resume_to_ref(path, refs["theory"], JOBS["theory"])
