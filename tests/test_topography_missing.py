"""Maps with undefined pixels, several channels and units (issue 36 item 1; docs/gfmd.md "Surfaces from data",
docs/jobs.md "Height maps from files"): refused by default with where they are, cropped to the largest valid
rectangle (checked against brute force), filled by harmonic interpolation (checked against discrete harmonic
functions, which it must reproduce exactly) or the nearest valid pixel (against brute force), ``channel=``,
and the sweep's keys, plan lines and store record. Files are written by SurfaceTopography's own NetCDF writer
(masked arrays, units); SurfaceTopography writes no multi-channel format, so those are MATLAB files made with
scipy.io.savemat, which its MatReader reads as one channel per 2-D array."""

from __future__ import annotations

import copy
import itertools
import json
import os
from pathlib import Path

import numpy as np
import pytest

from gapsweep.surfaces import topography
from gapsweep.surfaces.topography import fill_missing, largest_valid_rectangle, load

# --------------------------------------------------------------------------------- largest valid rectangle


def _brute_rectangle(valid: np.ndarray) -> int:
    """Area of the largest all-True block by trying every block (O(n^6) on tiny grids: independent)."""
    nx, ny = valid.shape
    best = 0
    for x0, x1 in itertools.combinations(range(nx + 1), 2):
        for y0, y1 in itertools.combinations(range(ny + 1), 2):
            if (x1 - x0) * (y1 - y0) > best and valid[x0:x1, y0:y1].all():
                best = (x1 - x0) * (y1 - y0)
    return best


@pytest.mark.parametrize("shape", [(7, 9), (9, 4), (1, 8), (6, 1), (5, 5)])
@pytest.mark.parametrize("density", [0.05, 0.3, 0.7])
def test_largest_valid_rectangle_equals_brute_force(shape, density) -> None:
    rng = np.random.default_rng(hash((shape, density)) % 2**32)
    for _ in range(20):
        valid = rng.random(shape) >= density
        x0, x1, y0, y1 = largest_valid_rectangle(valid)
        area = (x1 - x0) * (y1 - y0)
        assert area == _brute_rectangle(valid)
        if area:
            assert valid[x0:x1, y0:y1].all()
    assert largest_valid_rectangle(np.zeros((3, 4), bool)) == (0, 0, 0, 0)
    assert largest_valid_rectangle(np.ones((3, 4), bool)) == (0, 3, 0, 4)


# ------------------------------------------------------------------------------------------------ filling


def test_harmonic_fill_reproduces_discrete_harmonic_functions() -> None:
    """a + b x + c y + d (x^2 - y^2) + e x y has a zero 5-point Laplacian: the harmonic filling of any hole whose
    neighbours inside the map are known must give it back to round-off. At the map's border the filling leaves
    the neighbours outside the map out (a zero normal derivative), so a hole on an edge gives back a function
    that is flat across that edge and linear along it."""
    nx, ny = 23, 17
    x, y = np.meshgrid(np.arange(nx, dtype=float), np.arange(ny, dtype=float), indexing="ij")
    h = 0.3 + 1.5 * x - 0.7 * y + 0.02 * (x ** 2 - y ** 2) + 0.01 * x * y
    hole = np.zeros((nx, ny), bool)
    hole[4:9, 3:11] = True
    hole[15, 12] = True
    hole[12:14, 5:7] = True
    filled = fill_missing(np.where(hole, 1e6, h), hole, "harmonic")
    np.testing.assert_allclose(filled, h, rtol=0, atol=1e-9)
    for lin, (sx, sy) in ((0.3 - 0.7 * y, (slice(0, 3), slice(5, 9))), (0.3 + 1.5 * x, (slice(10, 14), ny - 1))):
        edge = np.zeros((nx, ny), bool)
        edge[sx, sy] = True
        np.testing.assert_allclose(fill_missing(np.where(edge, -7.0, lin), edge, "harmonic"), lin, rtol=0,
                                   atol=1e-9)


