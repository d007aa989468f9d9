"""The 0.1 name ``gapsweep.dataset`` (stable) of
:mod:`gapsweep.sweep.dataset` (docs/architecture.md, "The 0.1 names")."""

from gapsweep._compat import install

install(__name__, __spec__)
