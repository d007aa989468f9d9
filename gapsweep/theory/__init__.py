"""Theories of the interface: predictors of what GFMD measures (docs/model.md M4, M5; docs/theory.md).

One module per theory (a new theory is a new file here):

``field``       the paper's field theory of the mean gap (M4) and the magnification coefficients (M5).
``spectrum``    the height spectrum a theory needs, from self-affine parameters or from a height map.
``persson``     Persson's contact mechanics (hard wall): contact area, mean separation, pressure and gap
                distributions.
``cumulant``    next-order cumulant terms of the field theory: an error indicator for the paper's form.
``improved``    improved mean-gap predictors for exponential repulsion (beyond the paper).
``closure``     a gap-distribution closure whose strength is fixed by the mean-pressure identity.
                Also the multiscale gap distribution (coarse GFMD + that closure over the finer shells).

The names of the original single-module ``gapsweep.theory`` (the field theory) are re-exported here, so
``from gapsweep import theory; theory.mean_gap(...)`` works as before.
"""

from __future__ import annotations

from gapsweep.theory import closure, cumulant, improved, persson, spectrum
from gapsweep.theory.field import (
    FORMS,
    diffusion,
    drift,
    eta,
    flat_gap,
    high_pressure_limit,
    low_pressure_limit,
    mean_gap,
    mean_gap_discrete,
    mean_gap_spectrum,
    rigid_gap_density,
    rigid_mean_gap,
    roughness_integral,
)

__all__ = [
    "FORMS",
    "closure",
    "cumulant",
    "diffusion",
    "drift",
    "eta",
    "flat_gap",
    "high_pressure_limit",
    "improved",
    "low_pressure_limit",
    "mean_gap",
    "mean_gap_discrete",
    "mean_gap_spectrum",
    "persson",
    "rigid_gap_density",
    "rigid_mean_gap",
    "roughness_integral",
    "spectrum",
]
