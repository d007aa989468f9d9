"""Issue 31, item 6: every spec ``plan`` accepts runs, and one that cannot is refused by ``plan`` naming the field.

* Shapes: each method (theory forms, GFMD, SDE, Fokker-Planck, hybrid, multiscale), each surface (synthetic
  with each normalisation, Gaussian amplitudes, a length-unit label, another box; measured map files) and each
  interaction law (exponential, hard wall, adhesive), each with a pressure-unit label or not. For each shape
  ``plan`` passes and the cheapest task of every method is expanded and run: it must end ``done`` or
  ``not_converged``, never ``failed``. Before: ``[surface] unit = "nm"`` on a synthetic surface passed plan,
  then every task failed with "self_affine() got an unexpected keyword argument 'unit'".
* Extreme values are refused by plan with the field and its range (before: tracebacks): ``lambda_s = 5e-324``,
  ``length = 1e308``, a map's ``pixel_size = 1e-308`` with ``detrend = "plane"``.
* Reordering an axis's values (docs/jobs.md: the order does not enter) no longer blocks ``--resume``."""

from __future__ import annotations

from pathlib import Path

import pytest

from gapsweep import store
from gapsweep.sweep import runner, spec, tasks
from gapsweep.sweep.context import Context
from gapsweep.sweep.execute import run_task

from .conftest import HIST_JOB, gs, gs_here, one_line_error

ROOT = Path(__file__).resolve().parents[2]
JOBS_DIR = ROOT / "jobs"
MIXED = (JOBS_DIR / "test_mixed.toml").read_text()
PRED = (ROOT / "tests" / "test_predictor_methods.py").read_text().split('JOB = """', 1)[1].split('"""', 1)[0] \
    if 'JOB = """' in (ROOT / "tests" / "test_predictor_methods.py").read_text() else None


def _surface(text: str, extra: str, drop: str = "") -> str:
    if drop:
        text = text.replace(drop, "")
    return text.replace("[surface]\n", "[surface]\n" + extra, 1)


SHAPES = {
    "mixed": MIXED,
    "unit-label": _surface(MIXED, 'unit = "nm"\n'),
    "rms-height": _surface(MIXED, "rms_height = 0.01\n", "rms_slope = 1.0\n"),
    "c0": _surface(MIXED, "c0 = 1e-6\n", "rms_slope = 1.0\n")
    .replace("[methods.theory]\n", '[methods.theory]\nh_rms = "surface"\n')
    .replace("[methods.sde]\n", '[methods.sde]\nh_rms = "surface"\n')
    .replace("[methods.fokker_planck]\n", '[methods.fokker_planck]\nh_rms = "surface"\n'),
    "gaussian-amplitudes": _surface(MIXED, 'amplitudes = "gaussian"\n'),
    "other-box": _surface(MIXED, "length = 0.5\n"),
    "pressure-unit": MIXED.replace("[material]\n", '[material]\npressure_unit = "MPa"\ne_star = 100.0\n', 1),
    "hard-wall": MIXED.replace("rho = [2e-2]\n", "").replace("[material]\ngamma0 = 1e-3\n",
                                                             '[interaction]\nkind = "hard_wall"\n\n[material]\n')
    .split("[methods.sde]")[0].replace('forms = ["paper", "continuum", "discrete"]\nn = 64', 'forms = ["persson"]'),
    "file-hard-wall": (JOBS_DIR / "contact_file.toml").read_text(),
    "file-adhesive": (JOBS_DIR / "adhesion_quick.toml").read_text(),
    "file-measured": (JOBS_DIR / "measured_map.toml").read_text(),
}
if PRED:
    SHAPES["predictors"] = PRED


@pytest.mark.parametrize("shape", list(SHAPES))
def test_every_accepted_shape_runs(tmp_path, shape):
    job = JOBS_DIR / f".shape-{shape}.toml"  # beside the shipped jobs: their map paths are relative
    try:
        job.write_text(SHAPES[shape])
        runner.plan(job)  # accepted
        js = spec.load(job)
        spec.check_extra(js)
        all_tasks = tasks.expand(js)
        ctx = Context(rank=0)
        seen = {}
        for t in sorted(all_tasks, key=tasks.estimate_cost):
            if t.method in seen:
                continue
            res, _ = run_task(t, ctx)
            seen[t.method] = (res.status, res.message)
    finally:
        job.unlink(missing_ok=True)
    assert set(seen) == {t.method for t in all_tasks}
    for m, (status, msg) in seen.items():
        assert status in ("done", "not_converged"), (shape, m, status, msg)


