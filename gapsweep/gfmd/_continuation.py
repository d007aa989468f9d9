"""The step bookkeeping shared by the two load continuations of non-convex laws (docs/gfmd.md "Adhesive" and
"Hard wall with adhesion"): the smooth laws' ``_smooth._Solver.follow`` and the adhesive hard wall's
``_bounded._Solver.follow``. Their acceptance rules differ (the smooth one also rejects a step whose corrector
strays from its predictor; the hard wall's predictor is projected onto ``g >= 0``), so each keeps its own loop;
the next load and the record of the walk are one code. Loads in pressure units."""

from __future__ import annotations

from typing import Any


def next_load(s_k: float, ds: float, target: float, scale: float) -> tuple[float, float, bool]:
    """``(s_new, step, final)``: the load ``s_k + ds`` (``ds < 0``, unloading) clipped at ``target``; ``final``
    when it reaches ``target`` to within ``1e-12 scale`` (then ``s_new = target`` exactly); ``step = s_new - s_k``."""
    step = max(ds, target - s_k)
    final = s_k + step <= target + 1e-12 * scale
    s_new = target if final else s_k + step
    return s_new, s_new - s_k, final


def record(info: dict[str, Any], *, s_from: float, accepted: int, ds_min: float, attempts: int, jumps: int,
           status: str, target: float, s_k: float) -> None:
    """The walk's record in the solver's ``info``: its start, accepted and attempted steps, the smallest step,
    the jumps, and ``last_attached_load`` (``target`` when it converged there, else the last accepted load: the
    pull-off load lies between it and one smallest step below)."""
    info.update({"continuation_from": s_from, "continuation_steps": accepted, "min_step": ds_min,
                 "continuation_attempts": attempts, "jumps": jumps,
                 "last_attached_load": target if status == "converged" else s_k})
