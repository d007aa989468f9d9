"""One solve over several processes and the coarse-to-fine start (docs/gfmd.md "One solve over several
processes", "Coarse-to-fine start"; gapsweep.core.slab, gapsweep.gfmd.distributed, gapsweep.gfmd._coarse)
against analytic truths, in process: the ranks are threads of tests/validation/threadcomm.py (odd rank counts,
grids that do not divide evenly), so no mpiexec is needed.

* The distributed transform of a field made of a few cosines against its Fourier coefficients written out by hand.
* The distributed hard wall against Westergaard and the full-contact closed form.
* The exponential law, distributed and with the coarse start, against the linear response of one mode
  (exact as the amplitude over the range goes to zero) and its mean gap in closed form.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from gapsweep.core.slab import SlabFFT, slab_rows
from gapsweep.gfmd import solve
from gapsweep.reference import westergaard

from .threadcomm import run_ranks

pytestmark = pytest.mark.validation

# (kx, ky, amplitude, phase) of the test field: the mean, modes on both axes and an oblique one
MODES = [(0, 0, 0.75, 0.0), (1, 0, 2.0, 0.3), (0, 2, -1.25, 0.0), (3, 1, 0.5, -1.1), (2, 3, 0.4, 2.0)]


def field(nx: int, ny: int) -> np.ndarray:
    x = np.arange(nx)[:, None] / nx
    y = np.arange(ny)[None, :] / ny
    return sum(a * np.cos(2 * np.pi * (kx * x + ky * y) + ph) for kx, ky, a, ph in MODES)


def analytic_half_spectrum(nx: int, ny: int) -> np.ndarray:
    """``sum_r a(r) exp(-i q.r)`` of :func:`field` on the half spectrum ``[ky, kx]`` (``ky = 0..ny//2``): a
    cosine ``a cos(q.r + ph)`` puts ``a nx ny exp(+i ph)/2`` at ``(kx, ky)`` and its conjugate at ``(-kx, -ky)``;
    the mean ``a nx ny`` at 0 (every mode here lies below the Nyquist frequency)."""
    spec = np.zeros((ny // 2 + 1, nx), dtype=complex)
    for kx, ky, a, ph in MODES:
        if kx == 0 and ky == 0:
            spec[0, 0] += a * nx * ny
            continue
        c = a * nx * ny * np.exp(1j * ph) / 2
        spec[ky, kx % nx] += c
        if ky == 0:
            spec[0, -kx % nx] += np.conj(c)
    return spec


@pytest.mark.parametrize("ranks", [1, 2, 3, 5, 7])
@pytest.mark.parametrize(("nx", "ny"), [(15, 16), (21, 14), (33, 27), (64, 48)])
def test_distributed_transform_of_cosines(ranks: int, nx: int, ny: int) -> None:
    """Forward: each rank's columns of the half spectrum equal the analytic coefficients; inverse: the analytic
    coefficients give back each rank's rows of the field. Tolerance 1e-12 of the largest coefficient (FFT
    round-off on grids of ~10^3 points)."""
    if ny // 2 + 1 < ranks:
        pytest.skip("fewer half-spectrum columns than ranks (refused by design)")
    a = field(nx, ny)
    exact = analytic_half_spectrum(nx, ny)
    scale = np.abs(exact).max()

    def work(comm):
        fft = SlabFFT((nx, ny), comm)
        spec = fft.rfft2(a[fft.row])
        back = fft.irfft2(exact[fft.col] / (nx * ny))
        return fft.row, fft.col, spec, back

    rows_seen = []
    for row, col, spec, back in run_ranks(ranks, work):
        np.testing.assert_allclose(spec, exact[col], rtol=0, atol=1e-12 * scale)
        np.testing.assert_allclose(back, a[row], rtol=0, atol=1e-12 * np.abs(a).max())
        rows_seen.append((row.start, row.stop))
    assert rows_seen[0][0] == 0 and rows_seen[-1][1] == nx  # the slabs cover the grid in rank order


def wave(n: int, ny: int, amp: float, lam: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    x = np.arange(n) * (lam / n)
    return np.repeat((amp * np.cos(2 * np.pi * x / lam))[:, None], ny, axis=1), x


@pytest.mark.parametrize("ranks", [2, 3, 5])
@pytest.mark.parametrize("frac", [0.3, 0.6, 1.4])
@pytest.mark.parametrize("method", ["pcg", "pk"])
def test_distributed_hard_wall_is_westergaard(ranks: int, frac: float, method: str) -> None:
    """The hard wall split over ``ranks`` (63 rows: uneven slabs) against Westergaard (frac < 1: contact width
    within 2 pixels, pressure within 0.3/sqrt(contact pixels) rms as in test_contact_analytic) and the
    full-contact closed form ``pbar + p* cos`` (frac >= 1: within 1e-8 p*)."""
    n, amp = 63, 0.01
    pstar = math.pi * amp
    pbar = frac * pstar
    h, x = wave(n, n, amp)

    def work(comm):
        r = solve(h[slab_rows(n, comm)], comm=comm, sigma0=pbar, interaction="hard_wall", method=method,
                  tol=1e-10)
        return r.status, r.contact_area, r.pressure

    out = run_ranks(ranks, work)
    assert all(s == "converged" for s, _, _ in out)
    area = out[0][1]
    assert all(a == area for _, a, _ in out)  # the global scalars agree on every rank
    p = np.concatenate([pr for _, _, pr in out])[:, 0]
    if frac >= 1:
        assert area == 1.0
        np.testing.assert_allclose(p, pbar + pstar * np.cos(2 * np.pi * x), rtol=0, atol=1e-8 * pstar)
        return
    a, p_exact = westergaard(x, pbar, amp)
    assert abs(area - 2 * a) <= 2.0 / n
    assert np.sqrt(np.mean((p - p_exact) ** 2)) / pbar <= 0.3 / math.sqrt(2 * a * n)


def linear_response(eta: float, amp: float, rho: float, gamma0: float, sigma0: float) -> tuple[float, float]:
    """One mode ``h = amp cos(q x)`` under the exponential law, linearised in ``amp/rho`` (docs/model.md M4):
    ``u = amp cos(q x) / (1 + eta)`` with ``eta = rho q E* / (2 sigma0)``, and the mean gap
    ``rho ln(gamma0/(rho sigma0)) + <(h - u)^2>/(2 rho)`` (the second cumulant of ``(h - u)/rho``). Errors:
    O((amp/rho)^2) relative in the amplitude, O((amp/rho)^4) rho in the gap."""
    u_amp = amp / (1 + eta)
    g0 = rho * math.log(gamma0 / (rho * sigma0)) + (amp - u_amp) ** 2 / (4 * rho)
    return u_amp, g0


def mode_amplitude(u: np.ndarray, x: np.ndarray, lam: float) -> float:
    return 2 * float(np.mean(u[:, 0] * np.cos(2 * np.pi * x / lam)))


@pytest.mark.parametrize("ranks", [3, 5])
@pytest.mark.parametrize("eta", [0.1, 1.0, 10.0])
def test_distributed_exponential_linear_response(ranks: int, eta: float) -> None:
    """The exponential law split over odd rank counts (a 45 x 32 rectangle: the smooth minimiser) against the
    one-mode linear response at ``amp/rho = 1e-3``. Tolerances: the displacement amplitude within 1e-5
    relative (the O((amp/rho)^2) = 1e-6 nonlinearity plus the solver tolerance 1e-10), the mean gap within
    1e-9 rho."""
    nx, ny, amp, rho, gamma0, e_star = 45, 32, 5e-5, 5e-2, 1e-3, 1.0  # rho > dx (resolved)
    q = 2 * math.pi
    sigma0 = rho * q * e_star / (2 * eta)
    h, x = wave(nx, ny, amp)
    u_amp, g0 = linear_response(eta, amp, rho, gamma0, sigma0)

    def work(comm):
        r = solve(h[slab_rows(nx, comm)], comm=comm, sigma0=sigma0, gamma0=gamma0, rho=rho, length=(1.0, ny / nx),
                  tol=1e-10)
        return r.status, r.mean_gap, r.displacement

    out = run_ranks(ranks, work)
    assert all(s == "converged" for s, _, _ in out)
    u = np.concatenate([d for _, _, d in out])
    assert mode_amplitude(u, x, 1.0) == pytest.approx(u_amp, rel=1e-5, abs=0)
    assert out[0][1] == pytest.approx(g0, abs=1e-9 * rho)


@pytest.mark.parametrize("n", [128, 192])
@pytest.mark.parametrize("eta", [0.05, 1.0, 20.0])
def test_coarse_start_linear_response(n: int, eta: float) -> None:
    """The exponential law's coarse-to-fine start (levels=1: first a grid of n/2) on one process against the
    one-mode linear response at amp/rho = 1e-3. Tolerances: the displacement amplitude within 1e-5 relative
    (O((amp/rho)^2) nonlinearity plus the solver tolerance 1e-10), the mean gap within 1e-9 rho."""
    amp, rho, e_star, gamma0 = 1e-5, 1e-2, 1.0, 1e-3
    sigma0 = rho * 2 * math.pi * e_star / (2 * eta)
    h, x = wave(n, n, amp)
    u_amp, g0 = linear_response(eta, amp, rho, gamma0, sigma0)
    r = solve(h, sigma0=sigma0, gamma0=gamma0, rho=rho, tol=1e-10, start="coarse", levels=1)
    assert r.converged and [lv["shape"] for lv in r.diagnostics["levels"]] == [[n // 2, n // 2]]
    assert mode_amplitude(r.displacement, x, 1.0) == pytest.approx(u_amp, rel=1e-5, abs=0)
    assert r.mean_gap == pytest.approx(g0, abs=1e-9 * rho)


@pytest.mark.parametrize("ranks", [3, 5])
@pytest.mark.parametrize("eta", [0.1, 10.0])
@pytest.mark.parametrize("law", ["exponential", "adhesive"])
def test_distributed_coarse_start_linear_response(ranks: int, eta: float, law: str) -> None:
    """The coarse-to-fine start on slabs (levels=1: a 40 x 40 grid first, then 80 x 80, over 3 or 5 ranks)
    against the one-mode linear response ``u = amp / (1 + k/s)`` with the law's local stiffness ``s``
    (exponential: ``sigma0/rho``; adhesive: ``-p'(g0)`` at its flat gap, from tests/validation/test_laws_analytic),
    ``k/s = eta``, amp/rho = 1e-3. Tolerance: amplitude 1e-4 relative (the adhesive law's curvature shifts s at
    O(amp/rho)^2; the exponential law's error is smaller), on every rank's rows."""
    from .test_laws_analytic import rsf_pressure

    n, amp, rho, e_star = 80, 5e-5, 5e-2, 1.0
    q = 2 * math.pi
    h, x = wave(n, n, amp)
    if law == "exponential":
        kw = dict(gamma0=1e-3, rho=rho)
        sigma0 = rho * q * e_star / (2 * eta)
    else:
        from scipy.optimize import brentq

        w = 1e-3
        sigma0 = 0.5 * w / (math.e * rho)  # compressive: the coarse start is for compressive loads
        g0 = brentq(lambda g: rsf_pressure(g, w, rho) - sigma0, -20 * rho, rho)
        s = (w / rho**2) * (1 - g0 / rho) * math.exp(-g0 / rho)
        e_star = 2 * eta * s / q
        kw = dict(interaction="adhesive", work=w, rho=rho)

    def work(comm):
        r = solve(h[slab_rows(n, comm)], comm=comm, sigma0=sigma0, e_star=e_star, tol=1e-10, start="coarse",
                  levels=1, **kw)
        return r.status, [lv["shape"] for lv in r.diagnostics["levels"]], r.displacement

    out = run_ranks(ranks, work)
    assert all(st == "converged" for st, _, _ in out)
    assert out[0][1] == [[n // 2, n // 2]]
    u = np.concatenate([d for _, _, d in out])
    assert mode_amplitude(u, x, 1.0) == pytest.approx(amp / (1 + eta), rel=1e-4, abs=0)