EXTREME = [
    ("surface.lambda_s", "lambda_s = 0.0625", "lambda_s = 5e-324"),
    ("surface.length", "lambda_s = 0.0625", "lambda_s = 0.0625\nlength = 1e308"),
    ("surface.length", "lambda_s = 0.0625", "lambda_s = 0.0625\nlength = 5e-324"),
    ("surface.lambda_s", "lambda_s = 0.0625", "lambda_s = 1e-12"),
]


@pytest.mark.parametrize("field,old,new", EXTREME)
def test_extreme_values_refused_with_field(tmp_path, capsys, field, old, new):
    job = tmp_path / "x.toml"
    job.write_text(MIXED.replace(old, new, 1))
    p = gs_here(capsys, "plan", job)  # a refusal: in process
    one_line_error(p, field, "expected a number")
    assert p.returncode == 2


@pytest.mark.parametrize("value", ["1e-308", "1e308", "[1e-308, 0.5]", "0.0"])
def test_extreme_pixel_size_refused_with_field(capsys, value):
    text = (JOBS_DIR / "contact_file.toml").read_text()
    assert "pixel_size = 0.5" in text and 'detrend = "plane"' in text
    job = JOBS_DIR / ".extreme-pixel.toml"
    try:
        job.write_text(text.replace("pixel_size = 0.5", f"pixel_size = {value}"))
        p = gs_here(capsys, "plan", job)  # a refusal: in process
    finally:
        job.unlink(missing_ok=True)
    one_line_error(p, "surface.pixel_size", "expected a number")


def test_reordered_axis_values_resume(tmp_path, refs):
    """A store started from one spec is finished by the same spec with its axis values in another order."""
    path = tmp_path / "s.h5"
    p = gs("run", HIST_JOB, "--store", path, "--mpi", "off", "--progress", "none", GAPSWEEP_TEST_WRITE_ERROR="8")
    assert p.returncode == 1
    text = HIST_JOB.read_text()
    for a, b in (("hurst = [0.3, 0.8]", "hurst = [0.8, 0.3]"),
                 ("sigma0 = [1e-3, 1e-2, 1e-1]", "sigma0 = [1e-1, 1e-3, 1e-2]"),
                 ("seeds = [0, 1]", "seeds = [1, 0]"), ("sigma0 = [1e-3, 1e-1]", "sigma0 = [1e-1, 1e-3]")):
        assert a in text
        text = text.replace(a, b)
    job = tmp_path / "reordered.toml"
    job.write_text(text)
    p = gs("run", job, "--store", path, "--mpi", "off", "--progress", "none", "--resume")
    assert p.returncode == 0, p.stderr
    assert store.diff(path, refs["hist"]) == []
    # the job's description corrected too (free text, no task changes): the store still resumes
    path2 = tmp_path / "s2.h5"
    p = gs("run", HIST_JOB, "--store", path2, "--mpi", "off", "--progress", "none", GAPSWEEP_TEST_WRITE_ERROR="8")
    assert p.returncode == 1
    job.write_text(text.replace('description = "tests/faults: rows with histograms"',
                                'description = "tests/faults: rows with histograms (corrected)"'))
    assert job.read_text() != text
    p = gs("run", job, "--store", path2, "--mpi", "off", "--progress", "none", "--resume")
    assert p.returncode == 0, p.stderr
    assert store.diff(path2, refs["hist"]) == []
    # another job (a value changed, not reordered) is still refused
    job.write_text(text.replace("hurst = [0.8, 0.3]", "hurst = [0.8, 0.4]"))
    p = gs("run", job, "--store", path, "--mpi", "off", "--progress", "none", "--resume")
    one_line_error(p, "another job spec")