def test_harmonic_fill_is_smooth_and_keeps_valid_pixels() -> None:
    rng = np.random.default_rng(4)
    h = rng.standard_normal((20, 13))
    m = rng.random(h.shape) < 0.4
    f = fill_missing(h, m, "harmonic")
    np.testing.assert_array_equal(f[~m], h[~m])
    # every filled pixel is the mean of its neighbours inside the map (the discrete Laplace equation)
    for i, j in zip(*np.nonzero(m)):
        nb = [f[a, b] for a, b in ((i - 1, j), (i + 1, j), (i, j - 1), (i, j + 1)) if 0 <= a < 20 and 0 <= b < 13]
        assert f[i, j] == pytest.approx(np.mean(nb), abs=1e-10)
    # maximum principle: no filled value beyond the valid ones
    assert h[~m].min() - 1e-12 <= f[m].min() and f[m].max() <= h[~m].max() + 1e-12


def test_nearest_fill_equals_brute_force() -> None:
    rng = np.random.default_rng(8)
    h = rng.standard_normal((11, 7))
    m = rng.random(h.shape) < 0.5
    f = fill_missing(h, m, "nearest")
    vi, vj = np.nonzero(~m)
    for i, j in zip(*np.nonzero(m)):
        d = (vi - i) ** 2 + (vj - j) ** 2
        assert (f[i, j] == h[vi, vj][d == d.min()]).any()
    np.testing.assert_array_equal(f[~m], h[~m])


# ------------------------------------------------------------------------------------- files and load()


@pytest.fixture
def st():
    return pytest.importorskip("SurfaceTopography")


def _masked_file(st, path: Path, unit: str = "um", seed: int = 3) -> tuple[np.ndarray, np.ndarray]:
    """A 40 x 30 map with a hole inside and two undefined columns at an edge, written by SurfaceTopography."""
    rng = np.random.default_rng(seed)
    h = rng.standard_normal((40, 30))
    m = np.zeros(h.shape, bool)
    m[5:12, 3:9] = True
    m[:, 28:] = True
    st.Topography(np.ma.masked_array(h, m), physical_sizes=(4.0, 3.0), unit=unit, periodic=False).to_netcdf(
        str(path))
    return h, m


def test_masked_file_refused_with_count_and_where(st, tmp_path) -> None:
    _, m = _masked_file(st, tmp_path / "m.nc")
    with pytest.raises(ValueError) as e:
        load(tmp_path / "m.nc")
    msg = str(e.value)
    assert f"{int(m.sum())} of 1200 pixels" in msg and "10.2 %" in msg
    assert "bounding box of the missing pixels: x 0..39, y 3..29" in msg
    assert "columns (y) wholly missing: 2 (28..29)" in msg
    assert "largest valid rectangle: x 12..39, y 0..27 (28 x 28" in msg
    assert "missing='crop'" in msg and "fill_harmonic" in msg
    # the character map: the hole and the two missing columns
    rows = [ln.strip() for ln in msg.splitlines() if set(ln.strip()) <= set(".#+") and ln.strip()]
    assert len(rows) == 14 and all(r.endswith("##") for r in rows) and "######" in rows[2]
    # NaN in a plain array is missing data too, with the same report
    h = np.ones((6, 5))
    h[2, 3] = np.nan
    np.save(tmp_path / "n.npy", h)
    with pytest.raises(ValueError, match=r"(?s)1 of 30 pixels .*bounding box of the missing pixels: x 2..2, y 3..3"):
        load(tmp_path / "n.npy", length=1.0)


def test_masked_file_cropped_to_largest_valid_rectangle(st, tmp_path) -> None:
    h, m = _masked_file(st, tmp_path / "m.nc")
    t = load(tmp_path / "m.nc", missing="crop", detrend="none")
    x0, x1, y0, y1 = t.crop
    # brute force over every block of the 40 x 30 grid (summed-area table: a block is valid where it sums to 0)
    s = np.zeros((41, 31), dtype=np.int64)
    s[1:, 1:] = np.cumsum(np.cumsum(m, 0), 1)
    best = max((a1 - a0) * (b1 - b0) for a0, a1 in itertools.combinations(range(41), 2)
               for b0, b1 in itertools.combinations(range(31), 2)
               if s[a1, b1] - s[a0, b1] - s[a1, b0] + s[a0, b0] == 0)
    assert (x1 - x0) * (y1 - y0) == best
    assert (x1 - x0, y1 - y0) == (28, 28) and not m[x0:x1, y0:y1].any()
    np.testing.assert_array_equal(t.heights, h[x0:x1, y0:y1])
    assert t.length == pytest.approx((4.0 * 28 / 40, 3.0 * 28 / 30)) and t.unit == "um"
    assert t.missing == "crop" and t.missing_pixels == int(m.sum()) and t.file_shape == (40, 30)
    assert t.missing_fraction == pytest.approx(m.sum() / m.size)


