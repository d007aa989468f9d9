"""Measured height maps (docs/gfmd.md, "Surfaces from data"): :func:`load` reads a topography from a file into a
:class:`Topography` (heights, box size, unit), converts units and detrends; ``gapsweep.surface.load`` is this
function.

Formats: ``.npy`` (one 2-D array), ``.npz`` (the array named ``key``, default the only one), plain text grids
(``.txt``, ``.dat``, ``.asc``, ``.csv``: one row per line, ``#`` comments, comma or whitespace separated), x,y,z
point lists (``.xyz``, or any text file of exactly three columns: one point ``x y z`` per line; the points must
fill a regular grid, in any order, whose spacing becomes the pixel size; scattered points are refused, and a
genuine ``N x 3`` height grid is read with ``format="text"``) and,
with the optional extra ``topography`` (``pip install gapsweep[topography]``), every format that
SurfaceTopography reads (``format="surfacetopography"``, chosen automatically for other extensions). Axis 0 of
the array is x, axis 1 is y (as everywhere in gapsweep).

Units: heights and lateral sizes share ``unit`` unless ``height_unit`` is given; ``to_unit`` converts both (names
in :data:`UNITS`, metres). The box is ``length = (Lx, Ly)`` or ``pixel_size * (nx, ny)``. Detrending: "mean"
(subtract the mean: only ``h - <h>`` matters for contact at fixed load), "plane" (least-squares plane
``a + b x + c y``; for measured maps with a tilt) or "none".

Refused with one line naming the problem: empty files, maps of one row or column (a profile).

Missing data (pixels the instrument did not measure: SurfaceTopography's masked pixels, NaN or inf) are refused
by default (``missing="refuse"``) with their count, fraction, bounding box, the rows and columns they fill and a
small character map of where they are (:func:`missing_report`), because every filling invents roughness that
the contact then feels. On request: ``missing="crop"`` keeps the largest rectangle of valid pixels
(:func:`largest_valid_rectangle`, exact); ``missing="fill_harmonic"`` fills them with the harmonic (Laplace)
interpolant of the valid pixels around them (the smoothest filling: no new roughness, minimal gradient energy,
:func:`fill_missing`); ``missing="fill_nearest"`` with the height of the nearest valid pixel. The result
records what was done (``Topography.missing_pixels``, ``.missing``, ``.crop``).

Channels: a file with several data channels (SurfaceTopography formats) needs ``channel=`` (its index or name;
the error lists them); a file of one channel takes it.

Periodicity: ``Topography.periodic`` is the file's own flag, else the caller's ``periodic=``, else decided from
the map's edges after detrending (``theory.spectrum.edge_ratio <= 3``: a measured map is almost never
periodic). ``gfmd.solve`` honours it (free boundaries for ``periodic=False``: docs/gfmd.md, "Periodic or free
boundaries"), and so does ``theory.spectrum.map_spectrum``. :meth:`Topography.padded` is the older,
approximate alternative (see its docstring)."""

from __future__ import annotations

import logging
import math
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

__all__ = ["MISSING", "UNITS", "Topography", "detrend", "fill_missing", "largest_valid_rectangle", "load",
           "missing_report"]

#: unit name -> metres
UNITS: dict[str, float] = {"m": 1.0, "mm": 1e-3, "um": 1e-6, "nm": 1e-9, "A": 1e-10, "pm": 1e-12}
_ALIASES = {"\u00b5m": "um", "\u03bcm": "um", "\u00c5": "A", "\u212b": "A"}  # micro/mu signs, Angstrom signs
_TEXT = (".txt", ".dat", ".asc", ".csv", ".xyz_grid")
DETRENDS = ("none", "mean", "plane")
FORMATS = ("npy", "npz", "text", "xyz", "surfacetopography")
MISSING = ("refuse", "crop", "fill_harmonic", "fill_nearest")  # what load does with undefined pixels
log = logging.getLogger("gapsweep.topography")


