"""Job specs (gapsweep.spec, docs/jobs.md): validation errors name the key and the allowed values, the CLI exits
non-zero and writes nothing; task expansion and content ids (gapsweep.tasks)."""

from __future__ import annotations

from pathlib import Path

import pytest

from gapsweep import cli, spec
from gapsweep.sweep import tasks

ROOT = Path(__file__).resolve().parent.parent
BASE = """
[job]
name = "t"
[grid]
hurst = [0.3]
rho = [2e-3]
sigma0 = {min = 1e-3, max = 1e-1, num = 3}
seeds = [0, 1]
[surface]
lambda_l = 0.25
lambda_s = 0.0625
[methods.theory]
forms = ["paper"]
[methods.gfmd]
n = 64
"""


def test_base_spec_valid_and_expansion():
    js = spec.loads(BASE)
    assert js.grid["sigma0"] == [1e-3, 1e-2, 1e-1]
    ts = tasks.expand(js)
    # theory without the discrete form needs no surface: one task per (H, rho, sigma0); gfmd per seed too
    assert [t.method for t in ts].count("theory") == 3
    assert [t.method for t in ts].count("gfmd") == 6
    assert len({t.task_id for t in ts}) == 9
    # GFMD chains: one per seed, sigma0 decreasing (default order), one unit each
    units = tasks.make_units(ts)
    chains = [u for u in units if len(u.tasks) > 1]
    assert len(chains) == 2
    for u in chains:
        assert [ts[i].sigma0 for i in u.tasks] == [1e-1, 1e-2, 1e-3]


def test_task_ids_are_content_hashes():
    ids = {(t.method, t.sigma0, t.seed): t.task_id for t in tasks.expand(spec.loads(BASE))}
    # reordering the axes changes nothing; a changed parameter changes exactly the affected ids
    reordered = BASE.replace("seeds = [0, 1]", "seeds = [1, 0]").replace(
        "sigma0 = {min = 1e-3, max = 1e-1, num = 3}", "sigma0 = [1e-1, 1e-3, 1e-2]")
    assert {(t.method, t.sigma0, t.seed): t.task_id for t in tasks.expand(spec.loads(reordered))} == ids
    changed = {(t.method, t.sigma0, t.seed): t.task_id
               for t in tasks.expand(spec.loads(BASE.replace("n = 64", "n = 128")))}
    assert all(changed[k] == v for k, v in ids.items() if k[0] == "theory")
    assert all(changed[k] != v for k, v in ids.items() if k[0] == "gfmd")
    # and the job name / description are not part of a task's content
    renamed = BASE.replace('name = "t"', 'name = "other"')
    assert {t.task_id for t in tasks.expand(spec.loads(renamed))} == set(ids.values())


def test_shards_partition_units():
    js = spec.loads(BASE.replace("num = 3", "num = 7"))
    units = tasks.make_units(tasks.expand(js))
    parts = [tasks.shard_units(units, i, 3) for i in range(3)]
    flat = sorted(i for p in parts for u in p for i in u.tasks)
    assert flat == sorted(i for u in units for i in u.tasks)
    assert all(p for p in parts)
    with pytest.raises(ValueError, match="shard"):
        tasks.shard_units(units, 3, 3)


BAD = [
    # (replacement (old, new), expected fragments of the message)
    (("[surface]", "[surface]\nroughness = 1"), ["surface.roughness", "unknown key", "lambda_l"]),
    (("[methods.gfmd]", "[methods.gfmd]\ntoll = 1e-6"), ["methods.gfmd.toll", "allowed keys", "tol"]),
    (("n = 64", "n = 64\ntol = \"small\""), ["methods.gfmd.tol", "expected a number > 0"]),
    (("hurst = [0.3]", "hurst = [1.3]"), ["grid.hurst[0]", "> 0 and < 1"]),
    (("rho = [2e-3]", "rho = [-1e-3]"), ["grid.rho[0]", "> 0"]),
    (("num = 3}", "num = 0}"), ["grid.sigma0.num", ">= 1"]),
    (("seeds = [0, 1]", "seeds = [0, -1]"), ["grid.seeds[1]", ">= 0"]),
    (("seeds = [0, 1]", "seeds = [0.5]"), ["grid.seeds[0]", "expected an integer"]),
    (("n = 64", "n = 32"), ["methods.gfmd.n", "Nyquist", "n >= 33"]),
    (("[methods.theory]", "[methods.thoery]"), ["methods.thoery", "theory, gfmd, sde, fokker_planck"]),
    (('forms = ["paper"]', 'forms = ["exact"]'), ["methods.theory.forms[0]", "'paper', 'continuum', 'discrete'"]),
    (('forms = ["paper"]', 'forms = ["discrete"]'), ["methods.theory.n", "required"]),
    (("lambda_s = 0.0625", "lambda_s = 0.5"), ["surface.lambda_s", "< 0.25"]),
    (("lambda_s = 0.0625", "lambda_s = 0.0625\nrms_height = 0.01\nrms_slope = 1.0"),
     ["exactly one of rms_slope, rms_height, c0"]),
    (("hurst = [0.3]\n", ""), ["grid.hurst", "missing"]),
    (("[grid]", "[grid\n"), ["not valid TOML"]),
    (('name = "t"', 'name = "a b"'), ["job.name", "allowed characters"]),
    (("n = 64", 'n = 64\nbackend = "cuda"'), ["methods.gfmd.backend", "'numpy', 'pyfftw', 'cupy'"]),
    (("n = 64", 'n = 64\nmethod = "newton"'), ["methods.gfmd.method", "'cg', 'lbfgs', 'fire'"]),
]


