"""Job specifications: TOML files under ``jobs/`` describing a sweep (schema in ``docs/jobs.md``).

A spec names the grid axes (``hurst``, ``rho``, ``sigma0``, ``seeds``), the fixed surface and material
parameters (docs/model.md M1, M2, M6) and the methods to run at each grid point with their options. Everything is
validated before anything runs, by the same rules for ``plan`` and ``run``: an unknown key, a wrong type or an
out-of-range value raises :class:`SpecError` naming the dotted key and the allowed values.

This module validates the job's own tables (``[job]``, ``[grid]``, ``[surface]``, ``[material]``,
``[histogram]``, ``[interaction]``); each ``[methods.<name>]`` table is validated by its method plug-in
(gapsweep.sweep.methods), and its ``extra`` keys against the signature of the solver they are passed to. The sweep
is free of physics: the spec only checks ranges (and the Nyquist condition of M2, so that a grid that cannot
carry ``lambda_s`` fails here rather than in the middle of a sweep).
"""

from __future__ import annotations

import importlib
import inspect
import json
import math
import os
import tomllib
from pathlib import Path
from typing import Any

from gapsweep.sweep import methods as registry
from gapsweep.sweep import readers as rd
from gapsweep.sweep.filesurface import file_surface
from gapsweep.sweep.methods.base import GRID_AXES, Env
from gapsweep.sweep.schema import SUBSTRATE_KEYS, JobSpec, SpecError

__all__ = ["MAX_TASKS", "JobSpec", "SpecError", "check_extra", "load", "loads", "max_tasks"]

# Cap on the tasks of one job (every rank holds the task list: ~1.5 kB per task); raise it with
# GAPSWEEP_MAX_TASKS=<n> (docs/jobs.md, docs/reliability.md).
MAX_TASKS = 200_000


# Bounds of a synthetic surface's lengths (issue 31: 1e308 and 5e-324 gave tracebacks): the box L in the spec's
# length unit, and at most MAX_WAVES shortest wavelengths lambda_s per box (a grid resolving them needs
# n > 2 L / lambda_s points per side, far beyond any memory well before this bound).
MIN_LENGTH, MAX_LENGTH, MAX_WAVES = 1e-12, 1e12, 1e9


def _check_waves(length: float, lambda_s: float, given: Any) -> None:
    """At most MAX_WAVES shortest wavelengths per box (issue 31: ``lambda_s = 5e-324`` gave an OverflowError)."""
    if length / lambda_s > MAX_WAVES:
        raise SpecError(f"surface.lambda_s: expected a number >= length / {MAX_WAVES:g} = {length / MAX_WAVES:g} "
                        f"(at most {MAX_WAVES:g} shortest wavelengths per box), got {given!r}")


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
SURFACE_KINDS = ("self_affine", "file")
PRESSURE_UNITS = ("Pa", "kPa", "MPa", "GPa")
LENGTH_UNITS = ("m", "mm", "um", "nm", "A", "pm")


def _unit_label(key: str, v: Any, allowed: tuple[str, ...]) -> str:
    return rd.string(key, v, allowed)
INTERACTION_KINDS = ("exponential", "hard_wall", "adhesive", "hard_wall_adhesive")
TENSILE_KINDS = ("adhesive", "hard_wall_adhesive")  # laws that take zero and tensile loads
_TOP = ("job", "grid", "surface", "material", "histogram", "methods", "interaction")


