"""The installed package (issue 29 item 3): one top-level package, the shipped job specs run by name
(``gapsweep jobs``, ``gapsweep run fig2_quick --store ...``), ``gapsweep report`` unaffected by a user's own
``analysis.py``, and the wheel's contents (gapsweep only, with its jobs and their height maps; Requires-Python true
to the pins of constraints.txt)."""

from __future__ import annotations

import argparse
import os
import re
import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

from gapsweep import jobs

ROOT = Path(__file__).resolve().parents[1]
ENV = {**os.environ, "PYTHONPATH": str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", "")}
FIGURE_JOBS = ["fig2", "fig3", "fig4_5", "fig6", "fig6_grms1", "fig2_quick", "fig3_quick", "fig4_5_quick",
               "fig6_quick"]
EXAMPLES = ["demo", "contact_file", "measured_map", "adhesion_quick"]


def _gs(*args: str, cwd: Path) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "gapsweep", *args], capture_output=True, text=True, cwd=cwd,
                          env=ENV, timeout=300)


def test_shipped_jobs_are_the_readmes():
    """Every job the README runs by path is shipped, and the repository's jobs/<name>.toml is that file."""
    readme = (ROOT / "README.md").read_text(encoding="utf-8")
    used = set(re.findall(r"jobs/(\w+)\.toml", readme)) - {"gpu", "pub"}
    assert used and used <= set(jobs.names()), used - set(jobs.names())
    assert set(FIGURE_JOBS + EXAMPLES) <= set(jobs.names())
    for n in jobs.names():
        assert (ROOT / "jobs" / f"{n}.toml").resolve() == jobs.path(n).resolve(), n
        assert jobs.describe(n), n


