"""The sweep's schema: the records of the data path and the store's columns, in one module at the bottom.

Everything the sweep passes from one stage to the next is defined here (docs/architecture.md):

* :class:`JobSpec` -- a validated job spec (gapsweep.sweep.spec builds it; docs/jobs.md);
* :class:`Task` -- one grid point of one method, with its content id; :class:`Unit` -- what a worker runs in one
  go; :class:`TaskResult` -- one result record (a store row);
* the store's layout: status codes, result columns, the ``/tasks`` and ``/results`` row types, the format
  version (docs/store.md), and the errors of the spec and the store.

It imports nothing of gapsweep, so every other sweep module (spec, tasks, the method plug-ins, the store, its
validation, provenance, the dataset views) can import it without a circle.
"""

from __future__ import annotations

import hashlib
import json
import zlib
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

__all__ = [
    "FLAG_DETACHED",
    "FLAG_JUMP",
    "FLOAT_RESULTS",
    "FORMAT",
    "FORMAT_VERSION",
    "INTEGRITY",
    "INT_RESULTS",
    "LAYOUTS",
    "PLUGIN_COLUMNS",
    "PROVENANCE_ATTRS",
    "RESULT_DTYPE",
    "SPEC_ATTRS",
    "STATUS",
    "TASK_DTYPE",
    "Column",
    "JobSpec",
    "Layout",
    "SpecError",
    "StoreError",
    "StoreWriteError",
    "Task",
    "TaskResult",
    "Unit",
    "integrity_problem",
    "integrity_problems",
    "integrity_record",
    "layout_of",
    "make_task",
    "plugin_columns_of",
    "results_dtype",
    "task_id",
]

# ---------------------------------------------------------------------------------------------------------
# the job spec


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
        """The interaction law's name: "exponential" (default), "hard_wall", "adhesive" or "hard_wall_adhesive"
        (docs/gfmd.md)."""
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

    def units(self) -> dict[str, str | None]:
        """The physical units of the job's lengths and pressures (None: model units, lengths in units of L and
        pressures in units of E*): a file surface's length unit (``to_unit``, else ``unit``) or ``[surface]
        unit``, and ``[material] pressure_unit``. Written into the store (attribute ``units``) and carried to the
        dataset, the netCDF export and the report."""
        s = self.surface
        return {"length": s.get("to_unit") or s.get("unit") or None,
                "pressure": self.material.get("pressure_unit") or None}

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
# tasks, units, result records

# Status codes of the store (docs/store.md).
STATUS = {"pending": 0, "done": 1, "failed": 2, "not_converged": 3}
STATUS_NAMES = {v: k for k, v in STATUS.items()}
# Result columns (float64, NaN where not computed) and integer result columns (-1 where not computed). Every
# method plug-in declares which of them it fills (gapsweep.sweep.methods); the table is the store's format.
FLOAT_RESULTS = (
    "mean_gap", "mean_gap_paper", "mean_gap_continuum", "mean_gap_discrete", "h_rms", "g_rms",
    "residual", "load_error", "wall_time", "gap_std", "gap_min", "gap_max",
    # issue 12 (store format 2): quantities of every law, Persson's theory (docs/store.md)
    "contact_area", "elastic_energy", "contact_atom", "pressure_atom", "mean_gap_persson",
    # format 3: a predictor's own estimate of its error in mean_gap (same unit; NaN: no estimate); adhesion at
    # tensile loads: the most tensile load at which the solve stayed attached (the pull-off bracket)
    "error_estimate", "last_attached_load",
    # format 5 (issue 36): a measured map's spectral moments (theory.spectrum.map_spectrum), apart from h_rms and
    # g_rms, which are those of the heights solved
    "h_rms_spectrum", "g_rms_spectrum",
)
# format 5 (issue 40 item 5): ``algorithm_version``, the ALGORITHM_VERSION of the method plug-in that computed the
# row (-1: unknown -- a row of an older store, or one not computed); --reuse copies only rows of the same version
INT_RESULTS = ("iterations", "count", "rank", "flags", "algorithm_version")
# Columns a plug-in declares itself (a method's or an extension's ``own_columns``; docs/store.md "Plug-in
# columns"): appended after the columns above in the stores of the jobs that use the plug-in, listed in the store's
# attribute PLUGIN_COLUMNS. A job that uses no such plug-in writes exactly the table above.
PLUGIN_COLUMNS = "plugin_columns"
_PLUGIN_KINDS = {"float": "f8", "int": "i8"}