def _grid(key: str, t: dict, *, required: bool, law: str = "exponential", file: bool = False) -> dict[str, list]:
    """Grid axes of ``[grid]`` (``required``) or of a method override. A file surface has no Hurst exponent and
    the hard wall no range: those axes are then not given and hold the placeholder 0.0 (docs/jobs.md). The
    adhesive laws take tensile (negative) pressures too."""
    out: dict[str, list] = {}

    def _load(k, v):
        if law in TENSILE_KINDS:  # tensile loads allowed (docs/gfmd.md "Adhesion")
            return rd.number(k, v)
        return rd.positive(k, v)

    for ax, check in (("hurst", rd.hurst_value), ("rho", rd.positive), ("sigma0", _load)):
        unused = (ax == "hurst" and file) or (ax == "rho" and law == "hard_wall")
        if unused:
            if ax in t:
                why = "surface.kind = 'file' (a measured map has no Hurst exponent)" if ax == "hurst" else \
                    "interaction.kind = 'hard_wall' (no interaction range)"
                raise SpecError(f"{key}.{ax}: not used with {why}; remove it")
            if required:
                out[ax] = [0.0]
        elif ax in t:
            out[ax] = rd.axis(f"{key}.{ax}", t[ax], check)
        elif required:
            need = ", ".join(a for a in ("hurst", "rho", "sigma0") if not (
                (a == "hurst" and file) or (a == "rho" and law == "hard_wall")))
            raise SpecError(f"{key}.{ax}: missing; this job needs the grid axes {need}")
    if "seeds" in t:
        out["seeds"] = rd.seed_list(f"{key}.seeds", t["seeds"])
    elif required:
        out["seeds"] = [0]
    return out


def _method(name: str, t: dict, env: Env) -> dict[str, Any]:
    """``[methods.<name>]``: the plug-in's own keys (validated by the plug-in), grid overrides and ``extra``."""
    key = f"methods.{name}"
    m = registry.get(name)
    exts = registry.extensions(name)
    rd.known(key, t, (*m.keys, *exts, "extra", *GRID_AXES))
    if env.file and "seeds" in t:
        raise SpecError(f"{key}.seeds: a file surface is one map with one seed; remove seeds")
    o = m.validate(key, {k: v for k, v in t.items() if k not in exts}, env)
    for ename, e in exts.items():  # an extension's options: only when switched on (other task ids unchanged)
        if ename in t:
            opts = e.validate(f"{key}.{ename}", t[ename], o, env)
            if opts is not None:
                o[f"ext.{ename}"] = json.dumps(opts, sort_keys=True)
    o.update(_grid(key, t, required=False, law=env.law, file=env.file))
    extra = rd.table(f"{key}.extra", t.get("extra", {}))
    for k, v in extra.items():
        if not isinstance(v, (int, float, str, bool)):
            raise SpecError(f"{key}.extra.{k}: expected a number, string or boolean, got {v!r}")
    o["extra"] = dict(sorted(extra.items()))
    return o


_PRIMITIVES = {"bool": bool, "int": int, "float": float, "str": str}


def _check_extra_type(key: str, v: Any, param: inspect.Parameter, where: str) -> None:
    """An ``extra`` value must have a type the solver's parameter takes (its annotation, or its default's type):
    ``threads = "many"`` or ``host = 1`` fail here, before a sweep, not in every task. Parameters that take
    arrays or objects cannot be set from a job spec; a ``Literal[...]`` takes only its values."""
    ann = param.annotation if isinstance(param.annotation, str) else getattr(param.annotation, "__name__", "")
    ann = str(ann)
    import re

    names = {w for w in re.findall(r"\b(bool|int|float|str)\b", ann)}
    if "ArrayLike" in ann:  # a number is array-like (a scalar zeta, say)
        names |= {"int", "float"}
    literals = re.findall(r"['\"]([^'\"]+)['\"]", ann) if "Literal" in ann else []
    if literals:
        names.add("str")
    d = param.default
    if d is not inspect.Parameter.empty and d is not None and type(d).__name__ in _PRIMITIVES:
        names.add(type(d).__name__)
    if not names:
        raise SpecError(f"{key}: {where}'s parameter {param.name} takes {ann or 'an object'}, which a job spec "
                        "cannot give")
    ok = (isinstance(v, bool) and "bool" in names) or (
        isinstance(v, int) and not isinstance(v, bool) and names & {"int", "float"}) or (
        isinstance(v, float) and "float" in names) or (isinstance(v, str) and "str" in names)
    if not ok:
        raise SpecError(f"{key}: expected {' or '.join(sorted(names))} ({where}, parameter {param.name}: {ann}), "
                        f"got {v!r}")
    if isinstance(v, float) and not math.isfinite(v):
        raise SpecError(f"{key}: expected a finite number, got {v!r}")
    if literals and isinstance(v, str) and v not in literals:
        raise SpecError(f"{key}: expected one of {', '.join(map(repr, literals))}, got {v!r}")