def test_resolve_name_or_path(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    assert jobs.resolve("fig2") == jobs.path("fig2") == jobs.resolve("fig2.toml")
    own = tmp_path / "fig2.toml"  # a file of the user's wins over the shipped name
    own.write_text("[job]\nname = 'mine'\n")
    assert jobs.resolve("fig2.toml") == Path("fig2.toml")
    assert jobs.resolve(str(ROOT / "jobs" / "test_theory.toml")).name == "test_theory.toml"
    with pytest.raises(FileNotFoundError, match=r"no such file, nor a shipped job name.*fig2, fig2_quick"):
        jobs.resolve("nope")
    with pytest.raises(FileNotFoundError):
        jobs.resolve("sub/fig2")  # a folder: a path, not a name


def test_jobs_lists_and_run_by_name(tmp_path):
    r = _gs("jobs", cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    listed = [line.split()[0] for line in r.stdout.splitlines() if line and not line.startswith("(")]
    assert listed == jobs.names()
    assert _gs("jobs", "--path", "fig2", cwd=tmp_path).stdout.strip() == str(jobs.path("fig2"))
    r = _gs("run", "fig2_quick", "--store", "q.h5", "--progress", "none", cwd=tmp_path)
    assert r.returncode == 0, r.stderr[-2000:]
    from gapsweep import store

    df = store.read(tmp_path / "q.h5")
    assert len(df) > 0 and (df.status == "done").all()
    r = _gs("run", "no_such_job", "--store", "x.h5", cwd=tmp_path)
    assert r.returncode == 2 and "gapsweep jobs" in r.stderr and not (tmp_path / "x.h5").exists()  # a bad argument


def test_report_with_a_users_analysis_module(tmp_path):
    """``python -m gapsweep`` puts the working folder first on sys.path: a user's analysis.py (or analysis/) there
    once replaced the report's package (exit 1). gapsweep.analysis cannot be shadowed."""
    assert _gs("run", str(ROOT / "jobs" / "test_theory.toml"), "--store", "t.h5", "--progress", "none",
               cwd=tmp_path).returncode == 0
    (tmp_path / "analysis.py").write_text("raise ImportError('the user analysis module was imported')\n")
    r = _gs("report", "t.h5", "--out", "rep", cwd=tmp_path)
    assert r.returncode == 0, r.stderr[-2000:]
    assert (tmp_path / "rep" / "report.md").is_file() and (tmp_path / "rep" / "mean_gap.csv").is_file()


def _min_python() -> tuple[int, int]:
    """The oldest Python the pinned numpy supports (numpy 2.3+ needs 3.11)."""
    pin = re.search(r"^numpy==(\d+)\.(\d+)", (ROOT / "constraints.txt").read_text(), re.M)
    assert pin
    return (3, 11) if (int(pin[1]), int(pin[2])) >= (2, 3) else (3, 10)


@pytest.mark.slow
@pytest.mark.timeout(600)
def test_wheel_contents(tmp_path):
    """Build the wheel from a copy of the tree: only gapsweep (no top-level analysis, no studies), the shipped
    jobs with their data, every 0.1 alias file, and Requires-Python >= the pins' oldest Python."""
    pytest.importorskip("setuptools")
    src = tmp_path / "src"
    shutil.copytree(ROOT, src, symlinks=True, ignore=shutil.ignore_patterns(
        ".venv*", ".git", ".wt", "__pycache__", "*.h5", "build", "*.egg-info", "out", ".pytest_cache"))
    r = subprocess.run([sys.executable, "-m", "pip", "wheel", "--no-deps", "--no-build-isolation", "-q", "-w",
                        str(tmp_path / "dist"), str(src)], capture_output=True, text=True, timeout=500)
    assert r.returncode == 0, r.stderr[-3000:]
    (whl,) = (tmp_path / "dist").glob("gapsweep-*.whl")
    names = zipfile.ZipFile(whl).namelist()
    tops = {n.split("/")[0] for n in names if not n.split("/")[0].endswith(".dist-info")}
    assert tops == {"gapsweep"}, tops
    for n in jobs.names():
        assert f"gapsweep/jobs/{n}.toml" in names, n
    assert {"gapsweep/jobs/data/rough_tilted_256.npy", "gapsweep/jobs/data/measured_tilted_192x128.npz",
            "gapsweep/analysis/report.py", "gapsweep/_compat/store.py", "gapsweep/_compat/__init__.py"} <= set(names)
    # the Slurm job scripts: `gapsweep submit` from an installed wheel (issue 28)
    assert {f"gapsweep/sweep/jobscripts/{n}.sbatch" for n in ("array_job", "merge_job", "mpi_job")} <= set(names)
    assert not any(n.startswith("gapsweep/") and "/studies/" in n for n in names)
    meta = zipfile.ZipFile(whl).read(next(n for n in names if n.endswith("dist-info/METADATA"))).decode()
    lo = re.search(r"^Requires-Python: >=(\d+)\.(\d+)", meta, re.M)
    assert lo and (int(lo[1]), int(lo[2])) == _min_python()


def test_help_names_no_docs_file_without_saying_where_and_no_placeholder_urls():
    """issue 40: a wheel's help pointed to docs/*.md that the wheel does not install, and its project URLs were
    placeholders. Every help text (the top level and each command's) that names a docs/*.md says that these
    are the project's source files (not installed), each file it names exists in the source's docs/, and
    pyproject.toml names no placeholder address."""
    import tomllib

    from gapsweep import cli

    parser = cli._parser()
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    helps = {"gapsweep": parser.format_help(), **{f"gapsweep {k}": v.format_help() for k, v in sub.choices.items()}}
    named = 0
    for who, text in helps.items():
        files = set(re.findall(r"docs/([A-Za-z_]+)\.md", text)) - {"NAME"}
        named += len(files)
        for f in files:
            assert (ROOT / "docs" / f"{f}.md").is_file(), (who, f)
        if files:
            flat = " ".join(text.split())
            assert "the docs/ folder of the project's source" in flat and "does not install" in flat, who
    assert named >= 3  # the helps do name docs (the check above has cases)
    meta = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    for name, url in meta.get("urls", {}).items():
        host = re.sub(r"^https?://([^/]+).*", r"\1", url)
        assert not host.endswith((".invalid", ".example", "example.com", "example.org", "localhost")), (name, url)
    assert "example.invalid" not in (ROOT / "pyproject.toml").read_text()


def test_gpu_extra_names_the_cupy_that_was_measured():
    """issue 40: the gpu extra named cupy-cuda12x >= 13 while every GPU figure in benchmarks/results was measured
    with cupy 14 on CUDA 13. The extra's distribution is the CUDA major the results record, its version range
    admits every cupy version they record, and the missing-extra message names the same distribution."""
    import tomllib

    from packaging.requirements import Requirement

    from gapsweep.core import extras

    (req,) = [Requirement(r) for r in tomllib.loads((ROOT / "pyproject.toml").read_text())["project"][
        "optional-dependencies"]["gpu"]]
    texts = [p.read_text(errors="replace") for p in (ROOT / "benchmarks" / "results").rglob("*")
             if p.is_file() and p.suffix in (".json", ".txt", ".log", ".md")]
    measured = {v for t in texts for v in re.findall(r'"cupy": "(\d+\.\d+(?:\.\d+)?)"', t)}
    cuda = {m for t in texts for m in re.findall(r"CUDA (?:Version: |runtime )(\d+)\.", t)}
    assert measured and cuda, (measured, cuda)
    assert all(req.specifier.contains(v) for v in measured), (str(req), measured)
    assert cuda == {"13"} and req.name == "cupy-cuda13x", (req.name, cuda)
    assert extras.EXTRAS["cupy"] == (req.name, "gpu")
