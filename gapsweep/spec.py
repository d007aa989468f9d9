"""Job specifications: TOML files under ``jobs/`` describing a sweep (schema in ``docs/jobs.md``).

A spec names the grid axes (``hurst``, ``rho``, ``sigma0``, ``seeds``), the fixed surface and material
parameters (docs/model.md M1, M2, M6) and the methods to run at each grid point with their options. Everything is
validated before anything runs: an unknown key, a wrong type or an out-of-range value raises
:class:`SpecError` naming the dotted key and the allowed values.

The sweep layer is free of physics: the spec only checks ranges (and the Nyquist condition of M2, so that a
grid that cannot carry ``lambda_s`` fails here rather than in the middle of a sweep).
"""

from __future__ import annotations

import hashlib
import json
import math
import os
import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from gapsweep.fft import BACKENDS as FFT_BACKENDS

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib

__all__ = ["MAX_TASKS", "METHODS", "JobSpec", "SpecError", "load", "loads", "max_tasks"]

METHODS = ("theory", "gfmd", "sde", "fokker_planck")
# Cap on the tasks of one job (every rank holds the task list: ~1.5 kB per task); raise it with
# GAPSWEEP_MAX_TASKS=<n> (docs/jobs.md, docs/reliability.md).
MAX_TASKS = 200_000


def max_tasks() -> int:
    """The task cap: ``GAPSWEEP_MAX_TASKS`` if set (a positive integer), else :data:`MAX_TASKS`."""
    v = os.environ.get("GAPSWEEP_MAX_TASKS", "")
    if not v:
        return MAX_TASKS
    try:
        n = int(v)
        if n < 1:
            raise ValueError
    except ValueError:
        raise SpecError(f"GAPSWEEP_MAX_TASKS: expected a positive integer, got {v!r}") from None
    return n
THEORY_FORMS = ("paper", "continuum", "discrete", "persson")
# Forms of the field theory of exponential repulsion (docs/model.md M4); "persson" is Persson's hard-wall theory
# (gapsweep.theory.persson: contact area and mean separation), the one form for hard-wall jobs.
FIELD_FORMS = ("paper", "continuum", "discrete")
SURFACE_KINDS = ("self_affine", "file")
INTERACTION_KINDS = ("exponential", "hard_wall", "adhesive")
PERSSON_VARIANTS = ("persson2001", "yang_persson2008", "wang_muser2017")


class SpecError(ValueError):
    """A job spec is invalid; the message names the key and the allowed values."""


@dataclass(frozen=True)
class JobSpec:
    """A validated job spec. ``methods`` maps method name -> resolved options (grid overrides included)."""

    name: str
    description: str
    text: str
    grid: dict[str, list]
    surface: dict[str, Any]
    material: dict[str, Any]
    histogram: dict[str, Any]
    methods: dict[str, dict[str, Any]] = field(default_factory=dict)
    # [interaction] beyond the default exponential law ({} for it, so older specs keep their hash)
    interaction: dict[str, Any] = field(default_factory=dict)
    # directory that a file surface's path is relative to (not part of the hash: the file's sha256 is)
    base_dir: str = ""

    @property
    def law(self) -> str:
        """The interaction law's name: "exponential" (default), "hard_wall" or "adhesive" (docs/gfmd.md)."""
        return self.interaction.get("kind", "exponential")

    @property
    def sha256(self) -> str:
        """Hash of the parsed, canonical spec (every validated value, defaults filled in; not the text), stored
        in the store's attributes; resume and merge compare it, so comments and formatting do not matter."""
        return hashlib.sha256(self.canonical().encode()).hexdigest()

    @property
    def text_sha256(self) -> str:
        """Hash of the spec text (what stores written before the canonical hash carry)."""
        return hashlib.sha256(self.text.encode()).hexdigest()

    def canonical(self) -> str:
        """The validated spec as canonical JSON (sorted keys), the basis of :attr:`sha256`."""
        d = {"name": self.name, "description": self.description, "grid": self.grid, "surface": self.surface,
             "material": self.material, "histogram": self.histogram, "methods": self.methods}
        if self.interaction:  # only beyond the default law: the hashes of older specs stay as they were
            d["interaction"] = self.interaction
        return json.dumps(d, sort_keys=True, separators=(",", ":"), allow_nan=False)

    def task_count(self) -> int:
        """Upper bound of the number of tasks (product of the axes of each method), computed without
        expanding the grid."""
        total = 0
        for o in self.methods.values():
            k = 1
            for ax in ("hurst", "rho", "sigma0", "seeds"):
                k *= len(o.get(ax, self.grid[ax]))
            total += k * len(o.get("n", [0]))
        return total


