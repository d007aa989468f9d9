"""Bad inputs (docs/reliability.md, "Bad inputs"): each gets a clear one-line error naming the field (or file) and
the allowed values, a non-zero exit, and nothing written or changed. The refusals run the CLI in this process
(``gs_here``: ``cli.main``, its exit code and output), where no process boundary is under test; the cases that need
a child (fault hooks, a store's exit handlers) start one (``gs``)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from gapsweep import store

from .conftest import HIST_JOB, THEORY_JOB, gs, gs_here, one_line_error

BASE = THEORY_JOB.read_text()
_GFMD = '\n[methods.gfmd]\nn = 64\nbackend = "numpy"\n'


def _edit(old: str, new: str) -> str:
    assert old in BASE
    return BASE.replace(old, new)


# (case id, spec text, words the message must contain)
SPECS = [
    ("grid-1e8-points", _edit('sigma0 = {min = 1e-4, max = 1.0, num = 6, scale = "log"}\nseeds = [0, 1]',
                              'sigma0 = {min = 1e-4, max = 1.0, num = 10000, scale = "log"}\n'
                              'seeds = {start = 0, count = 10000}'), ["grid", "GAPSWEEP_MAX_TASKS", "400,000,000"]),
    ("extra-typo-theory", BASE + "\n[methods.theory.extra]\nzetta = 2.0\n", ["methods.theory.extra.zetta", "zeta"]),
    ("extra-fixed-key", BASE + "\n[methods.theory.extra]\nsigma0 = 2.0\n", ["methods.theory.extra.sigma0"]),
    ("extra-table-value", BASE + "\n[methods.theory.extra]\nzeta = [1, 2]\n", ["methods.theory.extra.zeta"]),
    ("range-infinite", _edit("[methods.theory]", "[histogram]\nrange = [-inf, inf]\n\n[methods.theory]"),
     ["histogram.range", "finite"]),
    ("range-reversed", _edit("[methods.theory]", "[histogram]\nrange = [1.0, 0.0]\n\n[methods.theory]"),
     ["histogram.range"]),
    ("range-nan", _edit("[methods.theory]", "[histogram]\nrange = [nan, 1.0]\n\n[methods.theory]"),
     ["histogram.range"]),
    ("not-toml", "this is [not toml", ["not valid TOML"]),
    ("missing-grid", "[job]\nname = 'x'\n[methods.theory]\n", ["grid"]),
    ("unknown-top-key", BASE + "\n[gird]\nx = 1\n", ["gird", "unknown key"]),
    ("hurst-out-of-range", _edit("hurst = [0.3, 0.8]", "hurst = [0.3, 1.5]"), ["grid.hurst[1]", "< 1"]),
    ("rho-negative", _edit("rho = [2e-3, 1e-3]", "rho = [2e-3, -1e-3]"), ["grid.rho[1]", "> 0"]),
    ("seeds-duplicate", _edit("seeds = [0, 1]", "seeds = [1, 1]"), ["grid.seeds", "distinct"]),
    ("seed-negative", _edit("seeds = [0, 1]", "seeds = [0, -1]"), ["grid.seeds[1]", ">= 0"]),
    ("n-below-nyquist", _edit("n = 64", "n = 16"), ["methods.theory.n", "Nyquist"]),
    ("sigma0-num-0", _edit("num = 6", "num = 0"), ["grid.sigma0.num", ">= 1"]),
    ("job-name-chars", _edit('name = "test-theory"', 'name = "a b/c"'), ["job.name"]),
    ("sde-samples-0", BASE + "\n[methods.sde]\nsamples = 0\n", ["methods.sde.samples", ">= 1"]),
    ("two-norms", _edit("rms_slope = 1.0", "rms_slope = 1.0\nrms_height = 0.1"), ["surface", "exactly one"]),
    ("no-methods", _edit('[methods.theory]\nforms = ["paper", "continuum", "discrete"]\nn = 64', "[methods]"),
     ["methods", "at least one"]),
    ("wrong-type", _edit("gamma0 = 1e-3", 'gamma0 = "small"'), ["material.gamma0", "number"]),
    ("lambda-s-too-big", _edit("lambda_s = 0.04", "lambda_s = 0.5"), ["surface.lambda_s"]),
    # round 2 (issue 19 item 9): what `plan` used to accept and `run` then failed on, task by task
    ("extra-host-set-by-sweep", BASE + _GFMD + "[methods.gfmd.extra]\nhost = false\n",
     ["methods.gfmd.extra.host", "set by the sweep"]),
    ("extra-threads-string", BASE + _GFMD + '[methods.gfmd.extra]\nthreads = "many"\n',
     ["methods.gfmd.extra.threads", "int"]),
    ("extra-heights-number", BASE + "\n[methods.theory.extra]\nheights = 1\n",
     ["methods.theory.extra.heights", "set by the sweep"]),
    ("extra-tol-bool", BASE + _GFMD + "[methods.gfmd.extra]\nthreads = true\n", ["methods.gfmd.extra.threads"]),
    ("sde-zeta-end-1e300", BASE + "\n[methods.sde]\nzeta_end = 1e300\n", ["methods.sde.zeta_end", "<= 1e+06"]),
    ("sde-steps-too-many", BASE + "\n[methods.sde]\nzeta_end = 1e6\ndzeta = 1e-4\n",
     ["methods.sde.zeta_end", "1e8"]),
    ("keep-fields-no-match", BASE + _GFMD + "keep_fields = { fields = [\"gap\"], sigma0 = [0.5] }\n",
     ["methods.gfmd.keep_fields.sigma0", "no field"]),
    ("pressure-unit-unknown", _edit("gamma0 = 1e-3", 'gamma0 = 1e-3\npressure_unit = "psi"'),
     ["material.pressure_unit", "MPa"]),
]


# `run` validates exactly as `plan` does (same loader); it is exercised on these, `plan` on all.
RUN_TOO = ("grid-1e8-points", "extra-typo-theory", "range-infinite", "not-toml", "n-below-nyquist",
           "extra-host-set-by-sweep", "extra-threads-string", "extra-heights-number", "sde-zeta-end-1e300",
           "keep-fields-no-match")


SPEC_CASES = [("plan", *c) for c in SPECS] + [("run", *c) for c in SPECS if c[0] in RUN_TOO]


@pytest.mark.parametrize("command,case,text,needles", SPEC_CASES, ids=[f"{c[0]}-{c[1]}" for c in SPEC_CASES])
def test_bad_spec(tmp_path, capsys, case, text, needles, command):
    job = tmp_path / "job.toml"
    job.write_text(text)
    out = tmp_path / "s.h5"
    args = ["run", job, "--store", out, "--mpi", "off"] if command == "run" else ["plan", job]
    p = gs_here(capsys, *args)
    err = one_line_error(p, *needles)
    assert p.returncode == 2, err
    assert str(job) in err  # the message names the file
    assert not out.exists() and not Path(str(out) + ".lease").exists()


def test_bad_spec_non_utf8(tmp_path, capsys):
    job = tmp_path / "latin1.toml"
    job.write_bytes(BASE.replace("tests: field theory", "caf\xe9").encode("latin-1"))
    p = gs_here(capsys, "plan", job)
    one_line_error(p, str(job), "UTF-8")


def test_bad_spec_missing_file(tmp_path, capsys):
    p = gs_here(capsys, "plan", tmp_path / "nope.toml")
    one_line_error(p, "nope.toml", "no such file")


def test_task_cap_env(tmp_path, capsys):
    """The cap is documented and can be raised; a bad value of the variable is named."""
    p = gs_here(capsys, "plan", THEORY_JOB, GAPSWEEP_MAX_TASKS="10")
    one_line_error(p, "48", "GAPSWEEP_MAX_TASKS")
    p = gs_here(capsys, "plan", THEORY_JOB, GAPSWEEP_MAX_TASKS="ten")
    one_line_error(p, "GAPSWEEP_MAX_TASKS", "positive integer")
    assert gs_here(capsys, "plan", THEORY_JOB, GAPSWEEP_MAX_TASKS="48").returncode == 0


ARGS = [
    ("plan-ranks-0", ["plan", THEORY_JOB, "--ranks", "0"], ["--ranks", ">= 1"]),
    ("plan-ranks-negative", ["plan", THEORY_JOB, "--ranks", "-3"], ["--ranks"]),
    ("resume-and-overwrite", ["run", THEORY_JOB, "--store", "{out}", "--resume", "--overwrite", "--mpi", "off"],
     ["--resume", "--overwrite"]),
    ("shard-out-of-range", ["run", THEORY_JOB, "--store", "{out}", "--shard", "3/2", "--mpi", "off"], ["--shard"]),
    ("shard-not-a-fraction", ["run", THEORY_JOB, "--store", "{out}", "--shard", "abc", "--mpi", "off"], ["--shard"]),
    ("shard-slurm-outside-slurm", ["run", THEORY_JOB, "--store", "{out}", "--shard", "slurm", "--mpi", "off"],
     ["SLURM_ARRAY_TASK_ID"]),
    ("task-timeout-negative", ["run", THEORY_JOB, "--store", "{out}", "--task-timeout", "-1", "--mpi", "off"],
     ["--task-timeout"]),
    ("task-timeout-zero", ["run", THEORY_JOB, "--store", "{out}", "--task-timeout", "0", "--mpi", "off"],
     ["--task-timeout"]),
    ("writer-unknown", ["run", THEORY_JOB, "--store", "{out}", "--writer", "nfs"], ["--writer"]),
    ("status-missing-store", ["status", "{out}"], ["no such file"]),
    ("merge-out-is-shard", ["merge", "{ref}", "--out", "{ref}", "--overwrite"], ["also a shard"]),
    ("merge-out-exists", ["merge", "{ref}", "--out", "{ref2}"], ["exists", "--overwrite"]),
]


@pytest.mark.parametrize("case,args,needles", ARGS, ids=[c[0] for c in ARGS])
def test_bad_arguments(tmp_path, capsys, monkeypatch, refs, case, args, needles):
    monkeypatch.delenv("SLURM_ARRAY_TASK_ID", raising=False)  # "outside Slurm", whatever runs the suite
    out = tmp_path / "s.h5"
    ref2 = tmp_path / "copy.h5"
    ref2.write_bytes(refs["theory"].read_bytes())
    subst = {"{out}": str(out), "{ref}": str(refs["theory"]), "{ref2}": str(ref2)}
    before = refs["theory"].read_bytes()
    p = gs_here(capsys, *[subst.get(str(a), a) for a in args])
    assert p.returncode != 0
    if "usage:" in p.stderr:  # argparse: a usage line and the error, exit 2
        assert p.returncode == 2 and "Traceback" not in p.stderr
        assert all(n in p.stderr for n in needles), p.stderr
    else:
        one_line_error(p, *needles)
    assert not out.exists()
    assert refs["theory"].read_bytes() == before and ref2.read_bytes() == before


def test_merge_different_jobs(tmp_path, capsys, refs):
    p = gs_here(capsys, "merge", refs["theory"], refs["hist"], "--out", tmp_path / "m.h5")
    one_line_error(p, "different job specs")
    assert not (tmp_path / "m.h5").exists()


def test_mpi_off_under_launcher(tmp_path, capsys):
    """A process that says --mpi off while a launcher reports several ranks is refused (it would run the whole
    job as one of several writers); simulated with the launcher's environment variable."""
    out = tmp_path / "s.h5"
    p = gs_here(capsys, "run", THEORY_JOB, "--store", out, "--mpi", "off", OMPI_COMM_WORLD_SIZE="2")
    one_line_error(p, "--mpi off", "2 ranks")
    assert not out.exists()


