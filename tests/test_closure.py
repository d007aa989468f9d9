"""The local-response gap closure (gapsweep.theory.closure): the exact identity and the paper's limit."""

from __future__ import annotations

import math

import numpy as np
import pytest

from gapsweep import theory
from gapsweep.theory import closure

KW = dict(hurst=0.3, h_rms=2.4e-3, rho=2e-3, gamma0=1e-3, lambda_l=0.25, lambda_s=2.5e-3)


@pytest.mark.parametrize("s0", [1e-4, 1e-1])
def test_identity_mean_pressure(s0):
    """(gamma0/rho) <exp(-g/rho)> = sigma0 holds for the drift a = D2/rho (Monte Carlo + step error)."""
    g = closure.local_response_samples(s0, n=40_000, dzeta=0.02, seed=1, **KW)
    ratio = (KW["gamma0"] / KW["rho"]) * np.mean(np.exp(-g / KW["rho"])) / s0
    assert ratio == pytest.approx(1.0, abs=0.02)


def test_mean_pressure_limit_is_the_paper_process():
    """local=False: Gaussian with the paper-form mean gap and variance 2 int D2 = 2 rho (g0 - flat)."""
    s0 = 1e-3
    g = closure.local_response_samples(s0, n=100_000, dzeta=0.01, seed=2, local=False, **KW)
    g0 = theory.mean_gap(s0, **KW)
    flat = theory.flat_gap(s0, rho=KW["rho"], gamma0=KW["gamma0"])
    sd = math.sqrt(2 * KW["rho"] * (g0 - flat))
    assert g.mean() == pytest.approx(g0, abs=5 * sd / math.sqrt(g.size) + 1e-3 * (g0 - flat))
    assert g.std() == pytest.approx(sd, rel=0.01)
    # the local closure is narrower at small gaps: stiff regions receive less of the fine roughness
    gl = closure.local_response_samples(s0, n=100_000, dzeta=0.01, seed=2, **KW)
    assert np.quantile(gl, 0.01) > np.quantile(g, 0.01)


def test_bad_input():
    with pytest.raises(ValueError, match="sigma0"):
        closure.local_response_samples(0.0, **KW)
    with pytest.raises(ValueError, match="lambda_s"):
        closure.local_response_samples(1e-3, **{**KW, "lambda_s": 1.0})
