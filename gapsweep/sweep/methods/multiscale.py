"""Sweep method ``multiscale``: the gap distribution predicted by the multiscale route
(``gapsweep.theory.closure.multiscale_gap_samples``, docs/theory.md "Multiscale gap distribution"): GFMD on the
coarse modes (the hybrid with ``zeta_c = "auto"``), the finer modes' gap fluctuations from theory, at about a tenth
of a full GFMD run's cost.

Spec keys (``[methods.multiscale]``): those of ``[methods.hybrid]`` (``n``, ``rtol``, ``max_cost_fraction``,
``tol``) and ``samples`` (default 2^17). Columns: ``mean_gap`` (the hybrid's), ``error_estimate`` (its estimate),
``gap_std``, ``gap_min``, ``gap_max`` of the samples, ``h_rms``, ``g_rms``, ``count`` and the gap histogram over
the job's bins. A row is ``not_converged`` where the hybrid misses ``rtol`` or the distribution's self-check
(``l1_estimate`` above 0.15, docs/theory.md "Multiscale gap distribution") fails; the message says which.
Exponential repulsion on a self-affine surface only.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from typing import Any

import numpy as np

from gapsweep.sweep import readers as rd
from gapsweep.sweep.context import Context, extra, hist
from gapsweep.sweep.methods.base import LENGTH, Env, Method, grid_tasks, register
from gapsweep.sweep.methods.hybrid import predictor_options, surface_set
from gapsweep.sweep.schema import JobSpec, Task, TaskResult

# The algorithm's version (Method.algorithm_version, stored per row): bump it when a change moves this
# method's results beyond the tolerance its docs state (docs/store.md "Algorithm versions").
ALGORITHM_VERSION = 2  # 2: shells grouped by 0.3 in ln q (was 0.04): other samples, same tolerance


@register
class Multiscale(Method):
    algorithm_version = ALGORITHM_VERSION
    name = "multiscale"
    order = 5
    keys = ("n", "rtol", "max_cost_fraction", "tol", "samples")
    columns = ("mean_gap", "error_estimate", "gap_std", "gap_min", "gap_max", "h_rms", "g_rms", "count")
    histogram = True
    variables = {  # noqa: RUF012 - read-only table
        "mean_gap": ("multiscale_mean_gap", "mean gap g0 of the multiscale prediction", LENGTH),
        "gap_std": ("multiscale_gap_std", "standard deviation of the predicted gap distribution", LENGTH),
        "error_estimate": ("multiscale_error_estimate", "estimate of |prediction - GFMD| in the mean gap", LENGTH),
    }
    select = "n"
    extra_target = ("gapsweep.theory.closure", "multiscale_gap_samples", (
        "sigma0", "heights", "rho", "gamma0", "lambda_l", "lambda_s", "e_star", "length", "samples", "seed", "rtol",
        "max_cost_fraction", "tol"))

    def validate(self, key: str, t: dict[str, Any], env: Env) -> dict[str, Any]:
        o = predictor_options(self.name, key, t, env)
        o["samples"] = rd.integer(f"{key}.samples", t.get("samples", 2**17), ge=100, le=10**8)
        return o

    def expand(self, spec: JobSpec) -> Iterator[Task]:
        yield from grid_tasks(spec, self.name, ns=spec.methods[self.name]["n"], with_hist=True)

    def cost(self, t: Task) -> float:
        # sampling: the samples, the previous grid's for the self-check and the drift tables (~0.05 CPU s at 2^17
        # samples with shells grouped by 0.3 in ln q, benchmarks/results/bounds/bounds_heldout.md)
        return t.opt("max_cost_fraction") * (0.02 + 20 * 1.5e-9 * t.n * t.n * math.log2(t.n)) + 5e-7 * t.opt(
            "samples")

    def memory(self, t: Task) -> float:
        return 8.0 * t.n * t.n * 12 + 8.0 * t.opt("samples") * 8 + 8.0 * 65 * 4096 * 4  # + the drift table

    def set_key(self, t: Task) -> str:
        return surface_set(t)

    def run(self, t: Task, ctx: Context, prev: Any) -> tuple[TaskResult, Any]:
        from gapsweep.theory import closure

        sp = t.surface_params()
        h = ctx.surface(t, t.n)
        h_rms, g_rms = ctx.surface_rms(t, t.n)
        ms = closure.multiscale_gap_samples(
            t.sigma0, h, rho=t.rho, gamma0=t.opt("gamma0"), lambda_l=sp["lambda_l"], lambda_s=sp["lambda_s"],
            e_star=t.opt("e_star"), length=sp["length"], samples=t.opt("samples"), seed=t.seed,
            rtol=t.opt("rtol"), max_cost_fraction=t.opt("max_cost_fraction"), tol=t.opt("tol"), **extra(t))
        g = np.asarray(ms.samples, dtype=float)
        v = {"mean_gap": float(ms.mean_gap), "error_estimate": float(ms.mean_gap_error), "h_rms": h_rms,
             "g_rms": g_rms, "gap_std": float(g.std()), "gap_min": float(g.min()), "gap_max": float(g.max())}
        ok = ms.status == "converged" and bool(np.all(np.isfinite(g)))
        msg = "" if ok else (f"multiscale: {ms.status} (mean-gap estimate {ms.mean_gap_error:.3g}, estimated L1 to "
                             f"GFMD {ms.l1_estimate:.3g})")
        return TaskResult("done" if ok else "not_converged", msg, v, hist(t, g)), None
