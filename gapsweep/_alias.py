"""The 0.1 flat names (``gapsweep.store``, ``gapsweep.surface``, ...) as plain alias modules (docs/architecture.md,
"The 0.1 names").

Each alias is a real file, ``gapsweep/<name>.py``, that calls :func:`install`: the file's entry in
``sys.modules`` is replaced by the module the name now lives in, so ``import gapsweep.store`` gives *that* module
object (attributes, monkeypatching and pickling act on the real module; ``importlib.reload`` reloads the real
module; its ``__spec__`` stays its own). Type checkers and IDEs read the file's ``from <target> import *`` under
``TYPE_CHECKING``. ``python -m gapsweep.<name>`` runs the target as ``__main__``. Names listed as deprecated warn
(:class:`DeprecationWarning`, naming the release that removes them) when first imported.
"""

from __future__ import annotations

import importlib
import runpy
import sys
import warnings

__all__ = ["REMOVED_IN", "install"]

#: the release in which the deprecated 0.1 names go
REMOVED_IN = "0.4"


def install(name: str, target: str, *, deprecated: bool, spec_name: str | None = None) -> None:
    """Make the alias module ``name`` (the caller's ``__name__``) the module ``target``.

    ``spec_name`` is the caller's ``__spec__.name``: under ``python -m`` the caller's ``__name__`` is
    ``"__main__"``, and then ``target`` runs as the main module instead."""
    alias = spec_name or name
    if deprecated:
        warnings.warn(f"{alias} is a deprecated 0.1 name and goes in gapsweep {REMOVED_IN}: import {target}",
                      DeprecationWarning, stacklevel=3)
    if name == "__main__":
        runpy.run_module(target, run_name="__main__", alter_sys=True)
        return
    sys.modules[name] = importlib.import_module(target)
