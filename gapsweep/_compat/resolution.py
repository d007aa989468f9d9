"""The 0.1 name ``gapsweep.resolution`` (stable) of
:mod:`gapsweep.gfmd.resolution` (docs/architecture.md, "The 0.1 names")."""

from gapsweep._compat import install

install(__name__, __spec__)