def test_comment_only_edit_resumes(tmp_path, refs):
    """Resume is keyed by the parsed spec: comments and formatting do not block it."""
    out = tmp_path / "s.h5"
    p = gs("run", THEORY_JOB, "--store", out, "--mpi", "off", "--progress", "none",
           GAPSWEEP_TEST_WRITE_ERROR="20")
    assert p.returncode == 1
    edited = tmp_path / "edited.toml"
    edited.write_text("# a new comment\n" + BASE.replace("rho = [2e-3, 1e-3]", "rho   =   [ 2.0e-3 , 0.001 ]  # ok"))
    p = gs("run", edited, "--store", out, "--resume", "--mpi", "off", "--progress", "none")
    assert p.returncode == 0, p.stderr
    from gapsweep import store

    assert store.diff(out, refs["theory"]) == []


def test_every_task_failed_exits_nonzero(tmp_path):
    out = tmp_path / "s.h5"
    p = gs("run", HIST_JOB, "--store", out, "--mpi", "off", "--progress", "none",
           GAPSWEEP_TEST_FAIL="0.001,0.01,0.1")
    assert p.returncode == 3, p.stderr
    assert "every task" in p.stderr and "Traceback" not in p.stderr


def test_nonfinite_theory_result_is_failed(tmp_path, monkeypatch):
    """A theory function returning NaN gives a failed row, never a done one (in-process: the NaN is injected)."""
    from gapsweep import runner, store, theory

    monkeypatch.setattr(theory, "mean_gap", lambda *a, **k: float("nan"))
    out = tmp_path / "s.h5"
    s = runner.run(THEORY_JOB, out, progress="none", mpi="off")
    assert s["failed"] == s["tasks"] and s["done"] == 0
    df = store.read(out)
    assert set(df.status) == {"failed"}
    assert all("non-finite result" in m for m in df.message)



