"""Height maps from files as job surfaces (``[surface] kind = "file"``, docs/jobs.md): validation of the
keys, loading once at validation, and the content key by which tasks find the map again.

The map's SHA-256 enters the task ids (a changed file changes them), its path does not (a moved job still
resumes). Loading itself is physics-side (gapsweep.surfaces.topography); this module only checks the spec's
keys and keeps the path of each validated map for the tasks of this process.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import math
from pathlib import Path
from typing import Any

import numpy as np

from gapsweep.surfaces import topography
from gapsweep.sweep import readers as rd
from gapsweep.sweep.schema import SpecError

__all__ = ["FILE_KEYS", "describe", "file_surface", "file_surface_heights", "length_unit", "load_file_surface",
           "map_record", "surface_map_attr"]


FILE_KEYS = ("kind", "path", "format", "key", "delimiter", "unit", "height_unit", "to_unit", "length",
              "pixel_size", "detrend", "periodic", "missing", "channel")


# Bounds of a map's box or pixel size in its unit (issue 31: pixel_size = 1e-308 with detrend = "plane" gave a
# traceback from the plane fit): wide enough for any unit from pm to km.
MIN_SIZE, MAX_SIZE = 1e-15, 1e15


def _pair_or_num(key: str, v: Any) -> float | list[float]:
    if isinstance(v, list):
        if len(v) != 2:
            raise SpecError(f"{key}: expected a number or a pair [x, y] of numbers >= {MIN_SIZE:g} and <= "
                            f"{MAX_SIZE:g}, got {v!r}")
        return [rd.number(f"{key}[{i}]", x, ge=MIN_SIZE, le=MAX_SIZE) for i, x in enumerate(v)]
    return rd.number(key, v, ge=MIN_SIZE, le=MAX_SIZE)


def _channel(c: Any) -> int | str:
    """``surface.channel``: a channel index (an integer >= 0) or a channel name."""
    if isinstance(c, str):
        return rd.string("surface.channel", c)
    if isinstance(c, int) and not isinstance(c, bool):
        return rd.integer("surface.channel", c, ge=0)
    raise SpecError(f"surface.channel: expected a channel index (an integer >= 0) or a channel name "
                    f"(a string), got {c!r} ({type(c).__name__})")


def _options(s: dict, path: str) -> dict[str, Any]:
    """The file surface's table as given (before loading): format, reader keys, units, box or pixel size,
    detrending, undefined pixels, channel."""
    out: dict[str, Any] = {"kind": "file", "path": path}
    if "format" in s:
        out["format"] = rd.string("surface.format", s["format"], topography.FORMATS)
    for k in ("key", "delimiter"):
        if k in s:
            out[k] = rd.string(f"surface.{k}", s[k])
    units = (*topography.UNITS, *topography._ALIASES)
    for k in ("unit", "height_unit", "to_unit"):
        if k in s:
            out[k] = rd.string(f"surface.{k}", s[k], units)
    if "length" in s and "pixel_size" in s:
        raise SpecError("surface: give length or pixel_size, not both")
    for k in ("length", "pixel_size"):
        if k in s:
            out[f"file_{k}"] = _pair_or_num(f"surface.{k}", s[k])
    out["detrend"] = rd.string("surface.detrend", s.get("detrend", "mean"), topography.DETRENDS)
    # undefined pixels (docs/jobs.md "Height maps from files"): the default "refuse" is left out of the table, so
    # the task ids of jobs written before the key existed stay the same
    missing = rd.string("surface.missing", s.get("missing", "refuse"), topography.MISSING)
    if missing != "refuse":
        out["missing"] = missing
    if "channel" in s:
        out["channel"] = _channel(s["channel"])
    return out


def _check_map(topo: Any, out: dict[str, Any], path: str) -> None:
    """A loaded map is refused (SpecError) when its heights or box are not finite after the unit conversion, or
    when it is flat after detrending (rms <= 1e-12 of its box)."""
    if not (np.all(np.isfinite(topo.heights)) and all(math.isfinite(x) and x > 0 for x in topo.length)):
        raise SpecError(f"surface.path: {path!r}: heights or box not finite after the unit conversion "
                        f"({out.get('unit')} -> {out.get('to_unit')}): allowed are maps whose values stay finite "
                        "floats (choose another to_unit)")
    h = np.asarray(topo.heights, dtype=float)
    rms = float(np.sqrt(np.mean((h - h.mean()) ** 2))) if h.size else 0.0
    if not rms > 1e-12 * max(topo.length):  # (heights and box share a unit; a plane leaves round-off ~1e-16 L)
        # a flat map (zero rms after detrending) has no contact problem: every task failed at run time (issue 40
        # item 9), so plan and run refuse it here
        raise SpecError(f"surface.path: {path!r}: the height map is flat after detrend = {out['detrend']!r} (rms "
                        f"{rms:g}): allowed are maps with a non-zero rms roughness (a measured surface; check the "
                        "file, its unit or the detrending)")


def file_surface(s: dict, base: str | Path | None) -> tuple[dict[str, Any], int]:
    """``[surface] kind = "file"``: validate the keys and load the map now (gapsweep.surface.load), so that a
    missing or unreadable file fails before anything runs. Returns the canonical surface table (with the file's
    SHA-256, so a changed file changes the task ids, and its box ``length``) and the map's nx."""
    rd.known("surface", s, FILE_KEYS)
    if "path" not in s:
        raise SpecError("surface.path: missing; the height map file, relative to the job spec")
    path = rd.string("surface.path", s["path"])
    full = Path(base if base is not None else ".") / path
    if not full.is_file():
        raise SpecError(f"surface.path: no such height map {str(full)!r} (paths are relative to the job spec)")
    out = _options(s, path)
    asked = rd.boolean("surface.periodic", s["periodic"]) if "periodic" in s else None
    try:
        topo = load_file_surface(out, full)
        digest = hashlib.sha256(full.read_bytes()).hexdigest()
    except SpecError:
        raise
    except (OSError, ValueError, ImportError) as e:
        raise SpecError(f"surface.path: {path!r} does not load as a height map: {e}") from None
    nx, ny = topo.shape
    _check_map(topo, out, path)
    out["sha256"] = digest
    # The box: one number for a square box (as before), [Lx, Ly] otherwise; a rectangular grid records its shape.
    if math.isclose(topo.length[0], topo.length[1], rel_tol=1e-12):
        out["length"] = float(topo.length[0])
    else:
        out["length"] = [float(topo.length[0]), float(topo.length[1])]
    if nx != ny:
        out["shape"] = [int(nx), int(ny)]
    # Periodic or free boundaries (docs/gfmd.md "Periodic or free boundaries"): the spec's choice, else the
    # file's own flag, else what the map's edges say (gapsweep.surfaces.topography).
    out["periodic"] = bool(topo.periodic) if asked is None else asked
    _FILES[digest] = str(full.resolve())
    _ASKED[digest] = asked is not None
    return out, nx


