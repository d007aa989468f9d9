"""The 0.1 flat names (``gapsweep.store``, ``gapsweep.surface``, ...), gathered here out of the package's face
(docs/architecture.md, "The 0.1 names").

This folder is on ``gapsweep.__path__`` (after the package's own folder), so Python's ordinary path finder finds
``gapsweep.store`` as the file ``gapsweep/_compat/store.py``: no import hook, no process-wide state. Each such file
calls :func:`install`, which replaces the file's entry in ``sys.modules`` by the module the name now lives in
(the table ``gapsweep.STABLE_NAMES``), so ``import gapsweep.store`` gives *that* module object (attributes,
monkeypatching and pickling act on the real module; ``importlib.reload`` reloads the real module; its
``__spec__`` stays its own). ``python -m gapsweep.<name>`` runs the target as ``__main__``. Names in
``gapsweep.DEPRECATED_NAMES`` warn (:class:`DeprecationWarning`, naming the release that removes them, attributed
to the importing line) when first imported.
"""

from __future__ import annotations

import importlib
import runpy
import sys
import warnings
from importlib.machinery import ModuleSpec

import gapsweep

__all__ = ["REMOVED_IN", "install"]

#: the release in which the deprecated 0.1 names go
REMOVED_IN = "0.4"


def install(name: str, spec: ModuleSpec | None) -> None:
    """Make the alias module ``name`` (the caller's ``__name__``) the module its 0.1 name stands for.

    ``spec`` is the caller's ``__spec__``, whose name is the 0.1 name: under ``python -m`` the caller's
    ``__name__`` is ``"__main__"``, and then the target runs as the main module instead."""
    alias = spec.name if spec is not None else name
    target = gapsweep.STABLE_NAMES.get(alias)
    if target is None:
        raise ImportError(f"{alias} is not a 0.1 name of gapsweep (gapsweep.STABLE_NAMES); import "
                          f"gapsweep.{alias.rpartition('.')[2]} instead", name=alias)
    if alias in gapsweep.DEPRECATED_NAMES:
        # stacklevel 3: this function, the alias file, then the importing line (Python skips its import frames)
        warnings.warn(f"{alias} is a deprecated 0.1 name and goes in gapsweep {REMOVED_IN}: import {target}",
                      DeprecationWarning, stacklevel=3)
    if name == "__main__":
        runpy.run_module(target, run_name="__main__", alter_sys=True)
        return
    sys.modules[name] = importlib.import_module(target)