def check_extra(spec: JobSpec) -> None:
    """Check every ``[methods.<m>.extra]`` key against the signature of the solver it is passed to (the
    plug-in's ``extra_target``), so that a typo fails before a sweep instead of failing every task. Raises
    ``SpecError``."""
    for m, o in spec.methods.items():
        extra = o.get("extra", {})
        if not extra:
            continue
        target = registry.get(m).extra_target
        if target is None:
            raise SpecError(f"methods.{m}.extra: the {m} method takes no extra keys")
        mod, fn, fixed = target
        params = inspect.signature(getattr(importlib.import_module(mod), fn)).parameters
        names = [k for k, p in params.items() if p.kind in (p.POSITIONAL_OR_KEYWORD, p.KEYWORD_ONLY)]
        allowed = [k for k in names if k not in fixed]
        for k, v in extra.items():
            if k in fixed:
                raise SpecError(f"methods.{m}.extra.{k}: set by the sweep itself (use the method's own key or the "
                                "grid), not allowed in extra")
            if k not in names:
                raise SpecError(f"methods.{m}.extra.{k}: not a parameter of {mod}.{fn}; allowed extra keys: "
                                f"{', '.join(allowed) or '(none)'}")
            _check_extra_type(f"methods.{m}.extra.{k}", v, params[k], f"{mod}.{fn}")


def _interaction(t: dict) -> dict[str, Any]:
    """``[interaction]``: ``kind`` ("exponential" default: its gamma0 is ``material.gamma0``, its range the grid's
    ``rho``), "hard_wall" (no parameter, no rho axis) or "adhesive" (``work`` > 0, the work of adhesion per area in
    units of E* L; its range is the grid's ``rho``) or "hard_wall_adhesive" (the contact-mechanics challenge's law:
    non-overlap plus ``-work exp(-g/rho)``; ``work`` as for "adhesive", range the grid's ``rho``). Returns {} for
    the default law so older specs keep their hash."""
    kind = rd.string("interaction.kind", t.get("kind", "exponential"), INTERACTION_KINDS)
    keys = {"exponential": ("kind",), "hard_wall": ("kind",), "adhesive": ("kind", "work"),
            "hard_wall_adhesive": ("kind", "work")}[kind]
    for k in t:
        if k not in keys:
            raise SpecError(f"interaction.{k}: unknown key for kind = {kind!r}; allowed keys: {', '.join(keys)}"
                            + (" (gamma0 is material.gamma0, rho the grid axis)" if kind == "exponential" else ""))
    if kind == "exponential":
        return {}
    out: dict[str, Any] = {"kind": kind}
    if kind in ("adhesive", "hard_wall_adhesive"):
        if "work" not in t:
            raise SpecError("interaction.work: missing; the work of adhesion per area (> 0, units of E* L)")
        out["work"] = rd.number("interaction.work", t["work"], gt=0.0)
    return out


# [material] keys of the body beyond E*: an elastic layer on a rigid base and the hard wall's pressure cap
# (gapsweep.gfmd.substrates, gapsweep.gfmd._plastic; docs/jobs.md "The body: layer and hardness"). Present in
# the task options only when given, so older specs keep their task ids.


