"""Sweep method ``fokker_planck``: the gap density from the Fokker-Planck equation in magnification
(docs/model.md M5, gapsweep.gapdist.fokker_planck).

Spec keys (``[methods.fokker_planck]``, docs/jobs.md): ``c1``, ``c2``, ``h_rms``, ``extra`` (keywords of
``gapsweep.fokker_planck.solve``). Columns: mean gap, gap statistics, ``h_rms``, ``g_rms``, the mass error
(``residual``), the steps (``iterations``) and the gap histogram. Expansion: one task per (hurst, rho, sigma0),
per seed only when h_rms comes from a seed-dependent surface.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from typing import Any

import numpy as np

from gapsweep.sweep.context import Context, extra, moments
from gapsweep.sweep.methods.base import LENGTH, Env, Method, grid_tasks, register
from gapsweep.sweep.methods.sde import gapdist_options
from gapsweep.sweep.schema import JobSpec, Task, TaskResult

# The algorithm's version (Method.algorithm_version, stored per row): bump it when a change moves this
# method's results beyond the tolerance its docs state (docs/store.md "Algorithm versions").
ALGORITHM_VERSION = 1


@register
class FokkerPlanck(Method):
    algorithm_version = ALGORITHM_VERSION
    name = "fokker_planck"
    order = 3
    keys = ("c1", "c2", "h_rms")
    columns = ("mean_gap", "h_rms", "g_rms", "gap_std", "gap_min", "gap_max", "residual", "iterations", "count")
    histogram = True
    variables = {  # noqa: RUF012 - read-only table
        "mean_gap": ("fokker_planck_mean_gap", "mean gap of the Fokker-Planck density", LENGTH),
        "gap_std": ("fokker_planck_gap_std", "standard deviation of the Fokker-Planck gap density", LENGTH),
    }
    seed_free = ("mean_gap", "gap_std")
    select = "c2"
    extra_target = ("gapsweep.fokker_planck", "solve", ("sigma0", "hurst", "h_rms", "rho", "gamma0", "lambda_l",
                                                        "lambda_s", "e_star", "c1", "c2"))

    def validate(self, key: str, t: dict[str, Any], env: Env) -> dict[str, Any]:
        return gapdist_options(self.name, key, t, env)

    def expand(self, spec: JobSpec) -> Iterator[Task]:
        o = spec.methods[self.name]
        seeded = o["h_rms"] == "surface" and spec.surface["amplitudes"] == "gaussian"
        yield from grid_tasks(spec, self.name, seeds=None if seeded else [0], with_hist=True)

    def run(self, t: Task, ctx: Context, prev: Any) -> tuple[TaskResult, Any]:
        return run_fokker_planck(t, ctx)


def run_fokker_planck(t: Task, ctx: Context) -> tuple[TaskResult, Any]:
    from gapsweep.gapdist import fokker_planck

    h_rms, g_rms = moments(t, ctx)
    sp = t.surface_params()
    kw = dict(hurst=t.hurst, h_rms=h_rms, rho=t.rho, gamma0=t.opt("gamma0"), lambda_l=sp["lambda_l"],
              lambda_s=sp["lambda_s"], e_star=t.opt("e_star"), c2=t.opt("c2"), **extra(t))
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
