"""Jobs whose GFMD tasks span every rank (``[methods.gfmd] distributed = true``, gapsweep.sweep.collective) under
``mpiexec -n 2/3`` on the CPU (skipped without mpiexec/mpi4py): the store's values equal those of the same job
run in one process without ``distributed`` (the single-process solve), for the exponential law (with a theory
method beside it, run on rank 0 alone) and for adhesion along a load path into tension. Tolerances: mean gap
1e-9 relative, contact area 1e-9, gap statistics and elastic energy 1e-9 relative, histograms 1e-9. The
exponential law runs the same minimiser split over ranks; adhesion runs the lean L-BFGS (2 pairs) where one
process keeps 8, so both are solved to tol 1e-11 (the lean path agrees to ~tol, docs/gfmd.md)."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

pytestmark = [pytest.mark.skipif(shutil.which("mpiexec") is None, reason="mpiexec not installed"), pytest.mark.slow]

ENV = {"OMPI_ALLOW_RUN_AS_ROOT": "1", "OMPI_ALLOW_RUN_AS_ROOT_CONFIRM": "1",
       "OMPI_MCA_rmaps_base_oversubscribe": "1", "PYTHONUNBUFFERED": "1"}
ROOT = Path(__file__).resolve().parents[2]

EXPONENTIAL = """
[job]
name = "dist-exp"
[grid]
hurst = [0.8]
rho = [2e-2]
sigma0 = [1e-3, 1e-2, 1e-1]
seeds = [0]
[surface]
lambda_l = 0.25
lambda_s = 0.0625
rms_slope = 1.0
[material]
gamma0 = 1e-3
[histogram]
bins = 16
[methods.theory]
forms = ["paper"]
[methods.gfmd]
n = 64
tol = 1e-11
backend = "numpy"
"""

ADHESIVE = """
[job]
name = "dist-adh"
[grid]
hurst = [0.8]
rho = [2e-2]
sigma0 = [1e-3, 2e-4, -1e-4]
seeds = [0]
[surface]
lambda_l = 0.25
lambda_s = 0.0625
rms_slope = 0.3
[interaction]
kind = "adhesive"
work = 2e-4
[histogram]
bins = 16
[methods.gfmd]
n = 64
tol = 1e-11
backend = "numpy"
order = "decreasing"
"""

COLUMNS = ("mean_gap", "gap_std", "gap_min", "gap_max", "elastic_energy", "residual")


def _mpirun(n: int, args: list[str]) -> subprocess.CompletedProcess:
    pytest.importorskip("mpi4py")
    env = dict(os.environ, **ENV)
    env["PYTHONPATH"] = os.pathsep.join([str(ROOT), env.get("PYTHONPATH", "")])
    return subprocess.run(["mpiexec", "-n", str(n), sys.executable, "-m", "gapsweep", *args], env=env,
                          capture_output=True, text=True, timeout=600)


def _rows(path: Path):
    from gapsweep import store

    df = store.read(path)
    df = df.sort_values(["method", "hurst", "rho", "sigma0", "seed", "n"]).reset_index(drop=True)
    return df, (store.read_histograms(path), store.read_pressure_histograms(path))


def _compare(ref: Path, got: Path) -> None:
    a, ha = _rows(ref)
    b, hb = _rows(got)
    assert list(a.method) == list(b.method) and np.array_equal(a.sigma0, b.sigma0)
    assert set(a.status) == {"done"} and set(b.status) == {"done"}, (a.message, b.message)
    g = (a.method == "gfmd").to_numpy()
    assert g.sum() == 3
    for c in ("mean_gap", "gap_std", "gap_min", "gap_max", "elastic_energy"):
        x, y = a[c].to_numpy()[g], b[c].to_numpy()[g]
        assert np.all(np.abs(y - x) <= 1e-9 * np.abs(x)), (c, x, y)
    x, y = a.contact_area.to_numpy()[g], b.contact_area.to_numpy()[g]
    assert np.all(np.abs(y - x) <= 1e-9) and np.all((x > 0) & (x < 1)), (x, y)
    assert np.all(b.residual.to_numpy()[g] <= 1e-11)
    t = ~g  # the theory rows (rank 0 alone): the same numbers
    assert np.array_equal(a.mean_gap.to_numpy()[t], b.mean_gap.to_numpy()[t], equal_nan=True)
    for ta, tb in zip(a.task_id[g], b.task_id[g]):
        for k in (0, 1):  # the gap's and the pressure's histograms
            (ea, da, *_), (eb, db, *_) = ha[k][ta], hb[k][tb]
            assert np.allclose(ea, eb, rtol=1e-9, atol=0), (k, ea, eb)
            assert np.allclose(da, db, rtol=0, atol=1e-9 * np.abs(da).max()), (k, da, db)


@pytest.fixture(scope="module")
def refs(tmp_path_factory):
    from gapsweep import runner

    d = tmp_path_factory.mktemp("collective")
    out = {}
    for name, text in (("exponential", EXPONENTIAL), ("adhesive", ADHESIVE)):
        (d / f"{name}.toml").write_text(text)
        (d / f"{name}_dist.toml").write_text(text.replace('backend = "numpy"', 'backend = "numpy"\n'
                                                                                 'distributed = true'))
        out[name] = d / f"{name}.h5"
        runner.run(d / f"{name}.toml", out[name], progress="none", mpi="off")
    return d, out


@pytest.mark.parametrize("law", ["exponential", "adhesive"])
@pytest.mark.parametrize("ranks", [2, 3])
def test_distributed_job_equals_single_process(tmp_path, refs, law, ranks):
    d, ref = refs
    path = tmp_path / "s.h5"
    p = _mpirun(ranks, ["run", str(d / f"{law}_dist.toml"), "--store", str(path), "--writer", "rank0",
                        "--progress", "log"])
    assert p.returncode == 0, p.stdout + p.stderr
    assert f"collective run: 3 distributed task(s), each solved by all {ranks} ranks together" in p.stderr, p.stderr
    _compare(ref[law], path)
    from gapsweep import store

    assert f'"mpi_size": {ranks}' in store.read_attrs(path)["runs"]


def test_spec_refuses_keep_fields_with_distributed(tmp_path):
    from gapsweep.sweep import spec

    text = EXPONENTIAL.replace('backend = "numpy"', 'backend = "numpy"\ndistributed = true\n'
                                                     'keep_fields = {fields = ["gap"]}')
    (tmp_path / "j.toml").write_text(text)
    with pytest.raises(spec.SpecError, match=r"methods\.gfmd\.distributed: .*drop keep_fields"):
        spec.load(tmp_path / "j.toml")
