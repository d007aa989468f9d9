"""--task-timeout that never poisons a run (issue 19 item 4; docs/reliability.md "Time limits"): a cold JIT cache
does not time the first tasks out (the method is warmed up outside the limit), the limit is kept between solver
iterations (no asynchronous exception inside numba's compiler or an import), later tasks of the same process run
normally, and a timed-out row is run again by --resume, which says so."""

from __future__ import annotations

import pytest

from gapsweep import store

from .conftest import gs

JOB = """
[job]
name = "timeouts"
[grid]
hurst = 0.8
rho = 4e-3
sigma0 = [1e-3, 1e-2, 1e-1]
seeds = [0, 1]
[surface]
lambda_l = 0.25
lambda_s = 0.0625
rms_slope = 1.0
[histogram]
bins = 8
[methods.gfmd]
n = 64
tol = 1e-8
"""


@pytest.fixture(scope="module")
def unlimited(tmp_path_factory):
    """An unlimited run's store of JOB (no --task-timeout, no delay), made once in this process: both tests
    compare their stores with it (each made its own copy with a third `gapsweep run` before)."""
    from gapsweep import runner

    d = tmp_path_factory.mktemp("timeouts_ref")
    (d / "j.toml").write_text(JOB)
    runner.run(d / "j.toml", d / "ref.h5", progress="none", mpi="off")
    return d / "ref.h5"


def test_cold_jit_cache_does_not_time_out(tmp_path, unlimited):
    """An empty numba cache: the first GFMD task would compile its kernels (seconds on 2 cores) inside a 1.5 s
    limit; warmed up outside the limit, every task finishes, and the rows equal an unlimited run's."""
    pytest.importorskip("numba")
    job = tmp_path / "j.toml"
    job.write_text(JOB)
    cache = tmp_path / "numba-cache"
    p = gs("run", job, "--store", tmp_path / "a.h5", "--mpi", "off", "--progress", "none", "--task-timeout", "1.5",
           NUMBA_CACHE_DIR=str(cache), timeout=300)
    assert p.returncode == 0, p.stderr
    df = store.read(tmp_path / "a.h5")
    assert set(df.status) == {"done"}, df[["status", "message"]]
    assert store.diff(tmp_path / "a.h5", unlimited) == []


def test_timed_out_rows_run_again_on_resume(tmp_path, unlimited):
    """Tasks that overrun their limit are failed rows saying 'timeout'; later tasks of the process are not
    poisoned; --resume runs the timed-out rows again (and says so) and reaches an unlimited run's store."""
    job = tmp_path / "j.toml"
    job.write_text(JOB)
    path = tmp_path / "s.h5"
    p = gs("run", job, "--store", path, "--mpi", "off", "--progress", "none", "--task-timeout", "0.3",
           GAPSWEEP_TEST_DELAY="2", timeout=300)
    assert p.returncode == 3, p.stderr  # every task timed out
    df = store.read(path)
    assert set(df.status) == {"failed"} and all(m.startswith("timeout:") for m in df.message)
    assert all("--resume" in m for m in df.message)
    p = gs("run", job, "--store", path, "--mpi", "off", "--resume", timeout=300)
    assert p.returncode == 0, p.stderr
    assert "timed-out row(s) are run again" in p.stderr
    assert set(store.read(path).status) == {"done"}
    assert store.diff(path, unlimited) == []
