"""The method plug-in interface and its registry (docs/architecture.md, "Adding a method").

A sweep method is one module in ``gapsweep/sweep/methods/`` with one subclass of :class:`Method`, registered
with :func:`register`. The class declares in one place everything the sweep needs to know about the method:

* ``keys`` and :meth:`Method.validate` -- its ``[methods.<name>]`` spec keys, their types, ranges and defaults;
* ``columns`` -- the store's result columns it fills (a subset of ``schema.FLOAT_RESULTS + INT_RESULTS``),
  ``own_columns`` -- columns of its own, declared here and added to the stores of the jobs that use it (no edit
  of the schema: docs/store.md "Plug-in columns"),
  ``histogram`` -- whether its rows carry a gap histogram, ``variables`` / ``seed_free`` / ``select`` -- how its
  columns appear in the xarray view (gapsweep.sweep.dataset);
* :meth:`Method.expand` -- how a job spec expands into its tasks (canonical order, content ids);
* :meth:`Method.cost`, :meth:`Method.memory`, :meth:`Method.needs_gpu`, :meth:`Method.set_key` -- what the
  scheduler and ``gapsweep plan`` need;
* ``extra_target`` -- the solver function that receives ``[methods.<name>.extra]`` keys (checked at validation);
* :meth:`Method.run` -- how one task runs and becomes a :class:`~gapsweep.sweep.schema.TaskResult`.

An :class:`Extension` adds quantities to the rows of another method (its host, e.g. ``gfmd``) from the host's
result: switched on by a key of the host's table (``[methods.gfmd] flow = true``), it declares its own columns
and computes their values in the host's row (the host calls :func:`extend_row`). Register it with
:func:`register_extension`.

The spec validator, the task expansion, the runner, the store's validation, the dataset view and the report
iterate :func:`methods`; none of them names a method. Third-party methods register through the entry-point group
``gapsweep.methods`` (an entry point names a module that calls :func:`register` on import).
"""

from __future__ import annotations

import json
import math
from collections.abc import Iterator
from dataclasses import dataclass
from typing import Any, ClassVar

from gapsweep.sweep import readers as rd
from gapsweep.sweep.schema import (
    CHECKSUM,
    FLOAT_RESULTS,
    INT_RESULTS,
    TASK_DTYPE,
    Column,
    JobSpec,
    SpecError,
    Task,
    TaskResult,
    make_task,
)

__all__ = [
    "GRID_AXES",
    "Column",
    "Env",
    "Extension",
    "Method",
    "axes",
    "common_options",
    "extend_row",
    "extensions",
    "grid_tasks",
    "h_rms_option",
    "n_list",
    "non_finite",
    "register",
    "register_extension",
    "registered",
]

GRID_AXES = ("hurst", "rho", "sigma0", "seeds")
# unit attributes of a length in the dataset view (lengths in units of the spec's L)
LENGTH = {"units": "1", "reference_unit": "L"}


@dataclass(frozen=True)
class Env:
    """What a method's validation needs to know of the rest of the job: the interaction law, whether the surface
    is a file (and its grid ``file_n``), the Nyquist limit of the surface's grid (M2) and which of rms_slope,
    rms_height, c0 normalises the spectrum (``"file"`` for a file surface)."""

    law: str = "exponential"
    file_n: int | None = None
    nyquist: int = 8
    norm: str = "rms_slope"

    @property
    def file(self) -> bool:
        return self.file_n is not None


