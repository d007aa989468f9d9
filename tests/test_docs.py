"""Docs that cannot drift (issue 29 item 5): scripts/check_docs.py passes on the repository and fails on a quoted
number that differs from its result file, names none, or names a file that is not there; docs/environment.md
lists every environment variable the package reads."""

from __future__ import annotations

import importlib.util
import json
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def _checker():
    spec = importlib.util.spec_from_file_location("check_docs", ROOT / "scripts" / "check_docs.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_repository_docs_pass():
    cd = _checker()
    problems = cd.check()
    assert problems == [], "\n".join(problems)
    assert len(cd.DEBTS) <= cd.KNOWN_DEBTS


@pytest.fixture
def fake(tmp_path, monkeypatch):
    """A repository of one result file and a README, with the checker rooted there."""
    cd = _checker()
    (tmp_path / "benchmarks" / "results").mkdir(parents=True)
    (tmp_path / "docs").mkdir()
    (tmp_path / "benchmarks" / "results" / "r.json").write_text(json.dumps(
        {"rows": [{"n": 1024, "t_s": 0.2651}, {"n": 2048, "t_s": 1.249}]}))
    (tmp_path / "benchmarks" / "results" / "log.txt").write_text("total 0.484 ms/task\n")
    monkeypatch.setattr(cd, "ROOT", tmp_path)

    def run(glance: str, bench: str = "") -> list[str]:
        (tmp_path / "README.md").write_text(f"# x\n\n## At a glance\n\n{glance}\n\n## Other\n\n12 things\n")
        (tmp_path / "docs" / "benchmarks.md").write_text(bench or "# B\n")
        return cd.check(tmp_path)

    return run


def test_checked_numbers(fake):
    ok = ("- `N = 1024` in [0.27 s](benchmarks/results/r.json#rows[n=1024].t_s), up to "
          "[1.25 s](benchmarks/results/r.json#rows.*.t_s|max) over [2](benchmarks/results/r.json#rows|len) cases, "
          "[< 2 s](benchmarks/results/r.json#rows.1.t_s), [~3e-1](benchmarks/results/r.json#rows.0.t_s), "
          "[484 us](<benchmarks/results/log.txt#re:total ([\\d.]+) ms|*1000>)")
    assert fake(ok) == []
    wrong = fake("- [0.25 s](benchmarks/results/r.json#rows[n=1024].t_s)")
    assert len(wrong) == 1 and "quoted '0.25 s' but r.json#rows[n=1024].t_s is 0.2651" in wrong[0]
    assert "no file" in fake("- [1 s](benchmarks/results/gone.json#rows.0.t_s)")[0]
    assert "no key" in fake("- [1 s](benchmarks/results/r.json#cols.0)")[0]


def test_strict_section_needs_a_file_for_every_number(fake):
    out = fake("- GFMD in 0.27 s at `N = 1024`")
    assert len(out) == 1 and "the number '0.27' names no result file" in out[0]
    assert fake("- GFMD at `N = 1024` (parameters are code), nothing measured") == []


def test_sourced_sections_of_the_benchmark_pages(fake):
    bench = "# B\n\n## Speed\n\n3.2 s per solve.\n"
    out = fake("- none", bench)
    assert len(out) == 1 and "section 'Speed' quotes numbers but names no result file" in out[0]
    assert fake("- none", bench + "raw: `benchmarks/results/r.json`\n") == []
    out = fake("- none", bench + "raw: `benchmarks/results/gone.json`\n")
    assert any("gone.json, which does not exist" in p for p in out)


def test_other_pages_are_checked(fake, tmp_path):
    """The other pages of docs/ too: their checked numbers (and the provenance of what they cite)."""
    (tmp_path / "docs" / "theory.md").write_text(
        "# T\n\nfast: [0.25 s](../benchmarks/results/r.json#rows[n=1024].t_s)\n")
    out = fake("- none")
    assert len(out) == 1 and out[0].startswith("docs/theory.md:3: quoted '0.25 s'"), out


VAR = re.compile(r"""(?:environ(?:\.get)?\s*[\[(]\s*|getenv\(\s*)["']([A-Z][A-Z0-9_]+)["']""")


def test_environment_page_lists_every_variable():
    """Every variable gapsweep's own code reads (os.environ / getenv with a literal name, and the tuples of
    launcher variables) and every ${VAR} of the Slurm scripts appears in docs/environment.md."""
    page = (ROOT / "docs" / "environment.md").read_text(encoding="utf-8")
    found: set[str] = set()
    for p in (ROOT / "gapsweep").rglob("*.py"):
        text = p.read_text(encoding="utf-8")
        found |= set(VAR.findall(text))
        for tup in re.findall(r"_(?:MPI|MPI_SIZE)_ENV = \(([^)]*)\)", text):
            found |= set(re.findall(r'"([A-Z_]+)"', tup))
    for p in (ROOT / "slurm").glob("*"):
        found |= {v for v in re.findall(r"\$\{(GAPSWEEP[A-Z_]*|SBATCH_ARGS)", p.read_text(encoding="utf-8"))}
    assert len(found) > 20
    missing = sorted(v for v in found if f"`{v}" not in page)
    assert missing == [], missing
    assert "environment.md" in (ROOT / "docs" / "README.md").read_text(encoding="utf-8")


def test_no_test_hook_in_the_package():
    """The package reads no GAPSWEEP_TEST_* variable but GAPSWEEP_TEST_DELAY (kept while
    tests/faults/test_concurrent.py, which uses it, is rewritten); the others live in tests/hooks."""
    names = set()
    for p in (ROOT / "gapsweep").rglob("*.py"):
        names |= set(re.findall(r'"(GAPSWEEP_TEST_[A-Z_]+)"', p.read_text(encoding="utf-8")))
    assert names <= {"GAPSWEEP_TEST_DELAY"}, names
