"""Hard wall with exponential adhesion, the law of the contact-mechanics challenge (Muser et al., Tribol. Lett.
65, 118, 2017; docs/model.md "Hard wall with exponential adhesion", docs/gfmd.md "Hard wall with adhesion"):

    g >= 0 (non-overlap),     V(g) = -w exp(-g/rho)  for g >= 0,

``w``: work of adhesion (energy per area; the challenge's ``gamma0``), ``rho``: range (length). The pressure on
the body is ``p = lambda - V'(g) = lambda - (w/rho) exp(-g/rho)``, with the contact multiplier ``lambda >= 0``
(non-zero only where ``g = 0``): attractive everywhere off contact, the largest tension ``w/rho`` at ``g = 0``.
``V`` is concave (``V'' = -(w/rho^2) exp(-g/rho)``): the energy is not convex, equilibria depend on the load path.
Loads may be tensile. Solved by the bound-constrained minimiser ``gapsweep.gfmd._bounded`` (``load_control =
"bounded"``); the contact area counts the pixels with ``g = 0`` exactly (the minimiser projects onto the bound).
Units: ``w`` pressure x length, ``rho`` length, pressures in the units of ``sigma0`` and ``E*``."""

from __future__ import annotations

from typing import Any, ClassVar

import numpy as np

from gapsweep.gfmd.interactions.base import AdhesionParams, Interaction

__all__ = ["HardWallAdhesive"]


class HardWallAdhesive(AdhesionParams, Interaction):
    """Non-overlap plus ``V(g) = -w exp(-g/rho)`` (module docstring)."""

    name: ClassVar[str] = "hard_wall_adhesive"
    load_control: ClassVar[str] = "bounded"
    contact_criterion: ClassVar[str] = "g = 0 (the non-overlap bound is active)"
    allows_tensile: ClassVar[bool] = True
    convex: ClassVar[bool] = False  # V'' < 0 everywhere: branches end (pull-off, snap-in)

    @property
    def max_tension(self) -> float:
        """Largest adhesive tension ``w / rho`` (at ``g = 0``)."""
        return self.work / self.rho

    def energy(self, g: Any, xp: Any = np) -> Any:
        """``V(g) = -w exp(-g/rho)`` (energy per area; ``g >= 0``)."""
        return -self.work * xp.exp(-g / self.rho)

    def force(self, g: Any, xp: Any = np) -> Any:
        """``V'(g) = (w/rho) exp(-g/rho)``: the adhesive tension (``p = -V'`` off contact)."""
        return (self.work / self.rho) * xp.exp(-g / self.rho)

    def stiffness(self, g: Any, xp: Any = np) -> Any:
        """``V''(g) = -(w/rho^2) exp(-g/rho)`` (negative: concave)."""
        return -(self.work / self.rho**2) * xp.exp(-g / self.rho)

    def curvature(self, sigma0: float) -> float:
        # |V''(0)| = w/rho^2, the largest local (de)stiffening; the preconditioner uses the elastic part only.
        return self.work / self.rho**2


    def mu_rho(self, dx: float, e_star: float) -> float:
        """Resolution measure of Wang, Zhou & Muser (Lubricants 9, 17, 2021): ``sqrt(max|V''| dx / E*)``;
        below about 0.5 the pixel ``dx`` resolves the law's range."""
        return float(np.sqrt(self.work / self.rho**2 * dx / e_star))

    def contact(self, gap: Any, pressure: Any) -> Any:
        return gap <= 0