def map_record(surface: dict[str, Any], topo: Any) -> dict[str, Any]:
    """What a validated file surface is, as the sweep solves it: the file's and the solved grid, box, unit,
    channel, the undefined pixels and what was done with them (``missing``: "refuse" when there were none,
    "crop" with the kept block ``crop``, or a filling), rms height and rms slope of the heights solved, and the
    periodic decision. Written into the store (attribute ``surface_map``, docs/store.md) and printed by
    ``gapsweep plan``."""
    return {"path": surface["path"], "sha256": surface["sha256"], "channel": topo.channel,
            "file_shape": list(topo.file_shape or topo.shape), "shape": list(topo.shape),
            "length": [float(topo.length[0]), float(topo.length[1])], "unit": topo.unit,
            "missing_pixels": int(topo.missing_pixels), "missing_fraction": float(topo.missing_fraction),
            "missing": topo.missing, "crop": list(topo.crop) if topo.crop is not None else None,
            "h_rms": topo.rms_height(), "g_rms": _slope(surface, topo), "periodic": bool(surface["periodic"]),
            "periodic_from": "the job's surface.periodic" if _ASKED.get(surface["sha256"]) else topo.periodic_from}


def _slope(surface: dict[str, Any], topo: Any) -> float:
    """rms slope of the map with the boundaries it is solved with (the spec's periodic flag)."""
    from dataclasses import replace

    return replace(topo, periodic=bool(surface["periodic"])).rms_slope()


def surface_map_attr(surface: dict[str, Any]) -> str:
    """The store attribute ``surface_map``: :func:`map_record` as JSON ("" when the map was not validated in this
    process)."""
    import json

    path = _FILES.get(surface["sha256"])
    if path is None:
        return ""
    return json.dumps(map_record(surface, load_file_surface(surface, path)), sort_keys=True)