# ---------------------------------------------------------------------------------------------------------
# small typed readers: each names its dotted key in the error


def _is_num(v: Any) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool)


def _num(key: str, v: Any, *, gt: float | None = None, ge: float | None = None, lt: float | None = None,
         le: float | None = None) -> float:
    rng = _range_text(gt, ge, lt, le)
    if not _is_num(v):
        raise SpecError(f"{key}: expected a number {rng}, got {v!r} ({type(v).__name__})")
    x = float(v)
    if not math.isfinite(x) or (gt is not None and not x > gt) or (ge is not None and not x >= ge) or (
        lt is not None and not x < lt
    ) or (le is not None and not x <= le):
        raise SpecError(f"{key}: expected a number {rng}, got {v!r}")
    return x


def _range_text(gt, ge, lt, le) -> str:
    lo = f"> {gt:g}" if gt is not None else (f">= {ge:g}" if ge is not None else "")
    hi = f"< {lt:g}" if lt is not None else (f"<= {le:g}" if le is not None else "")
    return " and ".join(s for s in (lo, hi) if s) or "(finite)"


def _int(key: str, v: Any, *, ge: int | None = None, le: int | None = None) -> int:
    rng = " and ".join(s for s in ((f">= {ge}" if ge is not None else ""), (f"<= {le}" if le is not None else ""))
                       if s)
    if not isinstance(v, int) or isinstance(v, bool):
        raise SpecError(f"{key}: expected an integer {rng}, got {v!r} ({type(v).__name__})")
    if (ge is not None and v < ge) or (le is not None and v > le):
        raise SpecError(f"{key}: expected an integer {rng}, got {v!r}")
    return v


def _str(key: str, v: Any, allowed: tuple[str, ...] | None = None) -> str:
    if not isinstance(v, str):
        raise SpecError(f"{key}: expected a string{_allowed(allowed)}, got {v!r} ({type(v).__name__})")
    if allowed is not None and v not in allowed:
        raise SpecError(f"{key}: got {v!r}, allowed values: {', '.join(map(repr, allowed))}")
    return v


def _allowed(allowed):
    return f" (one of {', '.join(map(repr, allowed))})" if allowed else ""


def _bool(key: str, v: Any) -> bool:
    if not isinstance(v, bool):
        raise SpecError(f"{key}: expected true or false, got {v!r} ({type(v).__name__})")
    return v


def _table(key: str, v: Any) -> dict:
    if not isinstance(v, dict):
        raise SpecError(f"{key}: expected a table, got {v!r} ({type(v).__name__})")
    return v


def _known(key: str, table: dict, allowed: tuple[str, ...]) -> None:
    for k in table:
        if k not in allowed:
            where = f"{key}.{k}" if key else k
            raise SpecError(f"{where}: unknown key; allowed keys in [{key or 'top level'}]: {', '.join(allowed)}")


def _sig(v: float) -> float:
    """Round generated grid values to 12 significant digits: stable, readable task parameters."""
    return float(f"{v:.12g}")