def test_plan_refuses_what_will_not_fit(tmp_path, capsys):
    """A GFMD grid of 65536^2 needs ~1 TB per rank: plan says so and refuses (exit 1). (`run` is not tried: it does not
    refuse on this rough upper bound and would start allocating.)"""
    job = tmp_path / "big.toml"
    job.write_text(BASE.replace('[methods.theory]\nforms = ["paper", "continuum", "discrete"]\nn = 64',
                                "[methods.gfmd]\nn = 65536\nseeds = [0]\nhurst = [0.3]\nrho = [2e-3]\n"
                                "sigma0 = [1e-2]"))
    p = gs_here(capsys, "plan", job)
    one_line_error(p, "per rank", "more than this machine")
    assert p.returncode == 1


def test_heights_that_overflow_after_unit_conversion(tmp_path, capsys):
    """A map in metres converted to picometres overflows float64: refused at validation (plan and run)."""
    np.save(tmp_path / "big.npy", np.full((16, 16), 1e300) * np.arange(256).reshape(16, 16))
    job = tmp_path / "j.toml"
    job.write_text('[job]\nname = "x"\n[grid]\nsigma0 = [1e-2]\n[surface]\nkind = "file"\npath = "big.npy"\n'
                   'unit = "m"\nto_unit = "pm"\npixel_size = 1.0\n[interaction]\nkind = "hard_wall"\n'
                   '[methods.gfmd]\nbackend = "numpy"\n')
    for cmd in (("plan", job), ("run", job, "--store", tmp_path / "s.h5", "--mpi", "off")):
        one_line_error(gs_here(capsys, *cmd), "surface.path", "not finite", "to_unit")
    assert not (tmp_path / "s.h5").exists()


