"""gapsweep.reference: the analytic solutions are internally consistent (each against an independent form of
itself: a quadrature, a limit, the force balance), so the solver tests built on them compare with something true."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy import integrate

from gapsweep import reference as ref


@pytest.mark.validation
def test_hertz_force_and_radius_invert_and_the_pressure_carries_the_force():
    h = ref.hertz(2500.0, 1.3, a=50.0)
    assert ref.hertz(2500.0, 1.3, force=h.force).a == pytest.approx(50.0, rel=1e-14)
    assert h.p0 == pytest.approx(2 * 1.3 * 50.0 / (math.pi * 2500.0), rel=1e-14)  # p0 = 2 E* a / (pi R)
    total, _ = integrate.quad(lambda r: 2 * math.pi * r * float(h.pressure(r)), 0.0, h.a)
    assert total == pytest.approx(h.force, rel=1e-9)
    assert float(h.pressure(60.0)) == 0.0 and h.depth == pytest.approx(1.0)
    with pytest.raises(ValueError, match="exactly one"):
        ref.hertz(1.0, a=1.0, force=1.0)


@pytest.mark.validation
@pytest.mark.parametrize("frac", [0.1, 0.5, 0.9])
def test_westergaard_pressure_averages_to_the_load(frac):
    amp, lam, e = 0.01, 2.0, 1.7
    pbar = frac * math.pi * e * amp / lam
    x = (np.arange(200_000) + 0.5) * (lam / 200_000)
    a, p = ref.westergaard(x, pbar, amp, e, lam)
    assert math.sin(math.pi * a / lam) ** 2 == pytest.approx(frac, rel=1e-12)
    assert float(p.mean()) == pytest.approx(pbar, rel=1e-3)  # the sqrt edge limits the midpoint rule
    assert np.all(p[np.abs(np.where(x > lam / 2, x - lam, x)) >= a] == 0)
    with pytest.raises(ValueError, match="pbar"):
        ref.westergaard(x, 2 * math.pi * e * amp / lam, amp, e, lam)


@pytest.mark.validation
def test_johnson_reduces_to_westergaard_and_has_a_tensile_pull_off():
    c0 = ref.johnson_wavy_adhesion(0.0)
    for psi in (0.2, 0.7, 1.2):
        assert c0.f(psi) == pytest.approx(math.sin(psi) ** 2)
    c = ref.johnson_wavy_adhesion(0.3)
    assert c.psi_c < c.psi_top and c.pull_off < 0
    assert c.pull_off == pytest.approx(-0.0959, abs=5e-5)  # the value tests/test_contact.py quotes
    psi = c.half_width(0.1)
    assert c.f(psi) == pytest.approx(0.1, abs=1e-12) and c.psi_c <= psi <= c.psi_top
    w = 0.3**2 * math.pi**2 * 0.05**2 / 2
    assert ref.johnson_alpha(w, 0.05) == pytest.approx(0.3, rel=1e-14)


@pytest.mark.validation
def test_boussinesq_rectangle_is_the_integrated_point_load():
    a, b, e = 0.5, 0.75, 2.0
    x, w = np.polynomial.legendre.leggauss(60)
    px, py = 2.0, 4.5
    r = np.hypot(px - a * x[:, None], py - b * x[None, :])
    quad = a * b * float(np.sum(w[:, None] * w[None, :] * ref.boussinesq_point(r, 1.0, e)))
    assert float(ref.boussinesq_rectangle(px, py, a, b, e)) == pytest.approx(quad, rel=1e-10)