def _axis(key: str, v: Any, check) -> list[float]:
    """A grid axis: a number, a list of numbers, or ``{min, max, num, scale = "log" | "linear"}``."""
    if _is_num(v):
        vals = [v]
    elif isinstance(v, list):
        if not v:
            raise SpecError(f"{key}: expected a non-empty list of numbers")
        vals = list(v)
    elif isinstance(v, dict):
        _known(key, v, ("min", "max", "num", "scale"))
        for k in ("min", "max", "num"):
            if k not in v:
                raise SpecError(f"{key}.{k}: missing; a range needs min, max, num (and scale = 'log' or 'linear')")
        scale = _str(f"{key}.scale", v.get("scale", "log"), ("log", "linear"))
        lo = check(f"{key}.min", v["min"])
        hi = check(f"{key}.max", v["max"])
        num = _int(f"{key}.num", v["num"], ge=1, le=100000)
        if hi < lo:
            raise SpecError(f"{key}: max ({hi!r}) must be >= min ({lo!r})")
        if num == 1:
            vals = [lo]
        elif scale == "log":
            if lo <= 0:
                raise SpecError(f"{key}.min: a log range needs min > 0, got {lo!r}")
            a, b = math.log10(lo), math.log10(hi)
            vals = [_sig(10 ** (a + (b - a) * i / (num - 1))) for i in range(num)]
        else:
            vals = [_sig(lo + (hi - lo) * i / (num - 1)) for i in range(num)]
    else:
        raise SpecError(f"{key}: expected a number, a list of numbers or a table {{min, max, num, scale}}, "
                        f"got {v!r} ({type(v).__name__})")
    out = [check(f"{key}[{i}]", x) for i, x in enumerate(vals)]
    if len(set(out)) != len(out):
        raise SpecError(f"{key}: values must be distinct, got {out}")
    return out


def _seeds(key: str, v: Any) -> list[int]:
    if isinstance(v, int) and not isinstance(v, bool):
        v = [v]
    if isinstance(v, dict):
        _known(key, v, ("start", "count"))
        start = _int(f"{key}.start", v.get("start", 0), ge=0)
        if "count" not in v:
            raise SpecError(f"{key}.count: missing; seeds = {{start, count}} or a list of integers")
        count = _int(f"{key}.count", v["count"], ge=1, le=100000)
        v = list(range(start, start + count))
    if not isinstance(v, list) or not v:
        raise SpecError(f"{key}: expected a non-empty list of integers >= 0 or {{start, count}}, got {v!r}")
    out = [_int(f"{key}[{i}]", s, ge=0, le=2**62) for i, s in enumerate(v)]
    if len(set(out)) != len(out):
        raise SpecError(f"{key}: seeds must be distinct, got {out}")
    return out


def _hurst(k, v):
    return _num(k, v, gt=0.0, lt=1.0)


def _pos(k, v):
    return _num(k, v, gt=0.0)


# ---------------------------------------------------------------------------------------------------------
# schema

_GRID_AXES = ("hurst", "rho", "sigma0", "seeds")
_TOP = ("job", "grid", "surface", "material", "histogram", "methods", "interaction")
_METHOD_KEYS = {
    "theory": ("forms", "n", "h_rms", "extra", "persson_variant", "persson_gamma", *_GRID_AXES),
    "gfmd": ("n", "tol", "max_iter", "method", "backend", "warm_start", "order", "extra", "keep_fields",
             *_GRID_AXES),
    "sde": ("samples", "dzeta", "zeta_end", "c1", "c2", "dtype", "device", "h_rms", "extra", *_GRID_AXES),
    "fokker_planck": ("c1", "c2", "h_rms", "extra", *_GRID_AXES),
}


def _grid(key: str, t: dict, *, required: bool, law: str = "exponential", file: bool = False) -> dict[str, list]:
    """Grid axes of ``[grid]`` (``required``) or of a method override. A file surface has no Hurst exponent and
    the hard wall no range: those axes are then not given and hold the placeholder 0.0 (docs/jobs.md). The
    adhesive law takes tensile (negative) pressures too."""
    out: dict[str, list] = {}

    def _load(k, v):
        if law == "adhesive":  # tensile loads allowed (docs/gfmd.md "Adhesion")
            return _num(k, v)
        return _pos(k, v)

    for ax, check in (("hurst", _hurst), ("rho", _pos), ("sigma0", _load)):
        unused = (ax == "hurst" and file) or (ax == "rho" and law == "hard_wall")
        if unused:
            if ax in t:
                why = "surface.kind = 'file' (a measured map has no Hurst exponent)" if ax == "hurst" else \
                    "interaction.kind = 'hard_wall' (no interaction range)"
                raise SpecError(f"{key}.{ax}: not used with {why}; remove it")
            if required:
                out[ax] = [0.0]
        elif ax in t:
            out[ax] = _axis(f"{key}.{ax}", t[ax], check)
        elif required:
            need = ", ".join(a for a in ("hurst", "rho", "sigma0") if not (
                (a == "hurst" and file) or (a == "rho" and law == "hard_wall")))
            raise SpecError(f"{key}.{ax}: missing; this job needs the grid axes {need}")
    if "seeds" in t:
        out["seeds"] = _seeds(f"{key}.seeds", t["seeds"])
    elif required:
        out["seeds"] = [0]
    return out