def test_keep_fields_select_zero_and_tensile_loads(tmp_path):
    """Valid input once mishandled (issue 19 item 11): an adhesive job keeps the fields of its tensile loads."""
    from gapsweep import spec

    text = (Path(__file__).resolve().parents[2] / "jobs" / "adhesion_quick.toml").read_text()
    tensile = [0.0, -1e-4, -8e-4]  # loads of jobs/adhesion_quick.toml
    assert "0.0, -1e-4, -2e-4, -4e-4, -8e-4]" in text
    js = spec.loads(text.replace("[methods.gfmd]\n", f"[methods.gfmd]\nkeep_fields = {{ fields = [\"gap\"], "
                                 f"sigma0 = {tensile} }}\n"), base=Path(__file__).resolve().parents[2] / "jobs")
    assert "keep_fields" in js.methods["gfmd"]


def test_export_theory_with_surface_h_rms_and_gaussian_amplitudes(tmp_path):
    """Valid input once mishandled (issue 19 item 11): the paper form with the surface's own h_rms depends on the
    seed, so the export keeps its seed dimension instead of failing with "values differ between seeds"."""
    pytest.importorskip("xarray")
    from gapsweep import runner, store

    job = tmp_path / "t.toml"
    job.write_text(BASE.replace("rms_slope = 1.0", 'rms_slope = 1.0\namplitudes = "gaussian"').replace(
        'forms = ["paper", "continuum", "discrete"]\nn = 64', 'forms = ["paper"]\nh_rms = "surface"'))
    runner.run(job, tmp_path / "t.h5", mpi="off", progress="none")
    ds = store.to_dataset(tmp_path / "t.h5")
    assert "seed" in ds["theory_paper"].dims and ds.sizes["seed"] == 2
    a = ds["theory_paper"].isel(seed=0).values
    b = ds["theory_paper"].isel(seed=1).values
    assert not np.allclose(a, b, rtol=1e-9, atol=0.0)