class Method:
    """Base class of a sweep method plug-in; see the module docstring for what a subclass declares."""

    name: str = ""
    order: int = 100  # place in the canonical order of task expansion (built-ins 0..3; ties by name)
    keys: tuple[str, ...] = ()
    columns: tuple[str, ...] = ()
    own_columns: ClassVar[dict[str, Column]] = {}  # its own store columns (docs/store.md "Plug-in columns")
    histogram: bool = False
    variables: ClassVar[dict[str, tuple[str, str, dict[str, str]]]] = {}
    seed_free: tuple[str, ...] = ()
    select: str | None = None  # the option ("n" or "c2") of which the dataset view keeps one value
    extra_target: tuple[str, str, tuple[str, ...]] | None = None  # (module, function, keys the sweep sets)
    # whether the method solves the body keys of [material] (schema.SUBSTRATE_KEYS: a layer, a pressure cap);
    # a job with them refuses every other method (docs/jobs.md "The body: layer and hardness")
    takes_body: bool = False
    rolloff: bool = False  # takes a roll-off spectrum ([surface] lambda_r; docs/jobs.md "Roll-off spectrum")
    # The version of the method's algorithm (the plug-in module's ALGORITHM_VERSION), stored in every row it
    # computes (column algorithm_version, docs/store.md): bumped when its results change beyond the tolerance its
    # docs state, so that --reuse never copies a row of the older code as current (issue 40 item 5)
    algorithm_version: int = 1

    def job_own_columns(self, spec: JobSpec) -> dict[str, Column]:
        """The own columns this method's rows have in ``spec``'s store: ``own_columns`` (default). A method whose
        columns depend on the job (a quantity of one interaction law only) returns those the job needs, so other
        jobs' stores stay as they were; each must still be declared in ``own_columns`` (checked at registration)."""
        return dict(self.own_columns)

    # -- validation --------------------------------------------------------------------------------------
    def validate(self, key: str, t: dict[str, Any], env: Env) -> dict[str, Any]:
        """The method's own options of ``[methods.<name>]`` (table ``t``), checked and with defaults filled in.
        Grid overrides and ``extra`` are read by the spec validator. Raise ``SpecError`` naming ``key.<k>``."""
        return {}

    def check_job(self, spec: JobSpec) -> None:
        """Checks of the method's options that need the whole validated job (raise ``SpecError``)."""
        return None

    # -- expansion and scheduling -------------------------------------------------------------------------
    def expand(self, spec: JobSpec) -> Iterator[Task]:
        """The method's tasks of ``spec`` in canonical order."""
        raise NotImplementedError

    def cost(self, t: Task) -> float:
        """Rough wall time of a task on one CPU core [s]; only ratios matter for scheduling."""
        return 1.0

    def memory(self, t: Task) -> float:
        """Peak working memory of one task [bytes] (order of magnitude, for ``gapsweep plan``)."""
        return 100e6

    def gpu_memory(self, t: Task) -> float:
        """GPU memory of one task [bytes] (0: a CPU task)."""
        return 0.0

    def needs_gpu(self, t: Task) -> bool:
        """Whether the task must run on a rank with a GPU."""
        return False

    def set_key(self, t: Task) -> str:
        """Key of independent tasks that share an expensive input (a surface) and run together, or ""."""
        return ""

    def warm_up_key(self, t: Task) -> tuple | None:
        """Tasks with the same key share one warm-up (None: this method needs none)."""
        return None

    def warm_up(self, t: Task, ctx: Any) -> None:
        """Import, compile and build what a task of this kind needs, on a tiny problem, before a time limit
        starts (``--task-timeout``)."""
        return None

    def provenance(self, options: dict[str, Any]) -> dict[str, Any]:
        """Run-record entries about how this method runs here (for example the SDE's engine)."""
        return {}

    # -- execution ------------------------------------------------------------------------------------------
    def run(self, t: Task, ctx: Any, prev: Any) -> tuple[TaskResult, Any]:
        """Run one task on this rank (``ctx``: gapsweep.sweep.context.Context; ``prev``: the warm-start state of
        the previous task of its chain). Returns the result record and the state for the next task."""
        raise NotImplementedError


class Extension:
    """Quantities added to another method's rows (module docstring). A subclass declares ``name`` (its key in
    the host's table, an identifier), ``host`` (the host method's name), ``own_columns`` and ``variables`` (as
    a method's), and implements :meth:`validate` and :meth:`compute`."""

    name: str = ""
    host: str = ""
    own_columns: ClassVar[dict[str, Column]] = {}
    variables: ClassVar[dict[str, tuple[str, str, dict[str, str]]]] = {}

    def validate(self, key: str, value: Any, host_options: dict[str, Any], env: Env) -> dict[str, Any] | None:
        """The extension's options from the host table's value at ``key`` (``true``, ``false`` or a table),
        checked, defaults filled in; None: switched off. ``host_options``: the host's validated options (to
        refuse combinations it cannot serve). Raise ``SpecError`` naming ``key``."""
        raise NotImplementedError

    def cost(self, t: Task, options: dict[str, Any]) -> float:
        """Rough wall time it adds to one row of the host on one CPU core [s] (scheduling, ``gapsweep plan``)."""
        return 0.0

    def memory(self, t: Task, options: dict[str, Any]) -> float:
        """Peak working memory it needs beside the host's result [bytes]."""
        return 0.0

    def compute(self, t: Task, options: dict[str, Any], result: Any) -> tuple[dict[str, float], str]:
        """The values of its columns for one row of the host (``result``: the host's solver result) and a
        problem ("" none; else the row is not counted as done and the message says why)."""
        raise NotImplementedError