def _n_list(key: str, v: Any, nyquist: int) -> list[int]:
    vals = v if isinstance(v, list) else [v]
    if not vals:
        raise SpecError(f"{key}: expected an integer or a non-empty list of integers")
    out = [_int(f"{key}[{i}]" if isinstance(v, list) else key, x, ge=8, le=65536) for i, x in enumerate(vals)]
    for x in out:
        if x < nyquist:
            raise SpecError(f"{key}: n={x} cannot carry surface.lambda_s (Nyquist, docs/model.md M2): "
                            f"allowed n >= {nyquist}")
    if len(set(out)) != len(out):
        raise SpecError(f"{key}: values must be distinct, got {out}")
    return out


def _method(name: str, t: dict, nyquist: int, norm: str, law: str = "exponential",
            file_n: int | None = None) -> dict[str, Any]:
    key = f"methods.{name}"
    _known(key, t, _METHOD_KEYS[name])
    file = file_n is not None
    if name in ("sde", "fokker_planck") and (law != "exponential" or file):
        raise SpecError(f"{key}: the {name} method models exponential repulsion on a self-affine surface "
                        f"(docs/model.md M5); not available with interaction.kind = {law!r}"
                        + (" and surface.kind = 'file'" if file else ""))
    o: dict[str, Any] = {}
    if name != "gfmd" and not (name == "theory" and (law != "exponential" or file)):
        # Which h_rms feeds the theory/SDE/FP: the continuum value of the spectrum or the rms height of the
        # discrete surface (seed-dependent only with gaussian amplitudes). docs/model.md M2, M4.
        o["h_rms"] = _str(f"{key}.h_rms", t.get("h_rms", "continuum"), ("continuum", "surface"))
        if o["h_rms"] == "continuum" and norm == "c0":
            raise SpecError(f"{key}.h_rms: 'continuum' needs surface.rms_slope or surface.rms_height; "
                            "with surface.c0 use h_rms = 'surface'")
    elif "h_rms" in t:
        raise SpecError(f"{key}.h_rms: not used by Persson's theory (it takes the surface's spectrum)")
    o.update(_grid(key, t, required=False, law=law, file=file))
    extra = _table(f"{key}.extra", t.get("extra", {}))
    for k, v in extra.items():
        if not isinstance(v, (int, float, str, bool)):
            raise SpecError(f"{key}.extra.{k}: expected a number, string or boolean, got {v!r}")
    o["extra"] = dict(sorted(extra.items()))
    if name == "theory":
        if law == "exponential" and not file:
            allowed, default = FIELD_FORMS, ["paper", "continuum"]
        elif law == "hard_wall":
            allowed, default = ("persson",), ["persson"]
        else:
            raise SpecError(f"{key}: no theory for interaction.kind = {law!r}"
                            + (" on a file surface" if file else "") + "; the field theory (M4) needs the "
                            "exponential law on a self-affine surface, Persson's theory the hard wall")
        forms = t.get("forms", default)
        if not isinstance(forms, list) or not forms:
            raise SpecError(f"{key}.forms: expected a non-empty list from {', '.join(allowed)}")
        o["forms"] = [_str(f"{key}.forms[{i}]", f, allowed) for i, f in enumerate(forms)]
        if "discrete" in o["forms"]:
            if "n" not in t:
                raise SpecError(f"{key}.n: required when forms contains 'discrete' (grid of the surface)")
            o["n"] = _n_list(f"{key}.n", t["n"], nyquist)
        elif "n" in t:
            raise SpecError(f"{key}.n: only allowed when forms contains 'discrete'")
        if "persson" in o["forms"]:
            o["persson_variant"] = _str(f"{key}.persson_variant", t.get("persson_variant", "persson2001"),
                                        PERSSON_VARIANTS)
            o["persson_gamma"] = _num(f"{key}.persson_gamma", t.get("persson_gamma", 0.42), gt=0.0, le=1.0)
        else:
            for k in ("persson_variant", "persson_gamma"):
                if k in t:
                    raise SpecError(f"{key}.{k}: only allowed when forms contains 'persson'")
    elif name == "gfmd":
        if file:  # the grid of the height map itself (no resampling)
            o["n"] = [file_n]
            if "n" in t and _n_list(f"{key}.n", t["n"], 8) != [file_n]:
                raise SpecError(f"{key}.n: a file surface is solved on its own grid: allowed n = {file_n} "
                                "(or leave n out)")
        else:
            if "n" not in t:
                raise SpecError(f"{key}.n: missing; the GFMD grid size (integer or list, >= {nyquist})")
            o["n"] = _n_list(f"{key}.n", t["n"], nyquist)
        o["tol"] = _num(f"{key}.tol", t.get("tol", 1e-6), gt=0.0, lt=1.0)
        o["max_iter"] = _int(f"{key}.max_iter", t.get("max_iter", 100000), ge=1)
        o["method"] = _str(f"{key}.method", t.get("method", "auto"), ("auto", *LAW_METHODS[law]))
        o["backend"] = _str(f"{key}.backend", t.get("backend", "auto"), ("auto", *FFT_BACKENDS))
        o["warm_start"] = _bool(f"{key}.warm_start", t.get("warm_start", True))
        o["order"] = _str(f"{key}.order", t.get("order", "decreasing"), ("decreasing", "increasing"))
        if "keep_fields" in t:  # only when asked: the task ids of other specs stay as they were
            o["keep_fields"] = _keep_fields(f"{key}.keep_fields", t["keep_fields"])
    elif name == "sde":
        o["samples"] = _int(f"{key}.samples", t.get("samples", 100000), ge=1, le=10**10)
        o["dzeta"] = _num(f"{key}.dzeta", t.get("dzeta", 0.01), gt=0.0, le=10.0)
        if "zeta_end" in t:
            o["zeta_end"] = _num(f"{key}.zeta_end", t["zeta_end"], ge=1.0)
        o["dtype"] = _str(f"{key}.dtype", t.get("dtype", "float32"), ("float32", "float64"))
        o["device"] = _str(f"{key}.device", t.get("device", "cpu"), ("cpu", "cuda"))
    if name in ("sde", "fokker_planck"):
        if "c1" in t:
            o["c1"] = _num(f"{key}.c1", t["c1"], gt=0.0)
        o["c2"] = _num(f"{key}.c2", t.get("c2", 0.0), ge=0.0, le=10.0)
    return o