# --- issue 19 item 1: no command deletes or replaces a store it was not asked to write --------------------------

@pytest.fixture(scope="module")
def report_dir(refs, tmp_path_factory) -> Path:
    """A report of the theory store (written once; cases copy it)."""
    d = tmp_path_factory.mktemp("rep") / "report"
    p = gs("report", refs["theory"], "--out", d)
    assert p.returncode == 0, p.stderr
    return d


def _copy_report(src: Path, dst: Path) -> Path:
    import shutil

    shutil.copytree(src, dst, dirs_exist_ok=True)
    return dst


REPORT_TRAPS = ["store-in-out", "store-below-out", "other-store-in-out", "kept-fields-in-out", "no-manifest"]


@pytest.mark.parametrize("case", REPORT_TRAPS)
def test_report_overwrite_keeps_stores(tmp_path, refs, report_dir, case):
    """``report --out DIR --overwrite`` where DIR holds (or lies above) a store, a kept-fields folder or a report
    without manifest: refused with a one-line error naming DIR, and every byte of the folder is kept (the old
    code deleted the folder, the store with it)."""
    d = _copy_report(report_dir, tmp_path / "d")
    inp = refs["theory"]
    if case == "store-in-out":
        inp = d / "s.h5"
    elif case == "store-below-out":
        (d / "sub").mkdir()
        inp = d / "sub" / "s.h5"
    elif case == "other-store-in-out":
        (d / "other.h5").write_bytes(refs["hist"].read_bytes())
    elif case == "kept-fields-in-out":
        (d / "s.h5.fields").mkdir()
        (d / "s.h5.fields" / "f.npz").write_bytes(b"kept")
    else:
        (d / ".gapsweep-report.json").unlink()
    if inp != refs["theory"]:
        inp.write_bytes(refs["theory"].read_bytes())
    before = {q: q.read_bytes() for q in d.rglob("*") if q.is_file()}
    p = gs("report", inp, "--out", d, "--overwrite")
    one_line_error(p, f"report --out {d}")
    assert {q: q.read_bytes() for q in d.rglob("*") if q.is_file()} == before


def test_report_overwrite_replaces_its_own(tmp_path, refs, report_dir):
    """The counterpart: a folder holding only the previous report (its manifest) is replaced, and the new
    manifest lists exactly the files there."""
    import json

    d = _copy_report(report_dir, tmp_path / "d")
    (d / "report.md").write_text("stale")
    p = gs("report", refs["theory"], "--out", d, "--overwrite")
    assert p.returncode == 0, p.stderr
    assert (d / "report.md").read_text() == (report_dir / "report.md").read_text()
    listed = json.loads((d / ".gapsweep-report.json").read_text())["files"]
    assert sorted(listed) == sorted(q.name for q in d.iterdir() if q.name != ".gapsweep-report.json")


EXPORT_TRAPS = ["out-is-input", "out-is-hardlink-of-input", "out-is-symlink-to-input", "out-is-other-store",
                "out-is-folder"]


