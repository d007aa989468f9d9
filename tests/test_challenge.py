"""The contact-mechanics challenge's problem (docs/challenge.md): the roll-off spectrum of the generator, the
challenge's constants, a height map in the shape of the published files loading and solving, the job specs of
the law, the shipped CI job end to end with the report's challenge section, and the contact-patch counter."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from gapsweep.analysis.challenge import patch_areas
from gapsweep.surfaces import challenge as ch
from gapsweep.surfaces import synthetic as syn
from gapsweep.sweep.schema import SpecError
from gapsweep.sweep.spec import loads

ROOT = Path(__file__).resolve().parents[1]


@pytest.mark.validation
def test_rolloff_spectrum_is_constant_below_q_r_and_a_power_law_above() -> None:
    """|h~(q)|^2 of the fixed-amplitude modes: one value for q_l <= q < q_r, (q/q_r)^(-2H-2) times it above."""
    L, hurst = 1.0, 0.8
    _, kx, ky, c = syn._coefficients(256, hurst, lambda_l=L, lambda_r=L / 5, lambda_s=L / 40, length=L,
                                     rms_slope=None, rms_height=None, c0=1.0, amplitudes="fixed", seed=3)
    k = np.hypot(kx, ky)
    p = np.abs(c) ** 2
    low = k < 5 - 1e-9
    assert low.sum() > 20 and np.allclose(p[low], p[low][0], rtol=1e-12)
    np.testing.assert_allclose(p[~low], p[low][0] * (k[~low] / 5) ** (-2 * hurst - 2), rtol=1e-12)
    # without lambda_r the generator is unchanged; lambda_r = lambda_l is the same spectrum
    a = syn.self_affine(64, hurst, lambda_l=0.25, lambda_s=0.05, seed=1)
    b = syn.self_affine(64, hurst, lambda_l=0.25, lambda_r=0.25, lambda_s=0.05, seed=1)
    np.testing.assert_allclose(a, b, rtol=0, atol=1e-14 * np.abs(a).max())


@pytest.mark.validation
def test_rolloff_rms_height_matches_quadrature_and_the_discrete_surface() -> None:
    """continuum_rms_height with lambda_r (closed form) against a quadrature of the spectrum, and the discrete
    surface of a fine mode set within 2 % (mode discreteness)."""
    hurst, L, lr, ls = 0.8, 1.0, 0.2, 1 / 300
    q = np.geomspace(2 * np.pi / L, 2 * np.pi / ls, 200001)
    c = np.minimum((q * lr / (2 * np.pi)) ** (-2 * hurst - 2), 1.0)
    trap = getattr(np, "trapezoid", None) or np.trapz  # noqa: NPY201
    ref = math.sqrt(trap(c * q, q) / trap(c * q**3, q))
    got = syn.continuum_rms_height(hurst, lambda_l=L, lambda_r=lr, lambda_s=ls)
    assert abs(got - ref) <= 1e-6 * ref
    h = syn.self_affine(1024, hurst, lambda_l=L, lambda_r=lr, lambda_s=ls, seed=2)
    assert abs(h.std() - got) <= 0.02 * got
    with pytest.raises(ValueError, match="lambda_r"):
        syn.self_affine(64, hurst, lambda_l=0.25, lambda_r=0.01, lambda_s=0.05)


def test_challenge_constants() -> None:
    """Derived numbers quoted in docs/challenge.md: h_rms 0.777 um, mu_rho 0.84 at the reference pixel, the
    largest adhesive tension gamma0/rho 24.1 MPa."""
    c = ch.CHALLENGE
    assert abs(ch.rms_height() - 0.7766) < 1e-3
    assert abs(ch.mu_rho(c["work"], c["rho"], c["e_star"], c["length"] / c["n_reference"]) - 0.8435) < 1e-3
    assert abs(c["work"] / c["rho"] - 24.14) < 0.01
    h = ch.surface(64, length=2.0, seed=1)  # a window of the spectrum (the full box needs n > 2000)
    assert h.shape == (64, 64) and abs(syn.rms_slope(h, 2.0) - 1.0) < 1e-9


def test_a_map_in_the_published_shape_loads_and_solves(tmp_path: Path) -> None:
    """The published surfaces are height matrices (one row per line, heights in um); such a file goes through
    gapsweep.surface.load (physical size and unit given) into the challenge's law on a periodic box."""
    from gapsweep.gfmd import solve
    from gapsweep.surface import load

    h = ch.surface(64, length=2.0, seed=4)
    path = tmp_path / "challenge_like.dat"
    np.savetxt(path, h, header="heights in um, 64 x 64, box 2 um x 2 um (challenge-like test file)")
    topo = load(path, length=2.0, unit="um", periodic=True)
    assert topo.heights.shape == (64, 64) and topo.periodic
    np.testing.assert_allclose(topo.heights, h - h.mean(), rtol=0, atol=1e-12)
    c = ch.CHALLENGE
    r = solve(topo, sigma0=2.5, interaction="hard_wall_adhesive", work=c["work"], rho=c["rho"], e_star=c["e_star"],
              tol=1e-8, backend="numpy")
    assert r.converged and 0 < r.contact_area < 1