@dataclass
class Topography:
    """A height map: ``heights[ix, iy]`` (float64, ``unit``) on a box ``length = (Lx, Ly)`` (``unit``: the
    length unit of heights and box alike, a name of :data:`UNITS` or None for model units). ``periodic``:
    whether the map is one period of a periodic surface (False: a finite map, solved with free boundaries)."""

    heights: np.ndarray
    length: tuple[float, float]
    unit: str | None = None
    periodic: bool = True
    source: str = ""
    #: undefined pixels of the file's map (masked, NaN or inf) and what was done with them (one of
    #: :data:`MISSING`; "refuse" when there were none), the file's grid shape, the kept block of a crop
    #: ``(x0, x1, y0, y1)`` (half-open indices into the file's grid) and the channel read
    missing_pixels: int = 0
    missing: str = "refuse"
    file_shape: tuple[int, int] | None = None
    crop: tuple[int, int, int, int] | None = None
    channel: str | None = None
    #: how ``periodic`` was decided: "asked" (the caller's flag), "file" (the file's flag) or "edges (...)"
    periodic_from: str = ""

    @property
    def missing_fraction(self) -> float:
        """Undefined pixels over all pixels of the file's map."""
        shape = self.file_shape or self.shape
        return self.missing_pixels / float(shape[0] * shape[1])

    def rms_height(self) -> float:
        """rms of the heights as they are (after detrending and filling): ``sqrt(<(h - <h>)^2>)``, length unit."""
        return float(np.std(self.heights))

    def rms_slope(self) -> float:
        """rms slope of the map from finite differences, ``sqrt(<(dh/dx)^2> + <(dh/dy)^2>)`` (dimensionless):
        across the wrap-around edges for a periodic map, not across them for a free one."""
        h = self.heights
        dx, dy = self.pixel_size
        if self.periodic:
            gx, gy = (np.roll(h, -1, 0) - h) / dx, (np.roll(h, -1, 1) - h) / dy
        else:
            gx, gy = np.diff(h, axis=0) / dx, np.diff(h, axis=1) / dy
        return float(np.sqrt(np.mean(gx ** 2) + np.mean(gy ** 2)))

    @property
    def shape(self) -> tuple[int, int]:
        return (int(self.heights.shape[0]), int(self.heights.shape[1]))

    @property
    def pixel_size(self) -> tuple[float, float]:
        return (self.length[0] / self.shape[0], self.length[1] / self.shape[1])

    def padded(self, factor: int = 2) -> Topography:
        """The map embedded at the origin of a ``factor`` times larger periodic box, the rest filled with the
        lowest height (never in contact before the map itself is flattened).

        Prefer ``gfmd.solve(topography, ...)`` with ``periodic=False`` (exact free boundaries, same cost class).
        If you use this: the padded box has ``factor^2`` times the map's area and only the map carries load, so
        to put the map under the mean pressure ``sigma0`` pass ``sigma0 / factor**2`` (the same ``sigma0`` puts
        ``factor^2`` times the load on the map); and results such as ``mean_gap`` and ``contact_area`` describe
        the padded box: take them over ``result.gap[:nx, :ny]`` yourself. The periodic images still couple
        elastically (a ``1/distance`` interaction that falls as ``factor`` grows): free boundaries only
        approximately."""
        if isinstance(factor, bool) or not isinstance(factor, int) or factor < 2:
            raise ValueError(f"factor must be an integer >= 2, got {factor!r}")
        nx, ny = self.shape
        out = np.full((factor * nx, factor * ny), float(self.heights.min()))
        out[:nx, :ny] = self.heights
        return Topography(out, (factor * self.length[0], factor * self.length[1]), self.unit, True,
                          f"{self.source} (zero-padded x{factor})")


def detrend(heights: np.ndarray, mode: str = "mean", length: tuple[float, float] = (1.0, 1.0)) -> np.ndarray:
    """``heights`` minus its mean ("mean"), its least-squares plane ("plane"), or unchanged ("none")."""
    if mode not in DETRENDS:
        raise ValueError(f"detrend must be one of {', '.join(map(repr, DETRENDS))}; got {mode!r}")
    h = np.asarray(heights, dtype=np.float64)
    if mode == "none":
        return h.copy()
    if mode == "mean":
        return h - h.mean()
    nx, ny = h.shape
    x = (np.arange(nx) - (nx - 1) / 2) * (length[0] / nx)
    y = (np.arange(ny) - (ny - 1) / 2) * (length[1] / ny)
    # x and y centred on the grid are orthogonal to 1 and to each other: the fit separates.
    bx = float(np.einsum("i,ij->", x, h)) / (ny * float(x @ x)) if nx > 1 else 0.0
    by = float(np.einsum("j,ij->", y, h)) / (nx * float(y @ y)) if ny > 1 else 0.0
    return h - h.mean() - bx * x[:, None] - by * y[None, :]


