"""Tasks: expansion of a job spec into tasks with stable content ids, work units, and the dispatch to solvers.

This is the only module that knows the solvers' signatures (``gapsweep.theory``, ``gfmd``, ``sde``,
``fokker_planck``); it calls their public functions and turns what they return into one store row
(:class:`TaskResult`). It holds no physics of its own.

* A :class:`Task` is one (method, hurst, rho, sigma0, seed, n) point with the spec's fixed parameters; its id is
  the first 16 hex digits of the SHA-256 of its canonical JSON (parameters that change the result, never the
  position in the grid), so resume and merge are keyed by content.
* A :class:`Unit` is what a worker runs in one go: a single task, a GFMD pressure chain (same surface,
  sigma0 in decreasing or increasing order) where each solve warm-starts from the previous solution, a set of
  discrete-theory tasks of one surface (its spectrum computed once), or a batch of chains (gapsweep.batching).
  A chain is always run from its start on one rank, so its results do not depend on the rank count or on resume.
* Adding a method: a ``_expand_<method>`` generator, a ``_run_<method>`` function and a cost model (a few lines).
"""

from __future__ import annotations

import hashlib
import inspect
import json
import math
import os
import time
import warnings
from collections import OrderedDict
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from gapsweep.spec import METHODS, JobSpec

__all__ = [
    "FLOAT_RESULTS",
    "INT_RESULTS",
    "STATUS",
    "Context",
    "Task",
    "TaskResult",
    "Unit",
    "estimate_cost",
    "expand",
    "make_units",
    "run_unit",
    "shard_units",
]

