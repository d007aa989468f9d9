"""The 0.1 name ``gapsweep.storecheck`` (deprecated: it warns and goes in gapsweep 0.4) of
:mod:`gapsweep.sweep.storecheck` (docs/architecture.md, "The 0.1 names")."""

from gapsweep._compat import install

install(__name__, __spec__)
