"""A row that failed because an optional package was missing (issue 40 item 10): after ``pip install gapsweep``
without the ``sde`` extra the demo's SDE rows failed, and after the extra was installed ``--resume`` (and the
demo, which resumes) said "nothing to do" (exit 5) for good. Such a row is now recorded with the
``missing extra:`` prefix and run again by the next resume. The package's absence is simulated in-process
(``sys.modules["warp"] = None`` makes its import fail as an uninstalled one does); its presence is the venv's."""

from __future__ import annotations

import sys

import pytest

from gapsweep.sweep import api as store
from gapsweep.sweep.schema import MISSING_EXTRA_PREFIX
from tests.storekit import run_job, small_job

JOB = small_job("extra-retry", sigma0="[1e-3, 1e-1]", methods="""
[methods.theory]
forms = ["paper"]
[methods.sde]
samples = 200
dzeta = 0.05
""")



def _run_without_warp(tmp_path, monkeypatch, old_message=None):
    """Run :data:`JOB` into ``tmp_path/s.h5`` with warp uninstalled (``old_message(m)``: a further patch, the old
    code's message form); returns ``(job file, store, summary)``."""
    job = tmp_path / "job.toml"
    job.write_text(JOB)
    path = tmp_path / "s.h5"
    with monkeypatch.context() as m:
        m.setitem(sys.modules, "warp", None)  # not installed
        if old_message is not None:
            old_message(m)  # the message as the old code wrote it
        s = run_job(job, path)
    return job, path, s


def test_rows_failed_for_a_missing_extra_run_again_once_it_is_installed(tmp_path, monkeypatch):
    pytest.importorskip("warp")
    job, path, s = _run_without_warp(tmp_path, monkeypatch)
    df = store.read(path)
    sde = df[df.method == "sde"]
    assert len(sde) == 2 and (sde.status == "failed").all()
    msgs = list(sde.message)
    assert all(m.startswith(MISSING_EXTRA_PREFIX) and "gapsweep[sde]" in m for m in msgs), msgs
    assert (df[df.method == "theory"].status == "done").all()
    assert s["failed"] == 2
    theory_before = df[df.method == "theory"].mean_gap.to_numpy()
    s = run_job(job, path, resume=True)  # the extra is there now
    assert s["mode"] == "resume" and s["todo"] == 2 and s["done"] == 2, s
    df = store.read(path)
    assert (df.status == "done").all()
    assert (df[df.method == "theory"].mean_gap.to_numpy() == theory_before).all()  # the done rows kept
    ref = tmp_path / "ref.h5"
    run_job(job, ref)
    assert store.diff(path, ref) == []


def test_rows_of_a_store_written_before_the_prefix_are_retried_too(tmp_path, monkeypatch):
    """A store whose SDE rows failed under the old message form ("MissingExtraError: ..."): resumed, they run."""
    pytest.importorskip("warp")
    from gapsweep.sweep import execute

    job, path, _ = _run_without_warp(tmp_path, monkeypatch,
                                     old_message=lambda m: m.setattr(execute, "_missing_extra", lambda e: False))
    sde = store.read(path).query("method == 'sde'")
    assert (sde.status == "failed").all() and all(x.startswith("MissingExtraError:") for x in sde.message)
    s = run_job(job, path, resume=True)
    assert s["todo"] == 2 and s["done"] == 2, s
    assert (store.read(path).status == "done").all()


def test_other_failures_are_not_retried(tmp_path, monkeypatch):
    """A task's own error (not a missing package) stays failed: the resume has nothing to do."""
    from gapsweep.sweep import execute

    job = tmp_path / "job.toml"
    job.write_text(JOB.replace("[methods.sde]\nsamples = 200\ndzeta = 0.05\n", ""))
    path = tmp_path / "s.h5"
    monkeypatch.setattr(execute.registry.get("theory"), "run",
                        lambda *a, **k: (_ for _ in ()).throw(ValueError("the task's own error")))
    run_job(job, path)
    df = store.read(path)
    assert (df.status == "failed").all() and all(m.startswith("ValueError") for m in df.message)
    s = run_job(job, path, resume=True)
    assert s["mode"] == "noop", s
