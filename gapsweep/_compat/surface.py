"""The 0.1 name ``gapsweep.surface`` (stable) of
:mod:`gapsweep.surfaces.synthetic` (docs/architecture.md, "The 0.1 names")."""

from gapsweep._compat import install

install(__name__, __spec__)
