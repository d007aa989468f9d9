"""The leak rate of every GFMD row: an extension of the ``gfmd`` method (docs/jobs.md "flow", docs/model.md M8).

``[methods.gfmd] flow = true`` (defaults) or a table ``flow = { viscosity = 1.0, pressure_drop = 1.0, axis = 1,
threshold = 0.0 }`` solves the Reynolds equation on each GFMD row's gap field (:func:`gapsweep.flow.solve`: the
pressure drop along array ``axis``, periodic across for a periodic surface, closed sides for a measured map with
free boundaries) and stores, in columns declared here (no edit of the store's schema):

* ``leak_rate`` -- flux per unit width ``K dp / L``, in units of (length unit)^3 (pressure unit) / (viscosity unit
  x length unit); with the defaults (mu = dp = 1, lengths in units of L) it equals ``K``;
* ``conductance`` -- ``K`` (length^3 / viscosity);
* ``conductance_ratio`` -- ``K / (<g>^3 / (12 mu))``;
* ``percolating`` -- 1 when an open path joins inlet and outlet (0: the contact seals, ``leak_rate = 0``);
* ``flow_bruggeman``, ``flow_critical_junction`` -- the two estimates of ``K`` from the row's own gap histogram
  (:mod:`gapsweep.flow.theory`), side by side with the solve.

A flow solve that does not converge turns the row into ``not_converged`` with the reason as its message.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from gapsweep.sweep import readers as rd
from gapsweep.sweep.methods.base import Env, Extension, register_extension
from gapsweep.sweep.schema import Column, SpecError, Task

KEYS = ("viscosity", "pressure_drop", "axis", "threshold", "tol")
K_UNITS = {"units": "1", "reference_unit": "L^3 / mu"}


@register_extension
class Flow(Extension):
    name = "flow"
    host = "gfmd"
    own_columns = {  # noqa: RUF012 - read-only table
        "leak_rate": Column("float", "leak rate per unit width K dp / L (Reynolds flow through the gap)",
                            {"units": "1", "reference_unit": "L^2 dp / mu"}),
        "conductance": Column("float", "effective conductance K of the gap (leak rate = K dp / L)", K_UNITS),
        "conductance_ratio": Column("float", "K over <g>^3 / (12 mu)"),
        "percolating": Column("int", "1: an open path joins inlet and outlet; 0: the contact seals"),
        "flow_bruggeman": Column("float", "Bruggeman effective-medium estimate of K from the gap histogram",
                                 K_UNITS),
        "flow_critical_junction": Column("float", "Persson critical-junction estimate of K from the gap "
                                         "histogram", K_UNITS),
    }
    variables = {k: (f"gfmd_{k}", c.description, c.units) for k, c in own_columns.items()}  # noqa: RUF012

    def validate(self, key: str, value: Any, host_options: dict[str, Any], env: Env) -> dict[str, Any] | None:
        if isinstance(value, bool):
            if not value:
                return None
            value = {}
        if not isinstance(value, dict):
            raise SpecError(f"{key}: expected true, false or a table with keys {', '.join(KEYS)}, got {value!r}")
        rd.known(key, value, KEYS)
        if host_options.get("distributed"):
            raise SpecError(f"{key}: the flow solve needs the whole gap field on one process; it cannot follow a "
                            "distributed GFMD solve (distributed = true)")
        return {
            "viscosity": rd.number(f"{key}.viscosity", value.get("viscosity", 1.0), gt=0.0),
            "pressure_drop": rd.number(f"{key}.pressure_drop", value.get("pressure_drop", 1.0), gt=0.0),
            "axis": rd.integer(f"{key}.axis", value.get("axis", 1), ge=0, le=1),
            "threshold": rd.number(f"{key}.threshold", value.get("threshold", 0.0), ge=0.0),
            "tol": rd.number(f"{key}.tol", value.get("tol", 1e-8), gt=0.0, lt=1e-2),
        }

    def cost(self, t: Task, options: dict[str, Any]) -> float:
        # benchmarks/bench_flow.py (2-core VM, one process): 0.38 s at 256^2 (direct), 6.0 s at 512^2 and 32 s
        # at 1024^2 (AMG-CG): about 3e-5 s per cell at and above 512^2
        cells = float(np.prod(t.opt("surface.shape") or (t.n, t.n)))
        return 3e-5 * cells

    def memory(self, t: Task, options: dict[str, Any]) -> float:
        # the sparse matrix (5 entries per cell), the multigrid hierarchy (about as much again), CG vectors
        cells = float(np.prod(t.opt("surface.shape") or (t.n, t.n)))
        return 8.0 * cells * 40

    def compute(self, t: Task, options: dict[str, Any], result: Any) -> tuple[dict[str, float], str]:
        from gapsweep import flow

        gap = result.gap
        length = t.opt("surface.length")
        periodic = t.opt("surface.periodic") is not False
        r = flow.solve(gap, length=length, axis=options["axis"], viscosity=options["viscosity"],
                       pressure_drop=options["pressure_drop"], periodic=periodic, threshold=options["threshold"],
                       tol=options["tol"])
        edges, density, contact = flow.gap_density(gap, threshold=options["threshold"])
        mu = options["viscosity"]
        vals = {"leak_rate": r.leak_rate, "conductance": r.conductance,
                "conductance_ratio": r.ratio if math.isfinite(r.ratio) else math.nan,
                "percolating": int(r.percolating),
                "flow_bruggeman": flow.bruggeman(edges, density, contact, viscosity=mu) if contact < 1 else 0.0,
                "flow_critical_junction": (flow.critical_junction(edges, density, contact, viscosity=mu)
                                           if contact < 1 else 0.0)}
        problem = "" if r.converged else (f"flow solve not converged (relative residual {r.residual:.3g}, "
                                          f"{r.iterations} iterations, {r.solver})")
        return vals, problem
