"""Start-up hook of the fault suite's child processes (test code: never installed, never imported by gapsweep).

tests/faults/conftest.py (:class:`Hold`) puts this folder first on ``PYTHONPATH`` of one ``gapsweep`` process and
sets ``FAULTS_HOLD=<dir>:<point>``. At the point the process creates ``<dir>/reached-<pid>`` and waits there
until ``<dir>/release`` exists or a SIGINT/SIGTERM has arrived. Points: ``k`` (a number): right after the
process's ``k``-th store row write (the row complete and flushed; inside the write, so a signal is acted on when
the write returns, as for any write; the store's stop file ``<store>.stop`` ends the wait too); ``import``: when
the run command has loaded its runner (signal handlers installed, nothing opened); ``lease``: the lease taken,
the store not yet opened or created; ``create``: a new store created, not yet opened by the run; ``opened``: the
store at its path opened by the run (a new one renamed into place), before anything else is written;
``startup-term-then-kill`` (no wait): the process sends itself SIGTERM once its lease is taken and SIGKILL once
its store is opened -- mpiexec's forwarded signal during start-up and its SIGKILL 1 s later, at their worst. A test then
knows where the run is (a barrier instead of a race between the run's speed and the test's): a second writer, a
signal, a kill or a full disk meets a run that is certainly in the middle of its work, on a loaded machine too.

The patches are made when ``gapsweep.sweep.store``, ``.lease`` or ``.runner`` is first imported (a meta-path
finder), so nothing else of the process's start-up changes (the CLI installs its signal handlers before numpy,
gapsweep.sweep.limits).
"""

from __future__ import annotations

import importlib.abc
import importlib.machinery
import os
import sys
import time

_SPEC = os.environ.get("FAULTS_HOLD", "")
_FOLDER, _, _POINT = _SPEC.rpartition(":")
_SIGNALS = int(os.environ.get("FAULTS_HOLD_SIGNALS", "0") or 0)


def _hold(stop: str | None = None) -> None:
    """Mark this process as arrived and wait for the release file, a SIGINT/SIGTERM (recorded by gapsweep's
    handlers, which are installed before any hold point) or the stop file ``stop``."""
    from gapsweep.sweep import limits

    open(os.path.join(_FOLDER, f"reached-{os.getpid()}"), "w").close()
    release = os.path.join(_FOLDER, "release")
    while not (os.path.exists(release) or (stop and os.path.exists(stop)) or limits._received is not None):
        time.sleep(0.005)  # polls a condition: how long it takes never decides an outcome
    if _SIGNALS > 1 and limits._received is not None:
        # FAULTS_HOLD_SIGNALS=n: say which signal was taken first (signalled-<pid>), then stay until n signals
        # have arrived, so the test's next signal certainly comes after the first was recorded and meets the
        # run before its clean-up (two signals sent back to back to a process with several threads can be
        # taken in either order by the kernel: no test may rely on that order)
        with open(os.path.join(_FOLDER, f"signalled-{os.getpid()}"), "w") as f:
            f.write(str(int(limits._received)))
        while not (os.path.exists(release) or limits.signal_count() >= _SIGNALS):
            time.sleep(0.005)


def _patch_store(mod) -> None:
    if _POINT == "create":  # the store created (under its temporary name), before the run opens it
        create = mod.Store.create.__func__

        def created(cls, *a, **kw):
            st = create(cls, *a, **kw)
            _hold()
            return st

        mod.Store.create = classmethod(created)
        return
    if _POINT in ("opened", "startup-term-then-kill"):  # the store at its path (created and renamed into
        open_ = mod.Store.open.__func__                    # place, or resumed), just opened

        def opened(cls, *a, **kw):
            st = open_(cls, *a, **kw)
            if _POINT == "opened":
                _hold()
            else:  # what mpiexec does 1 s after forwarding a SIGTERM, at the worst moment
                import signal

                os.kill(os.getpid(), signal.SIGKILL)
            return st

        mod.Store.open = classmethod(opened)
        return
    if not _POINT.isdigit():
        return
    k, orig, count = int(_POINT), mod.Store.write, [0]

    def write(self, i, res, *, flush=True):
        orig(self, i, res, flush=flush)
        count[0] += 1
        if count[0] == k:  # the k-th row is complete and flushed
            _hold(f"{self.path}.stop")

    mod.Store.write = write


def _patch_lease(mod) -> None:
    if _POINT not in ("lease", "startup-term-then-kill"):
        return
    acquire = mod.acquire

    def acquired(*a, **kw):
        held = acquire(*a, **kw)
        if _POINT == "lease":
            _hold()
        else:  # a SIGTERM while the run starts (the lease taken, the store not yet made): recorded, not acted on
            import signal

            os.kill(os.getpid(), signal.SIGTERM)
        return held

    mod.acquire = acquired


def _patch_runner(mod) -> None:
    if _POINT == "import":  # the run command's modules loading (its signal handlers are installed)
        _hold()


_TARGETS = {"gapsweep.sweep.store": _patch_store, "gapsweep.sweep.lease": _patch_lease,
            "gapsweep.sweep.runner": _patch_runner}


class _Loader(importlib.abc.Loader):
    def __init__(self, inner) -> None:
        self.inner = inner

    def create_module(self, spec):
        return self.inner.create_module(spec)

    def exec_module(self, module) -> None:
        self.inner.exec_module(module)
        _TARGETS[module.__name__](module)


class _Finder(importlib.abc.MetaPathFinder):
    def find_spec(self, name, path, target=None):
        if name not in _TARGETS:
            return None
        # the spec of the finders after this one (tests/hooks' fault injection wraps the same modules): this
        # patch runs after theirs
        for finder in sys.meta_path:
            if finder is self or not hasattr(finder, "find_spec"):
                continue
            spec = finder.find_spec(name, path, target)
            if spec is not None:
                break
        else:
            spec = importlib.machinery.PathFinder.find_spec(name, path)
        if spec is not None and spec.loader is not None:
            spec.loader = _Loader(spec.loader)
        return spec


def _chain() -> None:
    """Run the next ``sitecustomize.py`` on the path too (tests/hooks: the suite's fault injection)."""
    import importlib.util

    here = os.path.dirname(os.path.abspath(__file__))
    for d in sys.path:
        f = os.path.join(os.path.abspath(d or "."), "sitecustomize.py")
        if os.path.abspath(d or ".") != here and os.path.isfile(f):
            spec = importlib.util.spec_from_file_location("_next_sitecustomize", f)
            mod = importlib.util.module_from_spec(spec)
            spec.loader.exec_module(mod)
            return


_chain()
if _SPEC:
    sys.meta_path.insert(0, _Finder())
