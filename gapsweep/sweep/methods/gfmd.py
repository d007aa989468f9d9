"""Sweep method ``gfmd``: Green's function molecular dynamics at fixed mean pressure (docs/model.md M3,
docs/gfmd.md) with any interaction law of gapsweep.gfmd.interactions.

Spec keys (``[methods.gfmd]``, docs/jobs.md): ``n`` (grid sizes; a file surface: its own grid), ``tol``,
``max_iter``, ``method`` (the law's minimisers or "auto"), ``backend`` (FFT backend or "cupy"), ``warm_start``,
``order`` (of the pressures along a chain), ``keep_fields``, ``distributed`` (each solve split over every MPI
rank: ``gapsweep.sweep.collective``), ``extra`` (keywords of ``gapsweep.gfmd.solve``).
Columns: mean gap, rms height and slope of the surface, residual, load error, iterations, gap statistics,
contact area, elastic energy, contact and pressure atoms, flags; histograms of the gap and of the pressure.
Expansion: (hurst, rho, seed, n) chains over the pressures in ``order``; with ``warm_start`` each chain runs in
order on one rank, each solve starting from the previous converged one.
"""

from __future__ import annotations

import json
import math
from collections.abc import Iterator
from typing import Any

import numpy as np

from gapsweep.core.fft import BACKENDS as FFT_BACKENDS
from gapsweep.sweep import fields
from gapsweep.sweep import readers as rd
from gapsweep.sweep.context import Context, extra, hist, host, use_gpu
from gapsweep.sweep.methods.base import (
    LENGTH,
    Env,
    Method,
    axes,
    extend_row,
    extension_cost,
    grid_tasks,
    n_list,
    register,
)
from gapsweep.sweep.schema import (
    FIELD_NAMES,
    FLAG_DETACHED,
    FLAG_JUMP,
    SUBSTRATE_KEYS,
    Column,
    JobSpec,
    SpecError,
    Task,
    TaskResult,
    make_task,
)

JUMP_FACTOR = 3.0  # a jump: the mean gap moved by more than this times the secant prediction (docs/store.md)


def _law_methods() -> dict[str, tuple[str, ...]]:
    """Minimisers allowed for each interaction law (``method`` key), from gapsweep.gfmd's own tables."""
    from gapsweep.gfmd import _MINIMISERS
    from gapsweep.gfmd.interactions import INTERACTIONS

    return {k: _MINIMISERS[cls.load_control][1] for k, (cls, _) in INTERACTIONS.items()}


def _keep_fields_option(key: str, v: Any) -> str:
    """``keep_fields = {fields = [...], hurst = [...], rho = [...], sigma0 = [...], seeds = [...], n = [...]}``:
    the GFMD fields to keep and which tasks keep them (a missing selector: every value). Returned as canonical
    JSON (task options must be hashable). See docs/jobs.md and gapsweep.sweep.fields."""
    t = rd.table(key, v)
    rd.known(key, t, ("fields", "hurst", "rho", "sigma0", "seeds", "n"))
    names = t.get("fields")
    if not isinstance(names, list) or not names:
        raise SpecError(f"{key}.fields: expected a non-empty list from {', '.join(FIELD_NAMES)}")
    out: dict[str, Any] = {"fields": sorted({rd.string(f"{key}.fields[{i}]", f, FIELD_NAMES)
                                             for i, f in enumerate(names)})}
    for sel in ("hurst", "rho", "sigma0"):  # sigma0 may be 0 or tensile (adhesion); 0 is a placeholder axis
        if sel in t:
            vals = t[sel] if isinstance(t[sel], list) else [t[sel]]
            out[sel] = [rd.number(f"{key}.{sel}[{i}]", x, **({} if sel == "sigma0" else {"ge": 0.0}))
                        for i, x in enumerate(vals)]
    for sel in ("seeds", "n"):
        if sel in t:
            vals = t[sel] if isinstance(t[sel], list) else [t[sel]]
            out[sel] = [rd.integer(f"{key}.{sel}[{i}]", x, ge=0) for i, x in enumerate(vals)]
    return json.dumps(out, sort_keys=True)


# The algorithm's version (Method.algorithm_version, stored per row): bump it when a change moves this
# method's results beyond the tolerance its docs state (docs/store.md "Algorithm versions").
ALGORITHM_VERSION = 1


