"""Tests of gapsweep.sde (docs/model.md M5, M7): exact Gaussian for C2 = 0, agreement with the Fokker-Planck
solver, counter-based seeds, the stiff case, extreme pressures and bad input. CPU warp, small ensembles."""

import math

import numpy as np
import pytest
from scipy import stats

from gapsweep import fokker_planck, sde, theory

# docs/model.md M6 common parameters, g_rms = 1 at H = 0.3 (h_rms from the continuum spectrum, M2)
P = dict(hurst=0.3, h_rms=2.34e-3, gamma0=1e-3, lambda_l=0.25, lambda_s=2.5e-3)
STIFF = dict(P, rho=5e-4)


def _chi2_pvalue(counts: np.ndarray, prob: np.ndarray, n: int) -> float:
    """Pearson chi-square p-value of histogram counts against bin probabilities (bins with >= 10 expected)."""
    expected = n * prob
    keep = expected >= 10
    obs = counts[keep]
    exp = expected[keep]
    # lump everything else into one bin so that the totals agree
    obs = np.append(obs, n - obs.sum())
    exp = np.append(exp, n - exp.sum())
    if exp[-1] < 10:
        obs[-2] += obs[-1]
        exp[-2] += exp[-1]
        obs, exp = obs[:-1], exp[:-1]
    chi2 = float(np.sum((obs - exp) ** 2 / exp))
    return float(stats.chi2.sf(chi2, obs.size - 1))


@pytest.mark.validation
def test_plan_matches_theory_mean_gap():
    # the per-step quadrature of D1 reproduces the closed-form mean gap; D2 = rho D1 gives V = 2 rho (g0 - flat)
    for s0 in (1e-7, 1e-3, 10.0):
        for steps, dz in (("uniform", 0.5), ("log", 0.2)):
            pl = sde.plan_steps(s0, rho=2e-3, dzeta=dz, steps=steps, **P)
            g0 = theory.mean_gap(s0, rho=2e-3, **P)
            flat = theory.flat_gap(s0, rho=2e-3, gamma0=P["gamma0"])
            assert pl.g0_end == pytest.approx(g0, rel=1e-10, abs=1e-14)
            assert pl.variance == pytest.approx(2 * 2e-3 * (g0 - flat), rel=1e-9, abs=1e-18)


def test_zeta_grid():
    z = sde.zeta_grid(100.0, 0.01)
    assert z.size == 9901 and z[0] == 1.0 and z[-1] == 100.0
    assert np.allclose(np.diff(z), 0.01)
    zl = sde.zeta_grid(100.0, 0.01, "log")
    assert zl[-1] == 100.0 and np.allclose(zl[1:] / zl[:-1], zl[1] / zl[0])
    assert zl[1] / zl[0] == pytest.approx(1.01, rel=2e-3)
    assert sde.zeta_grid(1.0).tolist() == [1.0]


@pytest.mark.validation
@pytest.mark.parametrize("dtype", ["float32", "float64"])
def test_c2_zero_is_exact_gaussian(dtype):
    # M5: with C2 = 0 the gap is Gaussian, mean g0(zeta), variance 2 int D2: exact for any step size
    n = 20_000
    s0, rho = 1e-3, 2e-3
    g = sde.gap_samples(s0, rho=rho, n=n, dzeta=0.5, steps="log", seed=11, dtype=dtype, **P)
    pl = sde.plan_steps(s0, rho=rho, dzeta=0.5, steps="log", **P)
    mean_exact = theory.mean_gap(s0, rho=rho, **P)
    var_exact = pl.variance
    assert abs(g.mean() - mean_exact) < 5 * math.sqrt(var_exact / n)
    assert abs(g.var() - var_exact) < 5 * var_exact * math.sqrt(2.0 / n)
    assert stats.kstest((g - mean_exact) / math.sqrt(var_exact), "norm").pvalue > 1e-4


