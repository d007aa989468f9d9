"""Deprecated 0.1 name (docs/architecture.md, "The 0.1 names"): importing it warns; it goes in gapsweep
0.4. Import :mod:`gapsweep.sweep.tasks` instead."""

from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from gapsweep.sweep.tasks import *  # noqa: F403
else:
    from gapsweep._alias import install

    install(__name__, "gapsweep.sweep.tasks", deprecated=True, spec_name=__spec__.name if __spec__ else None)