@dataclass(frozen=True)
class Column:
    """A store column declared by a plug-in: ``kind`` "float" (float64, NaN where not computed) or "int" (int64,
    -1 where not computed; a flag is 0/1), a one-line ``description`` (the xarray view's long name) and the
    view's unit attributes (``{"units": "1"}``, or with ``reference_unit``)."""

    kind: str
    description: str
    units: dict[str, str] = field(default_factory=lambda: {"units": "1"})

    def __post_init__(self) -> None:
        if self.kind not in _PLUGIN_KINDS:
            raise ValueError(f"Column kind must be one of {sorted(_PLUGIN_KINDS)}, got {self.kind!r}")

    @property
    def dtype(self) -> str:
        return _PLUGIN_KINDS[self.kind]


# Bits of the ``flags`` column (GFMD rows; 0 = none, -1 = not a GFMD row): a jump along the load path (adhesion)
# and detachment (adhesion beyond pull-off: no equilibrium in contact, the row is not_converged). docs/store.md.
FLAG_JUMP = 1
FLAG_DETACHED = 2
# Columns filled by the sweep itself for every row (not by a method).
COMMON_RESULTS = ("wall_time", "rank", "algorithm_version")
# The message prefix of a row that ran out of its time limit (--task-timeout): such failed rows are run again by
# --resume (a slow node or a cold cache may have caused them).
TIMEOUT_PREFIX = "timeout:"
# The message prefix of a row whose task was cut by a signal or failed in a way that says it was interrupted (a
# signal inside numba's JIT compilation, delivered in an llvmlite callback, surfaces as "no compiled object yet";
# issue 31): never a result of the task's parameters, so --resume runs such rows again.
INTERRUPTED_PREFIX = "interrupted:"
# [material] keys of the body beyond E* (an elastic layer, the hard wall's pressure cap; docs/jobs.md "The body:
# layer and hardness"), validated by gapsweep.sweep.spec, passed to gfmd.solve by the gfmd method.
SUBSTRATE_KEYS = ("thickness", "poisson", "bottom", "hardness")
# The message prefix of a row that failed because an optional package (an extra: gapsweep.core.extras) is not
# installed: a fact of the installation, not of the task, so --resume (and the demo) runs such rows again once
# it is (issue 40: the demo's SDE rows stuck after `pip install 'gapsweep[sde]'`, "nothing to do").
MISSING_EXTRA_PREFIX = "missing extra:"
# The kept fields of a GFMD task (docs/jobs.md "keep_fields", gapsweep.sweep.fields).
FIELD_NAMES = ("gap", "pressure", "displacement", "height")


@dataclass(frozen=True)
class Task:
    """One grid point of one method. ``options`` holds every other input that changes the result."""

    method: str
    hurst: float
    rho: float
    sigma0: float
    seed: int
    n: int
    options: tuple[tuple[str, Any], ...]
    task_id: str = ""
    chain: str = ""

    def surface_params(self) -> dict[str, Any]:
        """The ``surface.*`` options without their prefix: keyword arguments of ``surfaces.self_affine`` (for a
        file surface, ``kind = "file"`` and the loading options of gapsweep.sweep.filesurface). A synthetic
        surface's ``unit`` is a label of its lengths (``t.opt("surface.unit")``), not a generator argument (issue
        31: every task of such a job failed with "unexpected keyword argument 'unit'")."""
        file = self.opt("surface.kind") == "file"
        return {k[8:]: v for k, v in self.options if k.startswith("surface.") and (file or k != "surface.unit")}

    @property
    def law(self) -> str:
        """The interaction law (docs/gfmd.md): "exponential" unless the job names another."""
        return self.opt("interaction", "exponential")

    def opt(self, key: str, default: Any = None) -> Any:
        for k, v in self.options:
            if k == key:
                return v
        return default

    @property
    def params(self) -> dict[str, Any]:
        return dict(self.options)


