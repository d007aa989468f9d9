"""The 0.1 name ``gapsweep.topography`` (stable) of
:mod:`gapsweep.surfaces.topography` (docs/architecture.md, "The 0.1 names")."""

from gapsweep._compat import install

install(__name__, __spec__)