def test_histogram_on_device_matches_samples():
    kw = dict(rho=5e-4, c2=1.0, n=4000, dzeta=0.1, steps="log", seed=2, **P)
    g = sde.gap_samples(1e-2, **kw)
    r = sde.gap_histogram_counts(1e-2, bins=40, **kw)
    ref, _ = np.histogram(g, r.edges)
    # float32 binning in the moving frame vs float64 on the host: at most a rounding-level edge case or two
    assert np.abs(ref - r.counts).sum() <= 2
    assert r.below + r.above + r.counts.sum() == 4000 and r.nonfinite == 0
    edges, dens, n_finite = sde.gap_histogram(1e-2, bins=r.edges, **kw)
    assert n_finite == 4000 and np.sum(dens * np.diff(edges)) == pytest.approx(1.0)
    # non-uniform edges take the binary-search path
    e2 = np.concatenate((r.edges[:10], r.edges[10::3]))
    r2 = sde.gap_histogram_counts(1e-2, bins=e2, **kw)
    assert np.abs(np.histogram(g, e2)[0] - r2.counts).sum() <= 2


def test_same_seed_same_samples_any_batch_split():
    kw = dict(rho=5e-4, c2=1.0, dzeta=0.2, seed=123, **P)
    a = sde.gap_samples(1e-2, n=1000, **kw)
    b = np.concatenate([sde.gap_samples(1e-2, n=300, batch=7, **kw),
                        sde.gap_samples(1e-2, n=700, first=300, batch=64, **kw)])
    assert np.array_equal(a, b)
    c = sde.gap_samples(1e-2, n=1000, seed=124, **{k: v for k, v in kw.items() if k != "seed"})
    assert not np.any(a == c)
    # histograms too: one launch vs many batches
    h1 = sde.gap_histogram_counts(1e-2, n=1000, bins=30, **kw)
    h2 = sde.gap_histogram_counts(1e-2, n=1000, bins=h1.edges, batch=99, **kw)
    assert np.array_equal(h1.counts, h2.counts)
    # seeds above 2**32 use the high key word
    d = sde.gap_samples(1e-2, n=10, seed=123 + 2**32, **{k: v for k, v in kw.items() if k != "seed"})
    assert not np.any(d == a[:10])


def test_float32_close_to_float64_same_stream():
    kw = dict(rho=5e-4, c2=1.0, n=2000, dzeta=0.1, seed=9, **P)
    a = sde.gap_samples(1e-2, dtype="float32", **kw)
    b = sde.gap_samples(1e-2, dtype="float64", **kw)
    sd = float(np.std(b))
    assert np.max(np.abs(a - b)) < 1e-3 * sd


@pytest.mark.validation
def test_repulsion_sde_matches_fokker_planck():
    # M5 with repulsion: SDE histogram vs noise-free FP density, chi-square at the Monte Carlo noise
    n = 40_000
    for s0 in (1e-4, 1e-2):
        kw = dict(rho=5e-4, c2=1.0, **P)
        r = sde.gap_histogram_counts(s0, n=n, bins=40, dzeta=0.02, steps="log", seed=4, **kw)
        ref = fokker_planck.solve(s0, n_steps=800, **kw)
        prob = np.diff(ref.cdf(r.edges))
        assert r.below + r.above <= 2
        assert _chi2_pvalue(r.counts, prob, r.counts.sum()) > 1e-4


@pytest.mark.validation
def test_stiff_case_finite_and_right():
    # M7: rho = 5e-4, C2 = 1, dzeta = 0.1 (uniform, as the paper's scheme would take it)
    n = 20_000
    for s0 in (1e-4, 1e-2, 1.0):
        g = sde.gap_samples(s0, n=n, dzeta=0.1, c2=1.0, seed=8, **STIFF)
        assert np.all(np.isfinite(g))
        fine = sde.gap_samples(s0, n=n, dzeta=0.005, steps="log", c2=1.0, seed=80, **STIFF)
        assert stats.ks_2samp(g, fine).pvalue > 1e-4
        ref = fokker_planck.solve(s0, c2=1.0, n_steps=800, **STIFF)
        assert abs(g.mean() - ref.mean()) < 5 * g.std() / math.sqrt(n)
        assert abs(g.std() / math.sqrt(ref.variance()) - 1) < 5 * math.sqrt(0.5 / n) + 2e-3