def _pair(v: Any, name: str) -> tuple[float, float]:
    vals = tuple(v) if isinstance(v, (tuple, list, np.ndarray)) else (v, v)
    if len(vals) != 2:
        raise ValueError(f"{name} must be a number or a pair (x, y), got {v!r}")
    out = []
    for x in vals:
        if isinstance(x, bool) or not isinstance(x, (int, float, np.integer, np.floating)) or not (
                math.isfinite(float(x)) and float(x) > 0):
            raise ValueError(f"{name} must be finite and > 0, got {v!r}")
        out.append(float(x))
    return out[0], out[1]


def _canonical(name: str | None) -> str | None:
    return _ALIASES.get(name, name) if isinstance(name, str) else name


def _unit(name: str | None, what: str) -> float:
    name = _canonical(name)
    if name is None:
        return 1.0
    if name not in UNITS:
        raise ValueError(f"{what} must be one of {', '.join(UNITS)}; got {name!r}")
    return UNITS[name]


def _read_text(path: Path, delimiter: str | None) -> np.ndarray:
    if delimiter is None:
        delimiter = "," if path.suffix.lower() == ".csv" else None
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", UserWarning)  # numpy's "input contained no data": refused below
            return np.loadtxt(path, delimiter=delimiter, comments="#", ndmin=2, dtype=np.float64)
    except ValueError as exc:
        raise ValueError(f"{path}: not a grid of numbers ({exc})") from exc


def _axis(values: np.ndarray, name: str, path: Path) -> tuple[np.ndarray, float]:
    """Index of every point along one axis of a regular grid and the spacing (ValueError if not regular)."""
    u = np.unique(values)
    if u.size < 2:
        raise ValueError(f"{path}: x,y,z points: all {name} are equal; a height map needs >= 2 points per axis")
    step = float(np.median(np.diff(u)))
    idx = np.rint((values - u[0]) / step)
    # Coordinates are written with finitely many digits: allow 1e-6 of a pixel.
    if not np.allclose(idx * step + u[0], values, rtol=0, atol=1e-6 * step) or int(idx.max()) + 1 != u.size:
        raise ValueError(f"{path}: x,y,z points are not on a regular grid ({name} values are not equally spaced); "
                         "scattered points must be interpolated onto a grid first")
    return idx.astype(np.int64), step


def _grid_from_points(xyz: np.ndarray, path: Path) -> tuple[np.ndarray, tuple[float, float]]:
    """``(heights[ix, iy], (dx, dy))`` of x,y,z points that fill a regular grid, in any order."""
    ix, dx = _axis(xyz[:, 0], "x", path)
    iy, dy = _axis(xyz[:, 1], "y", path)
    nx, ny = int(ix.max()) + 1, int(iy.max()) + 1
    count = np.zeros((nx, ny), dtype=np.int64)
    np.add.at(count, (ix, iy), 1)
    if np.any(count != 1):
        raise ValueError(f"{path}: x,y,z points do not fill a regular {nx} x {ny} grid once each "
                         f"({int(np.sum(count == 0))} grid points missing, {int(np.sum(count > 1))} repeated)")
    h = np.empty((nx, ny))
    h[ix, iy] = xyz[:, 2]
    return h, (dx, dy)


def _read_numpy(path: Path, fmt: str, key: str | None) -> np.ndarray:
    """A ``.npy`` array or one ``.npz`` member; an empty, truncated or foreign file or a missing key is a
    ValueError naming the file (numpy raises EOFError, BadZipFile or KeyError, which read as tracebacks)."""
    import zipfile

    try:
        if fmt == "npy":
            return np.load(path, allow_pickle=False)
        with np.load(path, allow_pickle=False) as z:
            names = list(z.keys())
            if key is None and len(names) != 1:
                raise ValueError(f"{path}: holds {names}; pass key= to choose the height map")
            if key is not None and key not in names:
                raise ValueError(f"{path}: has no array {key!r} (key); it holds {names}")
            return z[key if key is not None else names[0]]
    except (EOFError, OSError, zipfile.BadZipFile, UnicodeError) as e:
        what = "empty (0 bytes)" if path.stat().st_size == 0 else f"unreadable ({type(e).__name__}: {e})"
        raise ValueError(f"{path}: not a .{fmt} file: {what}") from None
    except ValueError as e:
        if str(e).startswith(str(path)):
            raise
        raise ValueError(f"{path}: not a readable .{fmt} file ({e})") from None