def test_masked_file_filled(st, tmp_path) -> None:
    h, m = _masked_file(st, tmp_path / "m.nc")
    for method in ("harmonic", "nearest"):
        t = load(tmp_path / "m.nc", missing=f"fill_{method}", detrend="none")
        assert t.shape == (40, 30) and t.missing == f"fill_{method}" and t.crop is None
        np.testing.assert_array_equal(t.heights[~m], h[~m])
        np.testing.assert_allclose(t.heights, fill_missing(np.where(m, 0.0, h), m, method), rtol=0, atol=1e-12)
    with pytest.raises(ValueError, match=r"missing must be one of 'refuse', 'crop', 'fill_harmonic'"):
        load(tmp_path / "m.nc", missing="fill")


def test_units_of_a_surfacetopography_file(st, tmp_path) -> None:
    h, m = _masked_file(st, tmp_path / "nm.nc", unit="nm")
    t = load(tmp_path / "nm.nc", missing="fill_harmonic", detrend="none", to_unit="um")
    assert t.unit == "um" and t.length == pytest.approx((4e-3, 3e-3))
    np.testing.assert_allclose(t.heights[~m], h[~m] * 1e-3, rtol=1e-15)


def test_multi_channel_file(st, tmp_path) -> None:
    scipy_io = pytest.importorskip("scipy.io")
    rng = np.random.default_rng(1)
    a, b = rng.standard_normal((12, 10)), rng.standard_normal((12, 10))
    scipy_io.savemat(tmp_path / "two.mat", {"height": a, "amplitude": b})
    with pytest.raises(ValueError, match=r"holds 2 channels \(0: 'height', 1: 'amplitude'\); choose one with "
                                         r"channel="):
        load(tmp_path / "two.mat", length=1.0)
    by_name = load(tmp_path / "two.mat", length=1.0, channel="amplitude", detrend="none")
    by_index = load(tmp_path / "two.mat", length=1.0, channel=0, detrend="none")
    assert by_name.channel == "amplitude" and by_index.channel == "height"
    np.testing.assert_array_equal(by_name.heights, b)
    np.testing.assert_array_equal(by_index.heights, a)
    with pytest.raises(ValueError, match=r"no channel 'phase' \(channel\); its channels are 0: 'height'"):
        load(tmp_path / "two.mat", length=1.0, channel="phase")
    with pytest.raises(ValueError, match=r"channel must be an index 0..1"):
        load(tmp_path / "two.mat", length=1.0, channel=2)
    np.save(tmp_path / "one.npy", a)
    with pytest.raises(ValueError, match=r"channel= applies to files SurfaceTopography reads"):
        load(tmp_path / "one.npy", length=1.0, channel=0)