@pytest.mark.parametrize("s0", [1.0, 10.0])
def test_euler_baseline_reports_failure_on_stiff_case(s0):
    # issue 9.7: the paper's explicit Euler-Maruyama overshoots here (sigma0 = 1: the first step jumps ~200 rho;
    # sigma0 = 10 used to return finite gaps of mean 0.999 against 0.0064); a step that breaks the stability bound
    # c dzeta exp(-g/rho)/rho <= 2 is a failure, never a number
    with pytest.raises(FloatingPointError, match="stability bound"):
        sde.gap_samples(s0, n=500, dzeta=0.1, c2=1.0, seed=8, scheme="euler", **STIFF)
    r = sde.gap_histogram_counts(s0, n=500, dzeta=0.1, c2=1.0, seed=8, scheme="euler", **STIFF)
    assert r.nonfinite == 500 and r.counts.sum() == 0


@pytest.mark.validation
def test_euler_baseline_runs_where_stable():
    # the same baseline with steps inside its stability bound returns gaps that agree with the split scheme
    kw = dict(rho=2e-3, c2=1.0, n=4000, dzeta=0.01, seed=3, **P)
    e = sde.gap_samples(1e-3, scheme="euler", **kw)
    s = sde.gap_samples(1e-3, **kw)
    assert abs(e.mean() - s.mean()) < 0.05 * s.std() and abs(e.std() / s.std() - 1) < 0.05


@pytest.mark.parametrize("dtype", ["float32", "float64"])
def test_extreme_pressures_no_overflow(dtype):
    # M7: sigma0 from 1e-7 to 10 (eta ~ 1e5 .. 1e-3), with and without repulsion
    for s0 in (1e-7, 1e-4, 1e-1, 10.0):
        for c2 in (0.0, 1.0):
            r = sde.gap_histogram_counts(s0, rho=5e-4, c2=c2, n=2000, dzeta=0.1, steps="log", bins=20,
                                         dtype=dtype, seed=1, **P)
            assert r.nonfinite == 0
            assert r.counts.sum() + r.below + r.above == 2000
            assert r.counts.sum() >= 1990  # the default range holds the distribution


def test_bad_input():
    kw = dict(rho=5e-4, **P)
    with pytest.raises(ValueError, match="n"):
        sde.gap_samples(1e-2, n=-5, **kw)
    with pytest.raises(ValueError, match="n"):
        sde.gap_samples(1e-2, n=0, **kw)
    with pytest.raises(TypeError, match="n"):
        sde.gap_samples(1e-2, n=2.5, **kw)
    with pytest.raises(ValueError, match="dzeta"):
        sde.gap_samples(1e-2, n=10, dzeta=0.0, **kw)
    with pytest.raises(ValueError, match="dzeta"):
        sde.gap_samples(1e-2, n=10, dzeta=-0.1, **kw)
    with pytest.raises(ValueError, match="zeta_end"):
        sde.gap_samples(1e-2, n=10, zeta_end=0.5, **kw)
    with pytest.raises(ValueError, match="c1"):
        sde.gap_samples(1e-2, n=10, c1=-1.0, **kw)
    with pytest.raises(ValueError, match="c2"):
        sde.gap_samples(1e-2, n=10, c2=-1.0, **kw)
    with pytest.raises(ValueError, match="c2"):
        sde.gap_samples(1e-2, n=10, c2=float("nan"), **kw)
    with pytest.raises(ValueError, match="device"):
        sde.gap_samples(1e-2, n=10, device="gpu", **kw)
    with pytest.raises(ValueError, match="device"):
        sde.gap_samples(1e-2, n=10, device="cuda:97", **kw)
    with pytest.raises(ValueError, match="dtype"):
        sde.gap_samples(1e-2, n=10, dtype="float16", **kw)
    with pytest.raises(ValueError, match="steps"):
        sde.gap_samples(1e-2, n=10, steps="cubic", **kw)
    with pytest.raises(ValueError, match="scheme"):
        sde.gap_samples(1e-2, n=10, scheme="rk4", **kw)
    with pytest.raises(ValueError, match="sigma0"):
        sde.gap_samples(-1.0, n=10, **kw)
    with pytest.raises(ValueError, match="seed"):
        sde.gap_samples(1e-2, n=10, seed=-1, **kw)
    with pytest.raises(ValueError, match="bins"):
        sde.gap_histogram(1e-2, n=10, bins=np.array([1.0, 0.5]), **kw)
    with pytest.raises(ValueError, match="bins"):
        sde.gap_histogram(1e-2, n=10, bins=0, **kw)