def _read_surfacetopography(path: Path, channel: int | str | None
                            ) -> tuple[np.ndarray, tuple[float, float] | None, str | None, bool, str | None]:
    """Heights (a masked array where the file marks undefined pixels), physical size, unit, periodic flag and
    channel name of one channel of a file SurfaceTopography reads."""
    try:
        from SurfaceTopography import open_topography
    except ImportError as exc:
        raise ImportError(f"reading {path.suffix or path.name!r} files needs SurfaceTopography: "
                          "pip install 'gapsweep[topography]'") from exc
    reader = open_topography(str(path))
    channels = list(reader.channels)
    names = [str(c.name) for c in channels]
    listing = ", ".join(f"{i}: {n!r}" for i, n in enumerate(names))
    if channel is None:
        if len(channels) > 1:
            raise ValueError(f"{path}: holds {len(channels)} channels ({listing}); choose one with channel= "
                             "(its index or name)")
        index = 0
    elif isinstance(channel, str):
        if channel not in names:
            raise ValueError(f"{path}: has no channel {channel!r} (channel); its channels are {listing}")
        if names.count(channel) > 1:  # instruments repeat names (e.g. trace and retrace "Height")
            same = ", ".join(str(i) for i, n in enumerate(names) if n == channel)
            raise ValueError(f"{path}: several channels are named {channel!r} (indices {same}); choose one by its "
                             f"index with channel=; its channels are {listing}")
        index = names.index(channel)
    else:
        if isinstance(channel, bool) or not 0 <= int(channel) < len(channels):
            raise ValueError(f"{path}: channel must be an index 0..{len(channels) - 1} or a name; its channels are "
                             f"{listing}; got {channel!r}")
        index = int(channel)
    info = channels[index]
    if getattr(info, "dim", 2) != 2:
        raise ValueError(f"{path}: channel {names[index]!r}: a 2-D height map is needed, it holds a "
                         f"{info.dim}-D topography")
    kw: dict[str, Any] = {"channel_index": index}
    if getattr(info, "physical_sizes", None) is None:
        kw["physical_sizes"] = (1.0, 1.0)  # a placeholder the reader demands: the caller's length= decides
    with warnings.catch_warnings():  # scipy's netCDF reader warns that it cannot unmap while arrays are alive
        warnings.filterwarnings("ignore", "Cannot close a netcdf_file", RuntimeWarning)
        topo = reader.topography(**kw)
        h = topo.heights()
        h = np.ma.masked_array(np.array(h.data, dtype=np.float64), np.ma.getmaskarray(h).copy()) \
            if np.ma.isMaskedArray(h) else np.array(h, dtype=np.float64)
        if hasattr(reader, "close"):
            reader.close()
    if topo.dim != 2:
        raise ValueError(f"{path}: a 2-D height map is needed, the file holds a {topo.dim}-D topography")
    sizes = getattr(info, "physical_sizes", None)
    return (h, tuple(float(x) for x in sizes) if sizes is not None else None, getattr(topo, "unit", None),
            bool(getattr(topo, "is_periodic", False)), names[index])


def largest_valid_rectangle(valid: Any) -> tuple[int, int, int, int]:
    """The largest axis-aligned block of True pixels of a 2-D boolean array, as half-open index ranges
    ``(x0, x1, y0, y1)`` (``valid[x0:x1, y0:y1]`` all True; the first of equal areas in row-major order of its
    bottom-right corner). Exact: the maximal rectangle under each row's histogram of consecutive True pixels,
    with a stack (O(nx ny)). ``(0, 0, 0, 0)`` when no pixel is valid."""
    v = np.asarray(valid, dtype=bool)
    if v.ndim != 2:
        raise ValueError(f"valid must be a 2-D array, got shape {v.shape}")
    nx, ny = v.shape
    heights = np.zeros(ny + 1, dtype=np.int64)  # a sentinel 0 at the end flushes the stack
    best = (0, 0, 0, 0, 0)  # area, x0, x1, y0, y1
    for i in range(nx):
        heights[:ny] = np.where(v[i], heights[:ny] + 1, 0)
        stack: list[int] = []
        for j in range(ny + 1):
            while stack and heights[stack[-1]] >= heights[j]:
                hgt = int(heights[stack.pop()])
                left = stack[-1] + 1 if stack else 0
                area = hgt * (j - left)
                if area > best[0]:
                    best = (area, i + 1 - hgt, i + 1, left, j)
            stack.append(j)
    return best[1], best[2], best[3], best[4]