# Status codes of the store (docs/store.md).
STATUS = {"pending": 0, "done": 1, "failed": 2, "not_converged": 3}
# Result columns (float64, NaN where not computed) and integer result columns (-1 where not computed).
FLOAT_RESULTS = (
    "mean_gap", "mean_gap_paper", "mean_gap_continuum", "mean_gap_discrete", "h_rms", "g_rms",
    "residual", "load_error", "wall_time", "gap_std", "gap_min", "gap_max",
    # issue 12 (store format 2): quantities of every law, Persson's theory (docs/store.md)
    "contact_area", "elastic_energy", "contact_atom", "pressure_atom", "mean_gap_persson",
)
INT_RESULTS = ("iterations", "count", "rank", "flags")
# Bits of the ``flags`` column (GFMD rows; 0 = none, -1 = not a GFMD row): a jump along the load path (adhesion:
# the mean gap moved by more than JUMP_FACTOR times the secant prediction of the chain's two previous steps) and
# detachment (adhesion beyond pull-off: no equilibrium in contact, the row is not_converged). docs/store.md.
FLAG_JUMP = 1
FLAG_DETACHED = 2
JUMP_FACTOR = 3.0
# SDE tasks with more realisations than this are binned on the device (gapsweep.sde.gap_histogram_counts) instead
# of copying every sample to the host (10^8 samples = 800 MB); each store bin is split into SDE_SUB_BINS equal
# sub-bins there, from which the moments are computed (see _sde_binned).
SDE_HOST_SAMPLES_MAX = 2**22
SDE_SUB_BINS = 64


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
        """The ``surface.*`` options without their prefix: keyword arguments of ``surface.self_affine`` (for a
        file surface, ``kind = "file"`` and the loading options of gapsweep.spec)."""
        return {k[8:]: v for k, v in self.options if k.startswith("surface.")}

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
    "batch" (``chains``: GFMD chains run side by side, gapsweep.batching; ``tasks`` is their concatenation)."""

    tasks: tuple[int, ...]
    cost: float
    gpu: bool = False
    kind: str = "single"
    chains: tuple[tuple[int, ...], ...] = ()

    def remap(self, new: dict[int, int]) -> Unit:
        """The unit with task indices mapped through ``new`` (old index -> new index)."""
        return Unit(tuple(new[i] for i in self.tasks), self.cost, self.gpu, self.kind,
                    tuple(tuple(new[i] for i in c) for c in self.chains))


def _task_id(payload: dict[str, Any]) -> str:
    text = json.dumps(payload, sort_keys=True, separators=(",", ":"), allow_nan=False)
    return hashlib.sha256(text.encode()).hexdigest()[:16]


def _make(method: str, hurst: float, rho: float, sigma0: float, seed: int, n: int, opts: dict[str, Any],
          chain: bool) -> Task:
    options = tuple(sorted(opts.items()))
    payload = {"method": method, "hurst": hurst, "rho": rho, "sigma0": sigma0, "seed": seed, "n": n,
               "options": {k: v for k, v in options}}
    tid = _task_id(payload)
    ckey = ""
    if chain:
        cpay = {k: v for k, v in payload.items() if k != "sigma0"}
        ckey = _task_id(cpay)
    return Task(method, hurst, rho, sigma0, seed, n, options, tid, ckey)


def _axes(spec: JobSpec, m: str) -> dict[str, list]:
    o = spec.methods[m]
    return {ax: o.get(ax, spec.grid[ax]) for ax in ("hurst", "rho", "sigma0", "seeds")}


def _common(spec: JobSpec, m: str, with_hist: bool) -> dict[str, Any]:
    """Options shared by all tasks of a method: surface, material, method options (grid overrides removed)."""
    o = {k: v for k, v in spec.methods[m].items() if k not in ("hurst", "rho", "sigma0", "seeds", "n", "extra")}
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


def _expand_theory(spec: JobSpec) -> Iterator[Task]:
    ax, o = _axes(spec, "theory"), _common(spec, "theory", with_hist=False)
    discrete = "discrete" in o["forms"]
    # Without the discrete form the theory needs no surface (unless h_rms comes from the surface): one task per
    # (hurst, rho, sigma0), seed 0.
    seeded = discrete or (o.get("h_rms") == "surface" and spec.surface.get("amplitudes") == "gaussian")
    seeds = ax["seeds"] if seeded else [0]
    ns = spec.methods["theory"].get("n", [0])
    for h in ax["hurst"]:
        for r in ax["rho"]:
            for s in seeds:
                for n in ns:
                    for p in ax["sigma0"]:
                        yield _make("theory", h, r, p, s, n, o, chain=False)


def _expand_gfmd(spec: JobSpec) -> Iterator[Task]:
    ax, o = _axes(spec, "gfmd"), _common(spec, "gfmd", with_hist=True)
    rev = o["order"] == "decreasing"
    for h in ax["hurst"]:
        for r in ax["rho"]:
            for s in ax["seeds"]:
                for n in spec.methods["gfmd"]["n"]:
                    for p in sorted(ax["sigma0"], reverse=rev):
                        yield _make("gfmd", h, r, p, s, n, o, chain=o["warm_start"])


def _expand_sde(spec: JobSpec) -> Iterator[Task]:
    ax, o = _axes(spec, "sde"), _common(spec, "sde", with_hist=True)
    for h in ax["hurst"]:
        for r in ax["rho"]:
            for s in ax["seeds"]:
                for p in ax["sigma0"]:
                    yield _make("sde", h, r, p, s, 0, o, chain=False)


def _expand_fokker_planck(spec: JobSpec) -> Iterator[Task]:
    ax, o = _axes(spec, "fokker_planck"), _common(spec, "fokker_planck", with_hist=True)
    seeds = ax["seeds"] if (o["h_rms"] == "surface" and spec.surface["amplitudes"] == "gaussian") else [0]
    for h in ax["hurst"]:
        for r in ax["rho"]:
            for s in seeds:
                for p in ax["sigma0"]:
                    yield _make("fokker_planck", h, r, p, s, 0, o, chain=False)


_EXPAND = {"theory": _expand_theory, "gfmd": _expand_gfmd, "sde": _expand_sde,
           "fokker_planck": _expand_fokker_planck}


def expand(spec: JobSpec) -> list[Task]:
    """All tasks of a job in canonical order (method, hurst, rho, seed, n, sigma0). Ids are unique."""
    out: list[Task] = []
    for m in METHODS:
        if m in spec.methods:
            out.extend(_EXPAND[m](spec))
    ids = [t.task_id for t in out]
    if len(set(ids)) != len(ids):  # pragma: no cover - only on a hash collision
        raise RuntimeError("duplicate task ids")
    return out


# ---------------------------------------------------------------------------------------------------------
# cost model (seconds on one core; rough, for ordering and `gapsweep plan`)


def estimate_cost(t: Task) -> float:
    """Rough wall time of a task on one CPU core [s]; only ratios matter for scheduling."""
    if t.method == "theory":
        return 2e-4 + (3e-8 * t.n * t.n * math.log2(max(t.n, 2)) if t.n else 0.0)
    if t.method == "gfmd":
        # ~ iterations x (FFT pair + a few array passes); preconditioned CG needs 5..30 (measured at N = 1024,
        # about 15 ms per iteration on one core with pyFFTW).
        cpu = 0.02 + 20 * 1.5e-9 * t.n * t.n * math.log2(t.n)
        return cpu / 20 if t.opt("backend") == "cupy" else cpu  # an H200 solve is ~20x a CPU core
    if t.method == "sde":
        zeta_s = t.opt("surface.lambda_l") / t.opt("surface.lambda_s")
        steps = (t.opt("zeta_end", zeta_s) - 1.0) / t.opt("dzeta")
        per = 2.5e-12 if t.opt("device") == "cuda" else 1.5e-8  # s per particle-step: H200, one CPU core
        return 0.5 + t.opt("samples") * steps * per
    return 1.0  # fokker_planck


def needs_gpu(t: Task) -> bool:
    """A task that must run on a rank with a GPU: SDE on ``device = "cuda"``, GFMD with ``backend = "cupy"``."""
    return t.opt("device") == "cuda" or (t.method == "gfmd" and t.opt("backend") == "cupy")


def _surface_set(t: Task) -> str:
    """Key of the discrete-theory tasks that share one surface (its spectrum is computed once per set), or ""."""
    if t.method != "theory" or "discrete" not in t.opt("forms") or not t.n:
        return ""
    return _task_id({"hurst": t.hurst, "seed": t.seed, "n": t.n, "surface": t.surface_params()})


def make_units(tasks: list[Task]) -> list[Unit]:
    """Group chained tasks (same ``chain`` key) in their expansion order, and discrete-theory tasks of one
    surface into a set; others are single-task units. Units are sorted largest cost first (ties by first task
    id), the order a coordinator hands them out."""
    chains: OrderedDict[str, list[int]] = OrderedDict()
    sets: OrderedDict[str, list[int]] = OrderedDict()
    units: list[Unit] = []
    for i, t in enumerate(tasks):
        if t.chain:
            chains.setdefault(t.chain, []).append(i)
        elif key := _surface_set(t):
            sets.setdefault(key, []).append(i)
        else:
            units.append(Unit((i,), estimate_cost(t), needs_gpu(t)))
    for kind, groups in (("chain", chains), ("set", sets)):
        for idx in groups.values():
            # a set pays its surface's spectrum once (the first task's estimate), each further task ~1 ms
            cost = (sum(estimate_cost(tasks[i]) for i in idx) if kind == "chain"
                    else estimate_cost(tasks[idx[0]]) + 1e-3 * (len(idx) - 1))
            units.append(Unit(tuple(idx), cost, any(needs_gpu(tasks[i]) for i in idx),
                              kind if len(idx) > 1 else "single"))
    units.sort(key=lambda u: (-u.cost, tasks[u.tasks[0]].task_id))
    return units


def shard_units(units: list[Unit], index: int, count: int) -> list[Unit]:
    """Units of shard ``index`` of ``count``: greedy longest-processing-time split of the cost-sorted units
    (deterministic, balanced by estimated cost)."""
    if not (isinstance(count, int) and count >= 1 and isinstance(index, int) and 0 <= index < count):
        raise ValueError(f"shard must be i/n with 0 <= i < n, got {index}/{count}")
    load = [0.0] * count
    mine = []
    for u in units:
        k = min(range(count), key=lambda j: (load[j], j))
        load[k] += u.cost
        if k == index:
            mine.append(u)
    return mine


# ---------------------------------------------------------------------------------------------------------
# execution


class Context:
    """Per-rank state: surface cache (one surface per (hurst, seed, n) and surface parameters), the GPU this
    rank may use, and test hooks (``GAPSWEEP_TEST_DELAY`` seconds per task, ``GAPSWEEP_TEST_FAIL`` a comma list
    of sigma0 values whose tasks raise)."""

    def __init__(self, rank: int = 0, gpu: int | None = None, max_surfaces: int = 4) -> None:
        self.rank = rank
        self.gpu = gpu
        self.fields_dir: Path | None = None  # where GFMD tasks keep their fields (set by the runner)
        self._surfaces: OrderedDict[tuple, np.ndarray] = OrderedDict()
        self._rms: dict[tuple, tuple[float, float]] = {}  # (h_rms, g_rms) of the cached surfaces
        self._spectra: dict[tuple, Any] = {}  # discrete spectra of the cached surfaces (theory, M4)
        self._on_gpu: dict[tuple, Any] = {}  # GPU copies of the cached surfaces (GFMD with backend = "cupy")
        self._max = max_surfaces
        self._delay = float(os.environ.get("GAPSWEEP_TEST_DELAY", "0") or 0)
        fail = os.environ.get("GAPSWEEP_TEST_FAIL", "")
        self._fail = {float(x) for x in fail.split(",") if x.strip()}

    def surface(self, t: Task, n: int) -> np.ndarray:
        """The surface of ``t`` on an ``n x n`` grid, generated once per rank (M2)."""
        from gapsweep import surface

        sp = t.surface_params()
        key = self._key(t, n, sp)
        h = self._surfaces.get(key)
        if h is None:
            if sp.get("kind") == "file":
                from gapsweep import spec as specmod

                h = specmod.file_surface_heights(sp)
            else:
                h = surface.self_affine(n, t.hurst, seed=t.seed, **sp)
            h.setflags(write=False)
            self._surfaces[key] = h
            while len(self._surfaces) > self._max:
                old = self._surfaces.popitem(last=False)[0]
                self._rms.pop(old, None)
                self._spectra.pop(old, None)
                self._on_gpu.pop(old, None)
        else:
            self._surfaces.move_to_end(key)
        return h

    def surface_rms(self, t: Task, n: int) -> tuple[float, float]:
        """``(h_rms, g_rms)`` of :meth:`surface` (M2), computed once per cached surface (``g_rms`` costs an FFT)."""
        from gapsweep import surface

        sp = t.surface_params()
        h = self.surface(t, n)
        key = self._key(t, n, sp)
        if key not in self._rms:
            self._rms[key] = (surface.rms_height(h), surface.rms_slope(h, sp["length"]))
        return self._rms[key]

    def spectrum(self, t: Task, n: int) -> Any:
        """Discrete spectrum (``theory.spectrum.from_heights``) of :meth:`surface`, computed once per cached
        surface: the discrete theory of every pressure of one surface shares it (M4)."""
        from gapsweep.theory import spectrum

        sp = t.surface_params()
        h = self.surface(t, n)
        key = self._key(t, n, sp)
        if key not in self._spectra:
            self._spectra[key] = spectrum.from_heights(h, sp["length"], lambda_l=sp["lambda_l"])
        return self._spectra[key]

    def surface_on_gpu(self, t: Task, n: int) -> Any:
        """:meth:`surface` as a cupy array on the current GPU, copied there once per cached surface (a pressure
        chain solved one task at a time then copies its surface to the GPU once, not once per task)."""
        import cupy

        h = self.surface(t, n)  # caches (and evicts) the host surface and, with it, its GPU copy
        key = self._key(t, n, t.surface_params())
        dev = cupy.cuda.Device().id
        cached = self._on_gpu.get(key)
        if cached is None or cached[0] != dev:
            cached = (dev, cupy.asarray(h))
            self._on_gpu[key] = cached
        return cached[1]

    @staticmethod
    def _key(t: Task, n: int, sp: dict[str, Any]) -> tuple:
        # list values (a file surface's [x, y] pixel size or length) as tuples: the key must be hashable
        return (t.hurst, t.seed, n, tuple(sorted((k, tuple(v) if isinstance(v, list) else v) for k, v in sp.items())))


def _moments(t: Task, ctx: Context) -> tuple[float, float]:
    """(h_rms, g_rms) fed to theory/SDE/FP: continuum values of the spectrum, or those of the discrete surface
    on the smallest grid that carries lambda_s (M2: the mode set does not depend on the grid)."""
    from gapsweep import surface

    sp = t.surface_params()
    if t.opt("h_rms") == "continuum":
        if "rms_height" in sp:
            return sp["rms_height"], math.nan
        g = sp["rms_slope"]
        return surface.continuum_rms_height(t.hurst, lambda_l=sp["lambda_l"], lambda_s=sp["lambda_s"],
                                            rms_slope=g), g
    n = 2 * int(math.floor(sp["length"] / sp["lambda_s"] * (1 + 1e-9))) + 2
    return ctx.surface_rms(t, n)


def _extra(t: Task) -> dict[str, Any]:
    return {k[6:]: v for k, v in t.options if k.startswith("extra.")}


def _hist(t: Task, samples: Any, exclude_zero: bool = False) -> tuple[np.ndarray, np.ndarray, int]:
    """Histogram ``(edges, density, count)`` of the finite samples over the job's bins and range (``"auto"``:
    the samples' min..max). A cupy array is binned on its GPU with the same edges (only the counts come back).
    ``exclude_zero`` (hard wall): the points at exactly 0 (the contact atom, stored apart) are left out and the
    density of the others integrates to their fraction ``1 - atom``."""
    from gapsweep.gfmd._ops import _is_cupy

    if exclude_zero:
        size = samples.size
        samples = samples[samples != 0.0]
        edges, dens, count = _hist(t, samples)
        return edges, dens * (count / size if size else 0.0), count
    if _is_cupy(samples):
        return _hist_device(t, samples)
    finite = samples[np.isfinite(samples)]
    rng = t.opt("range")
    r = None if rng == "auto" else tuple(rng)
    if r is None and finite.size and finite.min() == finite.max():
        r = (finite.min() - 0.5, finite.max() + 0.5)
    dens, edges = np.histogram(finite, bins=t.opt("bins"), range=r)
    total = dens.sum()
    width = np.diff(edges)
    density = dens / (total * width) if total else np.zeros_like(width)
    return edges, density, int(total)


def _hist_device(t: Task, samples: Any) -> tuple[np.ndarray, np.ndarray, int]:
    """:func:`_hist` of a cupy array: numpy's edges for the range, counts on the GPU (bin ``k`` holds
    ``edges[k] <= x < edges[k+1]``, the last bin closed, as numpy's)."""
    import cupy

    finite = samples[cupy.isfinite(samples)]
    rng = t.opt("range")
    if rng != "auto":
        r = (float(rng[0]), float(rng[1]))
    elif finite.size:
        lo, hi = float(finite.min()), float(finite.max())
        r = (lo - 0.5, hi + 0.5) if lo == hi else (lo, hi)
    else:
        r = (0.0, 1.0)  # numpy's default range for no data
    edges = np.histogram_bin_edges(np.empty(0), bins=t.opt("bins"), range=r)
    counts, _ = cupy.histogram(finite, bins=cupy.asarray(edges))
    dens = cupy.asnumpy(counts)
    total = dens.sum()
    width = np.diff(edges)
    density = dens / (total * width) if total else np.zeros_like(width)
    return edges, density, int(total)


