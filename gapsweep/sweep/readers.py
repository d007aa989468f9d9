"""Typed readers of job-spec values: each checks one value and names its dotted key in the error.

Shared by the spec validator (gapsweep.sweep.spec) and the method plug-ins (gapsweep.sweep.methods), so that one
rule holds for ``plan`` and ``run`` alike: a wrong type or an out-of-range value raises
:class:`gapsweep.sweep.schema.SpecError` with the key and the allowed range (docs/jobs.md).
"""

from __future__ import annotations

import math
from typing import Any

from gapsweep.sweep.schema import SpecError

__all__ = ["axis", "boolean", "integer", "is_num", "known", "number", "positive", "seed_list", "string", "table"]


def is_num(v: Any) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool)


def number(key: str, v: Any, *, gt: float | None = None, ge: float | None = None, lt: float | None = None,
         le: float | None = None) -> float:
    rng = range_text(gt, ge, lt, le)
    if not is_num(v):
        raise SpecError(f"{key}: expected a number {rng}, got {v!r} ({type(v).__name__})")
    x = float(v)
    if not math.isfinite(x) or (gt is not None and not x > gt) or (ge is not None and not x >= ge) or (
        lt is not None and not x < lt
    ) or (le is not None and not x <= le):
        raise SpecError(f"{key}: expected a number {rng}, got {v!r}")
    return x


def range_text(gt, ge, lt, le) -> str:
    lo = f"> {gt:g}" if gt is not None else (f">= {ge:g}" if ge is not None else "")
    hi = f"< {lt:g}" if lt is not None else (f"<= {le:g}" if le is not None else "")
    return " and ".join(s for s in (lo, hi) if s) or "(finite)"


def integer(key: str, v: Any, *, ge: int | None = None, le: int | None = None) -> int:
    rng = " and ".join(s for s in ((f">= {ge}" if ge is not None else ""), (f"<= {le}" if le is not None else ""))
                       if s)
    if not isinstance(v, int) or isinstance(v, bool):
        raise SpecError(f"{key}: expected an integer {rng}, got {v!r} ({type(v).__name__})")
    if (ge is not None and v < ge) or (le is not None and v > le):
        raise SpecError(f"{key}: expected an integer {rng}, got {v!r}")
    return v


def string(key: str, v: Any, allowed: tuple[str, ...] | None = None) -> str:
    if not isinstance(v, str):
        raise SpecError(f"{key}: expected a string{allowed_text(allowed)}, got {v!r} ({type(v).__name__})")
    if allowed is not None and v not in allowed:
        raise SpecError(f"{key}: got {v!r}, allowed values: {', '.join(map(repr, allowed))}")
    return v


def allowed_text(allowed):
    return f" (one of {', '.join(map(repr, allowed))})" if allowed else ""


def boolean(key: str, v: Any) -> bool:
    if not isinstance(v, bool):
        raise SpecError(f"{key}: expected true or false, got {v!r} ({type(v).__name__})")
    return v


def table(key: str, v: Any) -> dict:
    if not isinstance(v, dict):
        raise SpecError(f"{key}: expected a table, got {v!r} ({type(v).__name__})")
    return v


def known(key: str, table: dict, allowed: tuple[str, ...]) -> None:
    for k in table:
        if k not in allowed:
            where = f"{key}.{k}" if key else k
            raise SpecError(f"{where}: unknown key; allowed keys in [{key or 'top level'}]: {', '.join(allowed)}")


def sig(v: float) -> float:
    """Round generated grid values to 12 significant digits: stable, readable task parameters."""
    return float(f"{v:.12g}")


def axis(key: str, v: Any, check) -> list[float]:
    """A grid axis: a number, a list of numbers, or ``{min, max, num, scale = "log" | "linear"}``."""
    if is_num(v):
        vals = [v]
    elif isinstance(v, list):
        if not v:
            raise SpecError(f"{key}: expected a non-empty list of numbers")
        vals = list(v)
    elif isinstance(v, dict):
        known(key, v, ("min", "max", "num", "scale"))
        for k in ("min", "max", "num"):
            if k not in v:
                raise SpecError(f"{key}.{k}: missing; a range needs min, max, num (and scale = 'log' or 'linear')")
        scale = string(f"{key}.scale", v.get("scale", "log"), ("log", "linear"))
        lo = check(f"{key}.min", v["min"])
        hi = check(f"{key}.max", v["max"])
        num = integer(f"{key}.num", v["num"], ge=1, le=100000)
        if hi < lo:
            raise SpecError(f"{key}: max ({hi!r}) must be >= min ({lo!r})")
        if num == 1:
            vals = [lo]
        elif scale == "log":
            if lo <= 0:
                raise SpecError(f"{key}.min: a log range needs min > 0, got {lo!r}")
            a, b = math.log10(lo), math.log10(hi)
            vals = [sig(10 ** (a + (b - a) * i / (num - 1))) for i in range(num)]
        else:
            vals = [sig(lo + (hi - lo) * i / (num - 1)) for i in range(num)]
    else:
        raise SpecError(f"{key}: expected a number, a list of numbers or a table {{min, max, num, scale}}, "
                        f"got {v!r} ({type(v).__name__})")
    out = [check(f"{key}[{i}]", x) for i, x in enumerate(vals)]
    if len(set(out)) != len(out):
        raise SpecError(f"{key}: values must be distinct, got {out}")
    return out


def seed_list(key: str, v: Any) -> list[int]:
    if isinstance(v, int) and not isinstance(v, bool):
        v = [v]
    if isinstance(v, dict):
        known(key, v, ("start", "count"))
        start = integer(f"{key}.start", v.get("start", 0), ge=0)
        if "count" not in v:
            raise SpecError(f"{key}.count: missing; seeds = {{start, count}} or a list of integers")
        count = integer(f"{key}.count", v["count"], ge=1, le=100000)
        v = list(range(start, start + count))
    if not isinstance(v, list) or not v:
        raise SpecError(f"{key}: expected a non-empty list of integers >= 0 or {{start, count}}, got {v!r}")
    out = [integer(f"{key}[{i}]", s, ge=0, le=2**62) for i, s in enumerate(v)]
    if len(set(out)) != len(out):
        raise SpecError(f"{key}: seeds must be distinct, got {out}")
    return out


def hurst_value(k, v):
    return number(k, v, gt=0.0, lt=1.0)


def positive(k, v):
    return number(k, v, gt=0.0)