def _substrate(m: dict, law: str, grid: dict) -> dict[str, Any]:
    """``[material] thickness`` (> 0, units of the surface's length), ``poisson`` (-1 < nu < 0.5; required with
    a bonded layer), ``bottom`` ("bonded" default, "slip"), ``hardness`` (> every sigma0 of the grid, units of
    E*; interaction.kind = "hard_wall" only)."""
    out: dict[str, Any] = {}
    if "thickness" in m:
        out["thickness"] = rd.number("material.thickness", m["thickness"], gt=0.0)
        out["bottom"] = rd.string("material.bottom", m.get("bottom", "bonded"), ("bonded", "slip"))
        if "poisson" in m:
            out["poisson"] = rd.number("material.poisson", m["poisson"], gt=-1.0, lt=0.5)
        elif out["bottom"] == "bonded":
            raise SpecError("material.poisson: missing; a bonded layer (material.bottom = 'bonded') needs its "
                            "Poisson ratio, -1 < poisson < 0.5")
    else:
        for k in ("poisson", "bottom"):
            if k in m:
                raise SpecError(f"material.{k}: describes an elastic layer; give material.thickness too (or "
                                "remove it: the half-space)")
    if "hardness" in m:
        if law != "hard_wall":
            raise SpecError(f"material.hardness: the pressure cap of the hard wall; not used with "
                            f"interaction.kind = {law!r} (set interaction.kind = 'hard_wall' or remove it)")
        out["hardness"] = rd.number("material.hardness", m["hardness"], gt=0.0)
        top = max(grid["sigma0"])
        if not out["hardness"] > top:
            raise SpecError(f"material.hardness: must exceed every grid.sigma0 (the largest is {top!r}: at "
                            f"sigma0 >= H the whole surface flows), got {out['hardness']!r}")
    return out


def _job(raw: dict[str, Any]) -> tuple[str, str]:
    """The ``[job]`` table: its name (letters, digits, '-', '_', '.') and free-text description."""
    job = rd.table("job", raw["job"])
    rd.known("job", job, ("name", "description"))
    if "name" not in job:
        raise SpecError("job.name: missing; a short name for the job (letters, digits, '-', '_', '.')")
    name = rd.string("job.name", job["name"])
    if not name or not all(c.isalnum() or c in "-_." for c in name):
        raise SpecError(f"job.name: allowed characters are letters, digits, '-', '_', '.', got {name!r}")
    return name, rd.string("job.description", job.get("description", ""))


def _generated_surface(s: dict[str, Any]) -> tuple[dict[str, Any], str, int]:
    """A generated surface's ``[surface]`` table (model M2, docs/jobs.md): the canonical table, its
    normalisation key (rms_slope, rms_height or c0) and the smallest grid ``n`` that carries ``lambda_s``."""
    rd.known("surface", s, ("kind", "lambda_l", "lambda_s", "lambda_r", "length", "rms_slope", "rms_height",
                          "c0", "amplitudes", "unit"))
    length = rd.number("surface.length", s.get("length", 1.0), ge=MIN_LENGTH, le=MAX_LENGTH)
    lambda_l = rd.number("surface.lambda_l", s.get("lambda_l", 0.25), gt=0.0, le=length)
    lambda_s = rd.number("surface.lambda_s", s.get("lambda_s", 2.5e-3), gt=0.0, lt=lambda_l)
    _check_waves(length, lambda_s, s.get("lambda_s"))
    norms = [k for k in ("rms_slope", "rms_height", "c0") if k in s]
    if len(norms) > 1:
        raise SpecError(f"surface: give exactly one of rms_slope, rms_height, c0; got {', '.join(norms)}")
    norm = norms[0] if norms else "rms_slope"
    surface = {
        "lambda_l": lambda_l, "lambda_s": lambda_s, "length": length,
        norm: rd.number(f"surface.{norm}", s.get(norm, 1.0), gt=0.0),
        "amplitudes": rd.string("surface.amplitudes", s.get("amplitudes", "fixed"), ("fixed", "gaussian")),
    }
    if "lambda_r" in s:  # roll-off: constant spectrum between lambda_l and lambda_r (docs/jobs.md)
        surface["lambda_r"] = rd.number("surface.lambda_r", s["lambda_r"], gt=lambda_s, le=lambda_l)
    if "unit" in s:  # a label: lengths (L, lambda_l, lambda_s, rho, heights) are in this unit
        surface["unit"] = _unit_label("surface.unit", s["unit"], LENGTH_UNITS)
    # M2 Nyquist condition as the surface module applies it: n > 2 floor(L / lambda_s).
    nyquist = 2 * int(math.floor(length / lambda_s * (1 + 1e-9))) + 1
    return surface, norm, nyquist