def fill_missing(heights: Any, missing: Any, method: str = "harmonic") -> np.ndarray:
    """``heights`` with its ``missing`` pixels (boolean mask) filled; the valid pixels are kept bit for bit.

    "harmonic": the discrete Laplace equation ``sum_j (h_i - h_j) = 0`` over the 4 neighbours ``j`` inside the
    map of every missing pixel ``i`` (neighbours outside the map are left out: zero normal derivative at the
    map's border), the valid pixels fixed (Dirichlet data); the solution is the harmonic
    interpolant, the filling of least gradient energy ``sum (grad h)^2`` (no roughness of its own; docs/gfmd.md
    "Surfaces from data"). Solved exactly (sparse LU). "nearest": the height of the nearest valid pixel
    (Euclidean distance in pixels)."""
    h = np.array(heights, dtype=np.float64)
    m = np.asarray(missing, dtype=bool)
    if m.shape != h.shape:
        raise ValueError(f"missing mask of shape {m.shape} for heights of shape {h.shape}")
    if not m.any():
        return h
    if m.all():
        raise ValueError("every pixel is missing: nothing to fill from")
    if method == "nearest":
        from scipy import ndimage

        idx = ndimage.distance_transform_edt(m, return_distances=False, return_indices=True)
        return h[tuple(idx)]
    if method != "harmonic":
        raise ValueError(f"method must be 'harmonic' or 'nearest', got {method!r}")
    from scipy import sparse
    from scipy.sparse.linalg import spsolve

    nx, ny = h.shape
    number = -np.ones(h.shape, dtype=np.int64)
    number[m] = np.arange(int(m.sum()))
    xi, yi = np.nonzero(m)
    rows, cols, vals = [], [], []
    diag = np.zeros(xi.size)
    rhs = np.zeros(xi.size)
    k = number[xi, yi]
    for ox, oy in ((1, 0), (-1, 0), (0, 1), (0, -1)):
        x2, y2 = xi + ox, yi + oy
        inside = (x2 >= 0) & (x2 < nx) & (y2 >= 0) & (y2 < ny)
        diag[inside] += 1.0
        kk, xx, yy = k[inside], x2[inside], y2[inside]
        nb = number[xx, yy]
        unknown = nb >= 0
        rows.append(kk[unknown])
        cols.append(nb[unknown])
        vals.append(-np.ones(int(unknown.sum())))
        np.add.at(rhs, kk[~unknown], h[xx[~unknown], yy[~unknown]])
    a = sparse.csr_matrix((np.concatenate([diag, *vals]),
                           (np.concatenate([k, *rows]), np.concatenate([k, *cols]))), shape=(xi.size, xi.size))
    # every connected region of missing pixels touches a valid one (the grid is connected): a is positive definite
    h[xi, yi] = spsolve(a.tocsc(), rhs)
    return h