BASE = """
[job]
name = "t"
[grid]
hurst = [0.8]
rho = [0.01]
sigma0 = [1e-3, 0.0, -1e-4]
[surface]
lambda_l = 0.5
lambda_s = 0.05
{surface}
[interaction]
kind = "hard_wall_adhesive"
{inter}
[methods.gfmd]
n = 64
{gfmd}
{more}
"""


EXPONENTIAL_WITH_THEORY = """
[job]
name = "t"
[grid]
hurst = [0.8]
rho = [0.01]
sigma0 = [1e-3]
[surface]
lambda_l = 0.5
lambda_r = 0.2
lambda_s = 0.05
[methods.gfmd]
n = 64
[methods.theory]
forms = ["paper"]
"""


def spec(surface: str = "", inter: str = "work = 1e-4", gfmd: str = "", more: str = "") -> str:
    return BASE.format(surface=surface, inter=inter, gfmd=gfmd, more=more)


def test_job_specs_of_the_law() -> None:
    js = loads(spec(surface="lambda_r = 0.2"))
    assert js.interaction == {"kind": "hard_wall_adhesive", "work": 1e-4}
    assert js.surface["lambda_r"] == 0.2 and -1e-4 in js.grid["sigma0"]
    for text, key in ((spec(inter=""), "interaction.work"), (spec(surface="lambda_r = 0.01"), "surface.lambda_r"),
                      (EXPONENTIAL_WITH_THEORY, "surface.lambda_r"),
                      (spec(gfmd='distributed = true\nmethod = "pk"'), "method")):
        with pytest.raises(SpecError, match=key.replace(".", r"\.")):
            loads(text)
    loads(spec(gfmd="distributed = true"))  # the law's solve over ranks (gfmd._bounded on slabs)


def test_patch_areas_join_across_periodic_edges() -> None:
    m = np.zeros((8, 6), bool)
    m[0, 2] = m[7, 2] = True  # one patch across the x edge
    m[3, 0] = m[3, 5] = m[4, 5] = True  # one across the y edge
    m[5, 2:4] = True  # a separate patch of 2
    np.testing.assert_array_equal(patch_areas(m), [3.0, 2.0, 2.0])
    np.testing.assert_array_equal(patch_areas(m, periodic=False), [2.0, 2.0, 1.0, 1.0, 1.0])
    assert patch_areas(np.zeros((4, 4), bool)).size == 0


@pytest.mark.slow  # about 40 s on the shared 2-core machine (the report's figures)
def test_quick_job_runs_and_reports_the_challenge_outputs(tmp_path: Path, capsys) -> None:
    """The shipped CI job end to end (run, report): every task converges; the challenge section's tables hold
    area, mean gap and stiffness against load for each rho, patch statistics whose areas add up to the contact
    area, and the Tabor table; the loading path is named. The two commands run by ``cli.main`` in this process
    (the function ``python -m gapsweep`` exits with): two interpreter starts less."""
    from tests.storekit import cli_run

    pytest.importorskip("xarray")  # kept fields
    store = tmp_path / "cq.h5"
    job = ROOT / "gapsweep/jobs/challenge_quick.toml"
    rc, _, err = cli_run(capsys, "run", job, "--store", store)
    assert rc == 0, err[-2000:]
    rc, _, err = cli_run(capsys, "report", store, "--out", tmp_path / "r")
    assert rc == 0, err[-2000:]
    md = (tmp_path / "r/report.md").read_text()
    assert "## The contact-mechanics challenge's outputs" in md and "loads in increasing order" in md
    loads_t = pd.read_csv(tmp_path / "r/challenge_loads.csv")
    assert len(loads_t) == 24 and loads_t["flags"].eq(0).all()
    for _, g in loads_t.groupby("rho"):
        g = g.sort_values("sigma0")
        assert np.all(np.diff(g["contact_area"]) > 0) and np.all(np.diff(g["mean_gap"]) < 0)
        assert np.all(g["stiffness"] > 0)
        assert g["contact_area"].min() < 2e-3 and g["contact_area"].max() > 0.15  # spans 0.1 % .. 15 %
    ref = pd.read_csv(tmp_path / "r/challenge_reference.csv")
    assert len(ref) == 3 and (ref["patches"] > 0).all()
    box = 0.256**2
    np.testing.assert_allclose(ref["mean_patch_area"] * ref["patches"] / box, ref["contact_area"], rtol=1e-12)
    tab = pd.read_csv(tmp_path / "r/challenge_tabor.csv")
    assert len(tab) == 3 and np.all(np.diff(tab.sort_values("rho")["tabor"]) < 0)
