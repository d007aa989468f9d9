"""Where numba caches gapsweep's own compiled kernels (docs/environment.md, ``NUMBA_CACHE_DIR``).

The fused GFMD CPU kernels (``gapsweep.gfmd._ops``, ``gapsweep.gfmd._constrained_ops``) are compiled with
``cache=True``. Numba's default puts the cache next to the source (the package's ``__pycache__``): a read-only or
shared install fails to cache, and a checkout collects another user's files (issue 19). This module adds a numba
cache locator that answers for functions of gapsweep's own modules only and puts their cache in a per-user folder:

1. ``$NUMBA_CACHE_DIR`` when the user set it (then numba's own locator is used, unchanged);
2. else ``$XDG_CACHE_HOME/gapsweep/numba`` (``~/.cache/gapsweep/numba`` without ``XDG_CACHE_HOME``);
3. else ``<tempdir>/gapsweep-numba-<uid>``; with neither writable numba's default order applies.

Nothing process-wide changes: no environment variable is set, numba's configuration is untouched, and the
locator returns ``None`` for any function outside gapsweep, so other code's ``cache=True`` behaves as without
gapsweep. No numba import happens here until :func:`njit` is called.
"""

from __future__ import annotations

import os
import tempfile
from collections.abc import Callable
from functools import cache
from typing import Any

__all__ = ["cache_dir", "njit"]


@cache
def _writable(d: str) -> bool:
    try:
        os.makedirs(d, exist_ok=True)
    except OSError:
        return False
    return os.access(d, os.W_OK | os.X_OK)


def cache_dir() -> str | None:
    """The folder for gapsweep's kernels (see the module docstring), or None when numba's own rules apply
    (``$NUMBA_CACHE_DIR`` set, or no candidate writable). Read at each compilation, not at import."""
    if os.environ.get("NUMBA_CACHE_DIR"):
        return None
    home = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    uid = os.getuid() if hasattr(os, "getuid") else 0
    for d in (os.path.join(home, "gapsweep", "numba"), os.path.join(tempfile.gettempdir(), f"gapsweep-numba-{uid}")):
        if _writable(d):
            return d
    return None


_LOCATOR: type | None = None


def _install_locator() -> None:
    """Put gapsweep's locator first in numba's list (idempotent). Numba consults the list when a ``cache=True``
    dispatcher is created; the first locator whose ``from_function`` answers wins."""
    global _LOCATOR
    if _LOCATOR is not None:
        return
    from numba.core import caching

    class _GapsweepCacheLocator(caching._SourceFileBackedLocatorMixin, caching._CacheLocator):
        """As numba's locator for a user-provided folder, pointed at :func:`cache_dir`, for gapsweep's functions
        (the source file's modification time and size keep invalidating the cache, as numba's own do)."""

        def __init__(self, py_func: Any, py_file: str, root: str) -> None:
            self._py_file = py_file
            self._lineno = py_func.__code__.co_firstlineno
            self._cache_path = os.path.join(root, self.get_suitable_cache_subpath(py_file))

        @classmethod
        def from_function(cls, py_func: Any, py_file: str) -> Any:
            if not str(getattr(py_func, "__module__", "") or "").startswith("gapsweep."):
                return None
            root = cache_dir()
            if root is None or not os.path.isfile(py_file):
                return None
            return cls(py_func, py_file, root)

        def get_cache_path(self) -> str:
            return self._cache_path

    impl = getattr(caching, "CacheImpl", None) or caching._CacheImpl
    impl._locator_classes.insert(0, _GapsweepCacheLocator)
    _LOCATOR = _GapsweepCacheLocator


def njit(**options: Any) -> Callable[[Callable[..., Any]], Any]:
    """``numba.njit(cache=True, **options)`` with gapsweep's cache folder (module docstring)."""
    import numba

    _install_locator()
    return numba.njit(cache=True, **options)