_REGISTRY: dict[str, Method] = {}
_ORDERED: tuple[tuple, dict[str, Method]] | None = None
_EXTENSIONS: dict[str, Extension] = {}
# names no plug-in column may take: the store's own columns and the task table's
_RESERVED = frozenset((*FLOAT_RESULTS, *INT_RESULTS, *TASK_DTYPE.names, "status", "message", CHECKSUM))


def _check_own_columns(who: str, owner: str, cols: dict[str, Column]) -> None:
    for k, c in cols.items():
        if not (isinstance(k, str) and k.isidentifier() and len(k) <= 48):
            raise ValueError(f"{who}: own column name {k!r} must be an identifier of at most 48 characters")
        if k in _RESERVED:
            raise ValueError(f"{who}: own column {k!r} is a column of the store itself (gapsweep.sweep.schema)")
        if not isinstance(c, Column):
            raise ValueError(f"{who}: own column {k!r} must be a gapsweep.sweep.schema.Column, got {c!r}")
        for other in (*_REGISTRY.values(), *_EXTENSIONS.values()):
            oc = getattr(other, "own_columns", {})
            if k in oc and oc[k].kind != c.kind and other.name != owner:
                raise ValueError(f"{who}: own column {k!r} is declared by {other.name!r} as {oc[k].kind!r}")


def register(cls: type[Method]) -> type[Method]:
    """Class decorator: add a method plug-in to the registry (its ``name`` must be new and its ``columns``
    store columns)."""
    m = cls()
    if not m.name or not m.name.isidentifier() or len(m.name) > 16:
        raise ValueError(f"method plug-in {cls.__name__}: name must be an identifier of at most 16 characters "
                         f"(the store's method column), got {m.name!r}")
    if m.name in _REGISTRY and type(_REGISTRY[m.name]) is not cls:
        raise ValueError(f"method {m.name!r} is registered twice ({type(_REGISTRY[m.name]).__name__}, "
                         f"{cls.__name__})")
    unknown = [c for c in m.columns if c not in FLOAT_RESULTS + INT_RESULTS]
    if unknown:
        raise ValueError(f"method {m.name!r}: columns {unknown} are not store columns (gapsweep.sweep.schema)")
    _check_own_columns(f"method {m.name!r}", m.name, m.own_columns)
    _REGISTRY[m.name] = m
    return cls


def register_extension(cls: type[Extension]) -> type[Extension]:
    """Class decorator: add an :class:`Extension` (its ``name`` new among its host's keys and extensions)."""
    e = cls()
    if not e.name or not e.name.isidentifier():
        raise ValueError(f"extension {cls.__name__}: name must be an identifier, got {e.name!r}")
    if not e.host:
        raise ValueError(f"extension {e.name!r}: host (the method whose rows it extends) missing")
    if e.name in _EXTENSIONS and type(_EXTENSIONS[e.name]) is not cls:
        raise ValueError(f"extension {e.name!r} is registered twice")
    if e.host in _REGISTRY and e.name in _REGISTRY[e.host].keys:
        raise ValueError(f"extension {e.name!r}: a key of method {e.host!r} already")
    _check_own_columns(f"extension {e.name!r}", e.name, e.own_columns)
    _EXTENSIONS[e.name] = e
    return cls


def extensions(host: str) -> dict[str, Extension]:
    """The extensions of method ``host`` by name, in name order."""
    return {k: _EXTENSIONS[k] for k in sorted(_EXTENSIONS) if _EXTENSIONS[k].host == host}


def extension_cost(t: Task) -> tuple[float, float]:
    """(seconds, bytes) the task's switched-on extensions add to its host's cost and memory estimates."""
    sec = mem = 0.0
    for name, e in extensions(t.method).items():
        raw = t.opt(f"ext.{name}")
        if raw:
            o = json.loads(raw)
            sec, mem = sec + e.cost(t, o), max(mem, e.memory(t, o))
    return sec, mem


def extend_row(t: Task, result: Any, row: TaskResult) -> TaskResult:
    """Add the values of the task's switched-on extensions (options ``ext.<name>``, JSON) to the host's ``row``;
    a problem one reports turns a done row into ``not_converged`` with the problem as its message."""
    for name, e in extensions(t.method).items():
        raw = t.opt(f"ext.{name}")
        if not raw:
            continue
        vals, problem = e.compute(t, json.loads(raw), result)
        row.values.update(vals)
        if problem and row.status == "done":
            row.status, row.message = "not_converged", f"{name}: {problem}"
    return row


