"""Sweep method ``theory``: the paper's field theory (docs/model.md M4) and Persson's hard-wall theory.

Spec keys (``[methods.theory]``, docs/jobs.md): ``forms`` (exponential law on a self-affine surface: "paper",
"continuum", "discrete"; hard wall: "persson"), ``n`` (grids of the "discrete" form), ``h_rms`` ("continuum" or
"surface"), ``persson_variant``, ``persson_gamma``, ``extra`` (keywords of ``gapsweep.theory.mean_gap``).
Columns: ``mean_gap`` (the first form's) and one ``mean_gap_<form>`` per form, ``h_rms``, ``g_rms``; Persson's
form: ``mean_gap_persson`` and ``contact_area``. Expansion: one task per (hurst, rho, sigma0); per seed only when
the result depends on the surface (the discrete form, or h_rms = "surface" with gaussian amplitudes). The
discrete-form tasks of one surface form a set that computes its spectrum once.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from typing import Any

from gapsweep.sweep import readers as rd
from gapsweep.sweep.context import Context, extra, moments
from gapsweep.sweep.methods.base import LENGTH, Env, Method, grid_tasks, h_rms_option, n_list, register
from gapsweep.sweep.schema import JobSpec, SpecError, Task, TaskResult, task_id

FORMS = ("paper", "continuum", "discrete", "persson")
# Forms of the field theory of exponential repulsion (M4); "persson" is Persson's hard-wall theory
# (gapsweep.theory.persson: contact area and mean separation), the one form for hard-wall jobs.
FIELD_FORMS = ("paper", "continuum", "discrete")
PERSSON_VARIANTS = ("persson2001", "yang_persson2008", "wang_muser2017")


# The algorithm's version (Method.algorithm_version, stored per row): bump it when a change moves this
# method's results beyond the tolerance its docs state (docs/store.md "Algorithm versions").
ALGORITHM_VERSION = 1


@register
class Theory(Method):
    algorithm_version = ALGORITHM_VERSION
    name = "theory"
    order = 0
    keys = ("forms", "n", "h_rms", "persson_variant", "persson_gamma")
    columns = ("mean_gap", "mean_gap_paper", "mean_gap_continuum", "mean_gap_discrete", "mean_gap_persson",
               "contact_area", "h_rms", "g_rms", "h_rms_spectrum", "g_rms_spectrum")
    variables = {  # noqa: RUF012 - read-only table
        "mean_gap_persson": ("persson_mean_gap", "mean interfacial separation, Persson's theory (hard wall)", LENGTH),
        "contact_area": ("persson_contact_area", "real contact area fraction, Persson's theory (hard wall)",
                         {"units": "1"}),
        "mean_gap_paper": ("theory_paper", "mean gap g0, field theory, the paper's closed form", LENGTH),
        "mean_gap_continuum": ("theory_continuum", "mean gap g0, field theory, exact continuum prefactor", LENGTH),
        "mean_gap_discrete": ("theory_discrete", "mean gap g0, field theory, sum over the modes of the surface",
                              LENGTH),
        "h_rms": ("theory_h_rms", "rms height used by the field theory", LENGTH),
        "h_rms_spectrum": ("theory_h_rms_spectrum", "rms height of a measured map's spectrum (Persson's input)",
                           LENGTH),
        "g_rms_spectrum": ("theory_g_rms_spectrum", "rms gradient of a measured map's spectrum (Persson's input)",
                           {"units": "1"}),
    }
    # results that never depend on the seed (M4): no seed dimension in the dataset view
    seed_free = ("mean_gap_paper", "mean_gap_continuum", "mean_gap_persson", "contact_area")
    select = "n"
    extra_target = ("gapsweep.theory", "mean_gap", ("sigma0", "form", "hurst", "h_rms", "rho", "gamma0",
                                                     "lambda_l", "lambda_s", "e_star", "heights", "length"))

    def validate(self, key: str, t: dict[str, Any], env: Env) -> dict[str, Any]:
        o: dict[str, Any] = {}
        if env.law == "exponential" and not env.file:
            o["h_rms"] = h_rms_option(key, t, env)
            allowed, default = FIELD_FORMS, ["paper", "continuum"]
        elif env.law == "hard_wall":
            if "h_rms" in t:
                raise SpecError(f"{key}.h_rms: not used by Persson's theory (it takes the surface's spectrum)")
            allowed, default = ("persson",), ["persson"]
        else:
            raise SpecError(f"{key}: no theory for interaction.kind = {env.law!r}"
                            + (" on a file surface" if env.file else "") + "; the field theory (M4) needs the "
                            "exponential law on a self-affine surface, Persson's theory the hard wall")
        forms = t.get("forms", default)
        if not isinstance(forms, list) or not forms:
            raise SpecError(f"{key}.forms: expected a non-empty list from {', '.join(allowed)}")
        o["forms"] = [rd.string(f"{key}.forms[{i}]", f, allowed) for i, f in enumerate(forms)]
        if "discrete" in o["forms"]:
            if "n" not in t:
                raise SpecError(f"{key}.n: required when forms contains 'discrete' (grid of the surface)")
            o["n"] = n_list(f"{key}.n", t["n"], env.nyquist)
        elif "n" in t:
            raise SpecError(f"{key}.n: only allowed when forms contains 'discrete'")
        if "persson" in o["forms"]:
            o["persson_variant"] = rd.string(f"{key}.persson_variant", t.get("persson_variant", "persson2001"),
                                             PERSSON_VARIANTS)
            o["persson_gamma"] = rd.number(f"{key}.persson_gamma", t.get("persson_gamma", 0.42), gt=0.0, le=1.0)
        else:
            for k in ("persson_variant", "persson_gamma"):
                if k in t:
                    raise SpecError(f"{key}.{k}: only allowed when forms contains 'persson'")
        return o

    def expand(self, spec: JobSpec) -> Iterator[Task]:
        o = spec.methods[self.name]
        discrete = "discrete" in o["forms"]
        # Without the discrete form the theory needs no surface (unless h_rms comes from the surface): one task
        # per (hurst, rho, sigma0), seed 0.
        seeded = discrete or (o.get("h_rms") == "surface" and spec.surface.get("amplitudes") == "gaussian")
        yield from grid_tasks(spec, self.name, seeds=None if seeded else [0], ns=o.get("n", [0]), with_hist=False)

    def cost(self, t: Task) -> float:
        return 2e-4 + (3e-8 * t.n * t.n * math.log2(max(t.n, 2)) if t.n else 0.0)

    def memory(self, t: Task) -> float:
        return 8.0 * t.n * t.n * 10 if t.n else 1e6

    def set_key(self, t: Task) -> str:
        """Discrete-theory tasks of one surface share its spectrum (computed once per set)."""
        if "discrete" not in t.opt("forms") or not t.n:
            return ""
        return task_id({"hurst": t.hurst, "seed": t.seed, "n": t.n, "surface": t.surface_params()})

    def run(self, t: Task, ctx: Context, prev: Any) -> tuple[TaskResult, Any]:
        if t.opt("forms") == ["persson"]:
            v = _run_persson(t, ctx)
            v["mean_gap"] = v["mean_gap_persson"]
            return TaskResult("done", "", v), None
        return _run_field(t, ctx)


def _run_persson(t: Task, ctx: Context) -> dict[str, float]:
    """Persson's hard-wall theory (gapsweep.theory.persson, docs/theory.md): contact area (``persson_variant``)
    and mean interfacial separation (``persson_gamma``) at ``sigma0``, from the self-affine spectrum's parameters
    or, for a file surface, from the map's own spectrum (``heights=``)."""
    from gapsweep.surfaces import synthetic as surface
    from gapsweep.theory import persson

    sp = t.surface_params()
    kw: dict[str, Any] = {"e_star": t.opt("e_star"), "length": sp["length"]}
    if sp.get("kind") == "file":  # the map's own spectrum, taken right for its boundaries (map_spectrum)
        kw["heights"] = ctx.surface(t, 0)
        kw["periodic"] = sp.get("periodic", True)
        h_rms, g_rms = ctx.surface_rms(t, 0)  # of the heights solved (what a user normalises by)
        h_spec, g_spec = ctx.surface_spectrum_rms(t, 0)  # the spectrum's, which the theory uses
    else:
        h_spec = g_spec = math.nan
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
    return {"h_rms": h_rms, "g_rms": g_rms, "h_rms_spectrum": h_spec, "g_rms_spectrum": g_spec,
            "mean_gap_persson": sep, "contact_area": area}


def _run_field(t: Task, ctx: Context) -> tuple[TaskResult, Any]:
    from gapsweep import theory

    h_rms, g_rms = moments(t, ctx)
    sp = t.surface_params()
    kw = dict(hurst=t.hurst, h_rms=h_rms, rho=t.rho, gamma0=t.opt("gamma0"), lambda_l=sp["lambda_l"],
              lambda_s=sp["lambda_s"], e_star=t.opt("e_star"), **extra(t))
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
