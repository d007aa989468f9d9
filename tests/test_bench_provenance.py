"""Numbers with provenance (issue 40 item 11): every benchmark script names the code it measures and stamps its
result files (benchmarks/_record.py) with the commit of *this* repository, the command, the machine, the date and
the library versions; scripts/check_docs.py fails a cited result that is stale (its code changed in a later
commit), whose commit is unknown or lacks its code, or that has no record and is cited outside docs/history.md
without a remeasure marker that a remeasure script honours.
The staleness cases run in a throw-away git repository built here."""

from __future__ import annotations

import ast
import importlib.util
import json
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
pytestmark = pytest.mark.skipif(shutil.which("git") is None, reason="git not installed")


def _load(path: Path, name: str):
    spec = importlib.util.spec_from_file_location(name, path)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


record = _load(ROOT / "benchmarks" / "_record.py", "_bench_record_t")
check_docs = _load(ROOT / "scripts" / "check_docs.py", "_check_docs_t")


def _git(d: Path, *args: str) -> str:
    p = subprocess.run(["git", "-C", str(d), "-c", "user.name=t", "-c", "user.email=t@t", "-c",
                        "commit.gpgsign=false", *args], capture_output=True, text=True, timeout=60)
    assert p.returncode == 0, p.stderr
    return p.stdout.strip()


def _repo(d: Path) -> Path:
    d.mkdir(parents=True, exist_ok=True)
    _git(d, "init", "-q")
    return d


def _commit(d: Path, msg: str) -> str:
    _git(d, "add", "-A")
    _git(d, "commit", "-q", "-m", msg)
    return _git(d, "rev-parse", "HEAD")


def test_commit_is_the_projects_not_an_enclosing_repositorys(tmp_path):
    """A project folder inside another repository: without its own checkout it records no commit (the old
    farm file took the enclosing repository's); with one, its own."""
    outer = _repo(tmp_path / "outer")
    (outer / "x").write_text("x")
    outer_commit = _commit(outer, "outer")
    proj = outer / "proj"
    (proj / "code").mkdir(parents=True)
    (proj / "code" / "a.py").write_text("a = 1\n")
    assert record.project_commit(proj) is None
    assert record.record(["code/a.py"], ["bench.py"], root=proj)["commit"] is None
    _repo(proj)
    mine = _commit(proj, "project")
    assert mine != outer_commit and record.project_commit(proj) == mine
    rec = record.record(["code/a.py"], ["bench.py", "--n", "3"], root=proj)
    assert rec["commit"] == mine and rec["dirty"] is False and rec["code_paths"] == ["code/a.py"]
    assert rec["command"].endswith("bench.py --n 3") and rec["date"].endswith("Z")
    assert rec["machine"]["hostname"] and rec["versions"]["python"] and rec["versions"]["numpy"]
    with pytest.raises(ValueError, match="no_such"):
        record.record(["code/no_such.py"], [], root=proj)


def test_a_copy_without_git_takes_the_commit_it_is_told(tmp_path, monkeypatch):
    """A copy of the working tree without .git (what a lent GPU machine gets): GAPSWEEP_COMMIT names the commit
    (40 hex digits only), said so in the record, also where the copy carries a .git of another commit (a lent GPU
    machine's copy held the .git of the session's first commit under newer files: git's HEAD there was wrong);
    without it, git's own commit."""
    proj = tmp_path / "copy"
    (proj / "code").mkdir(parents=True)
    (proj / "code" / "a.py").write_text("a = 1\n")
    monkeypatch.setenv("GAPSWEEP_COMMIT", "abc123")  # not a full commit: ignored
    assert record.record(["code/a.py"], ["b.py"], root=proj)["commit"] is None
    monkeypatch.setenv("GAPSWEEP_COMMIT", "a" * 40)
    rec = record.record(["code/a.py"], ["b.py"], root=proj)
    assert rec["commit"] == "a" * 40 and rec["commit_source"] == "GAPSWEEP_COMMIT" and rec["dirty"] is None
    _repo(proj)
    mine = _commit(proj, "project")
    rec = record.record(["code/a.py"], ["b.py"], root=proj)
    assert rec["commit"] == "a" * 40 and rec["commit_source"] == "GAPSWEEP_COMMIT"
    monkeypatch.delenv("GAPSWEEP_COMMIT")
    rec = record.record(["code/a.py"], ["b.py"], root=proj)
    assert rec["commit"] == mine and rec["commit_source"] == "git" and rec["dirty"] is False
    # the copy's .git knows the commit it is told, but the files measured are not that commit's: refused (a
    # command that expanded $(git rev-parse HEAD) on the lent machine, whose .git held an older commit)
    (proj / "code" / "a.py").write_text("a = 2\n")
    monkeypatch.setenv("GAPSWEEP_COMMIT", mine)
    with pytest.raises(ValueError, match=r"differs from that commit.*code/a.py"):
        record.record(["code/a.py"], ["b.py"], root=proj)
    (proj / "code" / "a.py").write_text("a = 1\n")
    assert record.record(["code/a.py"], ["b.py"], root=proj)["commit"] == mine


