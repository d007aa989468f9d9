"""Shared scaffolding of the store and sweep tests: run a job into a store in-process, make the two-task
reference store of the ``units`` fault job, a store with chosen rows done, failed or pending, copy a store, run
the CLI in-process, and flip one bit of a store attribute (a damaged store). Imported as ``tests.storekit``."""

from __future__ import annotations

import shutil
from pathlib import Path
from typing import Any

import h5py

from gapsweep import cli
from gapsweep.sweep import runner

ROOT = Path(__file__).resolve().parents[1]
UNITS_JOB = ROOT / "tests" / "faults" / "jobs" / "units.toml"  # two tasks with physical units


def run_job(job: Any, path: Any, **kw: Any) -> dict:
    """``runner.run`` in this process: no MPI, no progress output; ``kw`` as runner.run's (resume=True, ...)."""
    return runner.run(job, path, mpi="off", progress="none", **kw)


def units_store(tmp_path_factory: Any, folder: str) -> Path:
    """A fresh store of :data:`UNITS_JOB` (both tasks done) in a new temporary ``folder``."""
    path = tmp_path_factory.mktemp(folder) / "u.h5"
    s = run_job(UNITS_JOB, path)
    assert s["done"] == s["tasks"] == 2, s
    return path


def partial_store(path: Path, ref: Path, job: Any = UNITS_JOB, copy: tuple[int, ...] = (),
                  failed: tuple[int, ...] = ()) -> Path:
    """A store of ``job`` at ``path`` (no run record) with the rows ``copy`` taken from the finished store
    ``ref`` of the same job, the rows ``failed`` written as failed (message "boom"), the others pending."""
    from gapsweep.sweep import methods as registry
    from gapsweep.sweep import provenance
    from gapsweep.sweep.schema import PRESSURE_HIST, TaskResult
    from gapsweep.sweep.store import Store, open_read

    spec = runner._load(job)
    tasks = runner._select(spec, None)[0]
    with open_read(ref) as f:
        res = f["results"][...]
        h = [f[k][...] for k in ("histograms/edges", "histograms/density", *PRESSURE_HIST)]
    st = Store.create(path, tasks, {**provenance.store_attrs(spec), "runs": "[]"}, spec.histogram["bins"],
                      columns=registry.job_columns(spec))
    try:
        for i in copy:
            st.copy_row(i, res[i], tuple(a[i] for a in h))
        for i in failed:
            st.write(i, TaskResult("failed", "boom", {}))
    finally:
        st.close()
    return path


def copy_store(ref: Path, tmp_path: Path, name: str = "s.h5") -> Path:
    """A copy of the store ``ref`` in ``tmp_path`` (to damage or extend without touching the reference)."""
    p = tmp_path / name
    shutil.copy(ref, p)
    return p


def cli_run(capsys: Any, *args: Any) -> tuple[int, str, str]:
    """``gapsweep ARGS`` in this process (``cli.main``, the function ``python -m gapsweep`` exits with):
    ``(exit code, stdout, stderr)`` of this command alone (output captured before it is dropped)."""
    capsys.readouterr()
    rc = cli.main([str(a) for a in args])
    out = capsys.readouterr()
    return rc, out.out, out.err


def flip_attr(path: Path, name: str) -> None:
    """Flip one bit of the store attribute ``name`` (the lowest bit of its middle character, or of an integer; an
    empty string gets one character), keeping its type."""
    with h5py.File(path, "r+") as f:
        v = f.attrs[name]
        if isinstance(v, bytes):
            v = v.decode()
        if isinstance(v, str):
            b = bytearray(v.encode()) or bytearray(b"@")
            i = len(b) // 2
            while b[i] >= 0x80:  # an ASCII character: the flipped text stays valid UTF-8 (h5py can write it)
                i += 1
            b[i] ^= 1
            f.attrs.modify(name, b.decode())
        else:
            f.attrs.modify(name, v ^ 1)


def small_job(name: str, methods: str, *, sigma0: str = "[1e-2, 5e-2]", seeds: str = "[0]", bins: int = 8,
              lambda_s: float = 0.0625) -> str:
    """The TOML text of a small job: ``H = 0.8``, ``rho = 2e-2``, the surface ``lambda_l = 0.25``, ``lambda_s``
    (default 0.0625), rms slope 1, ``gamma0 = 1e-3``, ``bins`` histogram bins; ``sigma0`` and ``seeds`` TOML arrays,
    ``methods`` the ``[methods.*]`` tables."""
    return f"""
[job]
name = "{name}"
[grid]
hurst = [0.8]
rho = [2e-2]
sigma0 = {sigma0}
seeds = {seeds}
[surface]
lambda_l = 0.25
lambda_s = {lambda_s}
rms_slope = 1.0
[material]
gamma0 = 1e-3
[histogram]
bins = {bins}
{methods.strip()}
"""
