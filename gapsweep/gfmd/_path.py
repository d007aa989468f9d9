"""Solutions along a load path, each warm-started from the previous one (docs/gfmd.md, "Load paths").

On a non-convex law (adhesion) the equilibrium at a load depends on the history: several local minima exist and
a branch can end (pull-off, jump into contact). :func:`solve_path` follows the branch it starts on by warm
starts and flags the steps where the solution jumps instead of hiding them."""

from __future__ import annotations

import logging
import math
import warnings
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from gapsweep.gfmd._common import UnderResolvedWarning
from gapsweep.gfmd._result import GFMDResult

log = logging.getLogger("gapsweep.gfmd")


@dataclass
class LoadPath:
    """Results along ``loads`` (same order). ``jumps``: indices ``i`` where the step from ``i - 1`` to ``i`` is
    a jump (contact area or mean gap changed by more than the thresholds). ``stopped``: why the path ended early
    ("detached", a non-finite state), or "" when every load was solved."""

    loads: np.ndarray
    results: list[GFMDResult]
    jumps: list[int] = field(default_factory=list)
    stopped: str = ""

    def table(self) -> dict[str, np.ndarray]:
        """Columns ``sigma0, mean_gap, contact_area, elastic_energy, converged`` of the solved steps."""
        rs = self.results
        return {
            "sigma0": np.array([r.sigma0 for r in rs]),
            "mean_gap": np.array([r.mean_gap for r in rs]),
            "contact_area": np.array([r.contact_area for r in rs]),
            "elastic_energy": np.array([r.elastic_energy for r in rs]),
            "converged": np.array([r.converged for r in rs]),
        }


def solve_path(heights: Any, loads: Any, *, jump_area: float = 0.1, jump_factor: float = 3.0,
               **kwargs: Any) -> LoadPath:
    """Solve at each mean pressure in ``loads`` in the given order, each warm-started from the previous
    solution (``initial=``); other keywords go to :func:`gapsweep.gfmd.solve` (``interaction`` included).

    For a law whose energy is not convex (adhesion), a step is a jump when the contact area changes by
    more than ``jump_area`` (fraction of the nominal area) or
    the mean gap moves by more than ``jump_factor`` times what the previous step's secant compliance
    ``dg0/dsigma0`` predicts (a branch that ends: pull-off, snap into contact): logged as a warning and listed in
    ``LoadPath.jumps``. Steps must be fine enough for the secant to hold on a smooth branch. The path stops at
    the first "detached" or "non_finite" step (beyond pull-off no equilibrium exists at more tensile loads either)."""
    from gapsweep.gfmd._solve import solve
    from gapsweep.gfmd.interactions import resolve

    if "initial" in kwargs:
        raise ValueError("solve_path warm-starts each step itself: do not pass initial")
    arr = np.asarray(loads, dtype=float)
    if arr.ndim != 1 or arr.size == 0 or not np.all(np.isfinite(arr)):
        raise ValueError("loads must be a non-empty 1-D sequence of finite mean pressures")
    law_kw = {k: kwargs.pop(k) for k in ("gamma0", "rho", "work") if k in kwargs}
    law = resolve(kwargs.pop("interaction", "exponential"), **law_kw)
    path = LoadPath(loads=arr, results=[])
    prev: GFMDResult | None = None
    for i, s0 in enumerate(arr):
        with warnings.catch_warnings():
            if i > 0:  # UnderResolvedWarning once per path (the first load's), not once per load
                warnings.simplefilter("ignore", UnderResolvedWarning)
            r = solve(heights, sigma0=float(s0), interaction=law, initial=prev, **kwargs)
        path.results.append(r)
        if prev is not None and not law.convex:  # a convex energy has one equilibrium per load: no jumps
            da, dg = abs(r.contact_area - prev.contact_area), abs(r.mean_gap - prev.mean_gap)
            predicted = math.inf
            if i >= 2:
                before = path.results[-3]
                ds_prev = prev.sigma0 - before.sigma0
                if ds_prev != 0:
                    predicted = abs((prev.mean_gap - before.mean_gap) / ds_prev * (s0 - prev.sigma0))
            if da > jump_area or dg > jump_factor * predicted:
                path.jumps.append(i)
                log.warning("load path: jump between sigma0=%g and %g (contact area %.4g -> %.4g, mean gap "
                            "%.4g -> %.4g)", prev.sigma0, r.sigma0, prev.contact_area, r.contact_area,
                            prev.mean_gap, r.mean_gap)
        if r.status in ("detached", "non_finite"):
            path.stopped = r.status
            log.warning("load path: %s at sigma0=%g; %d later loads not solved", r.status, s0, arr.size - i - 1)
            break
        prev = r
    return path