@register
class GFMD(Method):
    algorithm_version = ALGORITHM_VERSION
    name = "gfmd"
    rolloff = True  # solves any surface; the theories assume M2's spectrum
    order = 1
    keys = ("n", "tol", "max_iter", "method", "backend", "warm_start", "order", "keep_fields", "distributed",
            "split_chains")
    columns = ("mean_gap", "h_rms", "g_rms", "residual", "load_error", "iterations", "gap_std", "gap_min",
               "gap_max", "contact_area", "elastic_energy", "contact_atom", "pressure_atom", "flags", "count",
               "last_attached_load", "h_rms_spectrum", "g_rms_spectrum")
    histogram = True
    variables = {  # noqa: RUF012 - read-only table
        "mean_gap": ("gfmd_mean_gap", "mean gap g0 by GFMD", LENGTH),
        "h_rms": ("gfmd_h_rms", "rms height of the simulated surface", LENGTH),
        "g_rms": ("gfmd_g_rms", "rms gradient of the simulated surface", {"units": "1"}),
        "h_rms_spectrum": ("gfmd_h_rms_spectrum", "rms height of a measured map's spectrum", LENGTH),
        "g_rms_spectrum": ("gfmd_g_rms_spectrum", "rms gradient of a measured map's spectrum", {"units": "1"}),
        "residual": ("gfmd_residual", "GFMD residual rms(p_el - (p - <p>))/sigma0", {"units": "1"}),
        "load_error": ("gfmd_load_error", "GFMD load error |<p> - sigma0|/sigma0", {"units": "1"}),
        "iterations": ("gfmd_iterations", "GFMD iterations (force evaluations)", {"units": "1"}),
        "gap_std": ("gfmd_gap_std", "standard deviation of the gap field", LENGTH),
        "gap_min": ("gfmd_gap_min", "smallest gap of the gap field", LENGTH),
        "contact_area": ("gfmd_contact_area", "real contact area, fraction of the nominal area (by the law's "
                         "contact criterion, docs/gfmd.md)", {"units": "1"}),
        "elastic_energy": ("gfmd_elastic_energy", "stored elastic energy per nominal area (E*/4) sum q |u~(q)|^2",
                           {"units": "1", "reference_unit": "E* L"}),
        "contact_atom": ("gfmd_contact_atom", "fraction of the surface at exactly g = 0 (hard-wall contact atom, "
                         "apart from the gap histogram)", {"units": "1"}),
        "pressure_atom": ("gfmd_pressure_atom", "fraction of the surface at exactly p = 0 (hard wall: free "
                          "surface)", {"units": "1"}),
        "flags": ("gfmd_flags", "load-path flags: 1 jump from the previous step, 2 detached (adhesion)",
                  {"units": "1"}),
        "last_attached_load": ("gfmd_last_attached_load", "adhesion: the most tensile load at which the direct "
                               "solve's continuation from zero load stayed attached (pull-off bracket)",
                               {"units": "1", "reference_unit": "E*"}),
    }
    # columns of a pressure cap ([material] hardness; gapsweep.gfmd._plastic), declared here and added only to the
    # stores of jobs with a cap (job_own_columns; docs/store.md "Plug-in columns"): no edit of the store's schema
    own_columns = {  # noqa: RUF012 - read-only table
        "plastic_area": Column("float", "plastic area fraction: fraction of the nominal area at p = H (the "
                               "hard wall's pressure cap)"),
        "plastic_displacement_mean": Column("float", "mean plastic displacement <u_pl> over the nominal area "
                                            "(volume flattened per nominal area)", LENGTH),
        "plastic_displacement_max": Column("float", "largest plastic displacement max u_pl", LENGTH),
    }
    select = "n"
    takes_body = True  # [material] thickness, poisson, bottom, hardness (gapsweep.gfmd.substrates, _plastic)
    extra_target = ("gapsweep.gfmd", "solve", ("heights", "sigma0", "gamma0", "rho", "e_star", "length", "tol",
                                               "method", "backend", "max_iter", "initial", "interaction", "work",
                                               "periodic", "host", "thickness", "poisson", "bottom",
                                               "hardness"))

    def job_own_columns(self, spec: JobSpec) -> dict[str, Column]:
        """The plastic columns in the stores of jobs with ``[material] hardness`` only (other stores, their spec
        hashes and task ids stay as they were)."""
        return dict(self.own_columns) if "hardness" in spec.material else {}

    def validate(self, key: str, t: dict[str, Any], env: Env) -> dict[str, Any]:
        o: dict[str, Any] = {}
        if env.file:  # the grid of the height map itself (no resampling)
            o["n"] = [env.file_n]
            if "n" in t and n_list(f"{key}.n", t["n"], 8) != [env.file_n]:
                raise SpecError(f"{key}.n: a file surface is solved on its own grid: allowed n = {env.file_n} "
                                "(or leave n out)")
        else:
            if "n" not in t:
                raise SpecError(f"{key}.n: missing; the GFMD grid size (integer or list, >= {env.nyquist})")
            o["n"] = n_list(f"{key}.n", t["n"], env.nyquist)
        o["tol"] = rd.number(f"{key}.tol", t.get("tol", 1e-6), gt=0.0, lt=1.0)
        o["max_iter"] = rd.integer(f"{key}.max_iter", t.get("max_iter", 100000), ge=1)
        o["method"] = rd.string(f"{key}.method", t.get("method", "auto"), ("auto", *_law_methods()[env.law]))
        o["backend"] = rd.string(f"{key}.backend", t.get("backend", "auto"), ("auto", *FFT_BACKENDS))
        o["warm_start"] = rd.boolean(f"{key}.warm_start", t.get("warm_start", True))
        o["order"] = rd.string(f"{key}.order", t.get("order", "decreasing"), ("decreasing", "increasing"))
        if "keep_fields" in t:  # only when asked: the task ids of other specs stay as they were
            o["keep_fields"] = _keep_fields_option(f"{key}.keep_fields", t["keep_fields"])
        if rd.boolean(f"{key}.distributed", t.get("distributed", False)):  # only when asked, as keep_fields
            o["distributed"] = True
            _check_distributed(key, o, env)
        if "split_chains" in t:  # only when asked: the task ids of other specs stay as they were
            o["split_chains"] = _split_option(key, t["split_chains"], o, env)
        return o

    def check_job(self, spec: JobSpec) -> None:
        """Every ``keep_fields`` selector value must be one of the job's: a selector that matches no task would
        silently keep nothing."""
        o = spec.methods[self.name]
        _check_body(spec, o)
        if not o.get("keep_fields"):
            return
        sel = json.loads(o["keep_fields"])
        have = {**axes(spec, self.name), "n": o["n"]}
        for k, vals in sel.items():
            if k == "fields":
                continue
            pool = have[k]
            for v in vals:
                if not any(math.isclose(float(v), float(w), rel_tol=1e-9, abs_tol=0.0) for w in pool):
                    raise SpecError(f"methods.gfmd.keep_fields.{k}: {v!r} is not a value of the job's {k} "
                                    f"{pool}: it would keep no field")

    def expand(self, spec: JobSpec) -> Iterator[Task]:
        o = spec.methods[self.name]
        tasks = grid_tasks(spec, self.name, ns=o["n"], with_hist=True, chain=o["warm_start"], sort=True,
                           reverse=o["order"] == "decreasing")
        yield from (split_chains(tasks, o["split_chains"]) if o.get("split_chains") else tasks)

    def cost(self, t: Task) -> float:
        # ~ iterations x (FFT pair + a few array passes); preconditioned CG needs 5..30 (measured at N = 1024,
        # about 15 ms per iteration on one core with pyFFTW).
        cpu = 0.02 + 20 * 1.5e-9 * t.n * t.n * math.log2(t.n)
        # plus what its switched-on extensions add (the flow solve: gapsweep.sweep.methods.flow)
        return (cpu / 20 if t.opt("backend") == "cupy" else cpu) + extension_cost(t)[0]  # H200 ~20x a core

    def memory(self, t: Task) -> float:
        if t.opt("distributed"):  # each rank's rows (surface and solver) are sized with the rank count by
            # gapsweep.sweep.collective.check_memory; beyond them, a file map read whole by rank 0 and its spectrum
            nx, ny = t.opt("surface.shape") or (t.n, t.n)
            return 8.0 * nx * ny * 4 if t.opt("surface.kind") == "file" else 0.0
        # 4 cached surfaces + solver vectors + complex FFT buffers, and what an extension needs beside them
        return 8.0 * t.n * t.n * 28 + extension_cost(t)[1]

    def needs_gpu(self, t: Task) -> bool:
        return t.opt("backend") == "cupy"

    def gpu_memory(self, t: Task) -> float:
        """The solver's GPU memory plan (gapsweep.gfmd._cuda.solve_memory: the exponential law's measured to
        0.01 % at n >= 4096; the hard wall's counted from the code with one array of margin, issue 30). A
        distributed task's GPUs are sized with the rank count (gapsweep.sweep.collective.check_memory)."""
        if not self.needs_gpu(t) or t.opt("distributed"):
            return 0.0
        from gapsweep.gfmd._cuda import solve_memory

        if t.law == "hard_wall_adhesive":  # its own minimiser's count (gfmd._bounded.solve_memory)
            from gapsweep.gfmd._bounded import solve_memory as bounded_memory

            pairs = t.opt("extra.memory")  # [methods.gfmd.extra] memory: its L-BFGS pairs (default 10)
            return float(bounded_memory((max(t.n, 2), max(t.n, 2)), backend="cupy",
                                        **({} if pairs is None else {"memory": int(pairs)})))
        law = "hard_wall" if t.law == "hard_wall" else "exponential"
        method = t.opt("method") if t.opt("method") != "auto" else "auto"
        try:
            return float(solve_memory(max(t.n, 2), interaction=law, method=method)["bytes"])
        except ValueError:  # a method without a measured plan: the default's, a lower bound
            return float(solve_memory(max(t.n, 2), interaction=law)["bytes"])

    def run(self, t: Task, ctx: Context, prev: Any) -> tuple[TaskResult, Any]:
        return run_gfmd(t, ctx, prev)

    def warm_up_key(self, t: Task) -> tuple | None:
        return (t.law, t.opt("backend"), t.opt("method"), t.opt("surface.periodic") is False,
                t.opt("thickness") is not None, t.opt("hardness") is not None)

    def warm_up(self, t: Task, ctx: Context) -> None:
        """One solve of a 32 x 32 surface with the task's law, backend, minimiser and boundaries: numba's kernels
        compile (or load from their cache), FFT plans and GPU kernels are built."""
        from gapsweep import gfmd

        use_gpu(t, ctx)
        h = np.random.default_rng(0).standard_normal((32, 32)) * 1e-2
        if t.opt("backend") == "cupy":
            import cupy

            h = cupy.asarray(h)
        kw = law_params(t)
        if t.law != "hard_wall":
            kw["rho"] = 1e-2
        gfmd.solve(h, sigma0=abs(t.sigma0) or 1e-2, **kw, tol=1e-4, method=t.opt("method"),
                   backend=t.opt("backend"), max_iter=200, host=False, **boundaries(t), **body(t))