def _run_persson(t: Task, ctx: Context) -> dict[str, float]:
    """Persson's hard-wall theory (gapsweep.theory.persson, docs/theory.md): contact area (``persson_variant``)
    and mean interfacial separation (``persson_gamma``) at ``sigma0``, from the self-affine spectrum's parameters
    or, for a file surface, from the map's own spectrum (``heights=``)."""
    from gapsweep import surface
    from gapsweep.theory import persson

    sp = t.surface_params()
    kw: dict[str, Any] = {"e_star": t.opt("e_star"), "length": sp["length"]}
    if sp.get("kind") == "file":
        h = ctx.surface(t, 0)
        kw["heights"] = h
        h_rms, g_rms = surface.rms_height(h), surface.rms_slope(h, sp["length"])
    else:
        kw.update(hurst=t.hurst, lambda_l=sp["lambda_l"], lambda_s=sp["lambda_s"])
        for k in ("rms_slope", "rms_height", "c0"):
            if k in sp:
                kw[k] = sp[k]
        h_rms, g_rms = math.nan, sp.get("rms_slope", math.nan)  # continuum values of the spectrum (M2)
        if "rms_height" in sp:
            h_rms = sp["rms_height"]
        elif "rms_slope" in sp:
            h_rms = surface.continuum_rms_height(t.hurst, lambda_l=sp["lambda_l"], lambda_s=sp["lambda_s"],
                                                 rms_slope=sp["rms_slope"])
    area = float(persson.contact_area(t.sigma0, variant=t.opt("persson_variant"), **kw))
    sep = float(persson.mean_separation(t.sigma0, gamma=t.opt("persson_gamma"), **kw))
    return {"h_rms": h_rms, "g_rms": g_rms, "mean_gap_persson": sep, "contact_area": area}