def _keep_fields(key: str, v: Any) -> str:
    """``keep_fields = {fields = [...], hurst = [...], rho = [...], sigma0 = [...], seeds = [...], n = [...]}``:
    the GFMD fields to keep and which tasks keep them (a missing selector: every value). Returned as canonical
    JSON (task options must be hashable). See docs/jobs.md and gapsweep.dataset."""
    import json

    from gapsweep.dataset import FIELD_NAMES

    t = _table(key, v)
    _known(key, t, ("fields", "hurst", "rho", "sigma0", "seeds", "n"))
    fields = t.get("fields")
    if not isinstance(fields, list) or not fields:
        raise SpecError(f"{key}.fields: expected a non-empty list from {', '.join(FIELD_NAMES)}")
    out: dict[str, Any] = {"fields": sorted({_str(f"{key}.fields[{i}]", f, FIELD_NAMES) for i, f in enumerate(fields)})}
    for sel in ("hurst", "rho", "sigma0"):
        if sel in t:
            vals = t[sel] if isinstance(t[sel], list) else [t[sel]]
            out[sel] = [_num(f"{key}.{sel}[{i}]", x, gt=0.0) for i, x in enumerate(vals)]
    for sel in ("seeds", "n"):
        if sel in t:
            vals = t[sel] if isinstance(t[sel], list) else [t[sel]]
            out[sel] = [_int(f"{key}.{sel}[{i}]", x, ge=0) for i, x in enumerate(vals)]
    return json.dumps(out, sort_keys=True)


