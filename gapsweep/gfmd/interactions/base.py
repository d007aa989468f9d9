"""The interaction-law interface of the GFMD solver (docs/gfmd.md, "Interaction laws").

A law couples the rigid surface ``h`` and the elastic body through the local gap ``g = g0 + u - h`` (lengths in
units of ``length``; ``g0`` the mean gap, ``u`` the displacement with ``<u> = 0``). The minimiser needs four things
from it, and only these:

1. the energy density per area ``phi(g)`` and the pressure ``p(g) = -phi'(g)`` (smooth laws), or the constraint
   ``g >= 0`` whose multiplier is the pressure (the hard wall);
2. ``curvature(sigma0)``: a scalar estimate ``c`` of ``phi''`` for the Fourier-diagonal preconditioner
   ``M(q) = E* q/2 + c``;
3. ``load_control``: how the mean gap is fixed by the mean pressure ``sigma0``:

   - ``"softmax"``: eliminated in closed form (``<p> = sigma0`` by construction; the exponential law);
   - ``"multiplier"``: ``g0`` is the Lagrange multiplier of ``<p> = sigma0`` (constrained minimisation);
   - ``"variable"``: ``g0`` is one more unknown with gradient ``sigma0 - <p>`` (any smooth law, also
     non-convex ones and tensile loads);

   ``gapsweep.gfmd.solve`` picks the minimiser from this name (a table, no branch per law);
4. ``contact(gap, pressure)``: the documented criterion that defines the contact area.

A new law is a new file with a subclass of :class:`SmoothInteraction` (smooth laws run on the generic
``"variable"`` minimiser) or of :class:`Interaction`.
"""

from __future__ import annotations

import abc
import math
from typing import Any, ClassVar

import numpy as np

from gapsweep.core import checks as chk

__all__ = ["AdhesionParams", "Interaction", "SmoothInteraction"]


class Interaction(abc.ABC):
    """One interaction law (see the module docstring for what the minimiser asks of it)."""

    #: the law's name, as accepted by ``gapsweep.gfmd.solve(interaction=...)``
    name: ClassVar[str]
    #: how the mean gap follows from the load: "softmax", "multiplier" or "variable"
    load_control: ClassVar[str]
    #: the contact criterion in words (docs and result records)
    contact_criterion: ClassVar[str]
    #: whether the load may be zero or tensile (sigma0 <= 0)
    allows_tensile: ClassVar[bool] = False
    #: whether the energy is convex in the gap (then the equilibrium is unique and a load path has no jumps)
    convex: ClassVar[bool] = True

    @abc.abstractmethod
    def params(self) -> dict[str, float]:
        """The law's parameters by name (stored with every result)."""

    def range(self) -> float | None:
        """Interaction range (a length) to compare with the grid spacing, or None (no length scale)."""
        return None

    def check_load(self, sigma0: Any) -> float:
        """Validated mean pressure: ``> 0`` unless the law allows tensile loads (then any finite value)."""
        if not self.allows_tensile:
            return chk.positive(sigma0, "sigma0")
        s = chk.real(sigma0, "sigma0")
        if not math.isfinite(s):
            raise ValueError(f"sigma0 must be finite for interaction {self.name!r} (tensile loads allowed), got {s}")
        return s

    def pressure_scale(self, sigma0: float) -> float:
        """Pressure that the force residual and load error are measured in: ``|sigma0|`` by default; laws that
        allow zero or tensile loads add their own scale (e.g. the maximum tensile stress)."""
        return abs(sigma0)

    @abc.abstractmethod
    def curvature(self, sigma0: float) -> float:
        """Scalar estimate ``c >= 0`` of ``phi''`` for the preconditioner ``M(q) = E* q/2 + c`` (pressure/length)."""

    @abc.abstractmethod
    def contact(self, gap: Any, pressure: Any) -> Any:
        """Boolean contact mask (same array namespace as ``gap``) by :attr:`contact_criterion`."""

    def __repr__(self) -> str:
        args = ", ".join(f"{k}={v!r}" for k, v in self.params().items())
        return f"{type(self).__name__}({args})"


class SmoothInteraction(Interaction):
    """A law with a smooth energy density ``phi(g)`` per area: pressure ``p = -phi'``, stiffness ``phi''``.
    Methods take arrays of any namespace (numpy or cupy): ``xp`` is that namespace."""

    load_control: ClassVar[str] = "variable"

    @abc.abstractmethod
    def energy(self, g: Any, xp: Any = np) -> Any:
        """``phi(g)``: energy per area (pressure x length)."""

    @abc.abstractmethod
    def pressure(self, g: Any, xp: Any = np) -> Any:
        """``p(g) = -phi'(g)``: positive repulsive, negative attractive (pressure units)."""

    @abc.abstractmethod
    def stiffness(self, g: Any, xp: Any = np) -> Any:
        """``phi''(g) = -p'(g)`` (pressure per length); may be negative (non-convex laws)."""


class AdhesionParams:
    """The parameters an adhesive law shares, mixed in before its :class:`Interaction` base: the work of adhesion
    ``w`` (``work``, energy per area) and the range ``rho`` (a length), both > 0. The subclass gives
    ``max_tension`` (its largest tensile stress, pressure units); residuals are measured in
    ``max(|sigma0|, max_tension)`` (tensile and zero loads allowed; docs/model.md "Adhesive", "Hard wall with
    exponential adhesion"). The energy, pressure, curvature and contact criterion are the law's own."""

    work: float
    rho: float
    max_tension: float

    def __init__(self, work: float, rho: float) -> None:
        self.work = chk.positive(work, "work")
        self.rho = chk.positive(rho, "rho")

    def params(self) -> dict[str, float]:
        return {"work": self.work, "rho": self.rho}

    def range(self) -> float:
        return self.rho

    def pressure_scale(self, sigma0: float) -> float:
        return max(abs(sigma0), self.max_tension)