def _run_theory(t: Task, ctx: Context, prev: Any) -> tuple[TaskResult, Any]:
    from gapsweep import theory

    if t.opt("forms") == ["persson"]:
        v = _run_persson(t, ctx)
        v["mean_gap"] = v["mean_gap_persson"]
        return TaskResult("done", "", v), None
    h_rms, g_rms = _moments(t, ctx)
    sp = t.surface_params()
    kw = dict(hurst=t.hurst, h_rms=h_rms, rho=t.rho, gamma0=t.opt("gamma0"), lambda_l=sp["lambda_l"],
              lambda_s=sp["lambda_s"], e_star=t.opt("e_star"), **_extra(t))
    v: dict[str, float] = {"h_rms": h_rms, "g_rms": g_rms}
    for form in t.opt("forms"):
        if form == "discrete":
            # theory.mean_gap_discrete(sigma0, h, ...) with the surface's spectrum computed once per surface
            v["mean_gap_discrete"] = float(theory.field.mean_gap_spectrum(
                t.sigma0, ctx.spectrum(t, t.n), rho=t.rho, gamma0=t.opt("gamma0"), e_star=t.opt("e_star")))
        else:
            v[f"mean_gap_{form}"] = float(theory.mean_gap(t.sigma0, form=form, **kw))
    v["mean_gap"] = v[f"mean_gap_{t.opt('forms')[0]}"]
    return TaskResult("done", "", v), None


