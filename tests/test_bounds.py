"""The predictors' error estimates against stored GFMD references of a held-out set (issue 30 items 4 and 5).

References: ``benchmarks/results/bounds/gfmd_heldout.json``, written by ``benchmarks/bench_bounds.py --set
heldout`` (full GFMD, tol 1e-8, on the smallest power-of-two grid with ``lambda_s >= 4 dx``; keys
``H|lambda_l|zeta_s|rms_slope|gamma0|rho/h_rms|seed|sigma0/(E* g_rms)``). None of these surfaces, seeds or
pressures was used to choose the estimates' constants (the tuning set of the same script)."""

from __future__ import annotations

import json
import math
import warnings
from pathlib import Path

import numpy as np
import pytest

from gapsweep import surface
from gapsweep.theory import closure, improved

REFS = Path(__file__).resolve().parents[1] / "benchmarks" / "results" / "bounds" / "gfmd_heldout.json"


def _grid(lambda_l: float, zeta_s: float) -> int:
    n = 64
    while n < 4 * zeta_s / lambda_l - 1e-9:
        n *= 2
    return n


def _points(max_n: int, dist: bool):
    """(surface parameters, pressure, reference) of the stored held-out points on grids up to ``max_n``."""
    refs = json.loads(REFS.read_text())
    for key, ref in ((k, v) for k, v in refs.items() if k != "provenance"):  # the result's provenance record
        hurst, lam_l, zeta_s, slope, gamma0, rr, seed, ps = (float(v) for v in key.split("|"))
        n = _grid(lam_l, zeta_s)
        if n <= max_n and (not dist or "frac" in ref):
            yield (hurst, lam_l, zeta_s, slope, gamma0, rr, int(seed), n), ps, ref


def _surface(p):
    hurst, lam_l, zeta_s, slope, gamma0, rr, seed, n = p
    h = surface.self_affine(n, hurst, lambda_l=lam_l, lambda_s=lam_l / zeta_s, rms_slope=slope, seed=seed)
    return h, surface.rms_height(h), dict(rho=rr * surface.rms_height(h), gamma0=gamma0, lambda_l=lam_l)


def test_hybrid_error_estimate_bounds_the_error_on_held_out_points():
    """``hybrid(zeta_c="auto")`` at its defaults: |hybrid - GFMD| <= error_estimate at >= 95 % of the held-out
    points on grids up to 512 (42 points, 7 surfaces x 6 pressures); the estimate without its calibration
    (``safety=1, shift_fraction=0, floor=0, nonlinearity=0, steps=1``: the rule before issue 30) covers fewer,
    under 90 %. The median estimate is at most 3 % of ``max(|g0|, h_rms)``."""
    cover, raw_cover, rel = [], [], []
    for p, ps, ref in _points(512, dist=False):
        h, h_rms, kw = _surface(p)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            r = improved.hybrid(ps * p[3], h, zeta_c="auto", **kw)
            raw = improved.hybrid(ps * p[3], h, zeta_c="auto", safety=1.0, shift_fraction=0.0, floor=0.0,
                                  nonlinearity=0.0, steps=1, **kw)
        cover.append(abs(r.mean_gap - ref["mean_gap"]) <= r.error_estimate)
        raw_cover.append(abs(raw.mean_gap - ref["mean_gap"]) <= raw.error_estimate)
        rel.append(r.error_estimate / max(abs(ref["mean_gap"]), h_rms))
    assert len(cover) == 42
    assert np.mean(cover) >= 0.95, f"covered {sum(cover)}/{len(cover)}"
    assert np.mean(raw_cover) < 0.9
    assert np.median(rel) <= 0.03  # a bound, but not a vacuous one: typically within the 5 % goal


def test_multiscale_status_reports_its_misses_on_held_out_points():
    """``multiscale_gap_samples`` at its defaults on the held-out distributions on grids up to 512 (L1 on 80 bins
    over GFMD's range, GFMD's histogram stored): every distribution reported "converged" is within L1 = 0.15, and
    the self-check's ``l1_estimate`` is not below the actual L1 at >= 90 % of them."""
    rows = []
    for p, ps, ref in _points(512, dist=True):
        h, _, kw = _surface(p)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            ms = closure.multiscale_gap_samples(ps * p[3], h, seed=p[6], **kw)
        a = np.histogram(ms.samples, bins=np.linspace(ref["lo"], ref["hi"], closure.L1_BINS + 1))[0] / ms.samples.size
        l1 = float(np.sum(np.abs(a - np.asarray(ref["frac"]))) + 1.0 - a.sum())
        rows.append((l1, ms.status, ms.l1_estimate))
    assert len(rows) >= 15
    for l1, status, est in rows:
        assert status != "converged" or l1 <= 0.15, (l1, status, est)
        assert math.isfinite(est)
    assert np.mean([est >= l1 for l1, _, est in rows]) >= 0.9
    assert sum(status == "converged" for _, status, _ in rows) >= len(rows) // 2  # the check is not always failing


def test_hybrid_converged_is_bounded_on_issue39_points():
    """Issue 39's kind (H 0.2-0.3, rho/h_rms 0.05-0.07, zeta_s 40-50, N = 512; the stored GFMD references of
    ``bench_bounds.py --set issue39``, pressures 0.4 and 0.7 E* g_rms): wherever the hybrid at its defaults says
    "converged" its estimate bounds the error, and it says so at some points; the earlier rule (one change,
    ``shift_fraction=0.25, floor=2e-3``, no nonlinearity term) said "converged" outside its estimate there."""
    refs = json.loads((REFS.parent / "gfmd_issue39.json").read_text())
    now, before = [], []
    for key, ref in ((k, v) for k, v in refs.items() if k != "provenance"):  # the result's provenance record
        hurst, lam_l, zeta_s, slope, gamma0, rr, seed, ps = (float(v) for v in key.split("|"))
        if lam_l != 0.5 or ps < 0.4:
            continue
        h, _, kw = _surface((hurst, lam_l, zeta_s, slope, gamma0, rr, int(seed), _grid(lam_l, zeta_s)))
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            r = improved.hybrid(ps * slope, h, zeta_c="auto", **kw)
            old = improved.hybrid(ps * slope, h, zeta_c="auto", steps=1, shift_fraction=0.25, floor=2e-3,
                                  nonlinearity=0.0, **kw)
        for res, out in ((r, now), (old, before)):
            out.append((res.status == "converged", abs(res.mean_gap - ref["mean_gap"]) <= res.error_estimate))
    assert len(now) == 8
    assert all(bound for conv, bound in now if conv)
    assert sum(conv for conv, _ in now) >= 4
    assert any(conv and not bound for conv, bound in before)


@pytest.mark.parametrize("bad, match", [(dict(shift_fraction=-1.0), "shift_fraction"), (dict(floor=-1e-3), "floor"),
                                        (dict(nonlinearity=-0.1), "nonlinearity"), (dict(steps=0), "steps")])
def test_hybrid_estimate_constants_checked(bad, match):
    h = surface.self_affine(32, 0.5, lambda_l=0.5, lambda_s=0.1, seed=2)
    with pytest.raises(ValueError, match=match):
        improved.hybrid(0.01, h, zeta_c="auto", rho=5e-3, gamma0=1e-3, lambda_l=0.5, **bad)