@pytest.mark.parametrize("case", EXPORT_TRAPS)
def test_export_never_replaces_a_store(tmp_path, capsys, refs, case):
    """``export STORE --out X --overwrite`` where X is the store (by any path) or another store or a folder:
    refused, nothing replaced (the old code replaced the store by its netCDF view)."""
    import os

    s = tmp_path / "s.h5"
    s.write_bytes(refs["theory"].read_bytes())
    out = {"out-is-input": s, "out-is-hardlink-of-input": tmp_path / "link.nc",
           "out-is-symlink-to-input": tmp_path / "sym.nc", "out-is-other-store": tmp_path / "other.nc",
           "out-is-folder": tmp_path / "s.h5.fields"}[case]
    if case == "out-is-hardlink-of-input":
        os.link(s, out)
    elif case == "out-is-symlink-to-input":
        out.symlink_to(s)
    elif case == "out-is-other-store":
        out.write_bytes(refs["hist"].read_bytes())
    elif case == "out-is-folder":
        out.mkdir()
    before = refs["theory"].read_bytes()
    p = gs_here(capsys, "export", s, "--out", out, "--overwrite")
    one_line_error(p, "export --out", str(out))
    assert s.read_bytes() == before
    if case == "out-is-other-store":
        assert out.read_bytes() == refs["hist"].read_bytes()
    assert not list(tmp_path.glob(".*tmp*"))


def test_export_overwrite_replaces_its_own(tmp_path, refs):
    """--overwrite replaces an earlier export (of any store), and nothing else (issue 31: one rule for every
    command that writes; tests/faults/test_outputs.py has the other cases)."""
    out = tmp_path / "s.nc"
    assert gs("export", refs["hist"], "--out", out).returncode == 0
    p = gs("export", refs["theory"], "--out", out, "--overwrite")
    assert p.returncode == 0, p.stderr
    assert out.read_bytes()[:8] == b"\x89HDF\r\n\x1a\n"
    out.write_bytes(b"not the export")
    p = gs("export", refs["theory"], "--out", out, "--overwrite")
    one_line_error(p, "export --out", "not a netCDF file written by gapsweep export")
    assert out.read_bytes() == b"not the export"


# --- issue 19 item 10: unreadable inputs are one-line errors naming the file ------------------------------------

FILE_JOB = THEORY_JOB.parent / "contact_file.toml"


def _file_job(tmp_path: Path, surface_lines: str) -> Path:
    text = FILE_JOB.read_text()
    start = text.index("[surface]")
    end = text.index("\n[", start + 1)
    job = tmp_path / "job.toml"
    job.write_text(text[:start] + "[surface]\n" + surface_lines + text[end:])
    return job


MAPS = [
    ("npy-empty", "map.npy", lambda p: p.write_bytes(b""), "", ["map.npy", "empty"]),
    ("npy-truncated", "map.npy", lambda p: p.write_bytes(__import__("numpy").lib.format.magic(1, 0) + b"\x10"),
     "", ["map.npy", ".npy file"]),
    ("npz-missing-key", "map.npz",
     lambda p: __import__("numpy").savez(p, heights=__import__("numpy").zeros((8, 8))), 'key = "z"\n',
     ["map.npz", "no array 'z'", "heights"]),
    ("npz-not-a-zip", "map.npz", lambda p: p.write_bytes(b"PK\x03\x04 not really"), "", ["map.npz", ".npz"]),
]


@pytest.mark.parametrize("case,name,make,extra,needles", MAPS, ids=[m[0] for m in MAPS])
def test_bad_height_map(tmp_path, capsys, case, name, make, extra, needles):
    """An empty or truncated .npy, a .npz without the key asked for or not a zip: `plan` and `run` fail with
    one line naming the file and the problem, exit 2, nothing written (EOFError/KeyError tracebacks before)."""
    make(tmp_path / name)
    job = _file_job(tmp_path, f'kind = "file"\npath = "{name}"\npixel_size = 0.5\n{extra}')
    for cmd in (["plan", job], ["run", job, "--store", tmp_path / "s.h5", "--mpi", "off"]):
        p = gs_here(capsys, *cmd)
        err = one_line_error(p, "surface.path", *needles)
        assert p.returncode == 2, err
    assert not (tmp_path / "s.h5").exists()


