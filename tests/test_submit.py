"""``gapsweep submit`` and ``gapsweep requeue`` without a Slurm cluster (issue 28): stand-in ``sbatch``,
``squeue``, ``scontrol`` and ``sacctmgr`` record their arguments and answer as a site would (MaxArraySize,
queued jobs of the store, MaxSubmitJobs). tests/test_slurm.py runs the same on a real single-node Slurm."""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

from gapsweep import store
from gapsweep.sweep import slurm

ROOT = Path(__file__).resolve().parent.parent
JOB = ROOT / "jobs" / "test_theory.toml"

FAKES = {
    "sbatch": """#!/bin/bash
n=$(( $(cat "$SB_DIR/count" 2>/dev/null || echo 0) + 1 ))
echo "$n" > "$SB_DIR/count"
if [ "$n" = "${FAKE_FAIL_AT:-0}" ]; then
  echo "sbatch: error: Batch job submission failed: QOSMaxSubmitJobPerUserLimit" >&2; exit 1
fi
printf '%s\\n' "$@" > "$SB_DIR/call$n.args"
echo "${GAPSWEEP_SHARDS:-}|${GAPSWEEP_SHARD_OFFSET:-}|${GAPSWEEP_REQUEUE:-}" > "$SB_DIR/call$n.env"
echo "$((1000 + n));cluster"
""",
    "scontrol": """#!/bin/bash
echo "$@" >> "$SB_DIR/scontrol.log"
if [ "$1 $2" = "show config" ]; then
  printf 'MaxArraySize            = %s\\nMaxJobCount             = 10000\\n' "${FAKE_MAX_ARRAY:-1001}"
fi
""",
    "squeue": """#!/bin/bash
if [ -n "${FAKE_SQUEUE_FAIL:-}" ]; then echo "squeue: error: slurm_load_jobs error: Socket timed out" >&2; exit 1; fi
if [[ " $* " == *" -r "* ]]; then for ((k = 0; k < ${FAKE_USER_JOBS:-0}; k++)); do echo "$((500 + k))"; done
else printf '%b' "${FAKE_QUEUE:-}"; fi
""",
    "sacctmgr": """#!/bin/bash
[ -n "${FAKE_MAXSUBMIT:-}" ] && echo "${FAKE_MAXSUBMIT}|" || exit 1
""",
}


@pytest.fixture
def fake(tmp_path):
    d = tmp_path / "bin"
    d.mkdir()
    for name, text in FAKES.items():
        (d / name).write_text(text)
        (d / name).chmod(0o755)
    return d


def _submit(fake: Path, tmp_path: Path, *args: str, job: str | Path = JOB, out: str | Path | None = None,
            **env: str) -> subprocess.CompletedProcess:
    e = {k: v for k, v in os.environ.items() if not k.startswith(("GAPSWEEP_", "SLURM_", "SBATCH"))}
    e.update(PYTHONPATH=str(ROOT), SB_DIR=str(fake), PATH=f"{fake}:{os.environ['PATH']}", **env)
    out = tmp_path / "out" if out is None else out
    return subprocess.run([sys.executable, "-m", "gapsweep", "submit", str(job), str(out), *args],
                          env=e, capture_output=True, text=True, timeout=120, cwd=tmp_path)


def _calls(d: Path) -> list[list[str]]:
    n = int((d / "count").read_text()) if (d / "count").exists() else 0
    return [(d / f"call{i}.args").read_text().split("\n")[:-1] for i in range(1, n + 1)]


def test_split_at_max_array_size_throttle_and_merge_on_all(tmp_path, fake):
    """9 shards at MaxArraySize = 4: three arrays 0-3, 0-3, 0-0 (every index below 4) with shard offsets 0, 4, 8
    of 9, each throttled to %2, requeue and the warning signal asked for; the merge depends (afterany) on all
    three and merges 9 shards. The old submit.sh asked for --array=0-8: refused by such a site."""
    p = _submit(fake, tmp_path, "--shards", "9", "--max-running", "2", "--signal-lead", "120", FAKE_MAX_ARRAY="4")
    assert p.returncode == 0, p.stderr
    calls = _calls(fake)
    assert len(calls) == 4
    arrays = [next(a for a in c if a.startswith("--array=")) for c in calls[:3]]
    assert arrays == ["--array=0-3%2", "--array=0-3%2", "--array=0-0%2"]
    envs = [(fake / f"call{i}.env").read_text().strip() for i in (1, 2, 3)]
    assert envs == ["9|0|3", "9|4|3", "9|8|3"]
    key = slurm.store_key(tmp_path / "out" / "test_theory.h5")
    for c in calls[:3]:
        assert {"--requeue", "--signal=B:USR1@120", f"--comment=gapsweep:{key}", "--open-mode=append"} <= set(c), c
    merge = calls[3]
    assert "--dependency=afterany:1001:1002:1003" in merge and f"--comment=gapsweep:{key}" in merge
    assert merge[-2:] == ["9", str(tmp_path / "out" / "test_theory.h5")]
    assert p.stdout.split() == ["array", "1001,1002,1003", "merge", "1004", "store",
                                str(tmp_path / "out" / "test_theory.h5")]


