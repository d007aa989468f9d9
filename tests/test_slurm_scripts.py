"""The Slurm scripts without a Slurm cluster (issue 19 item 13): ``submit.sh`` against a stand-in ``sbatch``
that records its arguments (site options, the merge's dependency), and ``merge_job.sbatch`` run by bash as
Slurm would run it (missing and unfinished shards named, exit 1; the site's setup hook run first).
tests/test_slurm.py runs the same scripts on a real single-node Slurm where one is installed."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from gapsweep import store

ROOT = Path(__file__).resolve().parent.parent
JOB = ROOT / "jobs" / "test_theory.toml"
GS = f"{sys.executable} -m gapsweep"

FAKE_SBATCH = """#!/bin/bash
n=$(( $(cat "$SB_DIR/count" 2>/dev/null || echo 0) + 1 ))
echo "$n" > "$SB_DIR/count"
printf '%s\\n' "$@" > "$SB_DIR/call$n.args"
echo "${GAPSWEEP_SETUP:-}" > "$SB_DIR/call$n.setup"
echo "$((1000 + n));cluster"
"""


def _env(**kw: str) -> dict[str, str]:
    e = {k: v for k, v in os.environ.items() if not k.startswith(("GAPSWEEP_", "SLURM_"))}
    from tests.hooks.gapsweep_test_hooks import pythonpath

    e.update(PYTHONPATH=pythonpath(str(ROOT)), GAPSWEEP=GS, **kw)  # with the fault injection of tests/hooks
    return e


@pytest.fixture
def sbatch(tmp_path):
    d = tmp_path / "sb"
    d.mkdir()
    (d / "sbatch").write_text(FAKE_SBATCH)
    (d / "sbatch").chmod(0o755)
    (d / "squeue").write_text("#!/bin/bash\nexit 0\n")  # an empty queue (submit refuses when squeue cannot answer)
    (d / "squeue").chmod(0o755)
    return d


def _calls(d: Path) -> list[list[str]]:
    return [(d / f"call{i}.args").read_text().split("\n")[:-1] for i in (1, 2) if (d / f"call{i}.args").exists()]


@pytest.mark.parametrize("how", ["options", "environment"])
def test_submit_site_options_and_afterany(tmp_path, sbatch, how):
    """Account, partition, memory, time limits and the setup hook reach sbatch (options or environment); the
    merge is chained with afterany and --kill-on-invalid-dep=yes, never afterok (which waits forever once a
    shard fails). The old script took exactly four arguments and chained with afterok."""
    site = {"account": "phys123", "partition": "short", "mem": "4G", "time": "01:00:00", "merge-time": "00:10:00",
            "setup": "echo hook"}
    args, kw = [], {}
    if how == "options":
        for k, v in site.items():
            args += [f"--{k}", v]
    else:
        kw = {f"GAPSWEEP_{k.upper().replace('-', '_')}": v for k, v in site.items()}
    env = _env(SB_DIR=str(sbatch), PATH=f"{sbatch}:{os.environ['PATH']}", **kw)
    p = subprocess.run(["bash", str(ROOT / "slurm" / "submit.sh"), str(JOB), str(tmp_path / "out"), "--shards",
                        "3", *args], env=env, capture_output=True, text=True, timeout=120, cwd=tmp_path)
    assert p.returncode == 0, p.stderr
    assert p.stdout.split() == ["array", "1001", "merge", "1002", "store", f"{tmp_path}/out/test_theory.h5"]
    array, merge = _calls(sbatch)
    for call in (array, merge):
        assert {"--account=phys123", "--partition=short", "--mem=4G"} <= set(call), call
    assert "--time=01:00:00" in array and "--array=0-2" in array and array[-3].endswith("array_job.sbatch")
    assert "--time=00:10:00" in merge and "--dependency=afterany:1001" in merge
    assert "--kill-on-invalid-dep=yes" in merge and not any("afterok" in a for a in merge)
    assert merge[-3:] == [f"{tmp_path}/out/test_theory.shard{{i}}.h5", "3", f"{tmp_path}/out/test_theory.h5"]
    assert (sbatch / "call1.setup").read_text().strip() == "echo hook"  # the jobs inherit the hook


def test_submit_defaults_and_bad_option(tmp_path, sbatch):
    """Nothing site-specific given: no --account/--partition/--mem/--time (the cluster's defaults and the
    scripts' #SBATCH lines apply); an unknown option is refused naming the allowed ones, nothing submitted."""
    env = _env(SB_DIR=str(sbatch), PATH=f"{sbatch}:{os.environ['PATH']}")
    p = subprocess.run(["bash", str(ROOT / "slurm" / "submit.sh"), str(JOB), str(tmp_path / "o"), "--mpi", "2"],
                       env=env, capture_output=True, text=True, timeout=120, cwd=tmp_path)
    assert p.returncode == 0, p.stderr
    (call,) = _calls(sbatch)
    assert not [a for a in call if a.startswith(("--account", "--partition", "--mem", "--time"))], call
    assert "--ntasks=2" in call
    p = subprocess.run(["bash", str(ROOT / "slurm" / "submit.sh"), str(JOB), str(tmp_path / "o"), "--mpi", "2",
                        "--acount", "x"], env=env, capture_output=True, text=True, timeout=60, cwd=tmp_path)
    assert p.returncode == 2 and "--acount" in p.stderr and "--account" in p.stderr
    assert len(_calls(sbatch)) == 1


def _shard_args(tmp_path: Path, i: int) -> list[str]:
    return ["run", str(JOB), "--store", str(tmp_path / "s{i}.h5"), "--shard", f"{i}/3", "--mpi", "off", "--progress",
            "none", "--resume"]


def _shard(tmp_path: Path, i: int, **kw: str) -> subprocess.CompletedProcess:
    """A shard's run as a child process (the fault hooks of tests/hooks act there only)."""
    return subprocess.run([sys.executable, "-m", "gapsweep", *_shard_args(tmp_path, i)], env=_env(**kw),
                          capture_output=True, text=True, timeout=120)


def _shard_here(tmp_path: Path, i: int) -> int:
    """The same run by ``cli.main`` in this process (no fault hook, no process boundary under test): its exit
    code."""
    from gapsweep import cli

    return cli.main(_shard_args(tmp_path, i))


def test_merge_job_names_missing_and_unfinished_shards(tmp_path):
    """Run as Slurm runs it after afterany: shard 0 finished, shard 1 stopped by a write error (pending tasks),
    shard 2 never ran. The merge job merges what exists, names shard 1 (pending, how its run ended) and shard 2
    (missing), exits 1; the setup hook ran first. After the two shards are resubmitted it exits 0 and the
    merged store equals a single run. (The old job exited 0 with pending shards and failed on a missing one
    with the merge's bare error.)"""
    from gapsweep import runner

    ref = tmp_path / "ref.h5"  # a single run, in this process (a reference, not under test)
    runner.run(JOB, ref, progress="none", mpi="off")
    assert _shard_here(tmp_path, 0) == 0
    assert _shard(tmp_path, 1, GAPSWEEP_TEST_WRITE_ERROR="3").returncode == 1
    cmd = ["bash", str(ROOT / "slurm" / "merge_job.sbatch"), "s{i}.h5", "3", "m.h5"]
    env = _env(SLURM_SUBMIT_DIR=str(tmp_path), GAPSWEEP_SETUP="echo setup-hook-ran; unset NOPE_$NOPE")
    p = subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=120, cwd="/")
    assert p.returncode == 1, p.stdout + p.stderr
    assert "setup-hook-ran" in p.stdout
    err = p.stderr
    assert "2 of 3 shard(s) missing or unfinished" in err, err
    assert "shard 1 (s1.h5): store s1.h5:" in err and "tasks pending; its last run never finished" in err
    assert "shard 2 (s2.h5): missing" in err and "shard 0" not in err
    done0 = (store.read(tmp_path / "s0.h5").status == "done").sum()
    assert done0 > 0 and (store.read(tmp_path / "m.h5").status == "done").sum() >= done0
    assert _shard_here(tmp_path, 1) == 0 and _shard_here(tmp_path, 2) == 0
    p = subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=120, cwd="/")
    assert p.returncode == 0, p.stderr
    assert store.diff(tmp_path / "m.h5", ref) == []
