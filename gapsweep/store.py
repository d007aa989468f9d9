"""Stable 0.1 name (docs/architecture.md, "The 0.1 names"): importing it gives the module
:mod:`gapsweep.sweep.api` itself."""

from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from gapsweep.sweep.api import *  # noqa: F403
else:
    from gapsweep._alias import install

    install(__name__, "gapsweep.sweep.api", deprecated=False, spec_name=__spec__.name if __spec__ else None)
