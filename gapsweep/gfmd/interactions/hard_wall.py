"""Hard wall (non-overlap): ``g >= 0``, ``p >= 0``, ``p g = 0`` (docs/gfmd.md, "Hard wall").

No energy density and no length scale: the pressure is the Lagrange multiplier of the constraint, found by the
constrained minimiser (``load_control = "multiplier"``, gapsweep.gfmd._constrained)."""

from __future__ import annotations

from typing import Any, ClassVar

from gapsweep.gfmd.interactions.base import Interaction

__all__ = ["HardWall"]


class HardWall(Interaction):
    """Non-overlapping contact with a rigid wall at fixed mean pressure ``sigma0 > 0``."""

    name: ClassVar[str] = "hard_wall"
    load_control: ClassVar[str] = "multiplier"
    contact_criterion: ClassVar[str] = "p > 0 (equivalently g = 0)"

    def params(self) -> dict[str, float]:
        return {}

    def curvature(self, sigma0: float) -> float:
        return 0.0  # no local stiffness: the elastic operator alone preconditions

    def contact(self, gap: Any, pressure: Any) -> Any:
        return pressure > 0
