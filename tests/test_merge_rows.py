"""gapsweep.sweep.merge's rule for two rows of one task, in-process on made-up rows (merge._Rows.offer): a
better status always wins (done > not_converged > failed > pending, whatever the order of the shards), equal
content is no conflict (wall time, rank, checksum and algorithm version aside), different content of equal
status is a conflict that keeps the first row, or the last with ``on_conflict="last"``. The whole merge of
shard stores is tests/faults/test_merge_conflicts.py and tests/test_store_tools.py."""

from __future__ import annotations

import numpy as np
import pytest

from gapsweep.sweep.merge import _Rows
from gapsweep.sweep.schema import RESULT_DTYPE, STATUS
from gapsweep.sweep.store import empty_results

BINS = 3


def _row(status: str, mean_gap: float, wall: float = 1.0) -> tuple[np.void, tuple[np.ndarray, ...]]:
    r = empty_results(1, RESULT_DTYPE)[0]
    r["status"], r["mean_gap"], r["wall_time"] = STATUS[status], mean_gap, wall
    h = (np.linspace(0, 1, BINS + 1), np.full(BINS, mean_gap), np.linspace(0, 2, BINS + 1), np.ones(BINS))
    return r, h


def _merge(offers: list[tuple[str, str, float]], on_conflict: str = "first") -> _Rows:
    """Offer rows ``(shard, status, mean gap)`` of task 0 in this order; the merged rows."""
    rows = _Rows(1, BINS, RESULT_DTYPE)
    for k, (shard, status, g) in enumerate(offers):
        r, h = _row(status, g, wall=float(k))  # another wall time each: never a conflict by itself
        rows.offer(0, "t0", shard, r, h, on_conflict)
    return rows


@pytest.mark.parametrize("order", [1, -1])
def test_better_status_wins_in_either_order(order: int) -> None:
    ladder = [("a", "failed", 1.0), ("b", "not_converged", 2.0), ("c", "done", 3.0)][::order]
    rows = _merge(ladder)
    assert rows.results["status"][0] == STATUS["done"] and rows.results["mean_gap"][0] == 3.0
    assert rows.source == ["c"] and rows.conflicts == []
    assert np.array_equal(rows.dens[0], np.full(BINS, 3.0))  # the histograms come with the row


def test_equal_rows_are_no_conflict() -> None:
    rows = _merge([("a", "done", 1.5), ("b", "done", 1.5)])
    assert rows.conflicts == [] and rows.source == ["a"]


@pytest.mark.parametrize(("how", "kept"), [("first", ("a", 1.0)), ("error", ("a", 1.0)), ("last", ("b", 2.0))])
def test_different_rows_of_equal_status_conflict(how: str, kept: tuple[str, float]) -> None:
    rows = _merge([("a", "done", 1.0), ("b", "done", 2.0)], on_conflict=how)
    assert rows.conflicts == ["task t0: a and b both have a 'done' row with different results"]
    assert (rows.source[0], rows.results["mean_gap"][0]) == kept
    assert np.array_equal(rows.dens[0], np.full(BINS, kept[1]))


def test_a_failed_row_never_replaces_a_done_one() -> None:
    rows = _merge([("a", "done", 1.0), ("b", "failed", np.nan)], on_conflict="last")
    assert rows.results["status"][0] == STATUS["done"] and rows.source == ["a"] and rows.conflicts == []
