"""The L-BFGS of every GFMD minimiser that has one (docs/gfmd.md, "Methods"; Nocedal & Wright, Numerical
Optimization, Alg. 7.4 and 7.5), written once: the pair memory :func:`remember_pair` and the two-loop recursion
:func:`two_loop`, on any state through the few operations a minimiser passes in (its Parseval or real-space dot
product, its in-place or array updates, its preconditioner; fused loops where a minimiser has them). Used by
the exponential law's runner (``gfmd._solvers``), the smooth laws' (``gfmd._smooth``), their lean form
(``gfmd._lean``) and the free-boundary minimiser (``gfmd._free``, on pairs ``(spectrum, mean gap)``)."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any


def remember_pair(s_hist: list, y_hist: list, r_hist: list, s: Any, y: Any, sy: float, memory: int) -> None:
    """The L-BFGS memory (Nocedal & Wright, Alg. 7.4; docs/gfmd.md "Methods"): keep the step ``s`` and gradient
    change ``y`` with ``1/(s.y)`` when the curvature ``s.y > 0`` (else the pair would spoil the inverse-Hessian
    estimate), at most ``memory`` pairs, the oldest dropped."""
    if sy > 0:
        s_hist.append(s)
        y_hist.append(y)
        r_hist.append(1.0 / sy)
        if len(s_hist) > memory:
            for lst in (s_hist, y_hist, r_hist):
                lst.pop(0)


def two_loop(q: Any, pairs: Sequence[tuple[Any, Any, float]], dot: Callable[[Any, Any], float],
             axpy: Callable[[Any, float, Any], Any], precondition: Callable[[Any], Any],
             curvature: Callable[[Any], float], scale: Callable[[Any, float], Any],
             first: Callable[[Any], tuple[Any, list[float]]] | None = None,
             second: Callable[[Any, list[float]], Any] | None = None) -> Any:
    """``H q`` by the two-loop recursion (Nocedal & Wright Alg. 7.4): ``H`` the L-BFGS inverse-Hessian estimate
    of the ``pairs`` ``(s_i, y_i, r_i = 1/(s_i.y_i))`` (oldest first) over ``H0 = gamma P``, ``P`` the
    preconditioner and ``gamma = s.y / <y P y>`` of the newest pair (Alg. 7.5's scaling; 1 without pairs or
    when ``<y P y> <= 0``).

    The operations: ``dot(a, b)`` the minimiser's inner product; ``axpy(q, a, x)`` returns ``q + a x``
    (in place or a new array); ``precondition(q)`` returns ``P q``; ``curvature(y)`` is ``<y P y>``;
    ``scale(q, c)`` returns ``c q``. ``q`` may be updated in place (pass a copy). Returns ``H q``.

    ``first(q) -> (q, alphas newest first)`` and ``second(q, alphas) -> q``: drop-in replacements of the two
    loops by fused passes (the same arithmetic in fewer passes over the arrays; gfmd._free on the CPU)."""
    if first is None:
        alphas = []
        for s, y, r in reversed(pairs):
            al = r * dot(s, q)
            alphas.append(al)
            q = axpy(q, -al, y)
    else:
        q, alphas = first(q)
    q = precondition(q)
    if pairs:
        _, y, r = pairs[-1]
        yhy = curvature(y)
        if yhy > 0:
            q = scale(q, 1.0 / (r * yhy))  # gamma = s.y / <y P y>
    if second is not None:
        return second(q, alphas)
    for (s, y, r), al in zip(pairs, reversed(alphas)):
        q = axpy(q, al - r * dot(y, q), s)
    return q


def diagonal(dot: Callable[[Any, Any], float], minv: Any,
             axpy: Callable[[Any, float, Any], None] | None = None) -> dict[str, Callable]:
    """The operations of :func:`two_loop` on arrays updated in place with a diagonal preconditioner ``minv``
    (``P q = minv q``, ``<y P y> = dot(y, minv y)``); ``axpy(y, a, x)``: an in-place ``y += a x`` of the
    minimiser's (default the array expression)."""

    def ax(q: Any, a: float, x: Any) -> Any:
        if axpy is None:
            q += a * x
        else:
            axpy(q, a, x)
        return q

    def pre(q: Any) -> Any:
        q *= minv
        return q

    def sc(q: Any, c: float) -> Any:
        q *= c
        return q

    return dict(dot=dot, axpy=ax, precondition=pre, curvature=lambda y: dot(y, minv * y), scale=sc)
