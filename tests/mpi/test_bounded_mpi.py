"""The challenge's law (``interaction="hard_wall_adhesive"``) split over MPI ranks (gfmd.distributed.solve on
gapsweep.gfmd._bounded; docs/gfmd.md "Hard wall with adhesion") against the one-process solve, under ``mpiexec -n
2`` and ``-n 3`` (skipped without mpiexec/mpi4py). The worker (tests/mpi/bounded_worker.py) solves a 50 x 50
square (compressive), a 37 x 50 rectangle in a 0.74 x 1 box at a tensile load (continuation from zero load, odd
rows) and a 64 x 63 grid (odd columns, zero load, 3 pairs), each once on one process and once over the ranks:
the same statuses and iteration counts, mean gap and elastic energy to 1e-10 relative, contact area and the
contact pixels identical, the gap field to 1e-9 of its largest value, the same scalars on every rank. Memory
(192 x 160 compressive with 4 pairs, 150 x 192 tensile with 2): each rank's traced numpy peak within
``gfmd._bounded.memory_plan``, and the compressive one not below the plan's grid-sized parts."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest

from tests.mpi.mpirun import run_worker

WORKER = Path(__file__).with_name("bounded_worker.py")

pytestmark = pytest.mark.skipif(shutil.which("mpiexec") is None, reason="mpiexec not installed")


@pytest.mark.parametrize("ranks", [2, 3])
def test_bounded_distributed_equals_one_process(tmp_path, ranks):
    pytest.importorskip("mpi4py")
    d = run_worker(WORKER, tmp_path / "out.json", ranks)
    assert d["ranks"] == ranks and len(d["solve"]) == 3
    for s in d["solve"]:
        assert s["status"] == ["converged", "converged"], s
        assert s["iterations"][0] == s["iterations"][1], s  # the same iteration, decisions and all
        (g1, g), (a1, a), (e1, e) = s["mean_gap"], s["contact_area"], s["elastic_energy"]
        assert abs(g - g1) <= 1e-10 * abs(g1) and abs(e - e1) <= 1e-10 * abs(e1), s
        assert a == a1 and 0.0 < a1 < 1.0 and s["same_contact"], s  # a partial contact: a real check
        assert s["gap_field"] <= 1e-9 and s["same_on_ranks"], s
    assert d["solve"][1]["continuation_steps"] >= 1  # the tensile load was reached from zero load
    assert len(d["memory"]) == 2
    for m in d["memory"]:
        assert m["status"] == "converged", m
        assert m["measured_arrays"] <= m["estimated_arrays"], m  # the plan bounds the peak
    # and is not loose: its grid-sized parts alone (all that counts at large n) are reached by the compressive
    # solve (its pairs fill up; a tensile walk's short steps may never hold all pairs beside the two equilibria)
    m = d["memory"][0]
    assert m["sigma0"] > 0 and m["grid_arrays"] <= m["measured_arrays"], m