def _keep_fields(t: Task, ctx: Context, res: Any, h: np.ndarray, gap: np.ndarray, length: float) -> None:
    """Write the fields this task keeps (``[methods.gfmd] keep_fields``) beside the store (gapsweep.dataset)."""
    from gapsweep import dataset

    want = dataset.field_selected(json.loads(t.opt("keep_fields")), hurst=t.hurst, rho=t.rho, sigma0=t.sigma0,
                                  seed=t.seed, n=t.n)
    if not want:
        return
    g0 = float(res.mean_gap)
    arrays = {"gap": gap, "height": np.asarray(h, dtype=float)}
    arrays["displacement"] = gap - g0 + arrays["height"]  # g = g0 + u - h (docs/model.md M3)
    arrays["pressure"] = np.asarray(getattr(res, "pressure", None) if getattr(res, "pressure", None) is not None
                                    else t.opt("gamma0") / t.rho * np.exp(-gap / t.rho), dtype=float)
    attrs = {"method": t.method, "hurst": t.hurst, "rho": t.rho, "sigma0": t.sigma0, "seed": t.seed, "n": t.n,
             "e_star": t.opt("e_star"), "mean_gap": g0, "residual": float(res.residual), "interaction": t.law}
    if t.opt("gamma0") is not None:
        attrs["gamma0"] = t.opt("gamma0")
    dataset.write_fields(ctx.fields_dir, t.task_id, {k: arrays[k] for k in want}, length=length, attrs=attrs)


def use_gpu(t: Task, ctx: Context) -> None:
    """Make this rank's GPU current for a GFMD task with ``backend = "cupy"`` (clear error without cupy)."""
    if t.opt("backend") == "cupy":
        from gapsweep._extras import require

        cupy = require("cupy", 'GFMD on the GPU (backend = "cupy")')
        cupy.cuda.Device(ctx.gpu or 0).use()  # this rank's GPU (one GPU per rank on a node)


def gfmd_host_fields(t: Task, ctx: Context) -> bool | tuple[str, ...]:
    """Fields a GFMD task needs on the host: all when it keeps fields (gapsweep.dataset), else none -- the
    store's statistics and histogram of the gap are computed where the gap lives (on the GPU for cupy)."""
    if t.opt("keep_fields") and getattr(ctx, "fields_dir", None) is not None:
        from gapsweep import dataset

        if dataset.field_selected(json.loads(t.opt("keep_fields")), hurst=t.hurst, rho=t.rho, sigma0=t.sigma0,
                                  seed=t.seed, n=t.n):
            return True
    return False


def _run_gfmd(t: Task, ctx: Context, prev: Any) -> tuple[TaskResult, Any]:
    from gapsweep import gfmd

    sp = t.surface_params()
    use_gpu(t, ctx)
    h = ctx.surface_on_gpu(t, t.n) if t.opt("backend") == "cupy" else ctx.surface(t, t.n)
    res = gfmd.solve(h, sigma0=t.sigma0, **law_params(t), e_star=t.opt("e_star"),
                     length=sp["length"], tol=t.opt("tol"), method=t.opt("method"), backend=t.opt("backend"),
                     max_iter=t.opt("max_iter"), initial=prev if t.opt("warm_start") else None,
                     host=gfmd_host_fields(t, ctx), **_extra(t))
    return gfmd_row(t, ctx, res, prev)


def law_params(t: Task) -> dict[str, Any]:
    """``interaction=`` and the law's keywords of gfmd.solve for a task (docs/gfmd.md): the exponential law
    takes gamma0 and rho, the hard wall nothing, the adhesive law the work of adhesion and rho."""
    law = t.law
    if law == "exponential":
        return {"gamma0": t.opt("gamma0"), "rho": t.rho}
    if law == "hard_wall":
        return {"interaction": "hard_wall"}
    return {"interaction": law, "work": t.opt("work"), "rho": t.rho}


