"""Stable 0.1 name (docs/architecture.md, "The 0.1 names"): importing it gives the module
:mod:`gapsweep.gapdist.sde` itself."""

from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from gapsweep.gapdist.sde import *  # noqa: F403
else:
    from gapsweep._alias import install

    install(__name__, "gapsweep.gapdist.sde", deprecated=False, spec_name=__spec__.name if __spec__ else None)
