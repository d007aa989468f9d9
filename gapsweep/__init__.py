"""gapsweep: mean gap and gap distribution of an elastic body on a randomly rough surface.

Layout (data path top to bottom, see docs/model.md for the model M1..M7):
``surface`` (M2) -> ``theory`` (M4, M5 coefficients) -> ``gfmd`` (M3) / ``sde`` + ``fokker_planck`` (M5)
-> ``spec`` -> ``tasks`` -> ``runner`` -> ``store`` -> ``analysis`` (top-level package).
"""

__version__ = "0.1.0"