def _keep_fields(t: Task, ctx: Context, res: Any, h: Any, gap: Any, comm: Any = None) -> None:
    """Write the fields this task keeps (``[methods.gfmd] keep_fields``) beside the store (gapsweep.sweep.fields):
    the whole fields of one process, or (``comm``: a solve over every rank) this rank's rows of them, each rank
    writing its rows into the same file (``fields.write_field_rows``, by ``ctx.writer``). Collective with
    ``comm``. ``h``, ``gap``: the heights and the gap (or their rows), numpy or cupy."""
    want = fields.field_selected(json.loads(t.opt("keep_fields")), hurst=t.hurst, rho=t.rho, sigma0=t.sigma0,
                                  seed=t.seed, n=t.n)
    if not want:
        return
    g0 = float(res.mean_gap)
    gap = np.asarray(host(gap), dtype=float)
    arrays = {"gap": gap, "height": np.asarray(host(h), dtype=float)}
    arrays["displacement"] = gap - g0 + arrays["height"]  # g = g0 + u - h (docs/model.md M3)
    u_pl = getattr(res, "plastic_displacement", None)
    if u_pl is not None:  # a pressure cap: the gap is to the flattened surface h - u_pl (gfmd._plastic)
        u_pl = np.asarray(host(u_pl), dtype=float)
        arrays["displacement"] += float(u_pl.mean()) - u_pl
    p = getattr(res, "pressure", None)
    arrays["pressure"] = np.asarray(host(p) if p is not None else t.opt("gamma0") / t.rho * np.exp(-gap / t.rho),
                                    dtype=float)
    attrs = {"method": t.method, "hurst": t.hurst, "rho": t.rho, "sigma0": t.sigma0, "seed": t.seed, "n": t.n,
             "e_star": t.opt("e_star"), "mean_gap": g0, "residual": float(res.residual), "interaction": t.law}
    if t.opt("gamma0") is not None:
        attrs["gamma0"] = t.opt("gamma0")
    unit = t.opt("surface.to_unit") or t.opt("surface.unit")
    if unit:
        attrs["length_unit"] = unit
    if t.opt("pressure_unit"):
        attrs["pressure_unit"] = t.opt("pressure_unit")
    keep = {k: arrays[k] for k in want}
    length = t.surface_params()["length"]
    if comm is None:
        fields.write_fields(ctx.fields_dir, t.task_id, keep, length=length, attrs=attrs)
    else:
        fields.write_field_rows(ctx.fields_dir, t.task_id, keep, shape=res.shape, comm=comm, writer=ctx.writer,
                                length=length, attrs=attrs)