def test_dry_run_prints_commands_and_scripts_submits_nothing(tmp_path, fake):
    p = _submit(fake, tmp_path, "--shards", "5", "--max-running", "3", "--account", "phys1", "--dry-run",
                FAKE_MAX_ARRAY="4")
    assert p.returncode == 0, p.stderr
    assert not (fake / "count").exists() and not (tmp_path / "out").exists()
    out = p.stdout
    assert out.count("sbatch --parsable") == 3  # two arrays, the merge
    assert "--array=0-3%3" in out and "--array=0-0%3" in out and "GAPSWEEP_SHARD_OFFSET=4" in out
    assert "--account=phys1" in out and "--dependency=afterany:ARRAY_ID:ARRAY_ID" in out
    assert "# ---- array_job.sbatch ----" in out and "# ---- merge_job.sbatch ----" in out
    assert "#SBATCH --signal=B:USR1@300" in out


def test_submit_takes_a_shipped_job_name(tmp_path, fake):
    """``gapsweep submit fig2_quick OUT`` (a name of ``gapsweep jobs``, as ``run`` and ``plan`` take): the scripts
    run the shipped spec's file, the final store is OUT/fig2_quick.h5; an unknown name is a bad argument (exit 2)
    naming the shipped jobs, nothing submitted."""
    from gapsweep import jobs

    p = _submit(fake, tmp_path, "--shards", "2", "--dry-run", job="fig2_quick")
    assert p.returncode == 0, p.stderr
    assert str(jobs.path("fig2_quick").absolute()) in p.stdout and "fig2_quick.h5" in p.stdout
    p = _submit(fake, tmp_path, "--shards", "2", job="no_such_job")
    assert p.returncode == 2 and "no such file, nor a shipped job name" in p.stderr and "fig2_quick" in p.stderr
    assert not (fake / "count").exists() and not (tmp_path / "out").exists()


def test_second_submission_refused_unless_force(tmp_path, fake):
    """Jobs with the store's comment in the queue: refused naming them, nothing submitted; --force submits."""
    key = slurm.store_key(tmp_path / "out" / "test_theory.h5")
    queue = f"77_[0-2]|gapsweep:{key}|PENDING\\n78|gapsweep:{key}|PENDING\\n79|gapsweep:other|RUNNING\\n"
    p = _submit(fake, tmp_path, "--shards", "3", FAKE_QUEUE=queue)
    assert p.returncode == 1
    # job 79 (another store's) is not named; "79" may appear inside the store key's hex digits, hence \b
    assert "77_[0-2], 78" in p.stderr and not re.search(r"\b79\b", p.stderr) and "--force" in p.stderr
    assert not (fake / "count").exists()
    p = _submit(fake, tmp_path, "--shards", "3", "--force", FAKE_QUEUE=queue)
    assert p.returncode == 0, p.stderr
    assert len(_calls(fake)) == 2


def test_max_submit_jobs_refused_with_reason(tmp_path, fake):
    """MaxSubmitJobs = 6 with 3 jobs queued: 3 shards + merge (4 jobs) would make 7: refused, nothing submitted;
    2 shards + merge fit."""
    p = _submit(fake, tmp_path, "--shards", "3", FAKE_MAXSUBMIT="6", FAKE_USER_JOBS="3")
    assert p.returncode == 1 and "MaxSubmitJobs = 6" in p.stderr and "3 already queued" in p.stderr, p.stderr
    assert not (fake / "count").exists()
    p = _submit(fake, tmp_path, "--shards", "2", FAKE_MAXSUBMIT="6", FAKE_USER_JOBS="3")
    assert p.returncode == 0, p.stderr