# ---------------------------------------------------------------------------------------------------------
# [interaction] and file surfaces (issue 12; docs/jobs.md)


def _law_methods() -> dict[str, tuple[str, ...]]:
    from gapsweep.gfmd import _MINIMISERS
    from gapsweep.gfmd.interactions import INTERACTIONS

    return {k: _MINIMISERS[cls.load_control][1] for k, (cls, _) in INTERACTIONS.items()}


LAW_METHODS = _law_methods()


def _interaction(t: dict) -> dict[str, Any]:
    """``[interaction]``: ``kind`` ("exponential" default: its gamma0 is ``material.gamma0``, its range the grid's
    ``rho``), "hard_wall" (no parameter, no rho axis) or "adhesive" (``work`` > 0, the work of adhesion per area in
    units of E* L; its range is the grid's ``rho``). Returns {} for the default law so older specs keep their
    hash."""
    kind = _str("interaction.kind", t.get("kind", "exponential"), INTERACTION_KINDS)
    keys = {"exponential": ("kind",), "hard_wall": ("kind",), "adhesive": ("kind", "work")}[kind]
    for k in t:
        if k not in keys:
            raise SpecError(f"interaction.{k}: unknown key for kind = {kind!r}; allowed keys: {', '.join(keys)}"
                            + (" (gamma0 is material.gamma0, rho the grid axis)" if kind == "exponential" else ""))
    if kind == "exponential":
        return {}
    out: dict[str, Any] = {"kind": kind}
    if kind == "adhesive":
        if "work" not in t:
            raise SpecError("interaction.work: missing; the work of adhesion per area (> 0, units of E* L)")
        out["work"] = _num("interaction.work", t["work"], gt=0.0)
    return out


_FILE_KEYS = ("kind", "path", "format", "key", "delimiter", "unit", "height_unit", "to_unit", "length",
              "pixel_size", "detrend")


def _pair_or_num(key: str, v: Any) -> float | list[float]:
    if isinstance(v, list):
        if len(v) != 2:
            raise SpecError(f"{key}: expected a number or a pair [x, y] of numbers > 0, got {v!r}")
        return [_num(f"{key}[{i}]", x, gt=0.0) for i, x in enumerate(v)]
    return _num(key, v, gt=0.0)


def _file_surface(s: dict, base: str | Path | None) -> tuple[dict[str, Any], int]:
    """``[surface] kind = "file"``: validate the keys and load the map now (gapsweep.surface.load), so that a
    missing or unreadable file fails before anything runs. Returns the canonical surface table (with the file's
    SHA-256, so a changed file changes the task ids, and its box ``length``) and the map's nx."""
    import hashlib

    from gapsweep import topography

    _known("surface", s, _FILE_KEYS)
    if "path" not in s:
        raise SpecError("surface.path: missing; the height map file, relative to the job spec")
    path = _str("surface.path", s["path"])
    full = Path(base if base is not None else ".") / path
    if not full.is_file():
        raise SpecError(f"surface.path: no such height map {str(full)!r} (paths are relative to the job spec)")
    out: dict[str, Any] = {"kind": "file", "path": path}
    if "format" in s:
        out["format"] = _str("surface.format", s["format"], ("npy", "npz", "text", "surfacetopography"))
    for k in ("key", "delimiter"):
        if k in s:
            out[k] = _str(f"surface.{k}", s[k])
    units = (*topography.UNITS, *topography._ALIASES)
    for k in ("unit", "height_unit", "to_unit"):
        if k in s:
            out[k] = _str(f"surface.{k}", s[k], units)
    if "length" in s and "pixel_size" in s:
        raise SpecError("surface: give length or pixel_size, not both")
    for k in ("length", "pixel_size"):
        if k in s:
            out[f"file_{k}"] = _pair_or_num(f"surface.{k}", s[k])
    out["detrend"] = _str("surface.detrend", s.get("detrend", "mean"), topography.DETRENDS)
    try:
        topo = load_file_surface(out, full)
        digest = hashlib.sha256(full.read_bytes()).hexdigest()
    except SpecError:
        raise
    except (OSError, ValueError, ImportError) as e:
        raise SpecError(f"surface.path: {path!r} does not load as a height map: {e}") from None
    nx, ny = topo.shape
    if nx != ny or not math.isclose(topo.length[0], topo.length[1], rel_tol=1e-12):
        raise SpecError(f"surface.path: {path!r} is {nx} x {ny} with box {topo.length}; the sweep takes square "
                        "maps on square boxes (gapsweep.gfmd.solve itself takes rectangular ones)")
    out["sha256"] = digest
    out["length"] = float(topo.length[0])
    _FILES[digest] = str(full.resolve())
    return out, nx


