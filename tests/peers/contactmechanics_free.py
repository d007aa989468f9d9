"""Peer driver (run in ContactMechanics' own interpreter by tests/test_free_boundaries.py): hard-wall contact
of a finite map on ContactMechanics' FreeFFTElasticHalfSpace at a fixed total force.

    python contactmechanics_free.py in.npz out.npz     (in: h, lx, ly, sigma0, e_star; out: u, p, gap, success)
"""

import sys

import numpy as np
from ContactMechanics import FreeFFTElasticHalfSpace
from ContactMechanics.Systems import NonSmoothContactSystem
from SurfaceTopography import Topography

d = np.load(sys.argv[1])
h, lx, ly = d["h"], float(d["lx"]), float(d["ly"])
sigma0, e_star = float(d["sigma0"]), float(d["e_star"])
nx, ny = h.shape
system = NonSmoothContactSystem(FreeFFTElasticHalfSpace((nx, ny), e_star, physical_sizes=(lx, ly)),
                                Topography(h, (lx, ly), periodic=False))
res = system.minimize_proxy(external_force=sigma0 * lx * ly, pentol=1e-12 * h.std(), forcetol=1e-12,
                            maxiter=100000)
u = res.x[:nx, :ny]  # the displacement lives on the doubled grid; the map is its corner
p = res.jac[:nx, :ny] / (lx * ly / (nx * ny))  # pixel forces -> pressure
np.savez(sys.argv[2], u=u, p=p, gap=u - h - res.offset, success=bool(res.success))
