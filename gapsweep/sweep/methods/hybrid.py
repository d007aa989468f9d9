"""Sweep method ``hybrid``: the mean gap by the multiscale hybrid predictor to a requested accuracy
(``gapsweep.theory.improved.hybrid(zeta_c="auto")``, docs/theory.md "Beyond the paper"): GFMD on the coarse
modes, the field theory for the finer ones, at about a tenth of a full GFMD run's cost -- the cheap way to cover
a large grid, with its error estimate in the store.

Spec keys (``[methods.hybrid]``, docs/jobs.md): ``n`` (the grid of the surface, as GFMD's; >= Nyquist), ``rtol``
(the accuracy asked for: relative where ``|g0| >= h_rms``, in units of ``h_rms`` else; default 0.05),
``max_cost_fraction`` (of full GFMD's cost, default 0.1), ``tol`` (the coarse solves' residual, default 1e-6),
``extra`` (keywords of ``improved.hybrid``). Columns: ``mean_gap``, ``error_estimate`` (the predictor's estimate
of ``|hybrid - GFMD|``, same unit), ``h_rms``, ``g_rms`` of the surface, ``iterations`` (coarse force
evaluations), ``residual`` (of the last coarse solve). A row whose estimate misses ``rtol`` within the cost budget
is ``not_converged`` (message: by how much). Exponential repulsion on a self-affine surface only.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from typing import Any

from gapsweep.sweep import readers as rd
from gapsweep.sweep.context import Context, extra
from gapsweep.sweep.methods.base import LENGTH, Env, Method, grid_tasks, n_list, register
from gapsweep.sweep.schema import JobSpec, SpecError, Task, TaskResult, task_id


def predictor_options(name: str, key: str, t: dict[str, Any], env: Env) -> dict[str, Any]:
    """Options shared by the predictors built on the hybrid: ``n``, ``rtol``, ``max_cost_fraction``, ``tol``."""
    if env.law != "exponential" or env.file:
        raise SpecError(f"{key}: the {name} predictor models exponential repulsion on a self-affine surface "
                        f"(docs/theory.md); not available with interaction.kind = {env.law!r}"
                        + (" and surface.kind = 'file'" if env.file else ""))
    if "n" not in t:
        raise SpecError(f"{key}.n: missing; the grid of the surface (integer or list, >= {env.nyquist})")
    return {"n": n_list(f"{key}.n", t["n"], env.nyquist),
            "rtol": rd.number(f"{key}.rtol", t.get("rtol", 0.05), gt=0.0, lt=1.0),
            "max_cost_fraction": rd.number(f"{key}.max_cost_fraction", t.get("max_cost_fraction", 0.1), gt=0.0,
                                           le=1.0),
            "tol": rd.number(f"{key}.tol", t.get("tol", 1e-6), gt=0.0, lt=1.0)}


def surface_set(t: Task) -> str:
    """Tasks of one surface (its generation and shells are shared)."""
    return task_id({"hurst": t.hurst, "seed": t.seed, "n": t.n, "surface": t.surface_params()})


# The algorithm's version (Method.algorithm_version, stored per row): bump it when a change moves this
# method's results beyond the tolerance its docs state (docs/store.md "Algorithm versions").
ALGORITHM_VERSION = 1


@register
class Hybrid(Method):
    algorithm_version = ALGORITHM_VERSION
    name = "hybrid"
    order = 4
    keys = ("n", "rtol", "max_cost_fraction", "tol")
    columns = ("mean_gap", "error_estimate", "h_rms", "g_rms", "iterations", "residual")
    variables = {  # noqa: RUF012 - read-only table
        "mean_gap": ("hybrid_mean_gap", "mean gap g0 by the multiscale hybrid predictor", LENGTH),
        "error_estimate": ("hybrid_error_estimate", "the hybrid's estimate of |hybrid - GFMD| in the mean gap",
                           LENGTH),
    }
    select = "n"
    extra_target = ("gapsweep.theory.improved", "hybrid", ("sigma0", "heights", "zeta_c", "rho", "gamma0",
                                                           "lambda_l", "length", "e_star", "tol", "rtol",
                                                           "max_cost_fraction", "initial"))

    def validate(self, key: str, t: dict[str, Any], env: Env) -> dict[str, Any]:
        return predictor_options(self.name, key, t, env)

    def expand(self, spec: JobSpec) -> Iterator[Task]:
        yield from grid_tasks(spec, self.name, ns=spec.methods[self.name]["n"], with_hist=False)

    def cost(self, t: Task) -> float:
        # a tenth of a GFMD solve of the same grid (the cost budget; gfmd.py's model)
        return t.opt("max_cost_fraction") * (0.02 + 20 * 1.5e-9 * t.n * t.n * math.log2(t.n)) + 0.01

    def memory(self, t: Task) -> float:
        return 8.0 * t.n * t.n * 12  # the surface, its spectrum, the coarse problems

    def set_key(self, t: Task) -> str:
        return surface_set(t)

    def run(self, t: Task, ctx: Context, prev: Any) -> tuple[TaskResult, Any]:
        from gapsweep.theory import improved

        sp = t.surface_params()
        h = ctx.surface(t, t.n)
        h_rms, g_rms = ctx.surface_rms(t, t.n)
        r = improved.hybrid(t.sigma0, h, zeta_c="auto", rho=t.rho, gamma0=t.opt("gamma0"), lambda_l=sp["lambda_l"],
                            length=sp["length"], e_star=t.opt("e_star"), tol=t.opt("tol"), rtol=t.opt("rtol"),
                            max_cost_fraction=t.opt("max_cost_fraction"), **extra(t))
        coarse = r.result
        v = {"mean_gap": float(r.mean_gap), "error_estimate": float(r.error_estimate), "h_rms": h_rms,
             "g_rms": g_rms, "iterations": int(getattr(coarse, "iterations", -1)),
             "residual": float(getattr(coarse, "residual", math.nan))}
        if r.status == "converged":
            return TaskResult("done", "", v), None
        goal = t.opt("rtol") * max(abs(r.mean_gap), h_rms)
        return TaskResult("not_converged", f"hybrid: {r.status} (estimate {r.error_estimate:.3g}, goal "
                          f"{goal:.3g}; coarse grid {r.n_c}, {r.cost_fraction:.2f} of GFMD's cost)", v), None
