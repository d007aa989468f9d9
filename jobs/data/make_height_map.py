"""Regenerate ``jobs/data/rough_tilted_256.npy``: a measured-like height map for jobs/contact_file.toml.

A self-affine surface (H = 0.7, N = 256, lambda_l = L/4, lambda_s = L/64, rms slope 0.1, gaussian amplitudes,
seed 7; docs/model.md M2) on a 128 um x 128 um box (pixel 0.5 um), plus a plane tilt of 0.02 (x) and -0.01 (y)
and an offset of 3 um, as an instrument would record it; heights in micrometres, float32, axis 0 = x.
The job spec removes the tilt again (``detrend = "plane"``).

    python jobs/data/make_height_map.py          # writes jobs/data/rough_tilted_256.npy
"""

from pathlib import Path

import numpy as np

from gapsweep import surface

N, PIXEL_UM = 256, 0.5
L_UM = N * PIXEL_UM


def make() -> np.ndarray:
    h = surface.self_affine(N, 0.7, lambda_l=0.25, lambda_s=1 / 64, rms_slope=0.1, amplitudes="gaussian", seed=7)
    h = h * L_UM  # unit box -> micrometres (slopes unchanged)
    x = (np.arange(N) + 0.5) * PIXEL_UM
    tilt = 0.02 * x[:, None] - 0.01 * x[None, :] + 3.0
    return (h + tilt).astype(np.float32)


if __name__ == "__main__":
    out = Path(__file__).with_name("rough_tilted_256.npy")
    np.save(out, make())
    print(out)