def gfmd_row(t: Task, ctx: Context, res: Any, prev: Any = None) -> tuple[TaskResult, Any]:
    """Store row of a GFMD result and the warm start it gives the next task of its chain (the converged
    result, else None). The gap's statistics and histogram are taken where the gap lives (numpy or cupy).
    Every law stores contact_area, elastic_energy, the pressure histogram and its atom at p = 0; the hard wall
    its contact atom at g = 0 apart from the gap histogram; ``prev`` (the previous step's result, non-exponential
    laws) marks jumps along the load path in ``flags``."""
    from gapsweep.gfmd._ops import _is_cupy

    gap = res.gap
    xp = np
    if _is_cupy(gap):
        import cupy as xp
    else:
        gap = np.asarray(gap, dtype=float)
    h_rms, g_rms = ctx.surface_rms(t, t.n)
    if t.opt("keep_fields") and getattr(ctx, "fields_dir", None) is not None:
        sp = t.surface_params()
        _keep_fields(t, ctx, res, ctx.surface(t, t.n), np.asarray(_host(gap), dtype=float), sp["length"])
    v = {"mean_gap": float(res.mean_gap), "h_rms": h_rms, "g_rms": g_rms,
         "residual": float(res.residual), "load_error": float(getattr(res, "load_error", math.nan)),
         "iterations": int(res.iterations), "gap_std": float(xp.std(gap)), "gap_min": float(xp.min(gap)),
         "gap_max": float(xp.max(gap)), "contact_area": float(getattr(res, "contact_area", math.nan)),
         "elastic_energy": float(getattr(res, "elastic_energy", math.nan)), "flags": 0}
    ok = bool(res.converged) and math.isfinite(v["mean_gap"])
    status = "done" if ok else "not_converged"
    msg = "" if ok else f"gfmd: {getattr(res, 'status', 'not converged')} (residual {v['residual']:.3g})"
    if not (math.isfinite(v["contact_area"]) and math.isfinite(v["elastic_energy"])):
        _fill_quantities(t, res, v, gap, xp)
    hard = t.law == "hard_wall"
    if hard:  # the contact atom at g = 0 is stored apart; the histogram is that of the free points
        v["contact_atom"] = float(res.contact_atom())
    phist = None
    if getattr(res, "pressure", None) is not None:
        phist, v["pressure_atom"] = _pressure_hist(t, res.pressure, xp)
    if getattr(res, "status", "") == "detached":
        v["flags"] |= FLAG_DETACHED
        msg = (f"gfmd: detached at sigma0 = {t.sigma0:g} (beyond pull-off: no equilibrium in contact; "
               "later, more tensile loads of the chain cannot be in contact either)")
    # Jumps only where the energy is not convex (adhesion), by gfmd.solve_path's secant criterion: the mean gap
    # moves by more than JUMP_FACTOR times what the secant dg0/dsigma0 of the two previous steps predicts (a
    # branch that ends: snap-off, snap-in). Steps must be fine enough for the secant to hold on a smooth branch;
    # the first two steps of a chain have no secant and are not judged (docs/store.md "flags").
    if t.law == "adhesive" and prev is not None and hasattr(prev, "contact_area") and ok:
        before = getattr(prev, "_prev_step", None)
        dg = abs(v["mean_gap"] - float(prev.mean_gap))
        predicted = math.inf
        if before is not None and before[0] != float(prev.sigma0):
            predicted = abs((float(prev.mean_gap) - before[1]) / (float(prev.sigma0) - before[0])
                            * (t.sigma0 - float(prev.sigma0)))
        if dg > JUMP_FACTOR * predicted:
            v["flags"] |= FLAG_JUMP
            msg = (f"jump along the load path: contact area {float(prev.contact_area):.4g} -> "
                   f"{v['contact_area']:.4g}, mean gap {float(prev.mean_gap):.4g} -> {v['mean_gap']:.4g} "
                   f"from sigma0 = {float(prev.sigma0):g}")
    if t.law != "exponential" and ok:
        res._prev_step = (float(prev.sigma0), float(prev.mean_gap)) if hasattr(prev, "mean_gap") else None
    # warm start from the converged solution only. Exponential law: only its displacement is kept (the other
    # fields are dropped with the result once the row is made); the other laws start from the whole result
    # (hard wall: its pressure; adhesive: displacement and mean gap) and it marks jumps.
    state = (res.displacement if t.law == "exponential" else res) if ok else None
    return TaskResult(status, msg, v, _hist(t, gap, exclude_zero=hard), phist), state


def _fill_quantities(t: Task, res: Any, v: dict[str, float], gap: Any, xp: Any) -> None:
    """contact_area and elastic_energy of a result that lacks them (the batched exponential minimiser): the law's
    contact criterion on the gap, and ``(E*/4) sum_q q |u~(q)|^2`` with ``u~ = FFT(u)/N^2`` (docs/gfmd.md)."""
    from gapsweep.gfmd.interactions import resolve

    if not math.isfinite(v["contact_area"]):
        law = resolve(t.law, **{k: x for k, x in law_params(t).items() if k != "interaction"})
        v["contact_area"] = float(xp.count_nonzero(law.contact(gap, res.pressure))) / gap.size
    u = getattr(res, "displacement", None)
    if not math.isfinite(v["elastic_energy"]) and u is not None:
        nx, ny = u.shape
        length = t.opt("surface.length")
        qx = 2 * np.pi * np.fft.fftfreq(nx, d=length / nx)
        qy = 2 * np.pi * np.fft.fftfreq(ny, d=length / ny)
        q = xp.asarray(np.hypot(qx[:, None], qy[None, :]))
        uq = xp.fft.fft2(u) / (nx * ny)
        v["elastic_energy"] = float(0.25 * t.opt("e_star") * xp.sum(q * xp.abs(uq) ** 2))


def _pressure_hist(t: Task, p: Any, xp: Any) -> tuple[tuple[np.ndarray, np.ndarray], float]:
    """Pressure histogram ``(edges, density)`` over the store's bin count, range the loaded points' min..max,
    and the atom at exactly ``p = 0`` (the hard wall's free surface): the density of the other points integrates
    to ``1 - atom`` (docs/store.md)."""
    size = p.size
    loaded = p[p != 0.0]
    atom = 1.0 - loaded.size / size
    bins = t.opt("bins")
    if loaded.size == 0:
        return (np.linspace(0.0, 1.0, bins + 1), np.zeros(bins)), atom
    lo, hi = float(xp.min(loaded)), float(xp.max(loaded))
    if lo == hi:
        lo, hi = lo - 0.5 * abs(lo or 1.0), hi + 0.5 * abs(hi or 1.0)
    edges = np.linspace(lo, hi, bins + 1)
    counts, _ = xp.histogram(loaded, bins=xp.asarray(edges) if xp is not np else edges)
    counts = _host(counts)
    return (edges, counts / (size * np.diff(edges))), atom


def _host(a: Any) -> np.ndarray:
    return a.get() if hasattr(a, "get") and not isinstance(a, np.ndarray) else np.asarray(a)


