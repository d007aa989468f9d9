"""Predictors say where they were validated (issue 39 item 3): the field theory and the hybrid warn once outside
their validated domain (``PredictorDomainWarning``), the hybrid's coarse grids raise no resolution warning of
their own, and the hybrid's shared half-spectrum equals the full complex FFT it replaced (independent check)."""

from __future__ import annotations

import math
import warnings

import numpy as np
import pytest

from gapsweep import gfmd, surface, theory
from gapsweep.theory import improved
from gapsweep.theory.domain import PredictorDomainWarning

FT = dict(hurst=0.9, h_rms=1.0, gamma0=1e-3, lambda_l=0.5, lambda_s=0.01)


def _caught(fn, *args, **kwargs):
    with warnings.catch_warnings(record=True) as w:
        warnings.simplefilter("always")
        out = fn(*args, **kwargs)
    return out, w


def test_field_theory_warns_outside_its_domain_once_per_call():
    # rho/h_rms = 0.05: outside at every pressure (the paper's form is +209 % off there); one warning for 5 pressures
    _, w = _caught(theory.mean_gap, np.logspace(-4, -1, 5), rho=0.05, **FT)
    dom = [x for x in w if issubclass(x.category, PredictorDomainWarning)]
    assert len(dom) == 1 and "rho/h_rms = 0.05" in str(dom[0].message) and "5 of 5" in str(dom[0].message)
    assert dom[0].filename == __file__  # points at the caller, not at the library
    # inside: rho/h_rms >= 0.5 anywhere, or >= 0.12 at sigma0/(E* g_rms) >= 0.1
    _, w = _caught(theory.mean_gap, np.logspace(-4, -1, 5), rho=0.6, **FT)
    assert not [x for x in w if issubclass(x.category, PredictorDomainWarning)]
    g_rms = theory.spectrum.self_affine(0.9, lambda_l=0.5, lambda_s=0.01, rms_height=1.0).g_rms
    _, w = _caught(theory.mean_gap, 0.2 * g_rms, rho=0.2, **FT)
    assert not [x for x in w if issubclass(x.category, PredictorDomainWarning)]
    _, w = _caught(theory.mean_gap, [0.2 * g_rms, 0.01 * g_rms], rho=0.2, **FT)
    assert "1 of 2" in str(next(x for x in w if issubclass(x.category, PredictorDomainWarning)).message)


def test_field_theory_on_a_map_checks_the_maps_own_domain():
    h = surface.self_affine(64, 0.7, lambda_l=0.5, lambda_s=0.05, seed=3)
    h_rms = surface.rms_height(h)
    _, w = _caught(theory.mean_gap, 1e-3, heights=h, rho=0.05 * h_rms, gamma0=1e-3, lambda_l=0.5)
    assert [x for x in w if issubclass(x.category, PredictorDomainWarning)]
    _, w = _caught(theory.mean_gap, 1e-3, heights=h, rho=2.0 * h_rms, gamma0=1e-3, lambda_l=0.5)
    assert not [x for x in w if issubclass(x.category, PredictorDomainWarning)]


def test_hybrid_coarse_grids_raise_no_resolution_warning():
    """rho resolved on the input grid but not on the ladder's coarse grids: the coarse grids are the method, so no
    UnderResolvedWarning (issue 39: 240 of 260 hybrid calls raised 1-4); on an input grid that does not resolve
    rho, exactly one."""
    n = 256
    h = surface.self_affine(n, 0.6, lambda_l=0.5, lambda_s=4.0 / n, seed=11)
    rho = 2.0 / n  # two fine pixels: 16x coarser grids do not resolve it
    r, w = _caught(improved.hybrid, 0.01, h, zeta_c="auto", rho=rho, gamma0=1e-3, lambda_l=0.5)
    assert r.n_c < n and not [x for x in w if issubclass(x.category, gfmd.UnderResolvedWarning)]
    r, w = _caught(improved.hybrid, 0.01, h, zeta_c="auto", rho=0.5 / n, gamma0=1e-3, lambda_l=0.5)
    assert len([x for x in w if issubclass(x.category, gfmd.UnderResolvedWarning)]) == 1


def test_hybrid_warns_below_its_validated_rho():
    h = surface.self_affine(64, 0.6, lambda_l=0.5, lambda_s=0.05, seed=4)
    h_rms = surface.rms_height(h)
    _, w = _caught(improved.hybrid, 0.01, h, zeta_c="auto", rho=0.02 * h_rms, gamma0=1e-3, lambda_l=0.5)
    assert len([x for x in w if issubclass(x.category, PredictorDomainWarning)]) == 1
    _, w = _caught(improved.hybrid, 0.01, h, zeta_c="auto", rho=0.2 * h_rms, gamma0=1e-3, lambda_l=0.5)
    assert not [x for x in w if issubclass(x.category, PredictorDomainWarning)]


@pytest.mark.parametrize("n", [16, 30, 64])
def test_shells_half_spectrum_equals_the_full_complex_fft(n):
    """The hybrid's spectrum from one real FFT against the full complex FFT (the earlier code, written out here):
    shell powers, the largest live mode and every coarse surface, even and odd grids."""
    rng = np.random.default_rng(n)
    h = rng.standard_normal((n, n))
    sh = improved._Shells(h, 2.0)
    k = np.fft.fftfreq(n, d=1.0 / n).astype(np.int64)
    k2 = (k[:, None] ** 2 + k[None, :] ** 2).ravel()
    ht = np.fft.fft2(h - h.mean()) / h.size
    uk2 = np.flatnonzero(np.bincount(k2))
    assert np.array_equal(sh.k2, uk2)
    np.testing.assert_allclose(sh.pw, np.bincount(k2, weights=(np.abs(ht) ** 2).ravel())[uk2], rtol=1e-12,
                               atol=1e-20)
    assert sh.k_max == pytest.approx(math.sqrt(k2.max()), rel=1e-12)
    for k_c, n_c in ((3, 8), (7, 16), (n // 3, n), (n // 2 - 1, n), (n, n)):
        if n_c > n or (n_c < n and not 2 * k_c < n_c):
            continue
        kc = np.fft.fftfreq(n_c, d=1.0 / n_c).astype(int)
        full = ht[np.ix_(kc % n, kc % n)].copy()
        full[np.hypot(kc[:, None], kc[None, :]) > k_c] = 0.0
        np.testing.assert_allclose(sh.coarse(k_c, n_c), np.fft.ifft2(full).real * n_c * n_c, atol=1e-12)
    # a band-limited map: modes above |k| = 3 empty, so k_max is 3
    x = np.arange(n) / n
    assert improved._max_mode(np.cos(2 * math.pi * 3 * x)[:, None] + 0 * x[None, :]) == pytest.approx(3.0)
