"""Regenerate ``jobs/data/measured_tilted_192x128.npz``: a non-periodic, tilted, rectangular height map in
micrometres, the worked example of issue 20 (docs/gfmd.md, "Periodic or free boundaries").

A periodic self-affine surface (docs/model.md M2: H = 0.7, 256 x 256 pixels of 0.5 um, lambda_l = 32 um,
lambda_s = 2 um, rms slope 0.1, gaussian amplitudes, seed 20) is cropped to 192 x 128 pixels at offset (37, 71),
so opposite edges no longer match (not periodic), then a plane tilt of 0.015 along x and -0.008 along y and an
offset of 2 um are added, as an instrument records it. Stored: one array ``heights`` (float64, um, axis 0 = x);
pixel size 0.5 um, box 96 um x 64 um, periodic = false. Because the crop's parent is known, its exact rms slope
(0.1, and 0.1000 on the parent's modes) is the reference for the map's spectrum (theory.spectrum.map_spectrum).

    PYTHONPATH=$PWD python scripts/make_measured_map.py      # writes jobs/data/measured_tilted_192x128.npz
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from gapsweep import surface

N, PIXEL_UM = 256, 0.5
NX, NY, OFFSET = 192, 128, (37, 71)
OUT = Path(__file__).resolve().parent.parent / "jobs" / "data" / "measured_tilted_192x128.npz"


def parent() -> np.ndarray:
    """The periodic parent on the unit box, scaled to micrometres (slopes unchanged)."""
    h = surface.self_affine(N, 0.7, lambda_l=0.25, lambda_s=1 / 64, rms_slope=0.1, amplitudes="gaussian", seed=20)
    return h * (N * PIXEL_UM)


def make() -> np.ndarray:
    crop = parent()[OFFSET[0]:OFFSET[0] + NX, OFFSET[1]:OFFSET[1] + NY]
    x = (np.arange(NX) + 0.5) * PIXEL_UM
    y = (np.arange(NY) + 0.5) * PIXEL_UM
    return crop + 0.015 * x[:, None] - 0.008 * y[None, :] + 2.0


if __name__ == "__main__":
    np.savez_compressed(OUT, heights=make())
    print(OUT, OUT.stat().st_size, "bytes")