@pytest.mark.validation
def test_zeta_end_one_is_flat_gap():
    g = sde.gap_samples(1e-2, rho=5e-4, n=16, zeta_end=1.0, c2=1.0, **P)
    assert np.allclose(g, theory.flat_gap(1e-2, rho=5e-4, gamma0=P["gamma0"]))


# Random123 (D. E. Shaw Research) tests/kat_vectors, the three "philox4x32 10" lines: counter (4 words), key (2),
# expected output (4), all 32-bit hex.
PHILOX_KAT = [
    ((0x00000000, 0x00000000, 0x00000000, 0x00000000), (0x00000000, 0x00000000),
     (0x6627E8D5, 0xE169C58D, 0xBC57AC4C, 0x9B00DBD8)),
    ((0xFFFFFFFF, 0xFFFFFFFF, 0xFFFFFFFF, 0xFFFFFFFF), (0xFFFFFFFF, 0xFFFFFFFF),
     (0x408F276D, 0x41C83B0E, 0xA20BC7C6, 0x6D5451FD)),
    ((0x243F6A88, 0x85A308D3, 0x13198A2E, 0x03707344), (0xA4093822, 0x299F31D0),
     (0xD16CFE09, 0x94FDCCEB, 0x5001E420, 0x24126EA1)),
]


@pytest.mark.validation
def test_philox_known_answers():
    # issue 9.7: the generator the SDE kernels use (gapsweep._sde_kernels.philox4x32), run by warp on the CPU
    wp = sde._warp()
    from gapsweep.gapdist._sde_kernels import philox4x32

    @wp.kernel(module="unique")
    def kat(ctr: wp.array(dtype=wp.uint32), key: wp.array(dtype=wp.uint32), out: wp.array(dtype=wp.uint32)):
        i = wp.tid()
        r0, r1, r2, r3 = philox4x32(ctr[4 * i], ctr[4 * i + 1], ctr[4 * i + 2], ctr[4 * i + 3], key[2 * i],
                                    key[2 * i + 1])
        out[4 * i] = r0
        out[4 * i + 1] = r1
        out[4 * i + 2] = r2
        out[4 * i + 3] = r3

    ctr = wp.array(np.array([c for v in PHILOX_KAT for c in v[0]], dtype=np.uint32), dtype=wp.uint32, device="cpu")
    key = wp.array(np.array([k for v in PHILOX_KAT for k in v[1]], dtype=np.uint32), dtype=wp.uint32, device="cpu")
    out = wp.zeros(4 * len(PHILOX_KAT), dtype=wp.uint32, device="cpu")
    wp.launch(kat, dim=len(PHILOX_KAT), inputs=[ctr, key, out], device="cpu")
    got = out.numpy().reshape(-1, 4)
    for row, (_c, _k, want) in zip(got, PHILOX_KAT, strict=True):
        assert [hex(int(x)) for x in row] == [hex(x) for x in want]


def test_cuda_engine_devices_need_no_warp(monkeypatch):
    """Devices that the CUDA engine runs are validated without warp (a GPU node needs no warp for the figure
    jobs); CPU devices, or CUDA with the warp engine, still go through warp."""
    from gapsweep.gapdist import _sde_cuda

    def no_warp():
        raise AssertionError("warp imported")

    monkeypatch.setattr(sde, "_warp", no_warp)
    monkeypatch.setattr(_sde_cuda, "enabled", lambda d, scheme: d.startswith("cuda") and scheme == "split")
    monkeypatch.setattr(_sde_cuda, "device_name", lambda d: "cuda:0" if d == "cuda" else d)
    assert sde._devices("cuda") == ["cuda:0"]
    assert sde._devices(["cuda:0", "cuda:1"]) == ["cuda:0", "cuda:1"]
    with pytest.raises(ValueError, match="unknown device"):
        sde._devices("gpu")
    for device, scheme in (("cpu", "split"), ("cuda", "euler")):
        with pytest.raises(AssertionError, match="warp imported"):
            sde._devices(device, scheme)