def gfmd_host_fields(t: Task, ctx: Context) -> bool | tuple[str, ...]:
    """Fields a GFMD task needs on the host: all when it keeps fields (gapsweep.sweep.fields), else none -- the
    store's statistics and histogram of the gap are computed where the gap lives (on the GPU for cupy)."""
    if t.opt("keep_fields") and getattr(ctx, "fields_dir", None) is not None:
        if fields.field_selected(json.loads(t.opt("keep_fields")), hurst=t.hurst, rho=t.rho, sigma0=t.sigma0,
                                 seed=t.seed, n=t.n):
            return True
    return False


# laws whose solution at a load depends on the load path (adhesive hysteresis: snap-in, pull-off, detachment): a
# chain of them is never cut (a cold start in the middle would take another branch, not the same result)
_PATH_LAWS = ("adhesive", "hard_wall_adhesive")


def _split_option(key: str, v: Any, o: dict[str, Any], env: Env) -> int:
    """``split_chains = L``: warm-started chains cut into segments of at most ``L`` pressures (docs/jobs.md)."""
    n = rd.integer(f"{key}.split_chains", v, ge=1)
    if not o["warm_start"]:
        raise SpecError(f"{key}.split_chains: only with warm_start = true (without it every task starts cold "
                        "already)")
    if env.law in _PATH_LAWS:
        raise SpecError(f"{key}.split_chains: interaction {env.law!r} depends on the load path (hysteresis): a "
                        "chain cut in the middle would start another branch; remove split_chains")
    return n