def _surface(s: dict[str, Any], kind: str, base: str | Path | None, law: str,
             ) -> tuple[dict[str, Any], int | None, str, int]:
    """The ``[surface]`` table of either kind: the canonical table, a file map's grid size (None for a
    generated surface), the normalisation and the smallest grid ``n`` (Nyquist)."""
    if kind != "file":
        surface, norm, nyquist = _generated_surface(s)
        return surface, None, norm, nyquist
    surface, file_n = file_surface(s, base)
    if law == "hard_wall_adhesive" and surface.get("periodic") is False:
        raise SpecError("surface.periodic: interaction.kind = 'hard_wall_adhesive' runs on periodic surfaces "
                        "only (free boundaries are not implemented for it); set surface.periodic = true")
    return surface, file_n, "file", 8


def _material(m: dict[str, Any], law: str, grid: dict[str, Any]) -> dict[str, Any]:
    """The ``[material]`` table: E*, the pressure unit label, the exponential law's gamma0 and the body
    (gapsweep.sweep.spec._substrate: a layer, a hardness)."""
    rd.known("material", m, ("e_star", "gamma0", "pressure_unit", *SUBSTRATE_KEYS))
    material = {"e_star": rd.number("material.e_star", m.get("e_star", 1.0), gt=0.0)}
    if "pressure_unit" in m:  # a label: E*, sigma0, gamma0/rho and work/rho are then in this unit (docs/jobs.md)
        material["pressure_unit"] = _unit_label("material.pressure_unit", m["pressure_unit"], PRESSURE_UNITS)
    if law == "exponential":
        material["gamma0"] = rd.number("material.gamma0", m.get("gamma0", 1e-3), gt=0.0)
    elif "gamma0" in m:
        raise SpecError(f"material.gamma0: the exponential law's amplitude; not used with interaction.kind = "
                        f"{law!r} (remove it)")
    material.update(_substrate(m, law, grid))
    return material


def _histogram(h: dict[str, Any]) -> dict[str, Any]:
    """The ``[histogram]`` table: bins and range ('auto' or finite ``[lo, hi]`` of the absolute gap)."""
    rd.known("histogram", h, ("bins", "range"))
    bins = rd.integer("histogram.bins", h.get("bins", 64), ge=1, le=100000)
    rng = h.get("range", "auto")
    if rng != "auto":
        if not (isinstance(rng, list) and len(rng) == 2 and all(rd.is_num(x) and math.isfinite(x) for x in rng)
                and rng[0] < rng[1]):
            raise SpecError(f"histogram.range: expected 'auto' or [lo, hi] with finite lo < hi (absolute gap), "
                            f"got {rng!r}")
        rng = [float(rng[0]), float(rng[1])]
    return {"bins": bins, "range": rng}