@dataclass
class TaskResult:
    """One store row: status (key of :data:`STATUS`), message, scalar results, optional histogram."""

    status: str
    message: str = ""
    values: dict[str, float] = field(default_factory=dict)
    hist: tuple[np.ndarray, np.ndarray, int] | None = None  # (edges, density, count)
    phist: tuple[np.ndarray, np.ndarray] | None = None  # pressure histogram (edges, density), GFMD rows


@dataclass(frozen=True)
class Unit:
    """Indices of tasks run by one worker and its cost estimate [s]. ``kind``: "single", "chain" (run in order
    from its start, warm starts), "set" (independent tasks sharing a surface: only the wanted ones run) or
    "batch" (``chains``: GFMD chains run side by side, gapsweep.sweep.batching; ``tasks`` is their
    concatenation)."""

    tasks: tuple[int, ...]
    cost: float
    gpu: bool = False
    kind: str = "single"
    chains: tuple[tuple[int, ...], ...] = ()

    def remap(self, new: dict[int, int]) -> Unit:
        """The unit with task indices mapped through ``new`` (old index -> new index)."""
        return Unit(tuple(new[i] for i in self.tasks), self.cost, self.gpu, self.kind,
                    tuple(tuple(new[i] for i in c) for c in self.chains))


def task_id(payload: dict[str, Any]) -> str:
    """Content id: the first 16 hex digits of the SHA-256 of the payload's canonical JSON."""
    text = json.dumps(payload, sort_keys=True, separators=(",", ":"), allow_nan=False)
    return hashlib.sha256(text.encode()).hexdigest()[:16]


def make_task(method: str, hurst: float, rho: float, sigma0: float, seed: int, n: int, opts: dict[str, Any],
              chain: bool) -> Task:
    """A :class:`Task` with its content id (parameters that change the result, never the position in the
    grid) and, for a chained task, the key of its chain (the same payload without ``sigma0``)."""
    options = tuple(sorted(opts.items()))
    payload = {"method": method, "hurst": hurst, "rho": rho, "sigma0": sigma0, "seed": seed, "n": n,
               "options": {k: v for k, v in options}}
    tid = task_id(payload)
    ckey = ""
    if chain:
        ckey = task_id({k: v for k, v in payload.items() if k != "sigma0"})
    return Task(method, hurst, rho, sigma0, seed, n, options, tid, ckey)


# ---------------------------------------------------------------------------------------------------------
# the store's layout (docs/store.md)

FORMAT = "gapsweep-store"
# One format version per layout (the table LAYOUTS below, docs/store.md "Formats"): 5: + h_rms_spectrum and
# g_rms_spectrum (issue 36) and algorithm_version (issue 40); 4: format 3's last table
# with the attribute checksums (INTEGRITY); 3: per-row checksums (four layouts, written before the rule);
# 2: the issue-12 columns and pressure histograms; 1: the first format
FORMAT_VERSION = 5
MESSAGE_LEN = 240

TASK_DTYPE = np.dtype([
    ("task_id", "S16"), ("method", "S16"), ("chain", "S16"), ("hurst", "f8"), ("rho", "f8"), ("sigma0", "f8"),
    ("seed", "i8"), ("n", "i8"), ("lambda_l", "f8"), ("lambda_s", "f8"), ("length", "f8"), ("gamma0", "f8"),
    ("e_star", "f8"), ("c1", "f8"), ("c2", "f8"),
])
RESULT_DTYPE = np.dtype(
    [("status", "i1"), ("message", f"S{MESSAGE_LEN}")]
    + [(k, "f8") for k in FLOAT_RESULTS]
    + [(k, "i8") for k in INT_RESULTS]
    + [("checksum", "u8")]  # format 3: the row's checksum (row_checksum), written in the same write as the row
)
# The results tables of older layouts (such stores still open, read, resume and merge), spelled out column by
# column: a layout once written never changes (tests/test_store_formats.py holds their digests).
NEW_IN_V2 = ("contact_area", "elastic_energy", "contact_atom", "pressure_atom", "mean_gap_persson", "flags")
NEW_IN_V3 = ("error_estimate", "last_attached_load", "checksum")
NEW_IN_V5 = ("h_rms_spectrum", "g_rms_spectrum", "algorithm_version")