def split_chains(tasks: Iterator[Task], length: int) -> Iterator[Task]:
    """Cut every chain (tasks of one chain key, consecutive, in chain order) into segments of ``length`` tasks
    (the last may be shorter). The first segment is the chain's start as before; every task of a later segment
    gets the option ``chain_start`` = the pressure its segment starts from (cold, from the flat body), which
    enters its task id and its chain key: each segment is a chain of its own (a unit of its own,
    gapsweep.sweep.tasks.make_units) and each row says where its warm starts began. Deterministic: the cut
    depends on the job alone, never on the ranks that run it. A solve started cold converges to the same
    equilibrium within the solver's tolerance for laws with one solution per load (exponential, hard wall;
    tests/test_split_chains.py); the adhesive laws are refused (:func:`_split_option`)."""
    key, pos, start = None, 0, 0.0
    for t in tasks:
        if t.chain != key:
            key, pos = t.chain, 0
        if pos % length == 0:
            start = t.sigma0
        if pos >= length:
            opts = {**dict(t.options), "chain_start": start}
            t = make_task(t.method, t.hurst, t.rho, t.sigma0, t.seed, t.n, opts, chain=True)
        pos += 1
        yield t


def _check_body(spec: JobSpec, o: dict[str, Any]) -> None:
    """A layer or a pressure cap (``[material] thickness``, ``hardness``): one process, and the minimisers that
    solve them (gapsweep.gfmd.substrates.minimise_on)."""
    m = spec.material
    body = [k for k in SUBSTRATE_KEYS if k in m]
    if not body:
        return
    if o.get("distributed"):
        raise SpecError(f"methods.gfmd.distributed: a solve with material.{body[0]} runs on one process "
                        "(remove distributed)")
    if "hardness" in m and o.get("split_chains"):
        raise SpecError("methods.gfmd.split_chains: with material.hardness the plastic flow depends on the load "
                        "path: a chain cut in the middle would not give the same result; remove split_chains")
    if "hardness" in m:  # the method's own sigma0 (a grid override) too
        top = max(float(x) for x in axes(spec, "gfmd")["sigma0"])
        if not m["hardness"] > top:
            raise SpecError(f"material.hardness: must exceed every sigma0 of methods.gfmd (the largest is {top!r}: "
                            f"at sigma0 >= H the whole surface flows), got {m['hardness']!r}")
    if "thickness" in m:
        hard = spec.law == "hard_wall"
        ok = ("auto", "pk", "pcg", "mpcg") if hard and "hardness" in m else ("auto", "pk", "pcg") if hard else \
            ("auto", "lbfgs")
        if o["method"] not in ok:
            raise SpecError(f"methods.gfmd.method: on an elastic layer (material.thickness) allowed: "
                            f"{', '.join(map(repr, ok))}; got {o['method']!r}")


def _check_distributed(key: str, o: dict[str, Any], env: Env) -> None:
    """``distributed = true``: refuse what a solve split over ranks cannot do (docs/jobs.md)."""
    if o["backend"] not in ("auto", "numpy", "cupy"):
        raise SpecError(f"{key}.backend: a distributed solve runs on 'numpy' (CPU ranks) or 'cupy' (one GPU per "
                        f"rank), or 'auto'; got {o['backend']!r}")
    from gapsweep.gfmd.distributed import METHODS
    from gapsweep.gfmd.interactions import INTERACTIONS

    control = INTERACTIONS[env.law][0].load_control
    if control not in METHODS:
        raise SpecError(f"{key}.distributed: interaction {env.law!r} has no distributed solver; remove "
                        "distributed = true (it runs on one process)")
    allowed = METHODS[control]
    if o["method"] not in ("auto", *allowed):
        raise SpecError(f"{key}.method: a distributed {env.law} solve runs {', '.join(map(repr, allowed))} or "
                        f"'auto'; got {o['method']!r}")