def test_repeated_channel_names_need_an_index(st, tmp_path, monkeypatch) -> None:
    """Instrument files repeat channel names (a Bruker .di holds 'Height' twice: trace and retrace): a name that
    is not unique is refused, naming the indices; the index reads the channel asked for. The reader stands in
    for such a file (SurfaceTopography writes none): two channels of a MATLAB file renamed alike."""
    scipy_io = pytest.importorskip("scipy.io")
    rng = np.random.default_rng(2)
    a, b = rng.standard_normal((8, 6)), rng.standard_normal((8, 6))
    scipy_io.savemat(tmp_path / "two.mat", {"h1": a, "h2": b})
    real = st.open_topography

    class Renamed:  # the real reader, its channels listed under one name
        def __init__(self, reader):
            self._reader = reader
            self.channels = [copy.copy(c) for c in reader.channels]
            for c in self.channels:
                c._name = "Height"

        def topography(self, **kw):
            return self._reader.topography(**kw)

    def renamed(path, *args, **kwargs):
        return Renamed(real(path, *args, **kwargs))

    monkeypatch.setattr(st, "open_topography", renamed)
    assert [c.name for c in st.open_topography(str(tmp_path / "two.mat")).channels] == ["Height", "Height"]
    with pytest.raises(ValueError, match=r"several channels are named 'Height' \(indices 0, 1\); choose one by "
                                         r"its index"):
        load(tmp_path / "two.mat", length=1.0, channel="Height")
    np.testing.assert_array_equal(load(tmp_path / "two.mat", length=1.0, channel=1, detrend="none").heights, b)


# ------------------------------------------------------------------------------------------------ sweep


JOB = """
[job]
name = "masked"
[grid]
sigma0 = [1e-2]
[surface]
kind = "file"
path = "m.nc"
{extra}
[interaction]
kind = "hard_wall"
[material]
e_star = 10.0
[methods.gfmd]
tol = 1e-8
backend = "numpy"
"""


def _job(tmp_path: Path, extra: str) -> Path:
    p = tmp_path / "job.toml"
    p.write_text(JOB.format(extra=extra))
    return p


def test_sweep_keys_refuse_crop_fill_and_plan(st, tmp_path) -> None:
    from gapsweep import spec
    from gapsweep.sweep import runner

    h, _ = _masked_file(st, tmp_path / "m.nc")
    with pytest.raises(spec.SpecError, match=r"surface\.path: 'm.nc' does not load.*122 of 1200 pixels"):
        spec.load(_job(tmp_path, ""))
    with pytest.raises(spec.SpecError, match=r"surface\.missing: got 'fill', allowed values: 'refuse', 'crop'"):
        spec.load(_job(tmp_path, 'missing = "fill"'))
    with pytest.raises(spec.SpecError, match=r"surface\.channel: expected a channel index \(an integer >= 0\) "
                                             r"or a channel name"):
        spec.load(_job(tmp_path, 'missing = "crop"\nchannel = 1.5'))
    js = spec.load(_job(tmp_path, 'missing = "crop"'))
    assert js.surface["missing"] == "crop" and js.surface["length"] == pytest.approx(2.8)
    text = runner.plan(_job(tmp_path, 'missing = "crop"'))
    line = next(ln for ln in text.splitlines() if "height map 'm.nc'" in ln)
    assert "28 x 28 pixels, box 2.8 x 2.8 um" in line and "rms height" in line and "rms slope" in line
    crop = h[12:40, 0:28]
    assert f"rms height {np.std(crop - crop.mean()):.4g} um" in line
    info = text.splitlines()[text.splitlines().index(line) + 1]
    assert "122 missing pixels (10.2 %): cropped to the largest valid rectangle x 12..39, y 0..27" in info
    assert "boundaries periodic (from the map's edges: edge ratio" in info
    # a filling: its method in the task ids (a filled map is another surface) and in the store's record
    filled = spec.load(_job(tmp_path, 'missing = "fill_harmonic"\nperiodic = false'))
    assert filled.surface["missing"] == "fill_harmonic"
    out = tmp_path / "s.h5"
    runner.run(_job(tmp_path, 'missing = "fill_harmonic"\nperiodic = false'), out, progress="none", mpi="off")
    from gapsweep import store

    rec = json.loads(store.read_attrs(out)["surface_map"])
    assert rec["missing"] == "fill_harmonic" and rec["missing_pixels"] == 122 and rec["shape"] == [40, 30]
    assert rec["missing_fraction"] == pytest.approx(122 / 1200) and rec["periodic"] is False
    assert rec["periodic_from"] == "the job's surface.periodic" and rec["unit"] == "um"
    df = store.read(out)
    assert list(df.status) == ["done"]
    solved = topography.load(tmp_path / "m.nc", missing="fill_harmonic")
    assert rec["h_rms"] == pytest.approx(float(np.std(solved.heights)), rel=1e-12)


