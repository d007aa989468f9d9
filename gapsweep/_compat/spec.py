"""The 0.1 name ``gapsweep.spec`` (stable) of
:mod:`gapsweep.sweep.spec` (docs/architecture.md, "The 0.1 names")."""

from gapsweep._compat import install

install(__name__, __spec__)