def run_gfmd(t: Task, ctx: Context, prev: Any) -> tuple[TaskResult, Any]:
    from gapsweep import gfmd

    if t.opt("distributed") and getattr(ctx, "comm", None) is not None:  # gapsweep.sweep.collective
        return run_slab(t, ctx, prev)
    sp = t.surface_params()
    use_gpu(t, ctx)
    h = ctx.surface_on_gpu(t, t.n) if t.opt("backend") == "cupy" else ctx.surface(t, t.n)
    res = gfmd.solve(h, sigma0=t.sigma0, **law_params(t), e_star=t.opt("e_star"),
                     length=sp["length"], tol=t.opt("tol"), method=t.opt("method"), backend=t.opt("backend"),
                     max_iter=t.opt("max_iter"), initial=prev if t.opt("warm_start") else None,
                     host=gfmd_host_fields(t, ctx), **boundaries(t), **body(t), **extra(t))
    return gfmd_row(t, ctx, res, prev)


def body(t: Task) -> dict[str, Any]:
    """The body's keywords of gfmd.solve beyond E* (``[material] thickness, poisson, bottom, hardness``: an
    elastic layer, the hard wall's pressure cap; gapsweep.sweep.spec.SUBSTRATE_KEYS): those the job gives."""
    return {k: t.opt(k) for k in SUBSTRATE_KEYS if t.opt(k) is not None}


def boundaries(t: Task) -> dict[str, Any]:
    """``periodic=False`` for a measured map solved with free boundaries (docs/gfmd.md "Periodic or free
    boundaries"); nothing for periodic surfaces (older task ids and calls stay as they were)."""
    return {"periodic": False} if t.opt("surface.periodic") is False else {}


def law_params(t: Task) -> dict[str, Any]:
    """``interaction=`` and the law's keywords of gfmd.solve for a task (docs/gfmd.md): the exponential law
    takes gamma0 and rho, the hard wall nothing, the adhesive law the work of adhesion and rho."""
    law = t.law
    if law == "exponential":
        return {"gamma0": t.opt("gamma0"), "rho": t.rho}
    if law == "hard_wall":
        return {"interaction": "hard_wall"}
    return {"interaction": law, "work": t.opt("work"), "rho": t.rho}


class LocalStats:
    """The surface's rms values, the gap's statistics and histograms of a row, and the kept fields, from the whole
    fields on this process (numpy or cupy); :class:`_SlabStats` has those of fields split in rows over ranks."""

    def rms(self, t: Task, ctx: Context) -> tuple[float, float]:
        return ctx.surface_rms(t, t.n)

    def spectrum_rms(self, t: Task, ctx: Context) -> tuple[float, float]:
        return ctx.surface_spectrum_rms(t, t.n)

    def keep(self, t: Task, ctx: Context, res: Any, gap: Any) -> None:
        _keep_fields(t, ctx, res, ctx.surface(t, t.n), gap)

    def gap(self, gap: Any, xp: Any) -> dict[str, float]:
        return {"gap_std": float(xp.std(gap)), "gap_min": float(xp.min(gap)), "gap_max": float(xp.max(gap))}

    def hist(self, t: Task, gap: Any, exclude_zero: bool) -> tuple[np.ndarray, np.ndarray, int]:
        return hist(t, gap, exclude_zero=exclude_zero)

    def pressure_hist(self, t: Task, p: Any, xp: Any) -> tuple[tuple[np.ndarray, np.ndarray], float]:
        return _pressure_hist(t, p, xp)