def _result(root: Path, name: str, rec: dict | None) -> Path:
    f = root / "benchmarks" / "results" / name
    f.parent.mkdir(parents=True, exist_ok=True)
    f.write_text(json.dumps({"t_s": 1.0, **({"provenance": rec} if rec else {})}))
    return f


def test_check_docs_fails_stale_wrong_commit_and_unlisted_unversioned(tmp_path):
    root = _repo(tmp_path / "proj")
    (root / "benchmarks").mkdir()
    shutil.copy(ROOT / "benchmarks" / "_record.py", root / "benchmarks" / "_record.py")
    (root / "code").mkdir()
    (root / "code" / "solver.py").write_text("x = 1\n")
    (root / "code" / "other.py").write_text("y = 1\n")
    c1 = _commit(root, "c1")
    fresh = _result(root, "fresh.json", record.record(["code/solver.py"], ["b.py"], root=root))
    other = _result(root, "other.json", record.record(["code/other.py"], ["b.py"], root=root))
    text = root / "benchmarks" / "results" / "table.txt"
    text.write_text("1.0 s\n")
    record.stamp(text, record.record(["code/solver.py"], ["b.py"], root=root))  # a sidecar
    assert (root / "benchmarks" / "results" / "table.txt.provenance.json").is_file()
    _commit(root, "results")
    files = [fresh, other, text]
    assert check_docs.check_provenance(files, root) == []
    (root / "code" / "solver.py").write_text("x = 2  # the solver changed\n")
    _commit(root, "solver change")
    probs = check_docs.check_provenance(files, root)
    assert len(probs) == 2 and all("stale" in p for p in probs), probs
    assert any("fresh.json" in p for p in probs) and any("table.txt" in p for p in probs)
    (root / "code" / "solver.py").write_text("x = 1\n")  # the change reverted: the code measured is HEAD's again
    _commit(root, "revert")
    assert check_docs.check_provenance(files, root) == []
    (root / "code" / "solver.py").write_text("x = 3\n")
    _commit(root, "solver change again")
    assert len(check_docs.check_provenance(files, root)) == 2
    # a record naming a commit the repository lacks, or one at which its code did not exist
    bad = _result(root, "bad.json", {"commit": "f" * 40, "code_paths": ["code/solver.py"]})
    (root / "code" / "new.py").write_text("z = 1\n")
    _commit(root, "new code")
    early = _result(root, "early.json", {"commit": c1, "code_paths": ["code/new.py"]})
    probs = check_docs.check_provenance([bad, early], root)
    assert any("bad.json" in p and "does not have" in p for p in probs), probs
    assert any("early.json" in p and "did not exist" in p for p in probs), probs
    # unversioned, cited from a current page without a remeasure marker: a failure
    legacy = _result(root, "legacy.json", None)
    probs = check_docs.check_provenance([legacy], root)
    assert len(probs) == 1 and "no provenance record" in probs[0] and "docs/history.md" in probs[0]


