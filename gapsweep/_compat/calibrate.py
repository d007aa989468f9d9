"""The 0.1 name ``gapsweep.calibrate`` (stable) of
:mod:`gapsweep.gapdist.calibrate` (docs/architecture.md, "The 0.1 names")."""

from gapsweep._compat import install

install(__name__, __spec__)
