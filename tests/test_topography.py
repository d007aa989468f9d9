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


@pytest.mark.validation
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


# ---------------------------------------------------------------------------------------------- issue 20: loaders
def write_xyz(path, h: np.ndarray, dx: float, dy: float, order: np.ndarray | None = None, x0: float = 3.0) -> None:
    ix, iy = np.meshgrid(np.arange(h.shape[0]), np.arange(h.shape[1]), indexing="ij")
    pts = np.column_stack([x0 + ix.ravel() * dx, -1.0 + iy.ravel() * dy, h.ravel()])
    if order is not None:
        pts = pts[order]
    np.savetxt(path, pts, fmt="%.10g", header="x y z")


@pytest.mark.parametrize("suffix", ["xyz", "txt", "csv"])
def test_xyz_points_rebuild_the_grid(tmp_path, heights, suffix: str) -> None:
    """x,y,z points (shuffled, offset origin, dx != dy) give back the height grid and its pixel size; they used
    to load as an N x 3 height map."""
    path = tmp_path / f"pts.{suffix}"
    order = np.random.default_rng(3).permutation(heights.size)
    if suffix == "csv":
        ix, iy = np.meshgrid(np.arange(32), np.arange(24), indexing="ij")
        pts = np.column_stack([ix.ravel() * 0.25, iy.ravel() * 0.5, heights.ravel()])[order]
        np.savetxt(path, pts, delimiter=",", fmt="%.17g")
    else:
        write_xyz(path, heights, 0.25, 0.5, order)
    t = load(path, unit="um", detrend="none")
    assert t.shape == (32, 24) and t.length == pytest.approx((8.0, 12.0)) and t.unit == "um"
    assert t.pixel_size == pytest.approx((0.25, 0.5))
    np.testing.assert_allclose(t.heights, heights, rtol=0, atol=1e-9 * np.abs(heights).max())


def test_three_column_grid_on_request(tmp_path) -> None:
    h = np.random.default_rng(2).random((10, 3))
    np.savetxt(tmp_path / "g.txt", h)
    t = load(tmp_path / "g.txt", pixel_size=1.0, format="text", detrend="none")
    np.testing.assert_array_equal(t.heights, h)


@pytest.mark.parametrize(("rows", "match"), [
    ("0 0 1\n1 0 2\n0.4 1 3\n1 1 4\n", "not on a regular grid"),       # scattered x
    ("0 0 1\n1 0 2\n0 1 3\n", "1 grid points missing"),                # a hole
    ("0 0 1\n1 0 2\n0 1 3\n1 1 4\n1 1 5\n", "repeated"),               # a duplicate
    ("0 0 1\n0 1 2\n0 2 3\n", "all x are equal"),                      # a profile
    ("0 0 nan\n1 0 2\n0 1 3\n1 1 4\n", "1 of 4 pixels .* are missing .*NaN"),      # missing height
])
def test_bad_xyz(tmp_path, rows: str, match: str) -> None:
    (tmp_path / "p.xyz").write_text(rows)
    with pytest.raises(ValueError, match=match):
        load(tmp_path / "p.xyz")
    with pytest.raises(ValueError, match="states its own pixel size"):
        (tmp_path / "ok.xyz").write_text("0 0 1\n1 0 2\n0 1 3\n1 1 4\n")
        load(tmp_path / "ok.xyz", pixel_size=1.0)


@pytest.mark.parametrize(("content", "match"), [
    ("", "no heights"),
    ("# only a comment\n", "no heights"),
    ("1 2 3 4 5\n", "single profile"),
    ("nan nan\nnan nan\n", "all 4 heights are undefined .*NaN"),
])
def test_degenerate_text_maps_refused_in_one_line(tmp_path, content: str, match: str) -> None:
    (tmp_path / "m.txt").write_text(content)
    with pytest.raises(ValueError, match=match) as info:
        load(tmp_path / "m.txt", pixel_size=1.0)
    assert "\n" not in str(info.value)


def test_periodic_flag_from_the_edges(tmp_path) -> None:
    """Neither file nor caller says: a periodic surface (plus a tilt, removed by the plane detrend) loads as
    periodic, a crop of it as non-periodic; the caller's flag wins."""
    full = self_affine(64, 0.8, lambda_l=0.5, lambda_s=0.1, seed=4)
    x = np.arange(64)[:, None] / 64
    np.save(tmp_path / "full.npy", full + 0.2 * x)
    np.save(tmp_path / "crop.npy", full[5:50, 3:40])
    assert load(tmp_path / "full.npy", pixel_size=1 / 64, detrend="plane").periodic
    assert not load(tmp_path / "full.npy", pixel_size=1 / 64, detrend="mean").periodic  # the tilt is a jump
    assert not load(tmp_path / "crop.npy", pixel_size=1 / 64).periodic
    assert load(tmp_path / "crop.npy", pixel_size=1 / 64, periodic=True).periodic


def test_bad_format(tmp_path) -> None:
    np.save(tmp_path / "m.npy", np.zeros((4, 4)))
    with pytest.raises(ValueError, match="format must be one of"):
        load(tmp_path / "m.npy", pixel_size=1.0, format="tiff")
