"""The field theory on a surface's own spectrum (heights=, rectangular maps), docs/theory.md."""

from __future__ import annotations

import numpy as np
import pytest

from gapsweep import surface, theory
from gapsweep.theory import spectrum as spec

KW = dict(rho=2e-3, gamma0=1e-3)
SIG = np.logspace(-4, 0, 9)


def test_rectangular_map_of_a_tiled_surface_is_the_square_one():
    """Tiling a periodic surface twice along y (nx x 2nx map, box 1 x 2) leaves its spectrum, hence the
    discrete mean gap, unchanged: an exact identity."""
    h = surface.self_affine(64, 0.5, lambda_l=0.5, lambda_s=0.05, seed=2)
    sq = theory.mean_gap_discrete(SIG, h, lambda_l=0.5, **KW)
    rect = theory.mean_gap_discrete(SIG, np.concatenate([h, h], axis=1), lambda_l=0.5, length=(1.0, 2.0), **KW)
    np.testing.assert_allclose(rect, sq, rtol=1e-12)
    with pytest.raises(ValueError, match="heights"):
        theory.mean_gap_discrete(1e-3, np.concatenate([h, h], axis=1), lambda_l=0.5, **KW)


def test_mean_gap_heights_forms():
    h = surface.self_affine(256, 0.5, lambda_l=0.25, lambda_s=0.01, seed=4)
    disc = theory.mean_gap(SIG, heights=h, form="discrete", lambda_l=0.25, **KW)
    np.testing.assert_allclose(disc, theory.mean_gap_discrete(SIG, h, lambda_l=0.25, **KW), rtol=1e-12)
    cont = theory.mean_gap(SIG, heights=h, lambda_l=0.25, **KW)  # radially averaged PSD
    flat = theory.flat_gap(SIG, **KW)
    # the ring average keeps the variance to a few per cent, so the roughness parts agree to that level
    np.testing.assert_allclose(cont - flat, disc - flat, rtol=0.06)
    # low-pressure limit of the continuum form: flat + (ring variance)/(2 rho)
    v = spec.radial(h, 1.0).h_rms ** 2
    assert theory.mean_gap(1e-12, heights=h, lambda_l=0.25, **KW) == pytest.approx(
        theory.flat_gap(1e-12, **KW) + v / (2 * KW["rho"]), rel=1e-6)


def test_mean_gap_heights_bad_input():
    h = np.zeros((8, 8))
    with pytest.raises(ValueError, match="form"):
        theory.mean_gap(1e-3, heights=h, form="paper", lambda_l=0.25, **KW)
    with pytest.raises(ValueError, match="hurst"):
        theory.mean_gap(1e-3, lambda_l=0.25, lambda_s=0.01, h_rms=0.01, **KW)