def missing_report(missing: Any, width: int = 48, height: int = 16) -> str:
    """A few lines saying where the ``missing`` pixels (boolean mask, axis 0 = x) of a map are: count and
    fraction, bounding box, rows and columns wholly missing, the largest valid rectangle, and a character map
    of at most ``height`` x ``width`` cells ('#' all missing, '+' partly, '.' none), x down and y across."""
    m = np.asarray(missing, dtype=bool)
    nx, ny = m.shape
    count = int(m.sum())
    xs, ys = np.nonzero(m)
    lines = [f"{count} of {m.size} pixels ({100 * count / m.size:.3g} %) are missing (undefined: masked, NaN or inf)"]
    if count:
        lines.append(f"  bounding box of the missing pixels: x {xs.min()}..{xs.max()}, y {ys.min()}..{ys.max()} "
                     f"(indices of the {nx} x {ny} grid, axis 0 = x)")
        full_x, full_y = np.flatnonzero(m.all(axis=1)), np.flatnonzero(m.all(axis=0))
        lines.append(f"  rows (x) wholly missing: {_ranges(full_x)}; columns (y) wholly missing: {_ranges(full_y)}; "
                     f"rows with a missing pixel: {int(np.count_nonzero(m.any(axis=1)))} of {nx}")
        x0, x1, y0, y1 = largest_valid_rectangle(~m)
        lines.append(f"  largest valid rectangle: x {x0}..{x1 - 1}, y {y0}..{y1 - 1} ({x1 - x0} x {y1 - y0}, "
                     f"{100 * (x1 - x0) * (y1 - y0) / m.size:.3g} % of the map)" if x1 > x0 else
                     "  no valid rectangle")
        bx, by = -(-nx // min(nx, height)), -(-ny // min(ny, width))  # pixels per cell (ceil)
        lines.append(f"  where (x down, y across; one character = {bx} x {by} pixels; '#' all missing, '+' some, "
                     "'.' none):")
        for i in range(0, nx, bx):
            cells = []
            for j in range(0, ny, by):
                blk = m[i:i + bx, j:j + by]
                cells.append("#" if blk.all() else "+" if blk.any() else ".")
            lines.append("    " + "".join(cells))
    return "\n".join(lines)


def _ranges(idx: np.ndarray) -> str:
    """``[0, 1, 2, 7]`` -> "4 (0..2, 7)"; "none" when empty."""
    if idx.size == 0:
        return "none"
    parts, start, prev = [], int(idx[0]), int(idx[0])
    for v in idx[1:]:
        if int(v) != prev + 1:
            parts.append(f"{start}..{prev}" if prev > start else f"{start}")
            start = int(v)
        prev = int(v)
    parts.append(f"{start}..{prev}" if prev > start else f"{start}")
    shown = ", ".join(parts[:6]) + (", ..." if len(parts) > 6 else "")
    return f"{idx.size} ({shown})"


EDGE_RATIO_LIMIT = 3.0  # edge_ratio above this: not one period of a periodic surface


def edge_ratio(heights: Any) -> float:
    """How far a map is from periodic (dimensionless): the rms height difference across the wrap-around edges
    (``h[0] - h[-1]`` and ``h[:, 0] - h[:, -1]``) over the rms difference of interior neighbours, the larger of
    the two directions. About 1 for one period of a periodic surface; ``h_rms/(g_rms dx)`` for a crop; a tilt
    adds its full rise. 1.0 for a flat map."""
    h = np.asarray(heights, dtype=float)
    out = 1.0
    for axis in (0, 1):
        inner = float(np.sqrt(np.mean(np.diff(h, axis=axis) ** 2)))
        wrap = float(np.sqrt(np.mean((np.take(h, 0, axis=axis) - np.take(h, -1, axis=axis)) ** 2)))
        if inner > 0:
            out = max(out, wrap / inner)
        elif wrap > 0:
            out = math.inf
    return out


def load(path: str | Path, *, length: Any = None, pixel_size: Any = None, unit: str | None = None,
         height_unit: str | None = None, to_unit: str | None = None, detrend: str = "mean",
         periodic: bool | None = None, format: str | None = None, key: str | None = None,
         delimiter: str | None = None, missing: str = "refuse", channel: int | str | None = None) -> Topography:
    """Read a height map (module docstring for formats, units, detrending) into a :class:`Topography`.

    ``length`` (Lx, Ly) or ``pixel_size`` (dx, dy), one of them unless the file states the size
    (SurfaceTopography formats); a number stands for both directions. ``unit``: the file's lateral unit and,
    unless ``height_unit`` is given, its height unit; ``to_unit``: the unit of the result (default ``unit``).
    ``periodic``: the caller's flag, else the file's own, else decided from the map's edges (module docstring).
    ``format``: one of :data:`FORMATS` (default from the suffix; text files of three columns are x,y,z points
    unless ``format="text"``). ``missing``: what to do with undefined pixels (masked, NaN or inf), one of
    :data:`MISSING` (module docstring). ``channel``: the channel of a multi-channel file (index or name).
    Raises ValueError naming the problem for a missing file, an empty file, a map that is not 2-D (at least
    2 x 2), undefined pixels under ``missing="refuse"`` (with :func:`missing_report`), scattered x,y,z points,
    or inconsistent sizes."""
    p = Path(path)
    if not p.is_file():
        raise FileNotFoundError(f"no such height map: {p}")
    if format is not None and format not in FORMATS:
        raise ValueError(f"format must be one of {', '.join(map(repr, FORMATS))}; got {format!r}")
    if missing not in MISSING:
        raise ValueError(f"missing must be one of {', '.join(map(repr, MISSING))}; got {missing!r}")
    fmt = _format_of(p, format)
    if channel is not None and fmt != "surfacetopography":
        raise ValueError(f"{p}: channel= applies to files SurfaceTopography reads (format 'surfacetopography')"
                         + ("; choose an .npz member with key=" if fmt == "npz" else ""))
    raw = _read_file(p, fmt, explicit=format is not None, key=key, delimiter=delimiter, channel=channel)
    h, undefined = _height_grid(p, raw.heights)
    file_shape = (int(h.shape[0]), int(h.shape[1]))
    h, n_missing, crop = _treat_missing(p, h, undefined, missing)
    if unit is None and raw.unit is not None:
        unit = raw.unit
    unit, height_unit, to_unit = _canonical(unit), _canonical(height_unit), _canonical(to_unit)
    box = _file_box(p, file_shape, length=length, pixel_size=pixel_size, file_pixel=raw.pixel, file_size=raw.size)
    if crop is not None:
        box = (box[0] * h.shape[0] / file_shape[0], box[1] * h.shape[1] / file_shape[1])
    lateral = _unit(unit, "unit")
    vertical = _unit(height_unit if height_unit is not None else unit, "height_unit")
    target = _unit(to_unit if to_unit is not None else unit, "to_unit")
    if to_unit is not None and unit is None:
        raise ValueError("to_unit needs the file's unit: give unit=")
    with np.errstate(over="ignore"):  # an overflow is refused just below, in one line
        h = h * (vertical / target)
    if not np.all(np.isfinite(h)):
        raise ValueError(f"heights not finite after converting {height_unit or unit} to {to_unit or unit} "
                         "(float64 overflow): choose another to_unit")
    box = (box[0] * lateral / target, box[1] * lateral / target)
    h = globals()["detrend"](h, detrend, box)
    is_periodic, decided = _decide_periodic(p, h, periodic, raw.periodic if crop is None else None)
    done = missing if n_missing else "refuse"
    return Topography(h, box, to_unit if to_unit is not None else unit, is_periodic, str(p), n_missing, done,
                      file_shape, crop, raw.channel, decided)


def _format_of(p: Path, format: str | None) -> str:
    """The reader of a file: ``format`` when given, else from the suffix (SurfaceTopography for the others)."""
    if format is not None:
        return format
    suffix = p.suffix.lower()
    if suffix in (".npy", ".npz", ".xyz"):
        return suffix[1:]
    return "text" if suffix in _TEXT else "surfacetopography"


@dataclass
class _Raw:
    """What a reader found in a file: the heights as read (maybe masked) and what the file states itself
    (physical size, lateral unit, periodic flag, pixel size of x,y,z points, channel name), None where silent."""

    heights: Any
    size: Any = None
    unit: str | None = None
    periodic: bool | None = None
    pixel: tuple[float, float] | None = None
    channel: str | None = None


def _read_file(p: Path, fmt: str, *, explicit: bool, key: str | None, delimiter: str | None,
               channel: int | str | None) -> _Raw:
    """Read a file with the reader of ``fmt``; a text file of three columns is an x,y,z point list unless the
    format was given as "text" (``explicit``)."""
    if fmt in ("npy", "npz"):
        return _Raw(_read_numpy(p, fmt, key))
    if fmt in ("text", "xyz"):
        h = _read_text(p, delimiter)
        # Three columns and no explicit format="text": an x,y,z point list (a 3-wide height grid is rare).
        if h.size and (fmt == "xyz" or (not explicit and h.shape[1] == 3)):
            if h.shape[1] != 3:
                raise ValueError(f"{p}: an x,y,z file needs exactly 3 columns, got {h.shape[1]}")
            if not np.all(np.isfinite(h[:, :2])):
                raise ValueError(f"{p}: x,y,z points: {int(np.sum(~np.isfinite(h[:, :2])))} x or y coordinates "
                                 "are NaN or inf")
            h, pixel = _grid_from_points(h, p)
            log.info("%s: x,y,z points on a regular %d x %d grid, pixel %g x %g", p, *h.shape, *pixel)
            return _Raw(h, pixel=pixel)
        return _Raw(h)
    # surfacetopography (the format was validated by the caller)
    h, size, unit, periodic, channel_name = _read_surfacetopography(p, channel)
    return _Raw(h, size=size, unit=unit, periodic=periodic, channel=channel_name)


def _height_grid(p: Path, h: Any) -> tuple[np.ndarray, np.ndarray]:
    """The heights as a float64 grid of at least 2 x 2 and the mask of its undefined pixels (masked, NaN or
    inf); refuses an empty file, a non-2-D map, non-real values and a map without any defined height."""
    mask = np.ma.getmaskarray(h) if np.ma.isMaskedArray(h) else None
    h = np.asarray(h.data if np.ma.isMaskedArray(h) else h)
    if h.size == 0:
        raise ValueError(f"{p}: the file holds no heights (empty)")
    if h.ndim != 2 or min(h.shape) < 2:
        raise ValueError(f"{p}: a 2-D height map of at least 2 x 2 points is needed, got shape {h.shape}"
                         + (" (a single profile?)" if h.ndim == 2 else ""))
    if not np.issubdtype(h.dtype, np.number) or np.iscomplexobj(h):
        raise ValueError(f"{p}: heights must be real numbers, got dtype {h.dtype}")
    h = h.astype(np.float64)
    undefined = ~np.isfinite(h)
    if mask is not None:
        undefined |= mask
    if int(undefined.sum()) == h.size:
        raise ValueError(f"{p}: all {h.size} heights are undefined (masked, NaN or inf): no data")
    return h, undefined


def _treat_missing(p: Path, h: np.ndarray, undefined: np.ndarray, missing: str,
                   ) -> tuple[np.ndarray, int, tuple[int, int, int, int] | None]:
    """Apply the ``missing`` policy (module docstring): ``(heights, number of undefined pixels, crop)``; crop is
    ``(x0, x1, y0, y1)`` of the largest valid rectangle under ``missing="crop"``, else None."""
    n_missing = int(undefined.sum())
    if not n_missing:
        return h, 0, None
    if missing == "refuse":
        raise ValueError(f"{p}: {missing_report(undefined)}\n  gapsweep does not invent heights: crop the map "
                         "to its largest valid rectangle (missing='crop') or fill it (missing='fill_harmonic': "
                         "the harmonic interpolant, or 'fill_nearest'), or fix it in your instrument's software")
    if missing == "crop":
        x0, x1, y0, y1 = largest_valid_rectangle(~undefined)
        if x1 - x0 < 2 or y1 - y0 < 2:
            raise ValueError(f"{p}: the largest valid rectangle is {x1 - x0} x {y1 - y0} pixels: too small to crop "
                             f"to (at least 2 x 2)\n{missing_report(undefined)}")
        log.info("%s: %d missing pixels: cropped to x %d..%d, y %d..%d (%d x %d)", p, n_missing, x0, x1 - 1, y0,
                 y1 - 1, x1 - x0, y1 - y0)
        return h[x0:x1, y0:y1].copy(), n_missing, (x0, x1, y0, y1)
    method = missing.split("_", 1)[1]
    h = fill_missing(np.where(undefined, 0.0, h), undefined, method)
    frac = n_missing / h.size
    (log.warning if frac > 0.25 else log.info)(
        "%s: %d missing pixels (%.3g %% of the map) filled (%s)%s", p, n_missing, 100 * frac, method,
        ": most of what is solved is interpolation, not measurement" if frac > 0.5 else "")
    return h, n_missing, None


def _file_box(p: Path, file_shape: tuple[int, int], *, length: Any, pixel_size: Any,
              file_pixel: tuple[float, float] | None, file_size: Any) -> tuple[float, float]:
    """The box (Lx, Ly) of the file's whole grid, in the file's lateral unit: from the x,y,z points' pixel,
    ``length``, ``pixel_size`` or the file's stated size (one source only)."""
    if length is not None and pixel_size is not None:
        raise ValueError("give length or pixel_size, not both")
    if file_pixel is not None and (length is not None or pixel_size is not None):
        raise ValueError(f"{p}: an x,y,z file states its own pixel size {file_pixel}: leave length= and "
                         "pixel_size= out")
    if file_pixel is not None:
        return (file_pixel[0] * file_shape[0], file_pixel[1] * file_shape[1])
    if length is not None:
        return _pair(length, "length")
    if pixel_size is not None:
        d = _pair(pixel_size, "pixel_size")
        return (d[0] * file_shape[0], d[1] * file_shape[1])
    if file_size is not None:
        return _pair(file_size, "the file's physical size")
    raise ValueError(f"{p}: the file does not state its size: give length= or pixel_size=")


def _decide_periodic(p: Path, h: np.ndarray, periodic: bool | None, file_periodic: bool | None,
                     ) -> tuple[bool, str]:
    """``(periodic, how it was decided)``: the caller's flag, else the file's own (None for a crop: a crop of a
    periodic map is no period), else from the detrended map's edges (so a tilt alone is not a jump)."""
    if periodic is not None:
        return bool(periodic), "asked"
    if file_periodic is not None:
        return bool(file_periodic), "the file's flag"
    ratio = edge_ratio(h)
    is_periodic = ratio <= EDGE_RATIO_LIMIT
    log.info("%s: periodic=%s from the edges (edge ratio %.3g, limit %g)", p, is_periodic, ratio, EDGE_RATIO_LIMIT)
    return is_periodic, f"from the map's edges: edge ratio {ratio:.3g}, periodic up to {EDGE_RATIO_LIMIT:g}"
