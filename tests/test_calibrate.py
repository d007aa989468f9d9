"""Tests of gapsweep.calibrate (docs/model.md M5): recover a known C2 (and C1) from synthetic histograms."""

import math

import numpy as np
import pytest

from gapsweep import calibrate, fokker_planck, sde

P = dict(hurst=0.3, h_rms=2.34e-3, rho=5e-4, gamma0=1e-3, lambda_l=0.25, lambda_s=2.5e-3)


@pytest.mark.validation
def test_recovers_c2_from_noise_free_fp_histogram():
    truth = 0.4
    ref = fokker_planck.solve(1e-2, c2=truth, **P)
    g = ref.g[-1]
    edges = np.linspace(g[0], g[-1], 120)
    for metric in ("w1", "l1", "nll"):
        r = calibrate.fit(edges, ref.bin_density(edges), sigma0=1e-2, metric=metric, **P)
        assert r.status == "ok"
        assert r.c2 == pytest.approx(truth, rel=5e-3)
        assert r.distance < 1e-3 if metric != "nll" else math.isfinite(r.distance)


@pytest.mark.validation
def test_recovers_c2_from_sde_histogram_within_uncertainty():
    truth = 0.3
    h = sde.gap_histogram_counts(1e-2, c2=truth, n=40_000, dzeta=0.05, steps="log", seed=5, bins=60, **P)
    r = calibrate.fit(h.edges, h.density, sigma0=1e-2, count=h.n, **P)
    assert r.status == "ok"
    assert 0 < r.c2_err < 0.1 * truth
    assert abs(r.c2 - truth) < 4 * r.c2_err
    # a wrong model is far: C2 off by a factor 2 is many sigma away
    assert abs(0.6 - r.c2) > 10 * r.c2_err


def test_fit_c1_and_bootstrap():
    truth = 0.3
    h = sde.gap_histogram_counts(1e-2, c2=truth, n=40_000, dzeta=0.05, steps="log", seed=6, bins=60, **P)
    c1_true = P["hurst"] * P["h_rms"] ** 2
    r = calibrate.fit(h.edges, h.density, sigma0=1e-2, count=h.n, fit_c1=True, c1=1.3 * c1_true,
                      fp_options={"n_steps": 200}, **P)
    assert r.status == "ok"
    assert abs(r.c1 - c1_true) < 4 * r.c1_err and abs(r.c2 - truth) < 4 * r.c2_err
    rb = calibrate.fit(h.edges, h.density, sigma0=1e-2, count=h.n, uncertainty="bootstrap", n_boot=6,
                       fp_options={"n_steps": 200}, **P)
    assert rb.bootstrap.shape[0] == 6 and 0 < rb.c2_err < 0.05
    assert abs(rb.c2 - truth) < 5 * rb.c2_err


def test_bad_input_and_bounds():
    e = np.linspace(0, 1e-2, 11)
    d = np.ones(10)
    with pytest.raises(ValueError, match="edges"):
        calibrate.fit(e[::-1], d, sigma0=1e-2, **P)
    with pytest.raises(ValueError, match="density"):
        calibrate.fit(e, -d, sigma0=1e-2, **P)
    with pytest.raises(ValueError, match="metric"):
        calibrate.fit(e, d, sigma0=1e-2, metric="kl", **P)
    with pytest.raises(ValueError, match="c2_bounds"):
        calibrate.fit(e, d, sigma0=1e-2, c2_bounds=(1.0, 0.5), **P)
    with pytest.raises(ValueError, match="count"):
        calibrate.fit(e, d, sigma0=1e-2, count=-3, **P)
    # a histogram the model cannot produce drives C2 to a bound and says so
    ref = fokker_planck.solve(1e-2, c2=5.0, **P)
    edges = np.linspace(ref.g[-1][0], ref.g[-1][-1], 80)
    r = calibrate.fit(edges, ref.bin_density(edges), sigma0=1e-2, c2_bounds=(1e-3, 1.0), **P)
    assert r.status == "at_bound" and r.c2 == pytest.approx(1.0, rel=1e-2)


@pytest.mark.validation
def test_pulls_of_default_fit_have_unit_spread():
    # issue 9.2: over repeated synthetic targets (multinomial draws of `count` samples from the FP density at the
    # true C2) the pulls (c2 - truth) / c2_err of the default fit have a standard deviation within [0.7, 1.4]
    # (24 draws: the sample sd of unit pulls is 1 +- 0.15). With the old default (metric "w1", likelihood
    # curvature as its error) it was 1.76 here (2.15 at sigma0 = 1e-3; it grows with the count).
    truth, count = 0.3, 40_000
    fast = dict(n_steps=100, tol=None, estimate_error=False)
    ref = fokker_planck.solve(1e-2, c2=truth, **fast, **P)
    c = np.cumsum(ref.density[-1] * ref.widths)
    g = ref.g[-1]
    edges = np.linspace(g[np.searchsorted(c, 1e-4)], g[np.searchsorted(c, 1 - 1e-4)], 41)
    prob = np.diff(ref.cdf(edges))
    rng = np.random.default_rng(11)
    pulls = []
    for _ in range(24):
        counts = rng.multinomial(count, prob / prob.sum())
        r = calibrate.fit(edges, counts / np.diff(edges), sigma0=1e-2, count=count, fp_options=fast, **P)
        assert r.status == "ok" and r.uncertainty == "curvature"
        pulls.append((r.c2 - truth) / r.c2_err)
    assert 0.7 < np.std(pulls, ddof=1) < 1.4
    assert abs(np.mean(pulls)) < 3 / math.sqrt(len(pulls))


def test_distance_metrics_get_bootstrap_and_forward_model_error_shows():
    truth = 0.3
    h = sde.gap_histogram_counts(1e-2, c2=truth, n=20_000, dzeta=0.05, steps="log", seed=5, bins=40, **P)
    with pytest.raises(ValueError, match="curvature"):
        calibrate.fit(h.edges, h.density, sigma0=1e-2, count=h.n, metric="w1", uncertainty="curvature", **P)
    r = calibrate.fit(h.edges, h.density, sigma0=1e-2, count=h.n, metric="w1", n_boot=4, **P)
    assert r.uncertainty == "bootstrap" and r.bootstrap.shape[0] >= 2
    # a coarse forward model (10 steps): its estimated error shows as a systematic part of c2_err
    coarse = calibrate.fit(h.edges, h.density, sigma0=1e-2, count=h.n, fp_options=dict(n_steps=10, max_steps=10,
                                                                                          tol=None), **P)
    fine = calibrate.fit(h.edges, h.density, sigma0=1e-2, count=h.n, **P)
    assert coarse.c2_sys_err > fine.c2_sys_err and coarse.c2_err >= coarse.c2_stat_err
    assert abs(coarse.c2 - fine.c2) < 3 * math.hypot(coarse.c2_sys_err, fine.c2_sys_err) + 0.5 * fine.c2_stat_err