def test_store_with_non_json_runs(tmp_path, refs):
    """A store whose `runs` attribute is not JSON (a bare JSONDecodeError before issue 19; a refusal that blocked
    status, resume and merge until issue 31): status names the damage, merge works, a plain run changes nothing,
    --resume rebuilds the list (one record saying the earlier ones were lost); every row is kept."""
    import json

    import h5py

    from gapsweep import store

    s = tmp_path / "s.h5"
    s.write_bytes(refs["theory"].read_bytes())
    with h5py.File(s, "r+") as f:
        f.attrs["runs"] = "{not json"
        store.seal_attrs(f)  # written so (a tool's bug), not damaged since: the checksums agree
    before = s.read_bytes()
    p = gs("status", s, timeout=60)
    assert p.returncode == 0 and "'runs'" in p.stdout and "damaged" in p.stdout, (p.stdout, p.stderr)
    p = gs("merge", s, "--out", tmp_path / "m.h5", timeout=60)
    assert p.returncode == 0, p.stderr
    p = gs("run", THEORY_JOB, "--store", s, "--mpi", "off", timeout=60)
    assert p.returncode == 0 and s.read_bytes() == before, p.stderr
    p = gs("run", THEORY_JOB, "--store", s, "--resume", "--mpi", "off", timeout=60)
    assert p.returncode == 0, p.stderr
    runs = json.loads(store.read_attrs(s)["runs"])
    assert "rebuilt" in runs[0] and runs[-1]["finished"]
    assert store.diff(s, refs["theory"]) == []


@pytest.mark.parametrize("pattern", ["x{i}.h5", "x{n}.h5", "x{i}of{n}.h5"])
def test_shard_pattern_without_shard(tmp_path, capsys, pattern):
    """A store path with {i}/{n} but no --shard is refused (a file literally named x{i}.h5 was created)."""
    p = gs_here(capsys, "run", THEORY_JOB, "--store", tmp_path / pattern, "--mpi", "off")
    err = one_line_error(p, "--store", "--shard", pattern)
    assert p.returncode == 2, err
    assert list(tmp_path.iterdir()) == []


def test_merge_spec_error_names_the_shard(tmp_path, capsys, refs):
    """A shard whose stored spec no longer validates: the merge names that shard."""
    import h5py

    s = tmp_path / "shard0.h5"
    s.write_bytes(refs["theory"].read_bytes())
    with h5py.File(s, "r+") as f:
        f.attrs["spec_text"] = f.attrs["spec_text"].replace("hurst = [0.3, 0.8]", "hurst = [0.3, 1.5]")
        store.seal_attrs(f)  # a spec that no longer validates, not a damaged attribute (test_integrity.py)
    p = gs_here(capsys, "merge", s, "--out", tmp_path / "m.h5")
    one_line_error(p, "merge", str(s), "grid.hurst[1]")
    assert not (tmp_path / "m.h5").exists()


def test_demo_never_replaces_another_jobs_store(tmp_path, refs):
    """``demo --out DIR`` where DIR/demo.h5 is another job's store: refused naming it, the store unchanged (the
    old demo replaced any store there whose spec was not the demo's)."""
    (tmp_path / "demo.h5").write_bytes(refs["theory"].read_bytes())
    p = gs("demo", "--out", tmp_path, timeout=120)
    one_line_error(p, "demo --out", "test-theory", "not the demo's")
    assert (tmp_path / "demo.h5").read_bytes() == refs["theory"].read_bytes()


def test_demo_with_failed_rows_does_not_exit_0(tmp_path):
    """``gapsweep demo`` whose run leaves rows failed exits 5, as ``gapsweep run`` does (it printed its table and
    figures and exited 0 before); the store keeps the failed rows, and a second demo (nothing left to run: a
    failure of a task's own parameters is not retried) still exits 5."""
    p = gs("demo", "--job", HIST_JOB, "--out", tmp_path, timeout=120, GAPSWEEP_TEST_FAIL="0.01")
    assert p.returncode == 5, p.stderr
    assert "6 row(s) not done (6 failed" in p.stderr
    df = store.read(tmp_path / "demo.h5")
    assert (df.status == "failed").sum() == 6 and set(df.sigma0[df.status == "failed"]) == {0.01}
    assert (tmp_path / "fig2_demo.png").is_file()
    p = gs("demo", "--job", HIST_JOB, "--out", tmp_path, timeout=120)
    assert p.returncode == 5 and "6 row(s) not done (6 failed" in p.stderr, p.stderr
    assert (store.read(tmp_path / "demo.h5").status == "failed").sum() == 6
