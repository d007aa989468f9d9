"""The hard wall's fresh start after a stall (gfmd._constrained._STALL, ``_stalled``; docs/gfmd.md, "A
cycling hard-wall solve, and the fresh start that ends it").

The cycle it ends needs a 2048^2 map to appear (benchmarks/bench_hardwall_cycle.py, about a minute), so here the
mechanism is forced on small maps (``_stalled`` made true at the first iteration without a new lowest residual)
and its answer compared with the same problem solved without it: periodic (the spectral loop) and free
boundaries (the real-space loop), each method. And converging solves never start again at the shipped rule, nor
does the rule fire on a stretch as long as the longest seen in converging solves (14 at N = 4096)."""

from __future__ import annotations

import pytest

from gapsweep.gfmd import _constrained, solve
from gapsweep.surface import self_affine


def _surface(n: int, seed: int):
    return self_affine(n, 0.5, lambda_l=0.25, lambda_s=8 / n, seed=seed)


@pytest.mark.parametrize(("periodic", "method"), [(True, "pcg"), (True, "pk"), (False, "pcg")])
def test_a_forced_fresh_start_converges_to_the_same_answer(monkeypatch, periodic: bool, method: str) -> None:
    h = _surface(128, 4)  # at this load every one of the three meets an iteration without a new lowest residual
    kw = dict(sigma0=0.2, interaction="hard_wall", tol=1e-10, method=method, periodic=periodic, max_iter=20000)
    plain = solve(h, **kw)
    monkeypatch.setattr(_constrained, "_stalled", lambda it, it_best: True)
    again = solve(h, **kw)
    assert plain.converged and plain.diagnostics["restarted_at"] == []
    assert again.converged, again.status
    assert len(again.diagnostics["restarted_at"]) == 1  # once only: afterwards the earlier rule runs to the end
    assert len(again.history) == again.iterations + 1
    # the same contact problem: mean gap and area of the two solves agree to the tolerance's order
    assert abs(again.mean_gap - plain.mean_gap) <= 1e-8 * abs(plain.mean_gap)
    assert abs(again.contact_area - plain.contact_area) <= 2.0 / h.size


@pytest.mark.parametrize("seed", [11, 12])
@pytest.mark.parametrize("sigma0", [5e-3, 5e-2, 0.2])
def test_converging_solves_never_start_again(seed: int, sigma0: float) -> None:
    r = solve(_surface(256, seed), sigma0=sigma0, interaction="hard_wall", tol=1e-8)
    assert r.converged and r.diagnostics["restarted_at"] == []


def test_the_rule_waits_as_long_as_the_solve_took_to_its_best() -> None:
    stalled = _constrained._stalled
    assert not stalled(11 + 14, 11) and not stalled(200 + 150, 200)  # converging solves' stretches
    assert stalled(11 + _constrained._STALL, 11) and stalled(400, 200)  # the cycle (best at 11), a long stall