def _results_dtype(floats: Sequence[str], ints: Sequence[str], checksum: bool) -> np.dtype:
    return np.dtype([("status", "i1"), ("message", f"S{MESSAGE_LEN}")] + [(k, "f8") for k in floats]
                    + [(k, "i8") for k in ints] + ([("checksum", "u8")] if checksum else []))


_F1 = ("mean_gap", "mean_gap_paper", "mean_gap_continuum", "mean_gap_discrete", "h_rms", "g_rms", "residual",
       "load_error", "wall_time", "gap_std", "gap_min", "gap_max")
_F2 = (*_F1, "contact_area", "elastic_energy", "contact_atom", "pressure_atom", "mean_gap_persson")
_I1, _I2 = ("iterations", "count", "rank"), ("iterations", "count", "rank", "flags")
RESULT_DTYPE_V1 = _results_dtype(_F1, _I1, False)
RESULT_DTYPE_V2 = _results_dtype(_F2, _I2, False)
RESULT_DTYPE_V3B = _results_dtype((*_F2, "error_estimate"), _I2, False)
RESULT_DTYPE_V3C = _results_dtype((*_F2, "error_estimate"), _I2, True)
RESULT_DTYPE_V3D = _results_dtype((*_F2, "error_estimate", "last_attached_load"), _I2, True)
RESULT_DTYPE_V4 = RESULT_DTYPE_V3D  # format 4 added the attribute checksums, no column
# The attribute of format 4 that holds the checksums of every other attribute and of /tasks (docs/store.md).
INTEGRITY = "integrity"


@dataclass(frozen=True)
class Layout:
    """One layout of a store ever written: its ``format_version`` attribute, its ``/results`` table, where its
    row checksums live ("" none, "dataset": BLAKE2b in ``/checksums``, not verified by this version, "column":
    CRC-32 in the row, :func:`row_checksum`), whether it carries the attribute checksums (:data:`INTEGRITY`),
    and the commits that wrote it (docs/store.md "Formats"; fixtures in tests/data/stores)."""

    name: str
    version: int
    results: np.dtype
    row_checksums: str
    integrity: bool
    written_by: str

    def digest(self) -> str:
        """The layout's fingerprint: SHA-256 (16 hex digits) of its tables' columns with types and offsets,
        its checksum kinds and its version."""
        cols = [(n, self.results.fields[n][0].str, self.results.fields[n][1]) for n in self.results.names]
        tcols = [(n, TASK_DTYPE.fields[n][0].str, TASK_DTYPE.fields[n][1]) for n in TASK_DTYPE.names]
        text = json.dumps([self.version, cols, tcols, self.row_checksums, self.integrity], separators=(",", ":"))
        return hashlib.sha256(text.encode()).hexdigest()[:16]


LAYOUTS = (
    Layout("1", 1, RESULT_DTYPE_V1, "", False, "fe3dd80 .. a678e7c"),
    Layout("2", 2, RESULT_DTYPE_V2, "", False, "5619d0e .. 449a5c7"),
    Layout("3a", 3, RESULT_DTYPE_V2, "dataset", False, "9282d8f .. ca6983b"),
    Layout("3b", 3, RESULT_DTYPE_V3B, "dataset", False, "de98333"),
    Layout("3c", 3, RESULT_DTYPE_V3C, "column", False, "9093b41 .. 6bc25eb"),
    Layout("3d", 3, RESULT_DTYPE_V3D, "column", False, "be10c32 .. a6b475f"),
    Layout("4", 4, RESULT_DTYPE_V4, "column", True, "576c959 .. bb77f13"),
    Layout("5", 5, RESULT_DTYPE, "column", True, "this version"),
)
CURRENT_LAYOUT = LAYOUTS[-1]
RESULT_DTYPES = tuple(dict.fromkeys(x.results for x in LAYOUTS))


def layout_of(version: Any, results: np.dtype, checksums_dataset: bool, integrity: bool) -> Layout | None:
    """The layout of a store from its ``format_version`` attribute, ``/results`` dtype, whether it has a
    ``/checksums`` dataset and the :data:`INTEGRITY` attribute; None: no layout ever written looks like this."""
    try:
        v = int(version)
    except (TypeError, ValueError):
        v = None
    if results not in RESULT_DTYPES and plugin_columns_of(results):  # plug-in columns came with format 5
        if not integrity or (v is not None and v < 5):
            return None
        results = RESULT_DTYPE
    for x in LAYOUTS:
        if (x.results == results and x.integrity == integrity
                and (x.row_checksums == "dataset") == checksums_dataset and (v is None or v == x.version)):
            return x
    return None


