"""Start-up hook of the fault suite's child processes (test code: never installed, never imported by gapsweep).

tests/faults/conftest.py (:class:`Hold`) puts this folder first on ``PYTHONPATH`` of one ``gapsweep`` process and
sets ``FAULTS_HOLD=<dir>:<k>``. Right after that process's ``k``-th store row write (the row complete and
flushed) it creates ``<dir>/reached-<pid>`` and waits there -- inside the write, so a signal is acted on when
the write returns, as for any write -- until ``<dir>/release`` exists, a SIGINT/SIGTERM has arrived, or the
store's stop file ``<store>.stop`` exists. A test then knows the run is still going (a barrier instead of a race
between the run's speed and the test's): a second writer, a signal, a kill or a full disk meets a run that is
certainly in the middle of its work, on a loaded machine too.

The patch is made when ``gapsweep.sweep.store`` is first imported (a meta-path finder), so nothing else of the
process's start-up changes (the CLI installs its signal handlers before numpy, gapsweep.sweep.limits).
"""

from __future__ import annotations

import importlib.abc
import importlib.machinery
import os
import sys
import time

_SPEC = os.environ.get("FAULTS_HOLD", "")
_TARGET = "gapsweep.sweep.store"


def _patch(mod) -> None:
    folder, _, k = _SPEC.rpartition(":")
    k = int(k)
    orig = mod.Store.write
    count = [0]

    def write(self, i, res, *, flush=True):
        orig(self, i, res, flush=flush)
        count[0] += 1
        if count[0] != k:
            return
        from gapsweep.sweep import limits

        open(os.path.join(folder, f"reached-{os.getpid()}"), "w").close()
        release, stop = os.path.join(folder, "release"), f"{self.path}.stop"
        while not (os.path.exists(release) or os.path.exists(stop) or limits._received is not None):
            time.sleep(0.005)  # polls a condition: how long it takes never decides an outcome

    mod.Store.write = write


class _Loader(importlib.abc.Loader):
    def __init__(self, inner) -> None:
        self.inner = inner

    def create_module(self, spec):
        return self.inner.create_module(spec)

    def exec_module(self, module) -> None:
        self.inner.exec_module(module)
        _patch(module)


class _Finder(importlib.abc.MetaPathFinder):
    def find_spec(self, name, path, target=None):
        if name != _TARGET:
            return None
        spec = importlib.machinery.PathFinder.find_spec(name, path)
        if spec is not None and spec.loader is not None:
            spec.loader = _Loader(spec.loader)
        return spec


if _SPEC:
    sys.meta_path.insert(0, _Finder())