def test_sbatch_failure_names_what_was_submitted(tmp_path, fake):
    """The merge's sbatch fails after the array was queued: exit 1 with sbatch's reason and the array's id to
    cancel; nothing else is submitted."""
    p = _submit(fake, tmp_path, "--shards", "2", FAKE_FAIL_AT="2")
    assert p.returncode == 1
    assert "QOSMaxSubmitJobPerUserLimit" in p.stderr and "already submitted: 1001" in p.stderr, p.stderr
    assert "scancel 1001" in p.stderr


@pytest.mark.parametrize("args", [["--shards", "0"], ["--shards", "2", "--max-running", "0"],
                                  ["--shards", "2", "--requeue", "-1"], ["--mpi", "2", "--signal-lead", "5"]])
def test_bad_arguments_name_the_option(tmp_path, fake, capsys, monkeypatch, args):
    """Refused before anything is submitted: in this process (``cli.main``; no process boundary is under test),
    with the fake Slurm commands first on the PATH as for ``_submit``."""
    from gapsweep import cli

    for k in list(os.environ):
        if k.startswith(("GAPSWEEP_", "SLURM_", "SBATCH")):
            monkeypatch.delenv(k)
    monkeypatch.setenv("SB_DIR", str(fake))
    monkeypatch.setenv("PATH", f"{fake}:{os.environ['PATH']}")
    monkeypatch.chdir(tmp_path)
    try:
        rc = cli.main(["submit", str(JOB), str(tmp_path / "out"), *args])
    except SystemExit as e:  # argparse's usage errors
        rc = e.code
    err = capsys.readouterr().err
    assert rc == 2 and args[-2] in err, err
    assert not (fake / "count").exists()


def _partial(tmp_path: Path, at: int, store_path: Path | None = None, resume: bool = False) -> Path:
    path = store_path or tmp_path / "s.h5"
    e = {k: v for k, v in os.environ.items() if not k.startswith("GAPSWEEP_")}
    from tests.hooks.gapsweep_test_hooks import pythonpath

    e.update(PYTHONPATH=pythonpath(str(ROOT)), GAPSWEEP_TEST_SIGNAL_AT_WRITE=str(at))  # tests/hooks injects it
    p = subprocess.run([sys.executable, "-m", "gapsweep", "run", str(JOB), "--store", str(path), "--mpi", "off",
                        "--progress", "none", *(["--resume"] if resume else [])], env=e, capture_output=True,
                       text=True, timeout=120)
    assert p.returncode == 143, p.stderr
    return path


def test_requeue_decision_counts_progress_and_limit(tmp_path, fake, monkeypatch):
    """After a stopped attempt that finished rows: requeued (scontrol requeue JOBID), the count kept beside the
    store. Asked again without a new row: refused (no progress). After another attempt with rows: requeued
    again, up to --max; a new job id starts the count again."""
    monkeypatch.setenv("PATH", f"{fake}:{os.environ['PATH']}")
    monkeypatch.setenv("SB_DIR", str(fake))
    path = _partial(tmp_path, 10)
    ok, why = slurm.requeue(path, 2, "4242")
    assert ok, why
    assert (fake / "scontrol.log").read_text().split("\n")[-2] == "requeue 4242"
    rec = json.loads((tmp_path / "s.h5.requeue").read_text())
    assert rec["job"] == "4242" and rec["requeues"] == 1
    ok, why = slurm.requeue(path, 2, "4242")
    assert not ok and "no row finished" in why
    _partial(tmp_path, 5, resume=True)
    ok, why = slurm.requeue(path, 2, "4242")
    assert ok and "requeue 2 of 2" in why
    _partial(tmp_path, 5, resume=True)
    ok, why = slurm.requeue(path, 2, "4242", act=False)
    assert not ok and "requeued 2 time(s) already" in why
    ok, why = slurm.requeue(path, 2, "5151", act=False)
    assert ok and "requeue 1 of 2" in why
    assert (fake / "scontrol.log").read_text().count("requeue") == 2  # act=False ran nothing


