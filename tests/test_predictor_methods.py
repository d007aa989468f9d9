"""The predictors as sweep methods (issue 21 item 5; docs/jobs.md "Predictors"): ``hybrid`` (the mean gap to a
requested accuracy) and ``multiscale`` (the gap distribution) run in a job spec beside GFMD, with their error
estimates in the store. References: the same functions called directly (the route through the sweep changes
nothing), and GFMD of the same surfaces in the same store (the accuracy the predictor claims)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from gapsweep import runner, spec, store, surface
from gapsweep.theory import closure, improved

JOB = """
[job]
name = "predictors"
[grid]
hurst = 0.7
rho = [1e-2, 4e-2]
sigma0 = [1e-3, 3e-2]
seeds = [3]
[surface]
lambda_l = 0.25
lambda_s = 0.015625
rms_slope = 0.5
[material]
gamma0 = 1e-3
[histogram]
bins = 24
[methods.gfmd]
n = 256
tol = 1e-8
backend = "numpy"
[methods.hybrid]
n = 256
[methods.multiscale]
n = 256
samples = 20000
"""


@pytest.fixture(scope="module")
def store_path(tmp_path_factory):
    d = tmp_path_factory.mktemp("pred")
    (d / "j.toml").write_text(JOB)
    path = d / "p.h5"
    runner.run(d / "j.toml", path, progress="none", mpi="off")
    return path


def test_rows_equal_direct_calls(store_path):
    df = store.read(store_path)
    h = surface.self_affine(256, 0.7, lambda_l=0.25, lambda_s=0.015625, rms_slope=0.5, seed=3)
    for _, row in df[df.method == "hybrid"].iterrows():
        r = improved.hybrid(row.sigma0, h, zeta_c="auto", rho=row.rho, gamma0=1e-3, lambda_l=0.25, tol=1e-6)
        assert row.mean_gap == pytest.approx(r.mean_gap, rel=1e-12)
        assert row.error_estimate == pytest.approx(r.error_estimate, rel=1e-12)
        assert row.status == ("done" if r.status == "converged" else "not_converged")
    hists = store.read_histograms(store_path)
    for _, row in df[df.method == "multiscale"].iterrows():
        ms = closure.multiscale_gap_samples(row.sigma0, h, rho=row.rho, gamma0=1e-3, lambda_l=0.25,
                                            lambda_s=0.015625, samples=20000, seed=3, tol=1e-6)
        assert row.mean_gap == pytest.approx(ms.mean_gap, rel=1e-12)
        assert row.gap_std == pytest.approx(float(np.std(ms.samples)), rel=1e-12)
        e, d, c = hists[row.task_id]
        assert c == ms.samples.size and float(np.sum(d * np.diff(e))) == pytest.approx(1.0, rel=1e-12)


def test_hybrid_within_its_accuracy_of_gfmd(store_path):
    """Where the hybrid says done, it is within rtol of GFMD on the same surface (relative where |g0| >= h_rms,
    in units of h_rms else), and its estimate is stored and finite."""
    df = store.read(store_path)
    g = df[df.method == "gfmd"].set_index(["rho", "sigma0"])
    hy = df[df.method == "hybrid"].set_index(["rho", "sigma0"])
    assert np.isfinite(hy.error_estimate).all() and (hy.error_estimate >= 0).all()
    done = hy[hy.status == "done"]
    assert len(done) >= 2
    for k, row in done.iterrows():
        ref = g.loc[k]
        scale = max(abs(ref.mean_gap), ref.h_rms)
        assert abs(row.mean_gap - ref.mean_gap) <= 0.05 * scale, (k, row.mean_gap, ref.mean_gap)


def test_predictor_spec_errors():
    with pytest.raises(spec.SpecError, match=r"methods\.hybrid\.rtol"):
        spec.loads(JOB.replace("[methods.hybrid]\nn = 256", "[methods.hybrid]\nn = 256\nrtol = 2"))
    with pytest.raises(spec.SpecError, match=r"methods\.hybrid\.n"):
        spec.loads(JOB.replace("[methods.hybrid]\nn = 256", "[methods.hybrid]"))
    with pytest.raises(spec.SpecError, match=r"methods\.multiscale.*exponential"):
        spec.loads(JOB.replace("[material]\ngamma0 = 1e-3", '[interaction]\nkind = "hard_wall"').replace(
            "rho = [1e-2, 4e-2]\n", "").replace("[methods.gfmd]", "[methods.x]").split("[methods.x]")[0]
            + "[methods.multiscale]\nn = 256\n")
    assert math.isfinite(spec.loads(JOB).methods["hybrid"]["rtol"])