def _run_sde(t: Task, ctx: Context, prev: Any) -> tuple[TaskResult, Any]:
    from gapsweep import sde

    h_rms, g_rms = _moments(t, ctx)
    sp = t.surface_params()
    device = t.opt("device")
    if device == "cuda":
        device = f"cuda:{ctx.gpu or 0}"
    kw = dict(hurst=t.hurst, h_rms=h_rms, rho=t.rho, gamma0=t.opt("gamma0"), lambda_l=sp["lambda_l"],
              lambda_s=sp["lambda_s"], e_star=t.opt("e_star"), c2=t.opt("c2"), dzeta=t.opt("dzeta"),
              n=t.opt("samples"), seed=t.seed, device=device, dtype=t.opt("dtype"), **_extra(t))
    if t.opt("c1") is not None:
        kw["c1"] = t.opt("c1")
    if t.opt("zeta_end") is not None:
        kw["zeta_end"] = t.opt("zeta_end")
    if t.opt("samples") > SDE_HOST_SAMPLES_MAX:
        return _sde_binned(t, kw, {"h_rms": h_rms, "g_rms": g_rms}), None
    g = np.asarray(sde.gap_samples(t.sigma0, **kw), dtype=np.float64)
    fin = np.isfinite(g)
    nbad = int(g.size - fin.sum())
    gf = g[fin]
    v = {"h_rms": h_rms, "g_rms": g_rms, "mean_gap": float(gf.mean()) if gf.size else math.nan,
         "gap_std": float(gf.std()) if gf.size else math.nan,
         "gap_min": float(gf.min()) if gf.size else math.nan, "gap_max": float(gf.max()) if gf.size else math.nan}
    status, msg = ("done", "") if nbad == 0 else ("not_converged", f"sde: {nbad} of {g.size} samples not finite")
    return TaskResult(status, msg, v, _hist(t, g)), None


def _sde_binned(t: Task, kw: dict[str, Any], v: dict[str, float]) -> TaskResult:
    """SDE row from a histogram binned on the device (M5 ensemble; only the counts reach the host).

    Range: the job's ``[lo, hi]``, or for ``"auto"`` the SDE's default ``g0 -/+ 6 sd`` (widened for the
    repulsion; ``sde._default_edges``), not the data's min..max as on the exact path. Each store bin is split
    into ``K = SDE_SUB_BINS`` equal sub-bins of width ``w``; the stored histogram is the sub-bin counts summed
    back (density over the binned samples, count = samples inside the range). Moments are those of the sub-bin
    centres ``c_j`` with Sheppard's correction: ``mean = sum n_j c_j / N`` (within ``w/2`` of the exact mean of
    the binned samples), ``std^2 = sum n_j (c_j - mean)^2 / N - w^2/12``; ``gap_min``/``gap_max`` are the outer
    edges of the outermost occupied sub-bins (bounds at sub-bin resolution). Samples outside the range are not
    in the moments (the row's message says how many).
    """
    from gapsweep import sde

    bins, rng = t.opt("bins"), t.opt("range")
    if rng == "auto":
        names = inspect.signature(sde.plan_steps).parameters
        plan = sde.plan_steps(t.sigma0, **{k: x for k, x in kw.items() if k in names})
        coarse = sde._default_edges(plan, bins)
        lo, hi = float(coarse[0]), float(coarse[-1])
    else:
        lo, hi = float(rng[0]), float(rng[1])
    edges = np.linspace(lo, hi, bins + 1)  # the same edges as np.histogram(range=(lo, hi)) on the exact path
    k = SDE_SUB_BINS
    # sub-edges contain the store edges exactly, so summing sub-bins back gives the store bins' counts
    sub = np.append(np.linspace(edges[:-1], edges[1:], k + 1, axis=1)[:, :-1].ravel(), edges[-1])
    r = sde.gap_histogram_counts(t.sigma0, bins=sub, **kw)
    counts = np.asarray(r.counts, dtype=np.int64)
    coarse_counts = counts.reshape(bins, k).sum(axis=1)
    total = int(counts.sum())
    width = np.diff(edges)
    density = coarse_counts / (total * width) if total else np.zeros_like(width)
    msgs = []
    if total:
        centres = 0.5 * (sub[:-1] + sub[1:])
        mean = float(np.dot(counts, centres) / total)
        w = float(np.mean(np.diff(sub)))
        var = float(np.dot(counts, (centres - mean) ** 2) / total) - w * w / 12.0  # Sheppard's correction
        occ = np.flatnonzero(counts)
        v.update(mean_gap=mean, gap_std=math.sqrt(max(var, 0.0)), gap_min=float(sub[occ[0]]),
                 gap_max=float(sub[occ[-1] + 1]))
    else:
        v.update(mean_gap=math.nan, gap_std=math.nan, gap_min=math.nan, gap_max=math.nan)
    status = "done" if r.nonfinite == 0 and total else "not_converged"
    if r.nonfinite:
        msgs.append(f"sde: {r.nonfinite} of {r.n} samples not finite")
    if r.below + r.above:
        msgs.append(f"sde: {r.below + r.above} of {r.n} samples outside the histogram range "
                    "(moments from binned samples)")
    if not total:
        msgs.append("sde: no sample inside the histogram range (no moments)")
    return TaskResult(status, "; ".join(msgs), v, (edges, density, total))