def test_requeue_cli_outside_slurm_and_finished_store(tmp_path):
    e = {k: v for k, v in os.environ.items() if not k.startswith(("GAPSWEEP_", "SLURM_"))}
    e.update(PYTHONPATH=str(ROOT))
    path = tmp_path / "done.h5"
    assert subprocess.run([sys.executable, "-m", "gapsweep", "run", str(JOB), "--store", str(path), "--mpi", "off",
                           "--progress", "none"], env=e, timeout=120).returncode == 0
    p = subprocess.run([sys.executable, "-m", "gapsweep", "requeue", str(path)], env=e, capture_output=True,
                       text=True, timeout=60)
    assert p.returncode == 1 and "SLURM_JOB_ID unset" in p.stderr
    ok, why = slurm.requeue(path, 3, "1", act=False)
    assert not ok and "all 48 rows finished" in why
    assert (store.read(path).status == "done").all()


# --- issue 40 item 4: the guard keyed by the resolved path and the store's identity; squeue failing; `%` in the
# output folder; logs per attempt --------------------------------------------------------------------------------

def _path_key(path: Path) -> str:
    """The guard's key computed here from its definition (SHA-256 of the resolved path), not by slurm.store_key."""
    import hashlib

    return hashlib.sha256(os.path.realpath(path).encode()).hexdigest()[:16]


@pytest.mark.parametrize("spelling", ["dotdot", "symlink", "hardlink"])
def test_guard_sees_the_same_store_under_another_spelling(tmp_path, fake, spelling):
    """A first submission to OUT is queued; a second names the same store as ``./x/../out``, through a symlinked
    folder, or (the store exists) as a hard link in another folder: refused, nothing submitted. The old guard
    hashed the unresolved absolute path and let all three through."""
    out = tmp_path / "out"
    out.mkdir()
    (tmp_path / "x").mkdir()
    p = _submit(fake, tmp_path, "--shards", "2", out=out)
    assert p.returncode == 0, p.stderr
    tag = next(a for a in _calls(fake)[0] if a.startswith("--comment="))[len("--comment="):]
    assert tag == f"gapsweep:{_path_key(out / 'test_theory.h5')}"
    if spelling == "dotdot":
        other = "./x/../out"  # relative to cwd = tmp_path
    elif spelling == "symlink":
        other = tmp_path / "link"
        other.symlink_to(out)
    else:  # the store exists (a first run) and a hard link of it sits in another folder
        (out / "test_theory.h5").write_bytes(b"store")
        p = _submit(fake, tmp_path, "--shards", "2", out=out, FAKE_QUEUE="")  # its jobs now carry the identity
        assert p.returncode == 0, p.stderr
        tag = next(a for a in _calls(fake)[-1] if a.startswith("--comment="))[len("--comment="):]
        assert tag.count(":") == 2, tag
        other = tmp_path / "y"
        other.mkdir()
        os.link(out / "test_theory.h5", other / "test_theory.h5")
    before = len(_calls(fake))
    queue = f"2001_[0-1]|{tag}|PENDING\\n2002|{tag}|PENDING\\n"
    p = _submit(fake, tmp_path, "--shards", "2", out=other, FAKE_QUEUE=queue)
    assert p.returncode == 1 and "2001_[0-1], 2002" in p.stderr and "--force" in p.stderr, p.stderr
    assert len(_calls(fake)) == before


def test_squeue_failing_refuses_unless_force(tmp_path, fake):
    """squeue fails (the controller does not answer): nothing is submitted, the message says why and names
    --force; the old guard took the failure for "0 queued" and submitted. --force submits; --dry-run notes it."""
    p = _submit(fake, tmp_path, "--shards", "2", FAKE_SQUEUE_FAIL="1")
    assert p.returncode == 1 and "squeue failed" in p.stderr and "Socket timed out" in p.stderr, p.stderr
    assert "nothing was submitted" in p.stderr and "--force" in p.stderr
    assert not (fake / "count").exists() and "Traceback" not in p.stderr
    p = _submit(fake, tmp_path, "--shards", "2", "--dry-run", FAKE_SQUEUE_FAIL="1")
    assert p.returncode == 0 and "not checked" in p.stdout, p.stdout + p.stderr
    p = _submit(fake, tmp_path, "--shards", "2", "--force", FAKE_SQUEUE_FAIL="1")
    assert p.returncode == 0, p.stderr
    assert len(_calls(fake)) == 2  # the array and the merge


def _slurm_filename(pattern: str, job: str, task: str = "0") -> str:
    """What Slurm makes of an --output pattern (its filename patterns: %% a literal %, %j / %A the job id,
    %a the array index), written here from the sbatch manual, independently of gapsweep."""
    import re

    table = {"%": "%", "j": job, "A": job, "a": task}
    return re.sub(r"%(.)", lambda m: table.get(m.group(1), m.group(0)), pattern)


