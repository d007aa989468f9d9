"""Issue 31, item 3: a signal during numba's JIT compilation must not turn a row into a ``failed`` row that
``--resume`` never runs again.

numba compiles through llvmlite, which calls back into Python through ctypes; an exception that a signal
handler raises inside such a callback is swallowed by ctypes ("Exception ignored on calling ctypes callback
function"), and the dispatcher then fails with "no compiled object yet". The injection below does exactly that:
the task, on its k-th call, runs a real ctypes callback in which SIGTERM arrives (the run's handler raises
``Interrupted`` there and ctypes swallows it), then raises numba's error. Before the fix the row was stored as
``failed`` ("RuntimeError: no compiled object yet") and stayed so after ``--resume``."""

from __future__ import annotations

import ctypes
import os
import signal
import time

import pytest

from gapsweep import store
from gapsweep.sweep import limits, runner
from gapsweep.sweep import methods as registry

from .conftest import JOBS, assert_only_done_pending, gs


def _inject(monkeypatch, at: int, with_signal: bool) -> None:
    meth = registry.get("theory")
    real = meth.run
    calls = [0]

    def run(t, ctx, prev):
        calls[0] += 1
        if calls[0] == at:
            if with_signal:
                def callback():  # a signal inside a C callback, as in llvmlite during compilation
                    os.kill(os.getpid(), signal.SIGTERM)
                    time.sleep(5)  # the handler's Interrupted cuts this sleep, then ctypes swallows it

                ctypes.CFUNCTYPE(None)(callback)()
            raise RuntimeError("no compiled object yet")  # numba's dispatcher after the cut compilation
        return real(t, ctx, prev)

    monkeypatch.setattr(meth, "run", run)


@pytest.mark.filterwarnings("ignore::pytest.PytestUnraisableExceptionWarning")  # the swallowed signal, on purpose
def test_signal_during_jit_leaves_row_pending(tmp_path, refs, monkeypatch):
    path = tmp_path / "s.h5"
    _inject(monkeypatch, 5, with_signal=True)
    old = signal.getsignal(signal.SIGTERM)
    try:
        with pytest.raises(limits.Interrupted) as e:
            runner.run(JOBS["theory"], path, mpi="off", progress="none")
    finally:
        signal.signal(signal.SIGTERM, old)
    assert e.value.signum == signal.SIGTERM
    monkeypatch.undo()
    df = store.read(path)
    assert int((df.status == "done").sum()) == 4  # the four tasks before the cut one
    assert_only_done_pending(path)  # the cut task is pending, not failed
    p = gs("run", JOBS["theory"], "--store", path, "--mpi", "off", "--progress", "none", "--resume")
    assert p.returncode == 0, p.stderr
    assert store.diff(path, refs["theory"]) == []


def test_cut_compilation_without_signal_is_rerun(tmp_path, refs, monkeypatch):
    """The error alone (the signal went to another handler, or to a thread): the row is failed with the
    ``interrupted:`` prefix, and --resume runs it again."""
    path = tmp_path / "s.h5"
    _inject(monkeypatch, 3, with_signal=False)
    runner.run(JOBS["theory"], path, mpi="off", progress="none")
    monkeypatch.undo()
    df = store.read(path)
    bad = df[df.status != "done"]
    assert len(bad) == 1 and bad.status.iloc[0] == "failed"
    assert bad.message.iloc[0].startswith("interrupted:"), bad.message.iloc[0]
    p = gs("run", JOBS["theory"], "--store", path, "--mpi", "off", "--progress", "none", "--resume")
    assert p.returncode == 0, p.stderr
    assert store.diff(path, refs["theory"]) == []


def test_cut_by_signal_rules():
    """Which task errors count as interruptions (limits.cut_by_signal)."""
    n = limits.signal_count()
    assert not limits.cut_by_signal(ValueError("bad input"), n)
    assert limits.cut_by_signal(RuntimeError("no compiled object yet"), n)
    assert limits.cut_by_signal(ValueError("x"), n - 1)  # a signal arrived since the task started
    try:
        try:
            raise limits.Interrupted(signal.SIGINT)
        except limits.Interrupted:
            raise RuntimeError("lowering failed") from None
    except RuntimeError as e:  # the chain still holds the interruption (__context__)
        assert limits.cut_by_signal(e, n)
    assert limits.is_interrupted(limits.interrupted_message(RuntimeError("x")))
