"""The 0.1 name ``gapsweep.fokker_planck`` (stable) of
:mod:`gapsweep.gapdist.fokker_planck` (docs/architecture.md, "The 0.1 names")."""

from gapsweep._compat import install

install(__name__, __spec__)
