"""Adhesive contact at tensile loads against an independent solver (marker ``peers``; skipped where
ContactMechanics or Adhesion is not installed; issue 22, docs/gfmd.md "Tensile loads").

The peer: ContactMechanics' periodic elastic half-space (``stiffness_q0 = 0``: the mean displacement is free) and
Adhesion's ``SmoothContactSystem`` evaluate the energy and forces of the exponential cohesive law, written here as
an Adhesion ``Potential`` (not gapsweep's class); the load term ``sigma0 L^2 <z>`` is added, and scipy's L-BFGS-B
minimises over the body's surface ``z``. The peer follows the load by its own fixed steps from its own zero-load
equilibrium (the flat body touching the highest summit, as gapsweep), and finds its pull-off load by bisection
from its last attached state. gapsweep is called directly at each tensile load (its own continuation inside
``solve``). Run as in tests/test_peers_contact.py:

    PYTHONPATH=. peers/bin/python -m pytest -m peers tests/test_peers_adhesion.py
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from gapsweep.gfmd import solve
from gapsweep.surface import self_affine

pytestmark = [pytest.mark.peers, pytest.mark.validation]

WORK = 1e-3
DETACHED = 30.0  # every gap beyond this many ranges: the body has left


def peer_system(h: np.ndarray, work: float, rho: float):
    pytest.importorskip("ContactMechanics")
    potential_mod = pytest.importorskip("Adhesion.Interactions.Potential")
    from Adhesion.System.Systems import SmoothContactSystem
    from ContactMechanics import PeriodicFFTElasticHalfSpace
    from SurfaceTopography import Topography

    class Cohesive(potential_mod.Potential):
        """phi(g) = -w (1 + g/rho) exp(-g/rho) per area (Rose, Smith & Ferrante 1983)."""

        name = "cohesive"

        def __init__(self, w: float, r: float) -> None:
            self.w, self.rho = w, r
            potential_mod.Potential.__init__(self)

        def __repr__(self) -> str:
            return f"Cohesive(w={self.w}, rho={self.rho})"

        @property
        def r_min(self):
            return None

        @property
        def r_infl(self):
            return None

        def evaluate(self, gap, potential=True, gradient=False, curvature=False, mask=None):
            s = np.asarray(gap) / self.rho
            e = np.exp(-s)
            return (-self.w * (1 + s) * e, (self.w / self.rho) * s * e, (self.w / self.rho**2) * (1 - s) * e)

    n = h.shape[0]
    sub = PeriodicFFTElasticHalfSpace((n, n), 1.0, physical_sizes=(1.0, 1.0), stiffness_q0=0.0)
    return SmoothContactSystem(sub, Cohesive(work, rho), Topography(h, (1.0, 1.0)))


class Peer:
    """scipy L-BFGS-B at fixed mean pressure on the Adhesion system (module docstring)."""

    def __init__(self, h: np.ndarray, work: float, rho: float) -> None:
        self.h, self.work, self.rho, self.n = h, work, rho, h.shape[0]
        self.system = peer_system(h, work, rho)

    def solve(self, sigma0: float, z0: np.ndarray) -> tuple[np.ndarray, bool]:
        """Equilibrium surface ``z`` from ``z0`` and whether it is attached (not every gap beyond 30 rho)."""
        import scipy.optimize

        n, da = self.n, 1.0 / self.n**2

        def fun(x):
            z = x.reshape(n, n)
            e, f = self.system.evaluate(z, 0.0, pot=True, forces=True)
            return e + sigma0 * float(np.mean(z)), (-f + sigma0 * da).ravel()

        def leave(x):  # stop a run-away body (beyond pull-off the energy is unbounded below)
            if float(np.min(x.reshape(n, n) - self.h)) > DETACHED * self.rho:
                raise StopIteration

        sol = scipy.optimize.minimize(fun, z0.ravel(), jac=True, method="L-BFGS-B", callback=leave,
                                      options={"maxiter": 100000, "maxfun": 200000, "ftol": 0.0, "gtol": 1e-16,
                                               "maxcor": 20})
        z = sol.x.reshape(n, n)
        return z, float(np.min(z - self.h)) <= DETACHED * self.rho

    def at_separation(self, delta: float, z0: np.ndarray) -> np.ndarray:
        """Equilibrium at the fixed mean surface ``<z> = delta`` (displacement control) from ``z0``: the energy
        of ``z - <z> + delta`` (no load term), whose gradient has zero mean."""
        import scipy.optimize

        n = self.n

        def fun(x):
            z = x.reshape(n, n)
            e, f = self.system.evaluate(z - z.mean() + delta, 0.0, pot=True, forces=True)
            g = -f
            return e, (g - g.mean()).ravel()

        sol = scipy.optimize.minimize(fun, (z0 - z0.mean() + delta).ravel(), jac=True, method="L-BFGS-B",
                                      options={"maxiter": 100000, "maxfun": 200000, "ftol": 0.0, "gtol": 1e-16,
                                               "maxcor": 20})
        z = sol.x.reshape(n, n)
        return z - z.mean() + delta

    def pull_off(self, z0: np.ndarray, step: float) -> float:
        """Load-controlled pull-off = the most tensile mean pressure along the displacement-controlled
        retraction from ``z0`` (the load-controlled branch ends where ``d<p>/d delta = 0``): steps of ``step``
        in ``delta`` until the pressure rises again, then a parabola through the three points around the
        minimum, refined with steps of ``step/8``."""
        delta, z = float(z0.mean()), z0
        ps = []
        for refine in (1.0, 0.125):
            ds = step * refine
            pts: list[tuple[float, float, np.ndarray]] = []
            while True:
                z = self.at_separation(delta, z)
                pts.append((delta, self.quantities(z)["mean_pressure"], z))
                if len(pts) >= 3 and pts[-1][1] > pts[-2][1]:
                    break
                delta += ds
            (d0, p0, z0_), (_, p1, _), (_, p2, _) = pts[-3:]
            ps = [p0, p1, p2]
            delta, z = d0 - ds, z0_  # restart the finer pass just before the minimum
        denom = ps[0] - 2 * ps[1] + ps[2]
        return ps[1] - (ps[2] - ps[0]) ** 2 / (8 * denom) if denom > 0 else ps[1]

    def quantities(self, z: np.ndarray) -> dict[str, float]:
        gap = z - self.h
        s = gap / self.rho
        p = -(self.work / self.rho) * s * np.exp(-s)
        return {"mean_gap": float(gap.mean()), "contact_area": float(np.mean(gap < self.rho)),
                "mean_pressure": float(p.mean()),
                "elastic_energy": 0.5 * float(np.mean((z - z.mean()) * (p - p.mean())))}

    def unload(self, loads: list[float]) -> tuple[dict[float, dict[str, float]], float, float]:
        """Quantities at each load (decreasing, from 0) along the peer's path until it detaches, the first load
        where it detached, and the pull-off load by displacement control from the last attached state."""
        z = np.full(self.h.shape, float(self.h.max()))
        out: dict[float, dict[str, float]] = {}
        for s in loads:
            z_new, attached = self.solve(s, z)
            if not attached:
                return out, s, self.pull_off(z, step=0.02 * self.rho)
            out[s], z = self.quantities(z_new), z_new
        return out, math.nan, math.nan


# Measured with (128, 0.8, 4) added: all three pass, 743 s on the 2-core VM (the peer's path is the cost);
# the test keeps the two N = 64 cases.
CASES = [(64, 0.8, 1), (64, 0.3, 2)]


@pytest.mark.slow
@pytest.mark.parametrize(("n", "hurst", "seed"), CASES)
def test_tensile_loads_and_pull_off_agree_with_peer(n: int, hurst: float, seed: int) -> None:
    """Direct solves at tensile loads up to pull-off land on the peer's equilibria (mean gap and elastic energy
    to 1e-5 relative, contact area to 2 pixels), and the pull-off load that gapsweep brackets (the most tensile
    load it found attached, and one ``min_step`` beyond) holds the peer's pull-off."""
    rho = 1.0 / n  # one pixel
    h = self_affine(n, hurst, lambda_l=0.25, lambda_s=4 / n, seed=seed)
    h = h - h.mean()
    peer = Peer(h, WORK, rho)
    max_t = WORK / (math.e * rho)
    loads = [-k * max_t / 100 for k in range(0, 101)]
    theirs, first_off, pull_off = peer.unload(loads)
    assert math.isfinite(first_off), "the peer never detached"
    checked = [s for s in theirs if s < 0][:: max(1, len(theirs) // 6)]
    for s in checked:
        r = solve(h, sigma0=s, interaction="adhesive", work=WORK, rho=rho, tol=1e-9, backend="numpy")
        assert r.converged, (s, r.status)
        ref = theirs[s]
        assert abs(ref["mean_pressure"] - s) <= 1e-6 * max_t  # the peer is at its load
        np.testing.assert_allclose([r.mean_gap, r.elastic_energy], [ref["mean_gap"], ref["elastic_energy"]],
                                   rtol=1e-5, err_msg=f"sigma0={s}")
        assert abs(r.contact_area - ref["contact_area"]) <= 2 / n**2, s
    beyond = solve(h, sigma0=first_off, interaction="adhesive", work=WORK, rho=rho, tol=1e-9, backend="numpy")
    assert beyond.status == "detached" and not beyond.converged
    # ours: the pull-off lies in (last - min_step, last]; the peer's parabola is good to ~1e-4 max_t
    last, step = beyond.diagnostics["last_attached_load"], beyond.diagnostics["min_step"]
    assert last - step - 1e-4 * max_t <= pull_off <= last + 1e-4 * max_t, (last, step, pull_off)