def describe(surface: dict[str, Any]) -> list[str]:
    """``gapsweep plan``'s lines on a validated file surface (:func:`map_record`)."""
    path = _FILES.get(surface["sha256"])
    if path is None:
        return []
    r = map_record(surface, load_file_surface(surface, path))
    unit = r["unit"] or "model units"
    lines = [f"  height map {r['path']!r}" + (f" (channel {r['channel']!r})" if r["channel"] else "")
             + f": {r['shape'][0]} x {r['shape'][1]} pixels, box {r['length'][0]:.6g} x {r['length'][1]:.6g} "
             f"{unit}; rms height {r['h_rms']:.4g} {unit if r['unit'] else ''}".rstrip()
             + f", rms slope {r['g_rms']:.4g} (of the heights solved)"]
    what = {"refuse": "none", "crop": "cropped to the largest valid rectangle", "fill_harmonic":
            "filled (harmonic interpolation)", "fill_nearest": "filled (nearest valid pixel)"}[r["missing"]]
    miss = f"{r['missing_pixels']} missing pixels ({100 * r['missing_fraction']:.3g} %)"
    if r["crop"]:
        x0, x1, y0, y1 = r["crop"]
        what += f" x {x0}..{x1 - 1}, y {y0}..{y1 - 1} of the file's {r['file_shape'][0]} x {r['file_shape'][1]}"
    lines.append(f"    {miss}: {what}; boundaries "
                 + ("periodic" if r["periodic"] else "free (not periodic)")
                 + (f" ({r['periodic_from']})" if r["periodic_from"] else ""))
    return lines


# SHA-256 of a validated file surface -> its absolute path, filled when a spec is loaded in this process (every
# rank loads the spec itself), so that tasks find the map by content without the path entering their ids.
_FILES: dict[str, str] = {}
_ASKED: dict[str, bool] = {}  # SHA-256 -> whether the job set surface.periodic (plan says how it was decided)


def file_surface_heights(surface: dict[str, Any]):
    """Heights of a file surface (the ``surface.*`` options of a task) as loaded and detrended at validation;
    the file must still have the SHA-256 the spec recorded (a changed file would change the results)."""
    path = _FILES.get(surface["sha256"])
    if path is None or not Path(path).is_file():
        raise SpecError(f"surface.path: the height map {surface['path']!r} (sha256 {surface['sha256'][:12]}...) "
                        "was not loaded with the job spec in this process")
    if hashlib.sha256(Path(path).read_bytes()).hexdigest() != surface["sha256"]:
        raise SpecError(f"surface.path: {path!r} changed since the job spec was validated (sha256 differs)")
    return load_file_surface(surface, path).heights


def length_unit(surface: dict[str, Any]) -> str | None:
    """The length unit of a validated file surface's heights and box (``to_unit``, else ``unit``), or None
    (model units)."""
    u = surface.get("to_unit") or surface.get("unit")
    return topography._canonical(u) if u else None


def load_file_surface(surface: dict[str, Any], full: str | Path):
    """The :class:`gapsweep.topography.Topography` of a validated file-surface table (``full``: its path)."""
    kw: dict[str, Any] = {k: surface[k] for k in ("format", "key", "delimiter", "unit", "height_unit", "to_unit",
                                                  "missing", "channel") if k in surface}
    for k in ("length", "pixel_size"):
        if f"file_{k}" in surface:
            kw[k] = surface[f"file_{k}"]
    if "length" not in kw and "pixel_size" not in kw and surface.get("format") != "surfacetopography" \
            and Path(full).suffix.lower() in (".npy", ".npz", *topography._TEXT):
        raise SpecError("surface.length: missing; give length or pixel_size (the file does not state its size)")
    # One load per file state and options in this process: validation, the store's record, the plan and every
    # task of a rank read the same map, and a harmonic filling of a large map takes seconds (a sparse solve).
    st = Path(full).stat()
    key = (str(Path(full).resolve()), st.st_mtime_ns, st.st_size, surface.get("detrend", "mean"),
           json.dumps(kw, sort_keys=True, default=str))
    topo = _LOADED.get(key)
    if topo is None:
        topo = topography.load(full, detrend=surface.get("detrend", "mean"), **kw)
        _LOADED.clear()  # one map kept: a job has one surface
        _LOADED[key] = topo
    return dataclasses.replace(topo, heights=topo.heights.copy())


_LOADED: dict[tuple, Any] = {}  # the last map loaded (load_file_surface)