def _run_fokker_planck(t: Task, ctx: Context, prev: Any) -> tuple[TaskResult, Any]:
    from gapsweep import fokker_planck

    h_rms, g_rms = _moments(t, ctx)
    sp = t.surface_params()
    kw = dict(hurst=t.hurst, h_rms=h_rms, rho=t.rho, gamma0=t.opt("gamma0"), lambda_l=sp["lambda_l"],
              lambda_s=sp["lambda_s"], e_star=t.opt("e_star"), c2=t.opt("c2"), **_extra(t))
    if t.opt("c1") is not None:
        kw["c1"] = t.opt("c1")
    res = fokker_planck.solve(t.sigma0, **kw)
    g_edges = res.g_edges()  # cell edges in g at the final magnification
    v: dict[str, float] = {"h_rms": h_rms, "g_rms": g_rms, "mean_gap": res.mean(),
                           "gap_std": float(np.sqrt(max(0.0, res.variance()))), "gap_min": float(g_edges[0]),
                           "gap_max": float(g_edges[-1]), "residual": float(res.mass_error),
                           "iterations": int(res.n_steps)}
    rng = t.opt("range")
    lo, hi = (g_edges[0], g_edges[-1]) if rng == "auto" else rng
    edges = np.linspace(lo, hi, t.opt("bins") + 1)
    dens = res.bin_density(edges)
    ok = res.status == "ok" and all(math.isfinite(v[k]) for k in ("mean_gap", "gap_std"))
    msg = "" if ok else (f"fokker_planck: {res.status} (edge mass {res.edge_mass:.3g}, step error "
                         f"{res.error:.3g} of the sd, tol {res.tol})")
    return TaskResult("done" if ok else "not_converged", msg, v, (edges, dens, 0)), None


_RUN = {"theory": _run_theory, "gfmd": _run_gfmd, "sde": _run_sde, "fokker_planck": _run_fokker_planck}


# The solver function that receives each method's ``extra`` options, and the keywords the task sets itself.
_EXTRA_TARGET = {
    "theory": ("gapsweep.theory", "mean_gap", ("sigma0", "form", "hurst", "h_rms", "rho", "gamma0", "lambda_l",
                                               "lambda_s", "e_star")),
    "gfmd": ("gapsweep.gfmd", "solve", ("heights", "sigma0", "gamma0", "rho", "e_star", "length", "tol", "method",
                                        "backend", "max_iter", "initial", "interaction", "work")),
    "sde": ("gapsweep.sde", "gap_samples", ("sigma0", "hurst", "h_rms", "rho", "gamma0", "lambda_l", "lambda_s",
                                            "e_star", "c1", "c2", "dzeta", "zeta_end", "n", "seed", "device",
                                            "dtype", "bins")),
    "fokker_planck": ("gapsweep.fokker_planck", "solve", ("sigma0", "hurst", "h_rms", "rho", "gamma0", "lambda_l",
                                                          "lambda_s", "e_star", "c1", "c2")),
}


def check_extra(spec: JobSpec) -> None:
    """Check every ``[methods.<m>.extra]`` key against the signature of the solver it is passed to (at plan
    time, so that a typo fails before a sweep instead of failing every task). Raises ``SpecError``."""
    import importlib

    from gapsweep.spec import SpecError

    for m, o in spec.methods.items():
        extra = o.get("extra", {})
        if not extra:
            continue
        mod, fn, fixed = _EXTRA_TARGET[m]
        params = inspect.signature(getattr(importlib.import_module(mod), fn)).parameters
        names = [k for k, p in params.items() if p.kind in (p.POSITIONAL_OR_KEYWORD, p.KEYWORD_ONLY)]
        allowed = [k for k in names if k not in fixed]
        for k in extra:
            if k in fixed:
                raise SpecError(f"methods.{m}.extra.{k}: set by the sweep itself (use the method's own key or the "
                                "grid), not allowed in extra")
            if k not in names:
                raise SpecError(f"methods.{m}.extra.{k}: not a parameter of {mod}.{fn}; allowed extra keys: "
                                f"{', '.join(allowed) or '(none)'}")


def _non_finite(res: TaskResult) -> list[str]:
    return [k for k, v in res.values.items() if k.startswith("mean_gap") and not math.isfinite(v)]


def run_task(t: Task, ctx: Context, prev: Any = None) -> tuple[TaskResult, Any]:
    """Run one task; never raises: an exception becomes status ``failed`` with the message.
    Returns the result and the warm-start state for the next task of a chain (or None)."""
    t0 = time.perf_counter()
    try:
        if ctx._delay:
            time.sleep(ctx._delay)
        if t.sigma0 in ctx._fail:
            raise RuntimeError(f"injected failure (GAPSWEEP_TEST_FAIL) at sigma0={t.sigma0!r}")
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            res, state = _RUN[t.method](t, ctx, prev)
        if caught and not res.message:  # solver warnings (e.g. under-resolved rho) go into the row's message
            w = caught[0]
            res.message = f"warning: {w.category.__name__}: {w.message}"
        bad = _non_finite(res) if res.status == "done" else []
        if bad:  # never store a NaN as success
            res.status, res.message = "failed", f"non-finite result: {', '.join(bad)}"
            state = None
    except Exception as e:  # the sweep goes on; the row records what happened
        res, state = TaskResult("failed", f"{type(e).__name__}: {e}"), None
    res.values["wall_time"] = time.perf_counter() - t0
    res.values["rank"] = ctx.rank
    return res, state


def run_unit(tasks: list[Task], unit: Unit, ctx: Context, todo: set[int] | None = None,
             ) -> Iterator[tuple[int, TaskResult]]:
    """Run a unit's tasks in order, yielding ``(task index, result)`` for those in ``todo`` (all if None).
    A chain runs from its start up to its last wanted task, so warm starts are the same as in a full run; a set
    runs only its wanted tasks; a batch unit runs through :func:`gapsweep.batching.run_batch`."""
    if unit.kind == "batch":
        from gapsweep import batching  # late: batching builds on this module

        yield from batching.run_batch(tasks, unit, ctx, set(unit.tasks) if todo is None else todo)
        return
    want = [i for i in unit.tasks if todo is None or i in todo]
    if not want:
        return
    run = unit.tasks[: unit.tasks.index(want[-1]) + 1] if unit.kind == "chain" else want
    state = None
    for i in run:
        res, state = run_task(tasks[i], ctx, state)
        if todo is None or i in todo:
            yield i, res
