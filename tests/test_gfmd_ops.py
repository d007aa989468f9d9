"""The exponential law's array passes written once (gapsweep/gfmd/_ops.py; docs/gfmd.md, "One solve over several
processes"): the explicit Parseval weights against the real-space mean they stand for (full half spectrum and a
rank's columns, even and odd sides), the passes on a split spectrum (each piece with its weights and ``q = 0``
owner flag, the pieces' sums added as the reducer adds the ranks') against the passes on the whole one, and the
fused cupy variant of a rank's passes (gfmd._cuda._SlabCupyOps, through tests/cupy_shim.py) against the numpy
passes it replaces. In-process, small grids."""

from __future__ import annotations

import numpy as np
import pytest

from gapsweep.core.slab import SlabFFT
from gapsweep.gfmd._ops import LOCAL, Parseval, _Ops
from tests import cupy_shim
from tests.comm_stub import SizeRankComm as _Comm


def _pieces(nx: int, ny: int, ranks: int) -> list[tuple[slice, Parseval, bool]]:
    """Each rank's spectrum rows (columns ky of the half spectrum), Parseval weights and owner flag."""
    out = []
    for r in range(ranks):
        slab = SlabFFT((nx, ny), _Comm(ranks, r))
        out.append((slab.col, Parseval.columns(slab.weights()), slab.owns_zero))
    return out


@pytest.mark.parametrize(("nx", "ny", "ranks"), [(8, 8, 3), (9, 7, 2), (6, 5, 3), (10, 12, 4), (2, 2, 1)])
def test_parseval_weights_give_the_real_space_mean(nx: int, ny: int, ranks: int) -> None:
    """``<A B>`` of the normalised half spectra equals ``mean(a b)`` in real space (Parseval), to 1e-13 of
    ``mean(|a b|)``: on the full grid's half spectrum and summed over the ranks' columns."""
    rng = np.random.default_rng(nx * 100 + ny)
    a, b = rng.standard_normal((2, nx, ny))
    A, B = (np.fft.rfft2(x) / (nx * ny) for x in (a, b))
    want, scale = float(np.mean(a * b)), float(np.mean(np.abs(a * b)))
    assert Parseval.half(ny).dot(A, B) == pytest.approx(want, abs=1e-13 * scale)
    At, Bt = np.ascontiguousarray(A.T), np.ascontiguousarray(B.T)  # the slabs' layout [ky, kx]
    split = sum(w.dot(At[c], Bt[c]) for c, w, _ in _pieces(nx, ny, ranks))
    assert split == pytest.approx(want, abs=1e-13 * scale)


def _state(n: int, seed: int) -> dict:
    """A half spectrum state of the exponential law's passes (layout [ky, kx]) and real fields."""
    rng = np.random.default_rng(seed)
    nh = n // 2 + 1

    def spec() -> np.ndarray:
        return np.ascontiguousarray(rng.standard_normal((nh, n)) + 1j * rng.standard_normal((nh, n)))

    k = rng.uniform(0.5, 2.0, (nh, n))
    return dict(X=spec(), E=spec(), G=spec(), G_old=spec(), D=spec(), k=k, minv=1.0 / (k + 0.3),
                w=rng.standard_normal((n, n)), d=rng.standard_normal((n, n)))


def _run_passes(ops: _Ops, s: dict, c: slice | None = None) -> tuple[list[float], list[np.ndarray]]:
    """Every pass of ``ops`` on ``s`` (its rows ``c``), in a solver's order: the scalars they return and the
    arrays they leave (``X, G, D, e, wt`` on the host)."""
    xp = ops.xp
    sl = slice(None) if c is None else c
    X, E, G, G_old, D, k, minv = (xp.asarray(np.array(s[key][sl])) for key in
                                  ("X", "E", "G", "G_old", "D", "k", "minv"))
    w, d = xp.asarray(s["w"]), xp.asarray(s["d"])
    out: list[float] = []
    e, wt = xp.empty_like(w), xp.empty_like(w)
    out.append(ops.trial(w, d, -0.7, wt))
    out += ops.expstats(wt, 0.5, e, d)
    out += ops.moments(e, d)
    out.append(ops.grad_step(X, D, 0.3, E, 1.7, k, G))
    out += ops.cg_dots(G, G_old, minv)
    out += ops.cg_update(G, minv, D, 0.4, k, X)
    out.append(ops.dot(G, D))
    ops.axpy(X, -0.2, D)
    out.append(ops.dot(X, X))
    return [float(v) for v in out], [np.asarray(a) for a in (X, G, D, e, wt)]


@pytest.mark.parametrize(("n", "ranks"), [(8, 3), (9, 2), (12, 4)])
def test_split_spectrum_passes_add_up_to_the_whole(n: int, ranks: int) -> None:
    """The spectral passes on the ranks' pieces (weights, owner flag), their sums added, equal the passes on the
    whole spectrum (one piece holding every column) to 1e-12 relative; the real-space passes see the same
    fields on every piece here, so only the spectral scalars are added."""
    s = _state(n, seed=n)
    _, w_all, own_all = _pieces(n, n, 1)[0]
    whole = _run_passes(_Ops(np, n, weights=w_all, owner=own_all), s)[0]
    parts = [_run_passes(_Ops(np, n, red=LOCAL, weights=w, owner=own), s, c)[0] for c, w, own in _pieces(n, n, ranks)]
    spectral = slice(6, None)  # grad_step, cg_dots, cg_update, dot, dot
    np.testing.assert_allclose(np.sum([p[spectral] for p in parts], axis=0), whole[spectral], rtol=1e-12)
    for p in parts:
        assert p[:6] == whole[:6]  # trial max, (S, s1, s2), moments: the same real fields on each


def test_slab_cupy_passes_match_the_numpy_passes(monkeypatch) -> None:
    """gfmd._cuda._SlabCupyOps (row-wise cupy reductions and fused updates, here on the shim) returns the numpy
    passes' scalars to 1e-12 relative and leaves the same arrays, on the owner's piece and another."""
    cp = cupy_shim.install_fresh(monkeypatch)
    from gapsweep.gfmd._cuda import _SlabCupyOps

    n = 10
    s = _state(n, seed=3)
    for c, w, own in _pieces(n, n, 2):
        ref, ref_arrays = _run_passes(_Ops(np, n, weights=w, owner=own), s, c)
        got, arrays = _run_passes(_SlabCupyOps(cp, n, red=LOCAL, weights=w, owner=own), s, c)
        np.testing.assert_allclose(got, ref, rtol=1e-12)
        for a, b in zip(arrays, ref_arrays):
            np.testing.assert_allclose(a, b, rtol=1e-13, atol=1e-13)
    counts = cupy_shim.COUNTS
    assert counts["gapsweep_slab_rkdot"] >= 4 and counts["gapsweep_slab_grad"] == 2
    assert counts["gapsweep_slab_dir"] == 2 and counts["gapsweep_slab_axpy"] == 4 and counts["gapsweep_slab_m1"] == 4
    with pytest.raises(ValueError, match="rows"):
        _SlabCupyOps(cp, n, red=LOCAL, weights=Parseval.half(n), owner=True)
