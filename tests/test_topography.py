"""Height maps from files (gapsweep.surface.load, docs/gfmd.md "Surfaces from data"): round trips in every
supported format (same heights, same GFMD result), units, detrending, padding, clear errors."""

from __future__ import annotations

import numpy as np
import pytest

from gapsweep.gfmd import solve
from gapsweep.surface import load, self_affine
from gapsweep.topography import Topography


@pytest.fixture
def heights() -> np.ndarray:
    h = self_affine(32, 0.8, lambda_l=0.5, lambda_s=4 / 32, seed=9)
    return h[:, :24].copy()  # rectangular: nx != ny


def write(path, h: np.ndarray, fmt: str) -> None:
    if fmt == "npy":
        np.save(path, h)
    elif fmt == "npz":
        np.savez(path, heights=h)
    elif fmt == "csv":
        np.savetxt(path, h, delimiter=",", fmt="%.17g")
    else:
        np.savetxt(path, h, fmt="%.17g", header="heights in um")


@pytest.mark.parametrize("fmt", ["npy", "npz", "csv", "txt"])
def test_round_trip_same_heights_same_result(tmp_path, heights, fmt: str) -> None:
    path = tmp_path / f"map.{fmt}"
    write(path, heights, fmt)
    t = load(path, pixel_size=1 / 32, detrend="none")
    np.testing.assert_array_equal(t.heights, heights)
    assert t.length == (1.0, 0.75) and t.shape == (32, 24)
    a = solve(heights, sigma0=1e-2, interaction="hard_wall", length=(1.0, 0.75), tol=1e-9, backend="numpy")
    b = solve(t.heights, sigma0=1e-2, interaction="hard_wall", length=t.length, tol=1e-9, backend="numpy")
    assert a.converged and b.converged
    assert a.mean_gap == b.mean_gap and a.contact_area == b.contact_area
    np.testing.assert_array_equal(a.gap, b.gap)


def test_surfacetopography_round_trip(tmp_path, heights) -> None:
    """Optional extra: a map written by SurfaceTopography (its own NetCDF format) loads back the same."""
    st = pytest.importorskip("SurfaceTopography")
    topo = st.Topography(heights, (1.0, 0.75), unit="um", periodic=True)
    path = tmp_path / "map.nc"
    topo.to_netcdf(str(path))
    t = load(path, detrend="none")
    np.testing.assert_allclose(t.heights, heights, rtol=0, atol=0)
    assert t.length == (1.0, 0.75) and t.unit == "um" and t.periodic


def test_units_and_detrending(tmp_path) -> None:
    nx, ny = 16, 8
    x = np.arange(nx)[:, None] * 2.0
    y = np.arange(ny)[None, :] * 2.0
    rng = np.random.default_rng(1)
    bumps = rng.standard_normal((nx, ny))
    tilted = 5.0 + 0.3 * x - 0.2 * y + bumps  # nm heights, pixel 2 nm
    np.save(tmp_path / "t.npy", tilted)
    t = load(tmp_path / "t.npy", pixel_size=2.0, unit="nm", to_unit="um", detrend="plane")
    assert t.unit == "um" and t.length == pytest.approx((32e-3, 16e-3))
    # the plane is gone: what is left is the bumps minus their own best plane, in um
    from gapsweep.topography import detrend

    expected = detrend(bumps, "plane", (32.0, 16.0)) * 1e-3
    np.testing.assert_allclose(t.heights, expected, atol=1e-15)
    assert abs(t.heights.mean()) < 1e-15
    m = load(tmp_path / "t.npy", length=(32.0, 16.0), detrend="mean")
    np.testing.assert_allclose(m.heights, tilted - tilted.mean())
    # height_unit apart from the lateral unit
    u = load(tmp_path / "t.npy", pixel_size=2.0, unit="um", height_unit="nm", detrend="none")
    np.testing.assert_allclose(u.heights, tilted * 1e-3)
    assert u.length == (32.0, 16.0)


def test_padding_keeps_map_and_fills_lowest(heights) -> None:
    t = Topography(heights, (1.0, 0.75), periodic=False)
    p = t.padded()
    assert p.shape == (64, 48) and p.length == (2.0, 1.5) and p.periodic
    np.testing.assert_array_equal(p.heights[:32, :24], heights)
    assert np.all(p.heights[32:, :] == heights.min()) and np.all(p.heights[:, 24:] == heights.min())
    r = solve(p.heights, sigma0=1e-3, interaction="hard_wall", length=p.length, tol=1e-8, backend="numpy")
    assert r.converged and np.all(r.pressure[32:, :] == 0) and np.all(r.pressure[:, 24:] == 0)


@pytest.mark.parametrize(
    ("content", "kwargs", "match"),
    [
        (np.zeros(5), dict(pixel_size=1.0), "2-D height map"),
        (np.array([[1.0, np.nan], [0.0, 1.0]]), dict(pixel_size=1.0), "NaN"),
        (np.zeros((4, 4)), {}, "length= or pixel_size="),
        (np.zeros((4, 4)), dict(pixel_size=-1.0), "pixel_size must be finite and > 0"),
        (np.zeros((4, 4)), dict(pixel_size=1.0, length=2.0), "not both"),
        (np.zeros((4, 4)), dict(pixel_size=1.0, unit="furlong"), "unit must be one of"),
        (np.zeros((4, 4)), dict(pixel_size=1.0, to_unit="nm"), "to_unit needs"),
        (np.zeros((4, 4)), dict(pixel_size=1.0, detrend="quadratic"), "detrend must be one of"),
    ],
)
def test_bad_input(tmp_path, content, kwargs, match) -> None:
    np.save(tmp_path / "m.npy", content)
    with pytest.raises(ValueError, match=match):
        load(tmp_path / "m.npy", **kwargs)


def test_missing_file_and_garbled_text(tmp_path) -> None:
    with pytest.raises(FileNotFoundError, match="no such height map"):
        load(tmp_path / "nope.npy", pixel_size=1.0)
    (tmp_path / "bad.txt").write_text("1 2\n3 x\n")
    with pytest.raises(ValueError, match="not a grid of numbers"):
        load(tmp_path / "bad.txt", pixel_size=1.0)