@pytest.mark.parametrize("how", [["--shards", "2"], ["--mpi", "2"]])
def test_logs_in_a_percent_folder_one_per_submission_appended_per_attempt(tmp_path, fake, how):
    """An output folder with a % in its name: every job's log lands in that folder (sbatch's %% for the literal
    %; the old --output put "%j" of "r%jun" through as a pattern); a resubmission's logs are new files (the job
    id in the name) and a requeued attempt (same id) appends (--open-mode=append) instead of truncating."""
    out = tmp_path / "r%jun"
    logs = []
    for _ in range(2):
        p = _submit(fake, tmp_path, *how, "--force", out=out)
        assert p.returncode == 0, p.stderr
    calls = _calls(fake)
    for k, c in enumerate(calls):
        assert "--open-mode=append" in c, c
        job = str(1000 + k + 1)  # the fake sbatch's answer to its (k+1)-th call
        pat = next(a for a in c if a.startswith("--output="))[len("--output="):]
        log = Path(_slurm_filename(pat, job, "1"))
        assert log.parent == out, (pat, log)
        logs.append(log.name)
    assert len(set(logs)) == len(logs), logs  # no two jobs of the two submissions share a log


def _venv_bin(tmp_path: Path, mpiexec: str | None) -> Path:
    d = tmp_path / "venv" / "bin"
    d.mkdir(parents=True)
    (d / "python").symlink_to(sys.executable)
    if mpiexec is not None:
        (d / "mpiexec").write_text(mpiexec)
        (d / "mpiexec").chmod(0o755)
    return d


def test_mpi_uses_the_venvs_own_mpiexec(tmp_path, fake, monkeypatch):
    """``.venv/bin/gapsweep submit --mpi 2`` without the venv on PATH: the jobs get the mpiexec beside the
    interpreter (GAPSWEEP_MPIEXEC, which mpi_job.sbatch launches), not the first one on PATH."""
    venv = _venv_bin(tmp_path, "#!/bin/sh\necho 'HYDRA build details:'\n")
    monkeypatch.setattr(sys, "executable", str(venv / "python"))
    monkeypatch.setenv("PATH", f"{fake}:{os.environ['PATH']}")
    monkeypatch.delenv("GAPSWEEP_LAUNCHER", raising=False)
    sub = slurm.submit(JOB, tmp_path / "out", mpi=2, dry_run=True)
    assert sub.env["GAPSWEEP_MPIEXEC"] == str(venv / "mpiexec")
    text = sub.dry_run_text()
    assert f"GAPSWEEP_MPIEXEC={venv / 'mpiexec'}" in text
    assert "${GAPSWEEP_MPIEXEC:-mpiexec} -n" in text  # the job script launches it


def test_mpi_launcher_of_another_mpi_refused_naming_both(tmp_path, fake, monkeypatch):
    """No mpiexec beside the interpreter and the one on PATH is MPICH's while mpi4py was built with another
    MPI: refused before anything is queued, naming both and what to do (the old submit queued a job whose
    ranks failed to start, PMIx exit 16)."""
    pytest.importorskip("mpi4py")
    lib = slurm._mpi4py_library()
    if lib is None or slurm._vendor(lib) in (None, "MPICH"):
        pytest.skip(f"needs mpi4py built with an MPI other than MPICH, has: {lib}")
    (fake / "mpiexec").write_text("#!/bin/sh\nprintf 'HYDRA build details:\\n    Version: 4.1.2\\n'\n")
    (fake / "mpiexec").chmod(0o755)
    if (Path(sys.executable).parent / "mpiexec").exists():
        pytest.skip("this interpreter's venv has its own mpiexec (then that one is taken)")
    monkeypatch.setenv("PATH", f"{fake}:{os.environ['PATH']}")
    monkeypatch.setenv("SB_DIR", str(fake))
    monkeypatch.delenv("GAPSWEEP_LAUNCHER", raising=False)
    monkeypatch.delenv("GAPSWEEP_SETUP", raising=False)
    with pytest.raises(slurm.SubmitError) as e:
        slurm.submit(JOB, tmp_path / "out", mpi=2)
    msg = str(e.value)
    assert str(fake / "mpiexec") in msg and "MPICH" in msg and slurm._vendor(lib) in msg, msg
    assert "GAPSWEEP_LAUNCHER" in msg and not (fake / "count").exists()
