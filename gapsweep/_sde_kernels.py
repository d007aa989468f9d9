"""Deprecated 0.1 name (docs/architecture.md, "The 0.1 names"): importing it warns; it goes in gapsweep
0.4. Import :mod:`gapsweep.gapdist._sde_kernels` instead."""

from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from gapsweep.gapdist._sde_kernels import *  # noqa: F403
else:
    from gapsweep._alias import install

    install(__name__, "gapsweep.gapdist._sde_kernels", deprecated=True, spec_name=__spec__.name if __spec__ else None)