# SHA-256 of a validated file surface -> its absolute path, filled when a spec is loaded in this process (every
# rank loads the spec itself), so that tasks find the map by content without the path entering their ids.
_FILES: dict[str, str] = {}


def file_surface_heights(surface: dict[str, Any]):
    """Heights of a file surface (the ``surface.*`` options of a task) as loaded and detrended at validation;
    the file must still have the SHA-256 the spec recorded (a changed file would change the results)."""
    import hashlib

    path = _FILES.get(surface["sha256"])
    if path is None or not Path(path).is_file():
        raise SpecError(f"surface.path: the height map {surface['path']!r} (sha256 {surface['sha256'][:12]}...) "
                        "was not loaded with the job spec in this process")
    if hashlib.sha256(Path(path).read_bytes()).hexdigest() != surface["sha256"]:
        raise SpecError(f"surface.path: {path!r} changed since the job spec was validated (sha256 differs)")
    return load_file_surface(surface, path).heights


def load_file_surface(surface: dict[str, Any], full: str | Path):
    """The :class:`gapsweep.topography.Topography` of a validated file-surface table (``full``: its path)."""
    from gapsweep import topography

    kw: dict[str, Any] = {k: surface[k] for k in ("format", "key", "delimiter", "unit", "height_unit", "to_unit")
                          if k in surface}
    for k in ("length", "pixel_size"):
        if f"file_{k}" in surface:
            kw[k] = surface[f"file_{k}"]
    if "length" not in kw and "pixel_size" not in kw and surface.get("format") != "surfacetopography" \
            and Path(full).suffix.lower() in (".npy", ".npz", *topography._TEXT):
        raise SpecError("surface.length: missing; give length or pixel_size (the file does not state its size)")
    return topography.load(full, detrend=surface.get("detrend", "mean"), **kw)


