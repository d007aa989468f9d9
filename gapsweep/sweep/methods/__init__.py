"""The sweep's methods, one plug-in module each (interface: gapsweep.sweep.methods.base; docs/architecture.md).

Built-in methods, in the canonical order of task expansion: ``theory`` (field theory and Persson's theory),
``gfmd`` (the exact solver), ``sde`` (SDE ensembles), ``fokker_planck`` (the Fokker-Planck density), and the
predictors ``hybrid`` (the mean gap to a requested accuracy) and ``multiscale`` (the gap distribution). A method
of another package registers through the entry-point group ``gapsweep.methods``; it then follows the built-ins.
"""

from __future__ import annotations

import logging
from importlib import metadata

from gapsweep.sweep.methods import base, flow, fokker_planck, gfmd, hybrid, multiscale, sde, theory  # noqa: F401 - built-ins
from gapsweep.sweep.methods.base import Env, Extension, Method, register, register_extension, registered
from gapsweep.sweep.schema import Column, JobSpec

__all__ = ["Env", "Extension", "Method", "all_methods", "extensions", "get", "job_columns", "names", "register",
           "register_extension"]

log = logging.getLogger("gapsweep.sweep.methods")
_loaded = False


def _load_entry_points() -> None:
    """Import the modules named in the ``gapsweep.methods`` entry-point group once (each registers itself)."""
    global _loaded
    if _loaded:
        return
    _loaded = True
    for ep in metadata.entry_points(group="gapsweep.methods"):
        try:
            ep.load()
        except Exception as e:  # a broken third-party plug-in must not break the built-in methods
            log.warning("sweep method plug-in %s (%s) failed to load: %s: %s", ep.name, ep.value,
                        type(e).__name__, e)


def all_methods() -> dict[str, Method]:
    """Every registered method by name, built-ins first, in the canonical order of task expansion."""
    _load_entry_points()
    return registered()


def names() -> tuple[str, ...]:
    """The names of the registered methods, in canonical order."""
    return tuple(all_methods())


def get(name: str) -> Method:
    """The method plug-in ``name``; ``KeyError`` naming the registered methods otherwise."""
    reg = registered() if _loaded else all_methods()
    if name not in reg:
        raise KeyError(f"no sweep method {name!r}; registered: {', '.join(reg)}")
    return reg[name]


def extensions(host: str) -> dict[str, Extension]:
    """The extensions of method ``host`` (built-in and third-party), by name."""
    _load_entry_points()
    return base.extensions(host)


def job_columns(spec: JobSpec) -> list[tuple[str, str]]:
    """The plug-in columns ``(name, kind)`` of a job's store (docs/store.md "Plug-in columns"): the
    ``own_columns`` of each of its methods and of each extension it switches on, in the canonical method order,
    each name once. [] for a job without such plug-ins (its store has exactly the built-in table)."""
    out: dict[str, Column] = {}
    for name, m in all_methods().items():
        if name not in spec.methods:
            continue
        cols = m.job_own_columns(spec)
        undeclared = [k for k in cols if k not in m.own_columns]
        if undeclared:
            raise ValueError(f"method {name!r}: job_own_columns returned {undeclared}, not in its own_columns")
        for ename, e in extensions(name).items():
            if spec.methods[name].get(f"ext.{ename}"):
                cols.update(e.own_columns)
        for k, c in cols.items():
            if k in out and out[k].kind != c.kind:
                raise ValueError(f"plug-in column {k!r} declared as {out[k].kind!r} and {c.kind!r} in one job")
            out.setdefault(k, c)
    return [(k, c.kind) for k, c in out.items()]
