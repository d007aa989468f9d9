"""Rough surfaces (docs/model.md M2): synthetic self-affine surfaces with their spectra (``synthetic``) and
measured height maps with their readers (``topography``). Free of the sweep."""

from gapsweep.surfaces.synthetic import (  # noqa: F401
    continuum_rms_height,
    rms_height,
    rms_slope,
    self_affine,
    self_affine_rows,
)
from gapsweep.surfaces.topography import Topography, load  # noqa: F401
