"""Interaction laws of the GFMD solver: one file per law, one interface (:mod:`.base`, docs/gfmd.md).

``resolve(interaction, **params)`` turns the ``interaction=`` argument of ``gapsweep.gfmd.solve`` (a name or an
:class:`Interaction` object) into a law object; :data:`INTERACTIONS` maps names to classes and the keyword
parameters each takes."""

from __future__ import annotations

from typing import Any

from gapsweep.gfmd.interactions.adhesive import Adhesive
from gapsweep.gfmd.interactions.base import Interaction, SmoothInteraction
from gapsweep.gfmd.interactions.exponential import Exponential
from gapsweep.gfmd.interactions.hard_wall import HardWall
from gapsweep.gfmd.interactions.hard_wall_adhesive import HardWallAdhesive

__all__ = ["INTERACTIONS", "Adhesive", "Exponential", "HardWall", "HardWallAdhesive", "Interaction",
           "SmoothInteraction",
           "resolve"]

#: name -> (class, names of the keyword parameters solve() passes to it)
INTERACTIONS: dict[str, tuple[type[Interaction], tuple[str, ...]]] = {
    "exponential": (Exponential, ("gamma0", "rho")),
    "hard_wall": (HardWall, ()),
    "adhesive": (Adhesive, ("work", "rho")),
    "hard_wall_adhesive": (HardWallAdhesive, ("work", "rho")),
}


def resolve(interaction: Any, **params: Any) -> Interaction:
    """The law for ``interaction`` (a name in :data:`INTERACTIONS` or an :class:`Interaction`). ``params`` are
    solve()'s law keywords (None where not given): a name takes the ones it needs (each required) and
    rejects the others; an object takes none."""
    given = {k: v for k, v in params.items() if v is not None}
    if isinstance(interaction, Interaction):
        if given:
            raise ValueError(f"interaction is an object ({interaction!r}): pass {', '.join(sorted(given))} to it, "
                             "not to solve()")
        return interaction
    if not isinstance(interaction, str) or interaction not in INTERACTIONS:
        names = ", ".join(map(repr, INTERACTIONS))
        raise ValueError(f"interaction must be one of {names} or an Interaction object; got {interaction!r}")
    cls, keys = INTERACTIONS[interaction]
    extra = sorted(set(given) - set(keys))
    if extra:
        raise ValueError(f"interaction {interaction!r} takes {', '.join(keys) or 'no parameters'}; "
                         f"got also {', '.join(extra)}")
    missing = [k for k in keys if k not in given]
    if missing:
        raise ValueError(f"interaction {interaction!r} needs {', '.join(missing)}")
    return cls(**{k: given[k] for k in keys})