def test_unversioned_results_only_in_history_or_beside_a_remeasure_marker(tmp_path, monkeypatch):
    """A legacy result (no record) may be cited from docs/history.md, or from a current page where a remeasure
    marker naming it stands in the same table row or paragraph and a remeasure script rewrites it; once it carries
    a record the marker itself fails. The whole checker runs on a throw-away repository."""
    root = _repo(tmp_path / "proj")
    (root / "benchmarks").mkdir()
    shutil.copy(ROOT / "benchmarks" / "_record.py", root / "benchmarks" / "_record.py")
    (root / "code").mkdir()
    (root / "code" / "solver.py").write_text("x = 1\n")
    (root / "docs").mkdir()
    (root / "docs" / "benchmarks.md").write_text("# B\n")
    legacy = _result(root, "legacy.json", None)
    _commit(root, "c1")
    monkeypatch.setattr(check_docs, "ROOT", root)
    link = "[1.0 s](benchmarks/results/legacy.json#t_s)"
    mark = "<!-- remeasure: benchmarks/results/legacy.json -->"
    script = root / "benchmarks" / "remeasure_cpu.sh"

    def run(glance: str, history: str | None = None) -> list[str]:
        (root / "README.md").write_text(f"# x\n\n## At a glance\n\n{glance}\n")
        h = root / "docs" / "history.md"
        h.unlink(missing_ok=True)
        if history is not None:
            h.write_text(history)
        return check_docs.check(root)

    out = run(f"- solve in {link}")
    assert len(out) == 1 and out[0].startswith("README.md:5: cites benchmarks/results/legacy.json"), out
    out = run("- raw: `benchmarks/results/leg`")  # a stem cites every file it starts with
    assert len(out) == 1 and "cites benchmarks/results/legacy.json" in out[0], out
    out = run(f"- solve in {link} {mark}")  # marked, but no remeasure script writes it
    assert len(out) == 1 and "which benchmarks/remeasure_cpu.sh or benchmarks/remeasure_gpu.sh does not write" in out[0]
    script.write_text("python b.py > benchmarks/results/legacy.json\n")
    assert run(f"- solve in {link}\n  (`N = 8`) {mark}") == []  # same list: in scope
    assert any("awaiting re-measurement" in w and "legacy.json" in w for w in check_docs.WARNINGS)
    out = run(f"- solve in {link}\n- another item {mark}")  # another list item: out of scope
    assert len(out) == 1 and "README.md:5: cites" in out[0], out
    out = run(f"- solve in {link}\n\n{mark} another paragraph")  # another paragraph: out of scope
    assert len(out) == 1 and "README.md:5: cites" in out[0], out
    out = run(f"| a | b |\n| --- | --- |\n| x | {link} |\n| y | `z` {mark} |")  # another table row
    assert len(out) == 1 and "README.md:7: cites" in out[0], out
    assert run(f"| a | b |\n| --- | --- |\n| x | {link} {mark} |") == []
    out = run(f"- solve in `{mark}` {link}")  # a marker quoted in code is no marker
    assert len(out) == 1 and "cites" in out[0], out
    hist = f"# History\n\n## Old run\n\nMeasured in 2026 ({link.replace('](', '](../')}).\n"
    assert run("- nothing measured", hist) == []  # history.md may cite it
    out = run("- nothing measured", hist.replace("1.0 s", "2.0 s"))  # its numbers are still checked
    assert len(out) == 1 and "quoted '2.0 s'" in out[0], out
    # re-measured: the file carries a record now, so the marker must go; without it the citation passes
    legacy.write_text(json.dumps({"t_s": 1.04, "provenance": record.record(["code/solver.py"], ["b.py"],
                                                                               root=root)}))
    _commit(root, "re-measured")
    out = run(f"- solve in {link} {mark}")
    assert len(out) == 1 and "has been re-measured" in out[0] and "drop the remeasure marker" in out[0], out
    assert run(f"- solve in {link}") == []
    # a history-only citation of a stale result is not judged; a current one is
    (root / "code" / "solver.py").write_text("x = 2\n")
    _commit(root, "solver change")
    assert run("- nothing measured", hist) == []
    out = run(f"- solve in {link}")
    assert len(out) == 1 and "stale" in out[0], out


def test_the_repositorys_cited_results_pass():
    """The real docs: every cited result is current, cited from docs/history.md, or marked for re-measurement by
    a remeasure script."""
    assert check_docs.check() == []


def test_every_benchmark_script_tracks_its_provenance():
    """Each benchmarks/*.py script names existing CODE_PATHS and calls _record.track(CODE_PATHS...) first thing
    under ``if __name__ == "__main__":`` (helpers, named with a leading underscore -- _record.py, _peers_run.py --,
    measure nothing themselves)."""
    scripts = [p for p in sorted((ROOT / "benchmarks").glob("*.py")) if not p.name.startswith("_")]
    assert len(scripts) > 20
    for p in scripts:
        tree = ast.parse(p.read_text(encoding="utf-8"))
        paths = next((ast.literal_eval(n.value) for n in tree.body if isinstance(n, ast.Assign)
                      and any(getattr(t, "id", "") == "CODE_PATHS" for t in n.targets)), None)
        assert paths and all((ROOT / x).exists() for x in paths), (p.name, paths)
        main = next(n for n in tree.body if isinstance(n, ast.If) and "__main__" in ast.unparse(n.test))
        first = ast.unparse(main.body[0])
        assert first.startswith("_record.track(CODE_PATHS"), (p.name, first)


def test_studies_behind_cited_results_track_their_provenance():
    """The studies whose docs/results files the docs cite (and benchmarks/remeasure_cpu.sh re-runs) name existing
    CODE_PATHS and call studies.track(CODE_PATHS) first thing under ``if __name__ == "__main__":``."""
    script = (ROOT / "benchmarks" / "remeasure_cpu.sh").read_text(encoding="utf-8")
    names = sorted(set(re.findall(r"-m studies\.(\w+)", script)))
    assert {"persson_converged", "predictors_heldout", "predictors_wide", "leakage"} <= set(names), names
    for name in names:
        tree = ast.parse((ROOT / "studies" / f"{name}.py").read_text(encoding="utf-8"))
        paths = next((ast.literal_eval(n.value) for n in tree.body if isinstance(n, ast.Assign)
                      and any(getattr(t, "id", "") == "CODE_PATHS" for t in n.targets)), None)
        assert paths and all((ROOT / x).exists() for x in paths), (name, paths)
        main = next(n for n in tree.body if isinstance(n, ast.If) and "__main__" in ast.unparse(n.test))
        calls = [ast.unparse(x) for x in main.body if not isinstance(x, ast.Import)]
        assert calls[0] == "studies.track(CODE_PATHS)", (name, calls[0])


