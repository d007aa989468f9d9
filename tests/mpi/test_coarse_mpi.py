"""The coarse-to-fine start split over MPI ranks (gapsweep.gfmd._coarse, docs/gfmd.md "Coarse-to-fine start")
under ``mpiexec -n 2/3`` (skipped without mpiexec/mpi4py): the layout exchange against analytic samples of a
band-limited field (1e-12), and the solve (exponential and adhesive, square and 96 x 160 rectangle; 3 ranks: rows
and columns that do not divide) against the plain single-process solve: mean gap to 1e-7 relative, contact area
to 2 pixels, gap field to 1e-6 of its largest value, both converged to tol 1e-9 (2 coarse levels)."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest

from tests.mpi.mpirun import run_worker

WORKER = Path(__file__).with_name("coarse_worker.py")

pytestmark = pytest.mark.skipif(shutil.which("mpiexec") is None, reason="mpiexec not installed")


@pytest.mark.parametrize("ranks", [2, 3])
def test_coarse_start_over_ranks_equals_single_process(tmp_path, ranks):
    pytest.importorskip("mpi4py")
    d = run_worker(WORKER, tmp_path / "out.json", ranks)
    assert d["ranks"] == ranks
    assert len(d["prolong"]) == len(d["restrict"]) == 3
    for e in d["prolong"] + d["restrict"]:
        assert e["error"] <= 1e-12 * 1.8, e  # |field| <= 1.8
    assert len(d["solve"]) == 4
    for s in d["solve"]:
        assert s["status"] == ["converged", "converged"], s
        (g1, g), (a1, a) = s["mean_gap"], s["contact_area"]
        nx, ny = s["shape"]
        assert abs(g / g1 - 1) <= 1e-7, s
        assert abs(a - a1) <= 2 / (nx * ny) and 0 < a1 < 1, s
        assert s["gap_field"] <= 1e-6, s
        assert len(s["levels"]) == 2 and s["same_on_ranks"], s
