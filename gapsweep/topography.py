"""Stable 0.1 name (docs/architecture.md, "The 0.1 names"): importing it gives the module
:mod:`gapsweep.surfaces.topography` itself."""

from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from gapsweep.surfaces.topography import *  # noqa: F403
else:
    from gapsweep._alias import install

    install(__name__, "gapsweep.surfaces.topography", deprecated=False, spec_name=__spec__.name if __spec__ else None)