def test_a_benchmark_run_stamps_its_result(tmp_path):
    """bench_theory.py run for real (tiny): its JSON records this checkout's commit, its code paths, the
    command, the machine and the versions."""
    out = tmp_path / "theory.json"
    env = {"PYTHONPATH": str(ROOT), "PATH": os.environ["PATH"], "HOME": str(tmp_path)}
    p = subprocess.run([sys.executable, str(ROOT / "benchmarks" / "bench_theory.py"), "--out", str(out), "--n",
                        "50", "--repeat", "1"], capture_output=True, text=True, timeout=300, env=env, cwd=tmp_path)
    assert p.returncode == 0, p.stderr
    rec = json.loads(out.read_text())["provenance"]
    assert rec["commit"] == record.project_commit(ROOT) and rec["commit"]
    assert rec["code_paths"] == ["gapsweep/theory"] and "--n 50" in rec["command"]
    assert rec["machine"]["cpus"] >= 1 and rec["versions"]["numpy"]


TRACKED = """
import json, subprocess, sys
sys.path.insert(0, sys.argv[1])
import _record
_record.track(["benchmarks/_record.py"])
who, out = sys.argv[2], sys.argv[4]
print("tracking", flush=True)
sys.stdin.readline()  # the test's barrier: write when told
with open(f"{out}/{who}.json", "w") as f:
    json.dump({"who": who}, f)
if who == "A":  # a result a child process writes (no record of its own): the tracking run stamps it
    subprocess.run([sys.executable, "-c", f"open('{out}/child.txt', 'w').write('x')"], check=True)
"""


def test_concurrent_runs_stamp_only_their_own_results(tmp_path):
    """Two tracked benchmarks writing into one folder at the same time: each result carries the record of the
    run that wrote it (before, the run that exited last stamped every file modified since its start, so records
    named another benchmark's command); a file a child of the run wrote (no record) is stamped by that run.
    Order by barriers (stdin lines), no timing."""
    env = {"PYTHONPATH": str(ROOT), "PATH": os.environ["PATH"], "HOME": str(tmp_path)}
    out = tmp_path / "out"
    out.mkdir()

    def start(who: str) -> subprocess.Popen:
        p = subprocess.Popen([sys.executable, "-c", TRACKED, str(ROOT / "benchmarks"), who, "--out", str(out)],
                             stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                             env=env, cwd=tmp_path)
        assert p.stdout.readline().strip() == "tracking"
        return p

    a = start("A")
    b = start("B")  # started after A: B's file is modified after A's start
    _, err = b.communicate("go\n", timeout=120)
    assert b.returncode == 0, err
    _, err = a.communicate("go\n", timeout=120)
    assert a.returncode == 0, err
    for who in ("A", "B"):
        cmd = json.loads((out / f"{who}.json").read_text())["provenance"]["command"]
        assert f" {who} --out" in cmd, (who, cmd)
    assert " A --out" in record.read(out / "child.txt")["command"]


STOPPED = """
import json, sys, time
sys.path.insert(0, sys.argv[1])
import _record
_record.track(["benchmarks/_record.py"])
with open(sys.argv[3], "w") as f:
    json.dump({"partial": True}, f)
print("written", flush=True)
sys.stdin.readline()  # never answered: the test stops the run here, as `timeout` does
"""


def test_a_run_stopped_by_sigterm_still_stamps_what_it_wrote(tmp_path):
    """benchmarks/gpu_challenge_refine.sh cuts each GPU stage with `timeout` (SIGTERM) and keeps the JSON written
    so far; Python's default for SIGTERM skips atexit, so such a result carried no record (the stage-1 run of
    2026-11-29). Now track() turns SIGTERM into SystemExit and the file is stamped. Ordered by a pipe, no timing."""
    env = {"PYTHONPATH": str(ROOT), "PATH": os.environ["PATH"], "HOME": str(tmp_path)}
    out = tmp_path / "partial.json"
    p = subprocess.Popen([sys.executable, "-c", STOPPED, str(ROOT / "benchmarks"), "--out", str(out)],
                         stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env,
                         cwd=tmp_path)
    assert p.stdout.readline().strip() == "written"
    p.terminate()  # SIGTERM, as timeout(1) sends
    _, err = p.communicate(timeout=120)
    assert p.returncode == 128 + 15, (p.returncode, err)
    data = json.loads(out.read_text())
    assert data["partial"] is True and data["provenance"]["commit"] == record.project_commit(ROOT)
