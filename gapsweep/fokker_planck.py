"""Stable 0.1 name (docs/architecture.md, "The 0.1 names"): importing it gives the module
:mod:`gapsweep.gapdist.fokker_planck` itself."""

from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from gapsweep.gapdist.fokker_planck import *  # noqa: F403
else:
    from gapsweep._alias import install

    install(__name__, "gapsweep.gapdist.fokker_planck", deprecated=False, spec_name=__spec__.name if __spec__ else None)