def loads(text: str, base: str | Path | None = None) -> JobSpec:
    """Parse and validate a job spec from TOML text; raise :class:`SpecError` on any problem. ``base``: the
    directory a file surface's ``path`` is relative to (default: the current directory)."""
    try:
        raw = tomllib.loads(text)
    except tomllib.TOMLDecodeError as e:
        raise SpecError(f"not valid TOML: {e}") from None
    _known("", raw, _TOP)
    for k in ("job", "grid", "methods"):
        if k not in raw:
            raise SpecError(f"{k}: missing table [{k}]; a job needs [job], [grid] and [methods.<name>]")
    job = _table("job", raw["job"])
    _known("job", job, ("name", "description"))
    if "name" not in job:
        raise SpecError("job.name: missing; a short name for the job (letters, digits, - and _)")
    name = _str("job.name", job["name"])
    if not name or not all(c.isalnum() or c in "-_." for c in name):
        raise SpecError(f"job.name: allowed characters are letters, digits, '-', '_', '.', got {name!r}")
    description = _str("job.description", job.get("description", ""))

    interaction = _interaction(_table("interaction", raw.get("interaction", {})))
    law = interaction.get("kind", "exponential")

    s = _table("surface", raw.get("surface", {}))
    kind = _str("surface.kind", s.get("kind", "self_affine"), SURFACE_KINDS)
    file_n: int | None = None
    if kind == "file":
        surface, file_n = _file_surface(s, base)
        norm, nyquist = "file", 8
    else:
        _known("surface", s, ("kind", "lambda_l", "lambda_s", "length", "rms_slope", "rms_height", "c0",
                              "amplitudes"))
        length = _num("surface.length", s.get("length", 1.0), gt=0.0)
        lambda_l = _num("surface.lambda_l", s.get("lambda_l", 0.25), gt=0.0, le=length)
        lambda_s = _num("surface.lambda_s", s.get("lambda_s", 2.5e-3), gt=0.0, lt=lambda_l)
        norms = [k for k in ("rms_slope", "rms_height", "c0") if k in s]
        if len(norms) > 1:
            raise SpecError(f"surface: give exactly one of rms_slope, rms_height, c0; got {', '.join(norms)}")
        norm = norms[0] if norms else "rms_slope"
        surface = {
            "lambda_l": lambda_l, "lambda_s": lambda_s, "length": length,
            norm: _num(f"surface.{norm}", s.get(norm, 1.0), gt=0.0),
            "amplitudes": _str("surface.amplitudes", s.get("amplitudes", "fixed"), ("fixed", "gaussian")),
        }
        # M2 Nyquist condition as the surface module applies it: n > 2 floor(L / lambda_s).
        nyquist = 2 * int(math.floor(length / lambda_s * (1 + 1e-9))) + 1

    g = _table("grid", raw["grid"])
    _known("grid", g, _GRID_AXES)
    grid = _grid("grid", g, required=True, law=law, file=kind == "file")
    if kind == "file" and grid["seeds"] != [0]:
        raise SpecError(f"grid.seeds: a file surface is one surface: allowed seeds = [0] (or leave seeds out), "
                        f"got {grid['seeds']}")

    m = _table("material", raw.get("material", {}))
    _known("material", m, ("e_star", "gamma0"))
    material = {"e_star": _num("material.e_star", m.get("e_star", 1.0), gt=0.0)}
    if law == "exponential":
        material["gamma0"] = _num("material.gamma0", m.get("gamma0", 1e-3), gt=0.0)
    elif "gamma0" in m:
        raise SpecError(f"material.gamma0: the exponential law's amplitude; not used with interaction.kind = "
                        f"{law!r} (remove it)")

    h = _table("histogram", raw.get("histogram", {}))
    _known("histogram", h, ("bins", "range"))
    bins = _int("histogram.bins", h.get("bins", 64), ge=1, le=100000)
    rng = h.get("range", "auto")
    if rng != "auto":
        if not (isinstance(rng, list) and len(rng) == 2 and all(_is_num(x) and math.isfinite(x) for x in rng)
                and rng[0] < rng[1]):
            raise SpecError(f"histogram.range: expected 'auto' or [lo, hi] with finite lo < hi (absolute gap), "
                            f"got {rng!r}")
        rng = [float(rng[0]), float(rng[1])]
    histogram = {"bins": bins, "range": rng}

    meth = _table("methods", raw["methods"])
    _known("methods", meth, METHODS)
    if not meth:
        raise SpecError(f"methods: empty; add at least one of [methods.{'], [methods.'.join(METHODS)}]")
    methods = {k: _method(k, _table(f"methods.{k}", v), nyquist, norm, law, file_n) for k, v in meth.items()}
    js = JobSpec(name=name, description=description, text=text, grid=grid, surface=surface,
                 material=material, histogram=histogram, methods=methods, interaction=interaction,
                 base_dir=str(base) if base is not None else "")
    n, cap = js.task_count(), max_tasks()
    if n > cap:
        raise SpecError(f"grid: the job has up to {n:,} tasks, more than the cap of {cap:,} (every rank holds "
                        "the task list); split the job, or raise the cap with GAPSWEEP_MAX_TASKS=<n>")
    return js


def load(path: str | Path) -> JobSpec:
    """Read and validate a job spec file (see :func:`loads`)."""
    p = Path(path)
    if not p.is_file():
        raise SpecError(f"job spec {str(p)!r}: no such file")
    try:
        text = p.read_bytes().decode("utf-8")
    except UnicodeDecodeError as e:
        raise SpecError(f"job spec {str(p)!r}: not UTF-8 text (byte {e.start}); TOML files must be UTF-8") from None
    except OSError as e:
        raise SpecError(f"job spec {str(p)!r}: cannot be read ({e.strerror})") from None
    try:
        return loads(text, base=p.resolve().parent)
    except SpecError as e:
        raise SpecError(f"{p}: {e}") from None
