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

Refused with one line naming the problem: empty files, maps of one row or column (a profile), maps with NaN
or inf heights (missing data: no filling is done, because every filling invents roughness that the contact then
feels; crop the map to its valid part or fill it with your instrument's software first).

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

__all__ = ["UNITS", "Topography", "detrend", "load"]

#: unit name -> metres
UNITS: dict[str, float] = {"m": 1.0, "mm": 1e-3, "um": 1e-6, "nm": 1e-9, "A": 1e-10, "pm": 1e-12}
_ALIASES = {"\u00b5m": "um", "\u03bcm": "um", "\u00c5": "A", "\u212b": "A"}  # micro/mu signs, Angstrom signs
_TEXT = (".txt", ".dat", ".asc", ".csv", ".xyz_grid")
DETRENDS = ("none", "mean", "plane")
FORMATS = ("npy", "npz", "text", "xyz", "surfacetopography")
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


def _read_surfacetopography(path: Path) -> tuple[np.ndarray, tuple[float, float] | None, str | None, bool]:
    try:
        from SurfaceTopography import read_topography
    except ImportError as exc:
        raise ImportError(f"reading {path.suffix or path.name!r} files needs SurfaceTopography: "
                          "pip install 'gapsweep[topography]'") from exc
    topo = read_topography(str(path))
    if topo.dim != 2:
        raise ValueError(f"{path}: a 2-D height map is needed, the file holds a {topo.dim}-D topography")
    sizes = getattr(topo, "physical_sizes", None)
    return (np.asarray(topo.heights(), dtype=np.float64), tuple(sizes) if sizes is not None else None,
            getattr(topo, "unit", None), bool(getattr(topo, "is_periodic", False)))


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
         delimiter: str | None = None) -> Topography:
    """Read a height map (module docstring for formats, units, detrending) into a :class:`Topography`.

    ``length`` (Lx, Ly) or ``pixel_size`` (dx, dy), one of them unless the file states the size
    (SurfaceTopography formats); a number stands for both directions. ``unit``: the file's lateral unit and,
    unless ``height_unit`` is given, its height unit; ``to_unit``: the unit of the result (default ``unit``).
    ``periodic``: the caller's flag, else the file's own, else decided from the map's edges (module docstring).
    ``format``: one of :data:`FORMATS` (default from the suffix; text files of three columns are x,y,z points
    unless ``format="text"``). Raises ValueError naming the problem for a missing file, an empty file, a map
    that is not 2-D (at least 2 x 2), NaN or inf heights, scattered x,y,z points, or inconsistent sizes."""
    p = Path(path)
    if not p.is_file():
        raise FileNotFoundError(f"no such height map: {p}")
    if format is not None and format not in FORMATS:
        raise ValueError(f"format must be one of {', '.join(map(repr, FORMATS))}; got {format!r}")
    fmt = format or ("npy" if p.suffix.lower() == ".npy" else "npz" if p.suffix.lower() == ".npz"
                     else "xyz" if p.suffix.lower() == ".xyz" else "text" if p.suffix.lower() in _TEXT
                     else "surfacetopography")
    file_size = file_unit = None
    file_periodic = None
    file_pixel = None
    if fmt in ("npy", "npz"):
        h = _read_numpy(p, fmt, key)
    elif fmt in ("text", "xyz"):
        h = _read_text(p, delimiter)
        # Three columns and no explicit format="text": an x,y,z point list (a 3-wide height grid is rare).
        if h.size and (fmt == "xyz" or (format is None and h.shape[1] == 3)):
            if h.shape[1] != 3:
                raise ValueError(f"{p}: an x,y,z file needs exactly 3 columns, got {h.shape[1]}")
            if not np.all(np.isfinite(h[:, :2])):
                raise ValueError(f"{p}: x,y,z points: {int(np.sum(~np.isfinite(h[:, :2])))} x or y coordinates "
                                 "are NaN or inf")
            h, file_pixel = _grid_from_points(h, p)
            log.info("%s: x,y,z points on a regular %d x %d grid, pixel %g x %g", p, *h.shape, *file_pixel)
    else:  # surfacetopography (the format was validated above)
        h, file_size, file_unit, file_periodic = _read_surfacetopography(p)
    h = np.asarray(h)
    if h.size == 0:
        raise ValueError(f"{p}: the file holds no heights (empty)")
    if h.ndim != 2 or min(h.shape) < 2:
        raise ValueError(f"{p}: a 2-D height map of at least 2 x 2 points is needed, got shape {h.shape}"
                         + (" (a single profile?)" if h.ndim == 2 else ""))
    if not np.issubdtype(h.dtype, np.number) or np.iscomplexobj(h):
        raise ValueError(f"{p}: heights must be real numbers, got dtype {h.dtype}")
    h = h.astype(np.float64)
    finite = np.isfinite(h)
    if not np.any(finite):
        raise ValueError(f"{p}: all {h.size} heights are NaN or inf: no data")
    if not np.all(finite):
        raise ValueError(f"{p}: {int(np.sum(~finite))} of {h.size} heights are NaN or inf (missing data): "
                         "crop the map to its valid part or fill it first (gapsweep does not invent heights)")
    if unit is None and file_unit is not None:
        unit = file_unit
    unit, height_unit, to_unit = _canonical(unit), _canonical(height_unit), _canonical(to_unit)
    if length is not None and pixel_size is not None:
        raise ValueError("give length or pixel_size, not both")
    if file_pixel is not None and (length is not None or pixel_size is not None):
        raise ValueError(f"{p}: an x,y,z file states its own pixel size {file_pixel}: leave length= and "
                         "pixel_size= out")
    if file_pixel is not None:
        box = (file_pixel[0] * h.shape[0], file_pixel[1] * h.shape[1])
    elif length is not None:
        box = _pair(length, "length")
    elif pixel_size is not None:
        d = _pair(pixel_size, "pixel_size")
        box = (d[0] * h.shape[0], d[1] * h.shape[1])
    elif file_size is not None:
        box = _pair(file_size, "the file's physical size")
    else:
        raise ValueError(f"{p}: the file does not state its size: give length= or pixel_size=")
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
    if periodic is not None:
        is_periodic = bool(periodic)
    elif file_periodic is not None:
        is_periodic = bool(file_periodic)
    else:  # neither the file nor the caller says: the edges do (after detrending, so a tilt alone is not a jump)

        ratio = edge_ratio(h)
        is_periodic = ratio <= EDGE_RATIO_LIMIT
        log.info("%s: periodic=%s from the edges (edge ratio %.3g, limit %g)", p, is_periodic, ratio,
                 EDGE_RATIO_LIMIT)
    return Topography(h, box, to_unit if to_unit is not None else unit, is_periodic, str(p))