def _check_body(methods: dict[str, Any], material: dict[str, Any], law: str, surface: dict[str, Any],
                kind: str) -> None:
    """A body other than the elastic half-space (a layer, a hardness) only with methods that take it, and a
    layer neither under the adhesive hard wall nor under a non-periodic file surface."""
    body = [k for k in SUBSTRATE_KEYS if k in material]
    if not body:
        return
    names = registry.names()
    able = [k for k in names if registry.get(k).takes_body]
    for k in methods:
        if not registry.get(k).takes_body:
            raise SpecError(f"methods.{k}: not available with material.{body[0]} (no theory of a layer or of "
                            f"a plastic cap is implemented for it); methods that take them: {', '.join(able)}")
    if law == "hard_wall_adhesive" and "thickness" in material:
        raise SpecError("material.thickness: interaction.kind 'hard_wall_adhesive' is not available on an "
                        "elastic layer yet (the half-space only); remove material.thickness")
    if kind == "file" and surface.get("periodic") is False and "thickness" in material:
        from gapsweep.gfmd.substrates import FREE_LAYER_WHY

        raise SpecError("material.thickness: an elastic layer is solved with periodic boundaries only; this "
                        f"file surface is non-periodic (surface.periodic = false): {FREE_LAYER_WHY}. Instead: "
                        "surface.periodic = true, or leave out the layer (the half-space) if it is thick "
                        "against the map")


def loads(text: str, base: str | Path | None = None) -> JobSpec:
    """Parse and validate a job spec from TOML text; raise :class:`SpecError` on any problem. ``base``: the
    directory a file surface's ``path`` is relative to (default: the current directory)."""
    try:
        raw = tomllib.loads(text)
    except tomllib.TOMLDecodeError as e:
        raise SpecError(f"not valid TOML: {e}") from None
    rd.known("", raw, _TOP)
    for k in ("job", "grid", "methods"):
        if k not in raw:
            raise SpecError(f"{k}: missing table [{k}]; a job needs [job], [grid] and [methods.<name>]")
    name, description = _job(raw)

    interaction = _interaction(rd.table("interaction", raw.get("interaction", {})))
    law = interaction.get("kind", "exponential")

    s = rd.table("surface", raw.get("surface", {}))
    kind = rd.string("surface.kind", s.get("kind", "self_affine"), SURFACE_KINDS)
    surface, file_n, norm, nyquist = _surface(s, kind, base, law)

    g = rd.table("grid", raw["grid"])
    rd.known("grid", g, GRID_AXES)
    grid = _grid("grid", g, required=True, law=law, file=kind == "file")
    if kind == "file" and grid["seeds"] != [0]:
        raise SpecError(f"grid.seeds: a file surface is one surface: allowed seeds = [0] (or leave seeds out), "
                        f"got {grid['seeds']}")

    material = _material(rd.table("material", raw.get("material", {})), law, grid)
    histogram = _histogram(rd.table("histogram", raw.get("histogram", {})))

    meth = rd.table("methods", raw["methods"])
    names = registry.names()
    rd.known("methods", meth, names)
    if not meth:
        raise SpecError(f"methods: empty; add at least one of [methods.{'], [methods.'.join(names)}]")
    env = Env(law=law, file_n=file_n, nyquist=nyquist, norm=norm)
    methods = {k: _method(k, rd.table(f"methods.{k}", v), env) for k, v in meth.items()}
    _check_body(methods, material, law, surface, kind)
    refused = sorted(k for k in methods if not registry.get(k).rolloff)
    if "lambda_r" in surface and refused:
        raise SpecError(f"surface.lambda_r: a roll-off spectrum is not taken by {', '.join(refused)} (they assume "
                        f"the spectrum of M2, zero below q_l); remove "
                        f"{', '.join(f'[methods.{k}]' for k in refused)} or lambda_r")
    js = JobSpec(name=name, description=description, text=text, grid=grid, surface=surface,
                 material=material, histogram=histogram, methods=methods, interaction=interaction,
                 base_dir=str(base) if base is not None else "")
    n, cap = js.task_count(), max_tasks()
    if n > cap:
        raise SpecError(f"grid: the job has up to {n:,} tasks, more than the cap of {cap:,} (every rank holds "
                        "the task list); split the job, or raise the cap with GAPSWEEP_MAX_TASKS=<n>")
    check_extra(js)
    for m in js.methods:  # checks that need the whole job (a plug-in's selectors against the grid, say)
        registry.get(m).check_job(js)
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
