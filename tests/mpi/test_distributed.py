"""One GFMD solve split over MPI ranks (gapsweep.gfmd.distributed, docs/gfmd.md "One solve over several
processes") against the single-process solve, under ``mpiexec -n 2/3/4`` (skipped without mpiexec/mpi4py).

The worker (tests/mpi/distributed_worker.py) runs on every rank count: the distributed rfft2 against
numpy.fft.rfft2 (1e-12 relative), the surfaces made per rank against self_affine (bit for bit), and every law
(exponential cg and fire, hard wall pcg and pk, adhesive at a compressive and a tensile load) on a 50 x 50 grid
(50 rows: not divisible by 3 or 4) and a 96 x 160 rectangle in a 0.6 x 1 box, each against gfmd.solve in one
process: mean gap to 1e-9 relative, contact area to 1e-9, elastic energy to 1e-9, the same iteration count, the
gap field to 1e-9 of its largest value, the gap histogram to 1e-9, the same scalars on every rank."""

from __future__ import annotations

import itertools
import shutil
from pathlib import Path

import pytest

from tests.comm_stub import SizeRankComm as _Comm
from tests.mpi.mpirun import run_worker

WORKER = Path(__file__).with_name("distributed_worker.py")

pytestmark = pytest.mark.skipif(shutil.which("mpiexec") is None, reason="mpiexec not installed")


def _run(ranks: int, out: Path) -> dict:
    pytest.importorskip("mpi4py")
    return run_worker(WORKER, out, ranks)


@pytest.mark.parametrize("ranks", [2, 3, 4])
def test_distributed_equals_single_process(tmp_path, ranks):
    d = _run(ranks, tmp_path / "out.json")
    assert d["ranks"] == ranks
    assert len(d["transform"]) == 8
    for t in d["transform"]:
        assert t["forward"] <= 1e-12 and t["inverse"] <= 1e-12, t
    assert [s["identical"] for s in d["surface"]] == [True, True]
    assert len(d["solve"]) == 9
    for s in d["solve"]:
        assert s["status"] == ["converged", "converged"], s
        if s["strict"]:  # the same minimiser: the same iteration
            assert s["iterations"][0] == s["iterations"][1], s
        (g1, g), (a1, a), (e1, e) = s["mean_gap"], s["contact_area"], s["elastic_energy"]
        assert abs(g - g1) <= 1e-9 * abs(g1), s
        assert abs(a - a1) <= 1e-9, s
        assert 0.0 < a1 < 1.0, s  # a partial contact: the area is a real check
        assert abs(e - e1) <= 1e-9 * abs(e1), s
        # the lean L-BFGS with 2 pairs (not strict): fields to 10x the solver tolerance (1e-10) of the largest gap
        assert s["gap_field"] <= (1e-9 if s["strict"] else 10 * s["tol"]) and s["histogram"] <= 1e-9, s
        assert s["same_on_ranks"] and s["shape_reported"] == s["shape"], s
    assert sum(not s["strict"] for s in d["solve"]) == 2
    # memory: the traced peak per rank within the estimate of gfmd.distributed.solve_memory, adhesion (2 pairs)
    # within 12 arrays + 3 of scratch
    assert len(d["memory"]) == 3
    for m in d["memory"]:
        assert m["status"] == "converged", m
        assert m["measured_arrays"] <= m["estimated_arrays"], m
        if m["kind"] == "adhesive" and m["sigma0"] > 0:
            assert m["estimated_arrays"] <= 12 + 3, m


def test_comm_errors_name_the_extra():
    from gapsweep import gfmd

    with pytest.raises(TypeError, match=r"gapsweep\[distributed\]"):
        gfmd.slab_rows(10, None)
    with pytest.raises(TypeError, match=r"gapsweep\[distributed\]"):
        gfmd.solve([[0.0, 1.0], [1.0, 0.0]], sigma0=1e-2, gamma0=1e-3, rho=1e-2, comm="world")


@pytest.mark.parametrize("n,size", [(50, 3), (50, 4), (96, 5), (7, 7)])
def test_slab_rows_partition(n, size):
    from gapsweep import gfmd

    blocks = [gfmd.slab_rows(n, _Comm(size, r)) for r in range(size)]
    assert blocks[0].start == 0 and blocks[-1].stop == n
    assert all(a.stop == b.start for a, b in itertools.pairwise(blocks))
    lens = [b.stop - b.start for b in blocks]
    assert max(lens) - min(lens) <= 1 and sorted(lens, reverse=True) == lens
    with pytest.raises(ValueError, match="n_rows must be an integer >= the number of ranks"):
        gfmd.slab_rows(size - 1, _Comm(size, 0))
