"""Sweep method ``sde``: ensembles of the gap SDE in magnification (docs/model.md M5, gapsweep.gapdist.sde).

Spec keys (``[methods.sde]``, docs/jobs.md): ``samples``, ``dzeta``, ``zeta_end``, ``c1``, ``c2``, ``dtype``,
``device`` ("cpu" or "cuda"), ``h_rms``, ``extra`` (keywords of ``gapsweep.sde.gap_samples``). Columns: mean
gap, gap statistics, ``h_rms``, ``g_rms`` and the gap histogram (count = samples binned). Expansion: one task per
(hurst, rho, seed, sigma0). Ensembles above :data:`SDE_HOST_SAMPLES_MAX` are binned on the device.
"""

from __future__ import annotations

import inspect
import math
from collections.abc import Iterator
from typing import Any

import numpy as np

from gapsweep.sweep import readers as rd
from gapsweep.sweep.context import Context, extra, hist, moments
from gapsweep.sweep.methods.base import LENGTH, Env, Method, grid_tasks, h_rms_option, register
from gapsweep.sweep.schema import JobSpec, SpecError, Task, TaskResult

# SDE tasks with more realisations than this are binned on the device (gapsweep.sde.gap_histogram_counts) instead
# of copying every sample to the host (10^8 samples = 800 MB); each store bin is split into SDE_SUB_BINS equal
# sub-bins there, from which the moments are computed (see _sde_binned).
SDE_HOST_SAMPLES_MAX = 2**22
SDE_SUB_BINS = 64


def gapdist_options(name: str, key: str, t: dict[str, Any], env: Env) -> dict[str, Any]:
    """Options shared by the SDE and the Fokker-Planck method: h_rms, c1, c2 (M5)."""
    if env.law != "exponential" or env.file:
        raise SpecError(f"{key}: the {name} method models exponential repulsion on a self-affine surface "
                        f"(docs/model.md M5); not available with interaction.kind = {env.law!r}"
                        + (" and surface.kind = 'file'" if env.file else ""))
    o: dict[str, Any] = {"h_rms": h_rms_option(key, t, env)}
    if "c1" in t:
        o["c1"] = rd.number(f"{key}.c1", t["c1"], gt=0.0)
    o["c2"] = rd.number(f"{key}.c2", t.get("c2", 0.0), ge=0.0, le=10.0)
    return o


def sde_engine(scheme: str = "split") -> str:
    """The engine that runs SDE ensembles on a CUDA device in this process: ``"cuda"`` (gapsweep/gapdist/_sde_cuda.py:
    cupy, NVRTC, fast math) or ``"warp"`` (``GAPSWEEP_SDE_ENGINE=warp``, no cupy, or another scheme). Both draw
    the same Philox numbers; float32 results differ by fast-math rounding (docs/benchmarks.md, issue 14)."""
    from gapsweep.gapdist import _sde_cuda

    return "cuda" if _sde_cuda.enabled("cuda", scheme) else "warp"


# The algorithm's version (Method.algorithm_version, stored per row): bump it when a change moves this
# method's results beyond the tolerance its docs state (docs/store.md "Algorithm versions").
ALGORITHM_VERSION = 1


@register
class SDE(Method):
    algorithm_version = ALGORITHM_VERSION
    name = "sde"
    order = 2
    keys = ("samples", "dzeta", "zeta_end", "c1", "c2", "dtype", "device", "h_rms")
    columns = ("mean_gap", "h_rms", "g_rms", "gap_std", "gap_min", "gap_max", "count")
    histogram = True
    variables = {  # noqa: RUF012 - read-only table
        "mean_gap": ("sde_mean_gap", "mean gap of the SDE ensemble", LENGTH),
        "gap_std": ("sde_gap_std", "standard deviation of the SDE gap distribution", LENGTH),
    }
    select = "c2"
    extra_target = ("gapsweep.sde", "gap_samples", ("sigma0", "hurst", "h_rms", "rho", "gamma0", "lambda_l",
                                                    "lambda_s", "e_star", "c1", "c2", "dzeta", "zeta_end", "n",
                                                    "seed", "device", "dtype", "bins"))

    def validate(self, key: str, t: dict[str, Any], env: Env) -> dict[str, Any]:
        o = gapdist_options(self.name, key, t, env)
        o["samples"] = rd.integer(f"{key}.samples", t.get("samples", 100000), ge=1, le=10**10)
        o["dzeta"] = rd.number(f"{key}.dzeta", t.get("dzeta", 0.01), gt=0.0, le=10.0)
        if "zeta_end" in t:
            o["zeta_end"] = rd.number(f"{key}.zeta_end", t["zeta_end"], ge=1.0, le=1e6)
            steps = (o["zeta_end"] - 1.0) / o["dzeta"]
            if steps > 1e8:
                raise SpecError(f"{key}.zeta_end: {steps:.3g} steps of dzeta = {o['dzeta']:g}; allowed at most 1e8 "
                                "(raise dzeta or lower zeta_end)")
        o["dtype"] = rd.string(f"{key}.dtype", t.get("dtype", "float32"), ("float32", "float64"))
        o["device"] = rd.string(f"{key}.device", t.get("device", "cpu"), ("cpu", "cuda"))
        return o

    def expand(self, spec: JobSpec) -> Iterator[Task]:
        yield from grid_tasks(spec, self.name, with_hist=True)

    def cost(self, t: Task) -> float:
        zeta_s = t.opt("surface.lambda_l") / t.opt("surface.lambda_s")
        steps = (t.opt("zeta_end", zeta_s) - 1.0) / t.opt("dzeta")
        per = 2.5e-12 if t.opt("device") == "cuda" else 1.5e-8  # s per particle-step: H200, one CPU core
        return 0.5 + t.opt("samples") * steps * per

    def memory(self, t: Task) -> float:
        return 8.0 * min(int(t.opt("samples")), SDE_HOST_SAMPLES_MAX) * 8

    def needs_gpu(self, t: Task) -> bool:
        return t.opt("device") == "cuda"

    def provenance(self, options: dict[str, Any]) -> dict[str, Any]:
        """The engine of SDE ensembles on a CUDA device in this process (:func:`sde_engine`)."""
        if options.get("device") != "cuda":
            return {}
        return {"sde_engine": sde_engine(str(options.get("extra", {}).get("scheme", "split")))}

    def run(self, t: Task, ctx: Context, prev: Any) -> tuple[TaskResult, Any]:
        return run_sde(t, ctx)


def run_sde(t: Task, ctx: Context) -> tuple[TaskResult, Any]:
    from gapsweep.gapdist import sde

    h_rms, g_rms = moments(t, ctx)
    sp = t.surface_params()
    device = t.opt("device")
    if device == "cuda":  # this rank's GPU, current before the engine's first CUDA call (issue 38)
        device = f"cuda:{ctx.select_gpu()}"
    kw = dict(hurst=t.hurst, h_rms=h_rms, rho=t.rho, gamma0=t.opt("gamma0"), lambda_l=sp["lambda_l"],
              lambda_s=sp["lambda_s"], e_star=t.opt("e_star"), c2=t.opt("c2"), dzeta=t.opt("dzeta"),
              n=t.opt("samples"), seed=t.seed, device=device, dtype=t.opt("dtype"), **extra(t))
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
    return TaskResult(status, msg, v, hist(t, g)), None


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
    from gapsweep.gapdist import sde

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