def gfmd_row(t: Task, ctx: Context, res: Any, prev: Any = None, stats: Any = None) -> tuple[TaskResult, Any]:
    """Store row of a GFMD result and the warm start it gives the next task of its chain (the converged
    result, else None). The gap's statistics and histogram are taken where the gap lives (numpy or cupy).
    Every law stores contact_area, elastic_energy, the pressure histogram and its atom at p = 0; the hard wall
    its contact atom at g = 0 apart from the gap histogram; ``prev`` (the previous step's result, non-exponential
    laws) marks jumps along the load path in ``flags``."""
    from gapsweep.gfmd._ops import _is_cupy

    stats = stats or LocalStats()
    gap = res.gap
    xp = np
    if _is_cupy(gap):
        import cupy as xp
    else:
        gap = np.asarray(gap, dtype=float)
    h_rms, g_rms = stats.rms(t, ctx)
    h_spec, g_spec = stats.spectrum_rms(t, ctx)
    if t.opt("keep_fields") and getattr(ctx, "fields_dir", None) is not None:
        stats.keep(t, ctx, res, gap)
    v = {"mean_gap": float(res.mean_gap), "h_rms": h_rms, "g_rms": g_rms, "h_rms_spectrum": h_spec,
         "g_rms_spectrum": g_spec, "residual": float(res.residual),
         "load_error": float(getattr(res, "load_error", math.nan)),
         "iterations": int(res.iterations), **stats.gap(gap, xp),
         "contact_area": float(getattr(res, "contact_area", math.nan)),
         "elastic_energy": float(getattr(res, "elastic_energy", math.nan)), "flags": 0,
         # adhesion at a tensile load: where continuation from zero load stayed attached (the pull-off bracket)
         "last_attached_load": float(getattr(res, "diagnostics", {}).get("last_attached_load", math.nan))}
    ok = bool(res.converged) and math.isfinite(v["mean_gap"])
    status = "done" if ok else "not_converged"
    msg = "" if ok else f"gfmd: {getattr(res, 'status', 'not converged')} (residual {v['residual']:.3g})"
    if not (math.isfinite(v["contact_area"]) and math.isfinite(v["elastic_energy"])):
        _fill_quantities(t, res, v, gap, xp)
    hard = t.law in ("hard_wall", "hard_wall_adhesive")
    if hard:  # the contact atom at g = 0 is stored apart; the histogram is that of the free points
        v["contact_atom"] = float(res.contact_atom())
    phist = None
    if getattr(res, "pressure", None) is not None:
        phist, v["pressure_atom"] = stats.pressure_hist(t, res.pressure, xp)
    if t.opt("hardness") is not None:  # the pressure cap's own columns (GFMD.own_columns)
        v.update(_plastic_values(res))
    if getattr(res, "status", "") == "detached":
        v["flags"] |= FLAG_DETACHED
        msg = (f"gfmd: detached at sigma0 = {t.sigma0:g} (beyond pull-off: no equilibrium in contact; "
               "later, more tensile loads of the chain cannot be in contact either)")
    # Jumps only where the energy is not convex (adhesion), by gfmd.solve_path's secant criterion: the mean gap
    # moves by more than JUMP_FACTOR times what the secant dg0/dsigma0 of the two previous steps predicts (a
    # branch that ends: snap-off, snap-in). Steps must be fine enough for the secant to hold on a smooth branch;
    # the first two steps of a chain have no secant and are not judged (docs/store.md "flags").
    if t.law in ("adhesive", "hard_wall_adhesive") and prev is not None and hasattr(prev, "contact_area") and ok:
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
    # (hard wall: its pressure; adhesive: displacement and mean gap; hard_wall_adhesive: its gap) and it marks jumps.
    state = (res.displacement if t.law == "exponential" else res) if ok else None
    # the switched-on extensions' columns (e.g. the leak rate of gapsweep.sweep.methods.flow) from this result
    return extend_row(t, res, TaskResult(status, msg, v, stats.hist(t, gap, hard), phist)), state


def _plastic_values(res: Any) -> dict[str, float]:
    """``plastic_area`` (fraction at ``p = H``), the mean and the largest plastic displacement ``u_pl`` (units of
    the surface's lengths; 0 off the plastic set) of a capped hard-wall result (gapsweep.gfmd._plastic)."""
    u = getattr(res, "plastic_displacement", None)
    out = {"plastic_area": float(getattr(res, "plastic_area", math.nan)),
           "plastic_displacement_mean": math.nan, "plastic_displacement_max": math.nan}
    if u is not None:
        uxp = _xp(u)  # where the field lives (numpy or cupy)
        out["plastic_displacement_mean"] = float(uxp.mean(u))
        out["plastic_displacement_max"] = float(uxp.max(u))
    return out


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
        lx, ly = (length, length) if np.isscalar(length) else length
        qx = 2 * np.pi * np.fft.fftfreq(nx, d=lx / nx)
        qy = 2 * np.pi * np.fft.fftfreq(ny, d=ly / ny)
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
    counts = host(counts)
    return (edges, counts / (size * np.diff(edges))), atom


