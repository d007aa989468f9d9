"""Fault injection for the test suite, from outside the package (issue 29 item 6; docs/environment.md "Test
hooks"). gapsweep's own modules read no ``GAPSWEEP_TEST_*`` variable except ``GAPSWEEP_TEST_DELAY`` (left in
``gapsweep.sweep.context``/``execute`` while tests/faults/test_concurrent.py, which uses it, is being rewritten).

A test that starts a gapsweep process puts this folder on ``PYTHONPATH`` (:data:`DIR`, :func:`pythonpath`); its
``sitecustomize.py`` then calls :func:`install` when a ``GAPSWEEP_TEST_*`` variable is set, and the process's
gapsweep modules are patched right after they load:

=============================== ===================================================================================
``GAPSWEEP_TEST_FAIL=a,b``      tasks with these sigma0 values fail ("RuntimeError: injected failure ...")
``GAPSWEEP_TEST_WRITE_ERROR=k`` the k-th row write of the process fails with ENOSPC between payload and status
``GAPSWEEP_TEST_KILL_AT_WRITE=k`` the process SIGKILLs itself at that same point
``GAPSWEEP_TEST_SIGNAL_AT_WRITE=k`` the process sends itself SIGTERM there (a clean stop after that row)
``GAPSWEEP_TEST_PIDDIR=DIR``    each rank writes ``DIR/rank<r>.pid`` once its communicator exists
``GAPSWEEP_TEST_ABORT_RANK=r``  rank r raises after the store is open (where the progress starts)
``GAPSWEEP_TEST_GPUS=n``        the number of visible GPUs (the GPU-per-rank policy on machines without one)
``GAPSWEEP_TEST_MERGE_DELAY=s`` ``gapsweep merge`` waits s seconds with its output open (the signal cases)
=============================== ===================================================================================

In-process tests use the same patches through pytest's ``monkeypatch`` (:func:`fail_at`, :func:`gpus`).
"""

from __future__ import annotations

import importlib.abc
import importlib.machinery
import os
import signal
import sys
import time
from pathlib import Path
from typing import Any

DIR = Path(__file__).resolve().parent
_STATE: dict[str, Any] = {"writes": 0, "rank": 0}


def pythonpath(existing: str | None = None) -> str:
    """``PYTHONPATH`` for a child process: this folder first, then ``existing`` (or the current one)."""
    rest = os.environ.get("PYTHONPATH", "") if existing is None else existing
    return os.pathsep.join(p for p in (str(DIR), rest) if p)


def _env(name: str) -> str:
    return os.environ.get(f"GAPSWEEP_TEST_{name}", "")


# --- the patches, one per module ------------------------------------------------------------------------------


def _fail_values(text: str) -> set[float]:
    return {float(x) for x in text.split(",") if x.strip()}


def patch_context(mod: Any, values: set[float]) -> None:
    """Every Context made from now on fails the tasks at these sigma0 values (``Context._fail``)."""
    init = mod.Context.__init__

    def __init__(self: Any, *a: Any, **kw: Any) -> None:
        init(self, *a, **kw)
        self._fail = set(values)

    mod.Context.__init__ = __init__


def patch_store(mod: Any, write_error: int, kill_at: int, signal_at: int = 0) -> None:
    def _inject(self: Any) -> None:
        _STATE["writes"] += 1
        if signal_at and _STATE["writes"] == signal_at:
            os.kill(os.getpid(), signal.SIGTERM)
        if kill_at and _STATE["writes"] == kill_at:
            os.kill(os.getpid(), signal.SIGKILL)
        if write_error and _STATE["writes"] == write_error:
            raise OSError(28, "No space left on device (injected by GAPSWEEP_TEST_WRITE_ERROR)")

    mod.Store._inject = _inject


