"""Adhesion by the exponential cohesive law (docs/gfmd.md, "Adhesive"): the universal binding-energy relation
of Rose, Smith & Ferrante (Phys. Rev. B 28, 1835, 1983), the normal part of Xu & Needleman's cohesive law
(Modelling Simul. Mater. Sci. Eng. 1, 111, 1993):

    phi(g) = -w (1 + g/rho) exp(-g/rho),     p(g) = -phi'(g) = -(w g / rho^2) exp(-g/rho),

``w``: work of adhesion (energy per area, the depth of ``phi`` at its minimum ``g = 0``); ``rho``: range
(length). Repulsive (``p > 0``) for ``g < 0``, attractive beyond, the largest tensile stress ``w/(e rho)`` at
``g = rho``. Smooth for every ``g``, non-convex (``phi'' < 0`` for ``g > rho``). Loads may be tensile."""

from __future__ import annotations

import math
from typing import Any, ClassVar

import numpy as np

from gapsweep.gfmd.interactions.base import AdhesionParams, SmoothInteraction

__all__ = ["Adhesive"]


class Adhesive(AdhesionParams, SmoothInteraction):
    """Exponential cohesive law (module docstring), on the generic smooth minimiser."""

    name: ClassVar[str] = "adhesive"
    contact_criterion: ClassVar[str] = "gap < rho (closer than the distance of the largest tensile stress)"
    allows_tensile: ClassVar[bool] = True
    convex: ClassVar[bool] = False  # phi'' < 0 beyond g = rho: branches end (pull-off, snap-in)

    @property
    def max_tension(self) -> float:
        """Largest tensile stress ``w / (e rho)`` (at ``g = rho``)."""
        return self.work / (math.e * self.rho)

    def energy(self, g: Any, xp: Any = np) -> Any:
        s = g / self.rho
        return -self.work * (1.0 + s) * xp.exp(-s)

    def pressure(self, g: Any, xp: Any = np) -> Any:
        s = g / self.rho
        return -(self.work / self.rho) * s * xp.exp(-s)

    def stiffness(self, g: Any, xp: Any = np) -> Any:
        s = g / self.rho
        return (self.work / self.rho**2) * (1.0 - s) * xp.exp(-s)

    def curvature(self, sigma0: float) -> float:
        # phi''(0) = w/rho^2: the stiffness of the bonded contact, the largest the law has at moderate load.
        return self.work / self.rho**2


    def contact(self, gap: Any, pressure: Any) -> Any:
        return gap < self.rho
