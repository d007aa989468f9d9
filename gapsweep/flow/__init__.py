"""Leakage through the gap (docs/model.md, "M8 Leakage through the gap"): steady laminar flow of an
incompressible fluid through a gap field by the Reynolds equation (:func:`solve`), the open clusters that join
inlet and outlet (:func:`open_clusters`), and the effective-medium and critical-junction estimates of the
conductance from a gap distribution (:mod:`gapsweep.flow.theory`).

A physics package: it imports numpy, scipy and gapsweep.core only (pyamg and cupy optionally), never the sweep.

    from gapsweep import flow, gfmd
    res = gfmd.solve(heights, sigma0=1e-2, interaction="hard_wall")
    r = flow.solve(res.gap, length=1.0, axis=1, viscosity=1e-3, pressure_drop=1e5)
    r.leak_rate, r.conductance, r.percolating
"""

from gapsweep.flow._solve import FlowResult, open_clusters, solve
from gapsweep.flow.theory import bruggeman, critical_gap, critical_junction, gap_density

__all__ = ["FlowResult", "bruggeman", "critical_gap", "critical_junction", "gap_density", "open_clusters",
           "solve"]