def results_dtype(plugin: Sequence[tuple[str, str]] = ()) -> np.dtype:
    """The ``/results`` table of a new store: :data:`RESULT_DTYPE`, then the plug-in columns ``(name, kind)``
    (kind "float" or "int") in the order given. Without plug-in columns: :data:`RESULT_DTYPE` itself."""
    if not plugin:
        return RESULT_DTYPE
    return np.dtype([(k, RESULT_DTYPE.fields[k][0]) for k in RESULT_DTYPE.names]
                    + [(name, _PLUGIN_KINDS[kind]) for name, kind in plugin])


def plugin_columns_of(results: np.dtype) -> list[tuple[str, str]] | None:
    """The plug-in columns ``(name, kind)`` of a ``/results`` table: [] for a table of a layout ever written
    (:data:`RESULT_DTYPES`), the trailing float64/int64 columns of a table that begins with :data:`RESULT_DTYPE`
    exactly (same columns, types and offsets), None for anything else (not a gapsweep table)."""
    if results in RESULT_DTYPES:
        return []
    names = results.names or ()
    base = RESULT_DTYPE.names
    if names[:len(base)] != base or len(names) == len(base):
        return None
    if any(results.fields[k][:2] != RESULT_DTYPE.fields[k][:2] for k in base):
        return None
    back = {np.dtype(v): k for k, v in _PLUGIN_KINDS.items()}
    out = []
    for k in names[len(base):]:
        kind = back.get(results.fields[k][0])
        if kind is None:
            return None
        out.append((k, kind))
    return out if results == results_dtype(out) else None
PRESSURE_HIST = ("histograms/pressure_edges", "histograms/pressure_density")
# Format 3: each results row carries a checksum over its task parameters, itself (checksum field zero) and its
# four histogram rows; written with the row, after its payload. A finished row whose bytes no longer match is
# "damaged" (docs/store.md "Checksums").
CHECKSUM = "checksum"
# Columns that differ between two runs of the same job by nature, or say how a row was computed rather than what it
# holds (compare stores without them: merge's conflicts, diff); the checksum covers the wall time, so it differs
# with it; algorithm_version: rows equal in every value do not conflict because an older code computed one of
# them (the kept row keeps its own version)
VOLATILE = ("wall_time", "rank", "checksum", "algorithm_version")


class StoreError(RuntimeError):
    """A store cannot be used as asked (wrong spec, wrong format, conflicting merge)."""


class StoreWriteError(StoreError):
    """Writing to a store failed (full disk, file-size limit, I/O error); rows written before are intact."""


def row_checksum(task: np.void, result: np.void, hists: Sequence[np.ndarray]) -> int:
    """Checksum of one store row: CRC-32 over the raw bytes of its ``/tasks`` row, its ``/results`` row without
    the ``checksum`` field, and its gap and pressure histogram rows (edges, density) exactly as stored, with bit
    32 set (so never 0: 0 marks a row whose checksum was never written). A CRC catches every flip of up to 32
    adjacent bits and any other change with probability 1 - 2^-32, at a few microseconds per row (the cost of a
    cryptographic hash would show in sweeps of small tasks: docs/benchmarks.md, "Row checksums")."""
    c = zlib.crc32(task.tobytes())
    rb = result.tobytes()
    off = result.dtype.fields[CHECKSUM][1]  # the checksum's own 8 bytes are left out
    c = zlib.crc32(rb[off + 8:], zlib.crc32(rb[:off], c))
    for a in hists:  # float64 rows as stored; contiguous arrays are read in place (buffer protocol)
        c = zlib.crc32(a if isinstance(a, np.ndarray) and a.dtype == np.float64 and a.flags.c_contiguous
                       else np.ascontiguousarray(a, dtype=np.float64), c)
    return c | (1 << 32)


