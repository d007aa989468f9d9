"""Exponential repulsion (docs/model.md M3): ``phi(g) = gamma0 exp(-g/rho)``, ``p(g) = (gamma0/rho) exp(-g/rho)``.

``gamma0``: energy per area; ``rho``: range (length); ``gamma0/rho``: pressure. The mean gap is eliminated in
closed form (log-sum-exp, ``load_control = "softmax"``), so ``<p> = sigma0`` holds by construction."""

from __future__ import annotations

import math
from typing import Any, ClassVar

import numpy as np

from gapsweep.core import checks as chk
from gapsweep.gfmd.interactions.base import SmoothInteraction

__all__ = ["Exponential"]


class Exponential(SmoothInteraction):
    """Exponential repulsion of M3; the default law of ``gapsweep.gfmd.solve``."""

    name: ClassVar[str] = "exponential"
    load_control: ClassVar[str] = "softmax"
    contact_criterion: ClassVar[str] = "gap < rho (within one interaction range of the wall)"

    def __init__(self, gamma0: float, rho: float) -> None:
        self.gamma0 = chk.positive(gamma0, "gamma0")
        self.rho = chk.positive(rho, "rho")

    def params(self) -> dict[str, float]:
        return {"gamma0": self.gamma0, "rho": self.rho}

    def range(self) -> float:
        return self.rho

    def energy(self, g: Any, xp: Any = np) -> Any:
        return self.gamma0 * xp.exp(-g / self.rho)

    def pressure(self, g: Any, xp: Any = np) -> Any:
        return (self.gamma0 / self.rho) * xp.exp(-g / self.rho)

    def stiffness(self, g: Any, xp: Any = np) -> Any:
        return (self.gamma0 / self.rho**2) * xp.exp(-g / self.rho)

    def curvature(self, sigma0: float) -> float:
        # <phi''> = <p>/rho = sigma0/rho exactly at every point of the softmax minimiser.
        return sigma0 / self.rho

    def mean_gap(self, lse: float, sigma0: float) -> float:
        """``g0 = rho [ln(gamma0/(rho sigma0)) + lse]`` with ``lse = ln <exp((h - u)/rho)>`` (M3)."""
        return self.rho * (math.log(self.gamma0 / (self.rho * sigma0)) + lse)

    def contact(self, gap: Any, pressure: Any) -> Any:
        return gap < self.rho