def registered() -> dict[str, Method]:
    """The methods registered so far, in canonical order (use gapsweep.sweep.methods.all_methods, which
    loads the built-in and third-party plug-ins first)."""
    global _ORDERED
    key = tuple(_REGISTRY.items())
    if _ORDERED is None or _ORDERED[0] != key:  # sorted once per change of the registry (this runs per task)
        _ORDERED = (key, {m.name: m for m in sorted(_REGISTRY.values(), key=lambda m: (m.order, m.name))})
    return _ORDERED[1]


# ---------------------------------------------------------------------------------------------------------
# helpers shared by the plug-ins


def axes(spec: JobSpec, m: str) -> dict[str, list]:
    """The grid axes of method ``m``: its overrides, else the job's ``[grid]``."""
    o = spec.methods[m]
    return {ax: o.get(ax, spec.grid[ax]) for ax in GRID_AXES}


def common_options(spec: JobSpec, m: str, with_hist: bool) -> dict[str, Any]:
    """Options shared by all tasks of a method: surface, material, interaction, method options (grid overrides
    removed), ``extra.*`` and, for methods with histograms, the bins and range."""
    o = {k: v for k, v in spec.methods[m].items() if k not in (*GRID_AXES, "n", "extra")}
    o.update({f"surface.{k}": v for k, v in spec.surface.items()})
    o.update(spec.material)
    if spec.interaction:  # only beyond the default exponential law: older task ids stay as they were
        o["interaction"] = spec.interaction["kind"]
        o.update({k: v for k, v in spec.interaction.items() if k != "kind"})
    for k, v in spec.methods[m].get("extra", {}).items():
        o[f"extra.{k}"] = v
    if with_hist:
        o["bins"] = spec.histogram["bins"]
        o["range"] = spec.histogram["range"]
    if "forms" in o:
        o["forms"] = list(o["forms"])
    return o


def grid_tasks(spec: JobSpec, name: str, *, seeds: list[int] | None = None, ns: list[int] | None = None,
               with_hist: bool, chain: bool = False, sort: bool = False, reverse: bool = False,
               ) -> Iterator[Task]:
    """Tasks over (hurst, rho, seed, n, sigma0) in this nesting order -- the canonical order of every method --
    with ``seeds`` and ``ns`` defaulting to the method's seeds and ``[0]``; ``sort``: the pressures in increasing
    (``reverse``: decreasing) order, the order of a warm-started chain."""
    ax, o = axes(spec, name), common_options(spec, name, with_hist=with_hist)
    for h in ax["hurst"]:
        for r in ax["rho"]:
            for s in (ax["seeds"] if seeds is None else seeds):
                for n in (ns or [0]):
                    for p in (sorted(ax["sigma0"], reverse=reverse) if sort else ax["sigma0"]):
                        yield make_task(name, h, r, p, s, n, o, chain=chain)


def h_rms_option(key: str, t: dict[str, Any], env: Env) -> str:
    """``h_rms``: which rms height feeds the theory/SDE/FP -- the continuum value of the spectrum or that of the
    discrete surface (seed-dependent only with gaussian amplitudes). docs/model.md M2, M4."""
    v = rd.string(f"{key}.h_rms", t.get("h_rms", "continuum"), ("continuum", "surface"))
    if v == "continuum" and env.norm == "c0":
        raise SpecError(f"{key}.h_rms: 'continuum' needs surface.rms_slope or surface.rms_height; "
                        "with surface.c0 use h_rms = 'surface'")
    return v


def n_list(key: str, v: Any, nyquist: int) -> list[int]:
    """A list of distinct grid sizes ``n`` (8 .. 65536) that carry ``lambda_s`` (Nyquist, M2)."""
    vals = v if isinstance(v, list) else [v]
    if not vals:
        raise SpecError(f"{key}: expected an integer or a non-empty list of integers")
    out = [rd.integer(f"{key}[{i}]" if isinstance(v, list) else key, x, ge=8, le=65536) for i, x in enumerate(vals)]
    for x in out:
        if x < nyquist:
            raise SpecError(f"{key}: n={x} cannot carry surface.lambda_s (Nyquist, docs/model.md M2): "
                            f"allowed n >= {nyquist}")
    if len(set(out)) != len(out):
        raise SpecError(f"{key}: values must be distinct, got {out}")
    return out


def non_finite(res: TaskResult) -> list[str]:
    """The mean-gap columns of a result that are not finite (a done row must have none)."""
    return [k for k, v in res.values.items() if k.startswith("mean_gap") and not math.isfinite(v)]