# ---------------------------------------------------------------------------------------------------------
# format 4: checksums of the attributes and of /tasks (docs/store.md "Checksums")


def _value_bytes(v: Any) -> bytes:
    """An attribute's value as bytes with its kind (a str and the same bytes differ; so do 1 and 1.0)."""
    if isinstance(v, bytes):
        return b"b:" + v
    if isinstance(v, str):
        return b"s:" + v.encode("utf-8", "surrogateescape")
    a = np.asarray(v)
    return f"a:{a.dtype.str}:{a.shape}:".encode() + a.tobytes()


def _digest(b: bytes) -> str:
    return hashlib.sha256(b).hexdigest()[:16]


def _record_digest(items: dict[str, str]) -> str:
    return _digest(json.dumps(items, sort_keys=True, separators=(",", ":")).encode())


def integrity_record(attrs: dict[str, Any], tasks: np.ndarray) -> str:
    """The :data:`INTEGRITY` attribute: JSON of SHA-256 digests (16 hex digits) of every other attribute
    (``attr:<name>``) and of the ``/tasks`` table's bytes (``table:/tasks``: task ids and parameters), with
    ``self``, the digest of that map (a change of the record itself is told apart from a change of what it
    covers)."""
    items = {f"attr:{k}": _digest(_value_bytes(v)) for k, v in attrs.items() if k != INTEGRITY}
    items["table:/tasks"] = _digest(np.ascontiguousarray(tasks).tobytes())
    return json.dumps({**items, "self": _record_digest(items)}, sort_keys=True, separators=(",", ":"))


# Attributes whose damage leaves every row usable (issue 40 item 1): the provenance (rebuilt, marked as lost,
# by --resume and `gapsweep repair`) and the job spec's own (restored from the job file after checking every row).
# Damage to any other attribute (format, format_version, shard) still refuses the store.
PROVENANCE_ATTRS = ("created", "finished", "versions", "git_commit", "gapsweep_version", "merged_from", "job_name")
SPEC_ATTRS = ("spec_text", "spec_sha256", "units", "spec_dir")


def integrity_problems(record: Any, attrs: dict[str, Any], tasks: Any, skip: tuple[str, ...] = ()
                       ) -> list[tuple[str, str]]:
    """Every item that fails its checksum, as ``(key, rest of a one-line message)``: key ``"integrity"`` (the
    record itself is damaged: nothing else can be checked, the list ends there), ``"attr:<name>"`` or
    ``"table:/tasks"``. ``attrs``: the file's other attributes (an unreadable one as an exception instance);
    ``tasks``: a callable returning the ``/tasks`` table (None: none there, which the structural check reports)."""
    try:
        rec = json.loads(record)
        items = {k: v for k, v in rec.items() if k != "self"}
        ok = isinstance(rec, dict) and all(isinstance(v, str) for v in rec.values())
    except (TypeError, ValueError, AttributeError):
        ok = False
    if not ok or rec.get("self") != _record_digest(items):
        return [(INTEGRITY, f"attribute {INTEGRITY!r} (the checksums of the others) is damaged")]
    out = []
    for k, v in attrs.items():
        if f"attr:{k}" not in items:
            out.append((f"attr:{k}", f"attribute {k!r} is not in the store's checksums (added or renamed after the "
                        "store was written)"))
        elif isinstance(v, Exception) or _digest(_value_bytes(v)) != items[f"attr:{k}"]:
            out.append((f"attr:{k}", f"attribute {k!r} fails its checksum"))
    for k in items:
        if k.startswith("attr:") and k[5:] not in attrs and k not in skip:
            out.append((k, f"attribute {k[5:]!r} is missing (it is in the store's checksums)"))
    table = tasks()
    if table is not None and _digest(np.ascontiguousarray(table).tobytes()) != items.get("table:/tasks"):
        out.append(("table:/tasks", "table '/tasks' (task ids and parameters) fails its checksum"))
    return out


def integrity_problem(record: Any, attrs: dict[str, Any], tasks: Any, skip: tuple[str, ...] = ()) -> str | None:
    """The first of :func:`integrity_problems` as the rest of a one-line message ("attribute 'units' fails its
    checksum"), or None."""
    probs = integrity_problems(record, attrs, tasks, skip)
    return probs[0][1] if probs else None