@pytest.mark.parametrize(("repl", "fragments"), BAD, ids=[b[1][0] for b in BAD])
def test_bad_spec_names_key_exits_nonzero_writes_nothing(tmp_path, capsys, repl, fragments):
    text = BASE.replace(*repl, 1)
    assert text != BASE
    with pytest.raises(spec.SpecError) as ei:
        spec.loads(text)
    for frag in fragments:
        assert frag in str(ei.value)
    job = tmp_path / "bad.toml"
    job.write_text(text)
    out = tmp_path / "out" / "store.h5"
    for argv in (["run", str(job), "--store", str(out)], ["plan", str(job)]):
        assert cli.main(argv) == 2
        err = capsys.readouterr().err
        assert "invalid job spec" in err and fragments[0] in err
    assert not (tmp_path / "out").exists()


def test_missing_job_file(tmp_path, capsys):
    assert cli.main(["plan", str(tmp_path / "nope.toml")]) == 2
    assert "no such file" in capsys.readouterr().err


def test_repository_jobs_are_valid(capsys):
    jobs = [*sorted((ROOT / "jobs").glob("test_*.toml")), ROOT / "jobs" / "demo.toml"]
    for job in jobs:
        js = spec.load(job)
        assert tasks.expand(js), job
        assert cli.main(["plan", str(job)]) == 0
        out = capsys.readouterr().out
        assert f"{len(tasks.expand(js))} tasks" in out


def test_gpu_units_go_to_gpu_ranks():
    """GFMD with backend = "cupy" (whole pressure chains) and SDE on cuda are GPU units; the rest are not."""
    units = tasks.make_units(tasks.expand(spec.loads(BASE)))
    assert not any(u.gpu for u in units)
    gpu = tasks.make_units(tasks.expand(spec.loads(BASE.replace("n = 64", 'n = 64\nbackend = "cupy"'))))
    assert [u.gpu for u in gpu if len(u.tasks) > 1] == [True, True]
    assert not any(u.gpu for u in gpu if len(u.tasks) == 1)  # the theory tasks


def test_canonical_hash_ignores_comments_and_formatting():
    text = (Path(__file__).resolve().parent.parent / "jobs" / "test_theory.toml").read_text()
    a = spec.loads(text)
    b = spec.loads("# comment\n" + text.replace("rho = [2e-3, 1e-3]", "rho   = [ 0.002, 1.0e-3 ]   # x"))
    c = spec.loads(text.replace("rho = [2e-3, 1e-3]", "rho = [2e-3, 1.5e-3]"))
    assert a.sha256 == b.sha256 != c.sha256
    assert a.text_sha256 != b.text_sha256


def test_task_cap(monkeypatch):
    text = (Path(__file__).resolve().parent.parent / "jobs" / "test_theory.toml").read_text()
    assert spec.loads(text).task_count() == 48
    monkeypatch.setenv("GAPSWEEP_MAX_TASKS", "47")
    with pytest.raises(spec.SpecError, match=r"up to 48 tasks.*cap of 47.*GAPSWEEP_MAX_TASKS"):
        spec.loads(text)


@pytest.mark.parametrize("rng", ["[-inf, inf]", "[0.0, inf]", "[nan, 1.0]"])
def test_histogram_range_must_be_finite(rng):
    text = (Path(__file__).resolve().parent.parent / "jobs" / "test_theory.toml").read_text()
    with pytest.raises(spec.SpecError, match=r"histogram\.range.*finite"):
        spec.loads(text + f"\n[histogram]\nrange = {rng}\n")


def test_extra_keys_checked_against_solver_signature():
    text = (Path(__file__).resolve().parent.parent / "jobs" / "test_theory.toml").read_text()
    tasks.check_extra(spec.loads(text + "\n[methods.theory.extra]\nzeta = 2.0\n"))  # a real parameter
    with pytest.raises(spec.SpecError, match=r"methods\.theory\.extra\.zetta: not a parameter.*allowed.*zeta"):
        tasks.check_extra(spec.loads(text + "\n[methods.theory.extra]\nzetta = 2.0\n"))
    with pytest.raises(spec.SpecError, match=r"methods\.theory\.extra\.rho: set by the sweep"):
        tasks.check_extra(spec.loads(text + "\n[methods.theory.extra]\nrho = 2.0\n"))


def test_non_utf8_spec_names_the_file(tmp_path):
    p = tmp_path / "x.toml"
    p.write_bytes(b"[job]\nname = '\xff'\n")
    with pytest.raises(spec.SpecError, match=r"x\.toml.*not UTF-8"):
        spec.load(p)