def patch_runner(mod: Any, piddir: str, abort_rank: str) -> None:
    comm_of = mod._comm

    def _comm(mpi: str) -> Any:
        comm = comm_of(mpi)
        _STATE["rank"] = comm.rank if comm is not None else 0
        if piddir:
            Path(piddir, f"rank{_STATE['rank']}.pid").write_text(str(os.getpid()))
        return comm

    mod._comm = _comm
    if abort_rank:
        progress = mod.Progress

        def Progress(*a: Any, **kw: Any) -> Any:
            if str(_STATE["rank"]) == abort_rank:
                raise RuntimeError(f"injected error on rank {abort_rank} (GAPSWEEP_TEST_ABORT_RANK)")
            return progress(*a, **kw)

        mod.Progress = Progress


def patch_gpus(mod: Any, count: int) -> None:
    mod.visible_count = lambda: count


def patch_merge(mod: Any, seconds: float) -> None:
    class Store(mod.Store):
        @classmethod
        def create(cls, *a: Any, **kw: Any) -> Any:
            st = super().create(*a, **kw)
            time.sleep(seconds)  # the output is open: a signal now must leave nothing behind
            return st

    mod.Store = Store


def _patches() -> dict[str, Any]:
    out: dict[str, Any] = {}
    if _env("FAIL"):
        out["gapsweep.sweep.context"] = lambda m: patch_context(m, _fail_values(_env("FAIL")))
    if _env("WRITE_ERROR") or _env("KILL_AT_WRITE") or _env("SIGNAL_AT_WRITE"):
        out["gapsweep.sweep.store"] = lambda m: patch_store(m, int(_env("WRITE_ERROR") or 0),
                                                            int(_env("KILL_AT_WRITE") or 0),
                                                            int(_env("SIGNAL_AT_WRITE") or 0))
    if _env("PIDDIR") or _env("ABORT_RANK"):
        out["gapsweep.sweep.runner"] = lambda m: patch_runner(m, _env("PIDDIR"), _env("ABORT_RANK"))
    if _env("GPUS"):
        out["gapsweep.sweep.gpus"] = lambda m: patch_gpus(m, int(_env("GPUS")))
    if _env("MERGE_DELAY"):
        out["gapsweep.sweep.merge"] = lambda m: patch_merge(m, float(_env("MERGE_DELAY")))
    return out


class _AfterImport(importlib.abc.MetaPathFinder):
    """Finds the named modules as usual and runs a patch right after each one executes."""

    def __init__(self, patches: dict[str, Any]) -> None:
        self.patches = patches

    def find_spec(self, name: str, path: Any = None, target: Any = None) -> Any:
        if name not in self.patches:
            return None
        spec = importlib.machinery.PathFinder.find_spec(name, path)
        if spec is None or spec.loader is None:
            return spec
        loader, patch = spec.loader, self.patches[name]

        class Loader(importlib.abc.Loader):
            def create_module(self, s: Any) -> Any:
                return loader.create_module(s)

            def exec_module(self, module: Any) -> None:
                loader.exec_module(module)
                patch(module)

        spec.loader = Loader()
        return spec


def install() -> None:
    """Patch the gapsweep modules named by the ``GAPSWEEP_TEST_*`` variables as they load (see above)."""
    patches = _patches()
    if not patches:
        return
    for name, patch in patches.items():
        if name in sys.modules:
            patch(sys.modules[name])
    sys.meta_path.insert(0, _AfterImport({k: v for k, v in patches.items() if k not in sys.modules}))


# --- in-process use (pytest) -----------------------------------------------------------------------------------


def fail_at(monkeypatch: Any, *sigma0: float) -> None:
    """Tasks at these sigma0 values fail in this process (``GAPSWEEP_TEST_FAIL`` for in-process tests)."""
    from gapsweep.sweep import context

    init = context.Context.__init__

    def __init__(self: Any, *a: Any, **kw: Any) -> None:
        init(self, *a, **kw)
        self._fail = set(sigma0)

    monkeypatch.setattr(context.Context, "__init__", __init__)


def gpus(monkeypatch: Any, count: int) -> None:
    """This process sees ``count`` GPUs (``GAPSWEEP_TEST_GPUS`` for in-process tests)."""
    from gapsweep.sweep import gpus as mod

    monkeypatch.setattr(mod, "visible_count", lambda: count)