# ---------------------------------------------------------------------------------------------- distributed
class _SlabStats:
    """The row's surface rms values, gap statistics and histograms of fields split in rows over the ranks (the
    same numbers as :class:`LocalStats` of the whole field, up to summation order: reductions over ``comm``), and
    the kept fields written by rows (every rank its own). Collective."""

    def __init__(self, comm: Any) -> None:
        from gapsweep.core.slab import Reducer

        self.comm = comm
        self.red = Reducer(comm)

    def rms(self, t: Task, ctx: Context) -> tuple[float, float]:
        return ctx.surface_rows_rms(t, t.n, self.comm)

    def spectrum_rms(self, t: Task, ctx: Context) -> tuple[float, float]:
        return ctx.surface_rows_spectrum_rms(t, t.n, self.comm)

    def keep(self, t: Task, ctx: Context, res: Any, gap: Any) -> None:
        _keep_fields(t, ctx, res, ctx.surface_rows(t, t.n, self.comm), gap, comm=self.comm)

    def gap(self, gap: Any, xp: Any) -> dict[str, float]:
        n = self.red.sum(float(gap.size))
        (s,), (lo,), (hi,) = self.red.many(sums=(float(xp.sum(gap)),), mins=(_amin(gap),), maxs=(_amax(gap),))
        mean = s / n
        var = self.red.sum(float(xp.sum((gap - mean) ** 2))) / n
        return {"gap_std": math.sqrt(var), "gap_min": lo, "gap_max": hi}

    def _counts(self, a: Any, edges: np.ndarray, xp: Any) -> np.ndarray:
        c, _ = xp.histogram(a, bins=xp.asarray(edges) if xp is not np else edges)
        c = c.get() if xp is not np else c
        return np.asarray(self.red.sum(*[float(x) for x in c]), dtype=np.float64).reshape(-1)

    def hist(self, t: Task, gap: Any, exclude_zero: bool) -> tuple[np.ndarray, np.ndarray, int]:
        """``gapsweep.sweep.context.hist`` of the whole field."""
        xp = _xp(gap)
        size = self.red.sum(float(gap.size))
        a = gap[gap != 0.0] if exclude_zero else gap
        a = a[xp.isfinite(a)]
        rng = t.opt("range")
        if rng != "auto":
            r = (float(rng[0]), float(rng[1]))
        else:
            _, (lo,), (hi,) = self.red.many(mins=(_amin(a),), maxs=(_amax(a),))
            r = (0.0, 1.0) if not math.isfinite(lo) else ((lo - 0.5, hi + 0.5) if lo == hi else (lo, hi))
        edges = np.histogram_bin_edges(np.empty(0), bins=t.opt("bins"), range=r)
        counts = self._counts(a, edges, xp)
        total = counts.sum()
        width = np.diff(edges)
        dens = counts / (total * width) if total else np.zeros_like(width)
        if exclude_zero:
            dens = dens * (total / size if size else 0.0)
        return edges, dens, int(total)

    def pressure_hist(self, t: Task, p: Any, xp: Any) -> tuple[tuple[np.ndarray, np.ndarray], float]:
        """``gfmd._pressure_hist`` of the whole field."""
        loaded = p[p != 0.0]
        n_all, n_l = self.red.sum(float(p.size), float(loaded.size))
        atom = 1.0 - n_l / n_all
        bins = t.opt("bins")
        if n_l == 0:
            return (np.linspace(0.0, 1.0, bins + 1), np.zeros(bins)), atom
        _, (lo,), (hi,) = self.red.many(mins=(_amin(loaded),), maxs=(_amax(loaded),))
        if lo == hi:
            lo, hi = lo - 0.5 * abs(lo or 1.0), hi + 0.5 * abs(hi or 1.0)
        edges = np.linspace(lo, hi, bins + 1)
        counts = self._counts(loaded, edges, xp)
        return (edges, counts / (n_all * np.diff(edges))), atom


def _xp(a: Any) -> Any:
    from gapsweep.gfmd._ops import _is_cupy

    if _is_cupy(a):
        import cupy

        return cupy
    return np


def _amin(a: Any) -> float:
    return float(a.min()) if a.size else math.inf


def _amax(a: Any) -> float:
    return float(a.max()) if a.size else -math.inf


def run_slab(t: Task, ctx: Context, prev: Any) -> tuple[TaskResult, Any]:
    """One GFMD task solved by every rank of ``ctx.comm`` together (module docstring): each rank holds only its
    rows of the task's surface (``Context.surface_rows``: a synthetic surface made in place, gapsweep.sweep.slabs)
    and the row comes from the global scalars and histograms (:class:`_SlabStats`); kept fields are written by
    rows. The same on every rank; collective."""
    from gapsweep import gfmd

    if t.opt("surface.periodic") is False:
        raise ValueError("distributed = true: a distributed solve is periodic; this surface is solved with free "
                         "boundaries (surface.periodic = false)")
    comm = ctx.comm
    sp = t.surface_params()
    use_gpu(t, ctx)
    h = ctx.surface_rows(t, t.n, comm)
    backend = t.opt("backend") if t.opt("backend") in ("numpy", "cupy") else "auto"
    res = gfmd.solve(h, comm=comm, sigma0=t.sigma0, **law_params(t), e_star=t.opt("e_star"),
                     length=sp["length"], tol=t.opt("tol"), method=t.opt("method"), backend=backend,
                     max_iter=t.opt("max_iter"), initial=prev if t.opt("warm_start") else None, host=False,
                     **extra(t))
    return gfmd_row(t, ctx, res, prev, stats=_SlabStats(comm))