def test_filling_most_of_a_map_warns(tmp_path, caplog) -> None:
    """A map mostly undefined (an instrument file had 89 %) may be filled on request, but not silently."""
    h = np.random.default_rng(5).standard_normal((20, 16))
    h[:, 6:] = np.nan  # 62.5 % missing
    np.save(tmp_path / "strip.npy", h)
    with caplog.at_level("WARNING", logger="gapsweep.topography"):
        t = load(tmp_path / "strip.npy", length=1.0, missing="fill_harmonic")
    assert t.missing_fraction == pytest.approx(0.625)
    assert any("62.5 % of the map) filled (harmonic): most of what is solved is interpolation" in r.getMessage()
               for r in caplog.records if r.levelname == "WARNING")


def test_a_job_loads_its_map_once_per_file_state(tmp_path) -> None:
    """Validation, the store's record, the plan and the tasks read one map: a filling is computed once per file
    state and options (a second call gives equal heights in a fresh array), again after the file changed."""
    from gapsweep.sweep import filesurface

    h = np.random.default_rng(6).standard_normal((12, 10))
    h[3:6, 2:5] = np.nan
    np.save(tmp_path / "m.npy", h)
    surf = {"kind": "file", "path": "m.npy", "file_length": 1.0, "missing": "fill_harmonic", "detrend": "none"}
    calls = []
    real = topography.load

    def counted(*a, **k):
        calls.append(1)
        return real(*a, **k)

    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(topography, "load", counted)
        a = filesurface.load_file_surface(surf, tmp_path / "m.npy")
        b = filesurface.load_file_surface(surf, tmp_path / "m.npy")
        assert len(calls) == 1 and a.heights is not b.heights and np.array_equal(a.heights, b.heights)
        b.heights[0, 0] = 99.0  # a caller's change does not reach the kept map
        assert filesurface.load_file_surface(surf, tmp_path / "m.npy").heights[0, 0] == a.heights[0, 0]
        filesurface.load_file_surface({**surf, "missing": "fill_nearest"}, tmp_path / "m.npy")
        assert len(calls) == 2
        h[0, 0] = 5.0
        np.save(tmp_path / "m.npy", h)
        os.utime(tmp_path / "m.npy", ns=(1, 10**18))
        c = filesurface.load_file_surface(surf, tmp_path / "m.npy")
        assert len(calls) == 3 and c.heights[0, 0] == 5.0


def test_crop_of_a_periodic_file_is_decided_by_its_edges_and_tiny_crops_refused(st, tmp_path) -> None:
    """A file flagged periodic with a hole: its crop is no period of anything, so the file's flag no longer
    applies and the edges decide (a crop of a slope with a bump is not periodic); a mask leaving no 2 x 2 valid block
    is refused with the report. Rectangular, odd grid."""
    x, y = np.meshgrid(np.linspace(0, 1, 33), np.linspace(0, 1, 21), indexing="ij")
    h = 0.5 * x + np.exp(-((x - 0.3) ** 2 + (y - 0.6) ** 2) / 0.05)
    m = np.zeros(h.shape, bool)
    m[20:, :] = True
    st.Topography(np.ma.masked_array(h, m), physical_sizes=(3.3, 2.1), unit="nm", periodic=True).to_netcdf(
        str(tmp_path / "p.nc"))
    full = load(tmp_path / "p.nc", missing="fill_nearest")
    assert full.periodic and full.periodic_from == "the file's flag"
    t = load(tmp_path / "p.nc", missing="crop")
    assert t.crop == (0, 20, 0, 21) and t.length == pytest.approx((2.0, 2.1)) and t.unit == "nm"
    assert not t.periodic and t.periodic_from.startswith("from the map's edges")
    checker = np.zeros((6, 7))
    checker[::2, ::2] = np.nan
    checker[1::2, 1::2] = np.nan
    np.save(tmp_path / "c.npy", checker)
    with pytest.raises(ValueError, match=r"(?s)largest valid rectangle is \d x \d pixels: too small.*missing"):
        load(tmp_path / "c.npy", length=1.0, missing="crop")
