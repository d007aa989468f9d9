"""Progress and the time left, in-process against hand-computed values: the run's own ETA
(gapsweep.sweep.progress: elapsed / n * (total - n), a stand-in clock) and the cost left between runs
(gapsweep.sweep.costleft: a made-up cost table -> calibrated ratios -> core- and GPU-seconds -> the rate of the
last run -> the ETA)."""

from __future__ import annotations

import datetime as _dt
import logging
import math

import numpy as np
import pytest

from gapsweep.sweep import costleft
from gapsweep.sweep.progress import Progress, eta_s
from gapsweep.sweep.schema import TaskResult


class Clock:
    def __init__(self) -> None:
        self.t = 100.0

    def __call__(self) -> float:
        return self.t


def test_eta_of_the_run_so_far() -> None:
    assert eta_s(30.0, 3, 10) == pytest.approx(70.0, rel=1e-15)  # 10 s per row, 7 rows left
    assert eta_s(5.0, 10, 10) == 0.0
    assert math.isnan(eta_s(5.0, 0, 10))  # no row yet: unknown, not 0 or infinity


def test_progress_counts_and_line(caplog: pytest.LogCaptureFixture) -> None:
    clock = Clock()
    p = Progress(4, mode="log", every=10.0, clock=clock)
    caplog.set_level(logging.INFO, logger="gapsweep.runner")
    clock.t += 4.0
    p.update(TaskResult("done", "", {}))  # 4 s < every: no line yet
    assert caplog.records == []
    clock.t += 8.0
    p.update(TaskResult("failed", "boom", {}))  # 12 s: a line, 6 s per row, 2 left
    assert [r.getMessage() for r in caplog.records] == [
        "2/4 finished (1 done, 1 failed, 0 not converged), 2 remaining, elapsed 12.0 s, ETA 12.0 s"]
    clock.t += 3.0
    p.update(TaskResult("not_converged", "", {}))  # 3 s after the line: none
    assert len(caplog.records) == 1
    assert p.count == {"pending": 0, "done": 1, "failed": 1, "not_converged": 1}
    assert p.line().endswith("1 remaining, elapsed 15.0 s, ETA 5.0 s")
    p.close()  # the final line, always
    assert len(caplog.records) == 2
    quiet = Progress(4, mode="none", clock=clock)
    quiet.update(TaskResult("done", "", {}))
    quiet.close()
    assert len(caplog.records) == 2 and quiet.count["done"] == 1


# A made-up cost table: method a runs at 2x its model cost, b at 0.5x; row 0 (a) also paid 20 s of start-up
# (its ratio 22 is over OUTLIER = 5 times a's median 2: left out of the calibration);
# rows 5..8 remain (row 8 of b on a GPU), row 9 of a method c that has not finished a row yet.
METHODS = ["a", "a", "a", "b", "b", "a", "b", "b", "b", "c"]
MODEL = np.array([1.0, 2.0, 3.0, 4.0, 2.0, 5.0, 6.0, 1.0, 8.0, 3.0])
WALL = np.array([22.0, 4.0, 6.0, 2.0, 1.0, np.nan, np.nan, np.nan, np.nan, np.nan])
FINISHED = np.array([True] * 5 + [False] * 5)
GPU = np.array([False] * 8 + [True, False])


def test_cost_left_of_a_made_up_table() -> None:
    e = costleft.estimate(METHODS, MODEL, WALL, GPU, FINISHED, [5, 6, 7, 8, 9], processes=2)
    assert e["ratios"] == {"a": 2.0, "b": 0.5}
    overall = (4 + 6 + 2 + 1) / (2 + 3 + 4 + 2)  # the kept rows (row 0 is the start-up outlier)
    assert e["overall"] == pytest.approx(overall, rel=1e-15)
    assert e["startup_s"] == pytest.approx(22.0 - 2.0 * 1.0, rel=1e-15)
    core = 2.0 * 5.0 + 0.5 * 6.0 + 0.5 * 1.0 + overall * 3.0 + 2 * 20.0  # + start-up of 2 processes
    assert e["core_seconds"] == pytest.approx(core, rel=1e-14)
    assert e["gpu_seconds"] == pytest.approx(0.5 * 8.0, rel=1e-15)
    none_left = costleft.estimate(METHODS, MODEL, WALL, GPU, FINISHED, [], processes=2)
    assert none_left["core_seconds"] == 0.0 == none_left["gpu_seconds"]  # no start-up when nothing remains
    cold = costleft.estimate(METHODS, MODEL, WALL, GPU, np.zeros(10, bool), [5, 9], processes=1)
    assert cold["overall"] is None and cold["core_seconds"] == pytest.approx(5.0 + 3.0, rel=1e-15)  # ratio 1


def test_eta_from_the_rate_of_the_last_run() -> None:
    """The last run finished 5 rows in 20 s, at a mean measured 4 s each: 1 task-second per second; the ETA is
    the cost left over that rate. A run still going (its lease held) counts up to now."""
    t0 = _dt.datetime(2026, 1, 1, 12, 0, 0, tzinfo=_dt.UTC)
    runs = [{"started": t0.isoformat(), "interrupted_at": (t0 + _dt.timedelta(seconds=20)).isoformat(),
             "interrupted": "SIGTERM", "counts": {"done": 5}, "todo": 10}]
    rate = costleft.run_rate(runs, 5, 10, 4.0, t0 + _dt.timedelta(hours=1), held=False)
    assert rate == {"run": "last", "rows": 5, "elapsed_s": 20.0, "task_s_per_s": pytest.approx(1.0, rel=1e-15)}
    assert costleft.eta_s(30.0, 6.0, rate) == pytest.approx(36.0, rel=1e-15)
    assert costleft.eta_s(30.0, 6.0, None) is None
    going = [{"started": t0.isoformat(), "todo": 10}]
    rate = costleft.run_rate(going, 7, 10, 4.0, t0 + _dt.timedelta(seconds=56), held=True)
    assert rate == {"run": "current", "rows": 7, "elapsed_s": 56.0, "task_s_per_s": pytest.approx(0.5, rel=1e-15)}
    # not held: a run that never recorded its end (killed) has no end time, hence no rate
    assert costleft.run_rate(going, 7, 10, 4.0, t0, held=False) is None
    assert costleft.run_rate([], 7, 10, 4.0, t0, held=True) is None
    assert costleft.run_rate(going, 7, 10, None, t0, held=True) is None  # no measured row
