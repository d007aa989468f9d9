"""The Slurm scripts on a real single-node Slurm cluster (recipe in docs/running.md:
slurmctld + slurmd + munge, brought up
here in a temporary directory; skipped unless slurmctld/slurmd/munged are installed and we are root): a 3-shard
array job plus the merge job chained with --dependency=afterok equals a single-run store; so does an MPI job."""

from __future__ import annotations

import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from gapsweep import runner, store

ROOT = Path(__file__).resolve().parent.parent
JOB = ROOT / "jobs" / "test_mixed.toml"
NEEDED = ("slurmctld", "slurmd", "munged", "sbatch", "squeue", "sinfo")

pytestmark = [
    pytest.mark.slurm,
    pytest.mark.skipif(any(shutil.which(x) is None for x in NEEDED), reason="Slurm/munge not installed"),
    pytest.mark.skipif(not hasattr(os, "geteuid") or os.geteuid() != 0, reason="a local Slurm needs root"),
]

CONF = """ClusterName=gapsweeptest
SlurmctldHost=localhost
SlurmctldPort={port}
SlurmdPort={port2}
AuthType=auth/munge
ProctrackType=proctrack/linuxproc
TaskPlugin=task/none
SelectType=select/cons_tres
SelectTypeParameters=CR_Core
SlurmUser=root
SlurmdUser=root
StateSaveLocation={d}/state
SlurmdSpoolDir={d}/spool
SlurmctldPidFile={d}/slurmctld.pid
SlurmdPidFile={d}/slurmd.pid
SlurmctldLogFile={d}/slurmctld.log
SlurmdLogFile={d}/slurmd.log
ReturnToService=2
MpiDefault=none
JobAcctGatherType=jobacct_gather/none
NodeName=localhost CPUs={cpus} RealMemory=2000 State=UNKNOWN
PartitionName=debug Nodes=localhost Default=YES MaxTime=INFINITE State=UP
"""


def _munge_ok() -> bool:
    try:
        m = subprocess.run("munge -n | unmunge", shell=True, capture_output=True, timeout=10)
    except (OSError, subprocess.SubprocessError):
        return False
    return m.returncode == 0


def _stop(pidfile: Path) -> None:
    if pidfile.exists():
        try:
            pid = int(pidfile.read_text().strip())
            os.kill(pid, signal.SIGTERM)
            for _ in range(50):
                os.kill(pid, 0)
                time.sleep(0.1)
        except (ProcessLookupError, ValueError):
            pass


@pytest.fixture(scope="module")
def cluster(tmp_path_factory):
    d = tmp_path_factory.mktemp("slurm")
    for sub in ("state", "spool"):
        (d / sub).mkdir()
    started_munge = False
    if not _munge_ok():
        Path("/run/munge").mkdir(parents=True, exist_ok=True)
        shutil.chown("/run/munge", "munge", "munge")
        subprocess.run(["runuser", "-u", "munge", "--", "munged"], check=True, timeout=30)
        started_munge = True
        for _ in range(50):
            if _munge_ok():
                break
            time.sleep(0.1)
    conf = d / "slurm.conf"
    conf.write_text(CONF.format(d=d, cpus=os.cpu_count() or 2, port=16817, port2=16818))
    env = dict(os.environ, SLURM_CONF=str(conf))
    subprocess.run(["slurmctld", "-i"], env=env, check=True, timeout=30)
    subprocess.run(["slurmd", "-N", "localhost"], env=env, check=True, timeout=30)
    try:
        t0 = time.monotonic()
        while time.monotonic() - t0 < 60:
            s = subprocess.run(["sinfo", "-h", "-o", "%T"], env=env, capture_output=True, text=True, timeout=20)
            if s.stdout.strip() == "idle":
                break
            time.sleep(0.5)
        else:
            pytest.fail(f"Slurm node not idle: {s.stdout} {s.stderr}\n" + (d / "slurmctld.log").read_text()[-2000:])
        yield env
    finally:
        _stop(d / "slurmd.pid")
        _stop(d / "slurmctld.pid")
        if started_munge:
            _stop(Path("/run/munge/munged.pid"))


def _gapsweep() -> str:
    exe = Path(sys.executable).parent / "gapsweep"
    return str(exe) if exe.exists() else f"{sys.executable} -m gapsweep"


def _wait(env, ids: list[str], timeout: float = 240) -> None:
    t0 = time.monotonic()
    while time.monotonic() - t0 < timeout:
        q = subprocess.run(["squeue", "-h", "-j", ",".join(ids), "-o", "%i %T"], env=env, capture_output=True,
                           text=True, timeout=20)
        if q.returncode == 0 and not q.stdout.strip():
            return
        time.sleep(1)
    pytest.fail(f"Slurm jobs {ids} did not finish in {timeout} s")


@pytest.fixture(scope="module")
def single(tmp_path_factory):
    path = tmp_path_factory.mktemp("slurmref") / "single.h5"
    runner.run(JOB, path, progress="none", mpi="off")
    return path


def test_array_shards_and_chained_merge(cluster, single, tmp_path):
    env = dict(cluster, GAPSWEEP=_gapsweep())
    out = tmp_path / "out"
    p = subprocess.run(["bash", str(ROOT / "slurm" / "submit.sh"), str(JOB), str(out), "--shards", "3"],
                       env=env, capture_output=True, text=True, timeout=60, cwd=tmp_path)
    assert p.returncode == 0, p.stdout + p.stderr
    words = p.stdout.split()
    array_id, merge_id = words[words.index("array") + 1], words[words.index("merge") + 1]
    _wait(env, [array_id, merge_id])
    merged = out / "test_mixed.h5"
    logs = "\n".join(f.read_text() for f in sorted(out.glob("*.out")))
    assert merged.exists(), logs
    assert sorted(f.name for f in out.glob("*.shard*.h5")) == [f"test_mixed.shard{i}.h5" for i in range(3)]
    assert all(store.read_attrs(out / f"test_mixed.shard{i}.h5")["shard"] == f"{i}/3" for i in range(3))
    assert store.diff(merged, single) == [], logs
    assert "pending" in logs and "merged 3 shard(s)" in logs


@pytest.mark.skipif(shutil.which("mpiexec") is None, reason="mpiexec not installed")
def test_mpi_job(cluster, single, tmp_path):
    env = dict(cluster, GAPSWEEP=_gapsweep(), OMPI_ALLOW_RUN_AS_ROOT="1", OMPI_ALLOW_RUN_AS_ROOT_CONFIRM="1",
               OMPI_MCA_rmaps_base_oversubscribe="1")
    out = tmp_path / "out"
    p = subprocess.run(["bash", str(ROOT / "slurm" / "submit.sh"), str(JOB), str(out), "--mpi", "2"],
                       env=env, capture_output=True, text=True, timeout=60, cwd=tmp_path)
    assert p.returncode == 0, p.stdout + p.stderr
    words = p.stdout.split()
    _wait(env, [words[words.index("mpi") + 1]])
    logs = "\n".join(f.read_text() for f in sorted(out.glob("*.out")))
    assert (out / "test_mixed.h5").exists(), logs
    assert store.diff(out / "test_mixed.h5", single) == [], logs
    assert '"mpi_size": 2' in store.read_attrs(out / "test_mixed.h5")["runs"]


def test_failed_shards_merge_runs_and_names_them(cluster, tmp_path):
    """Issue 19 item 13: every shard fails (a write error injected through the submitted environment). The
    merge, chained with afterany, still runs -- nothing stays queued (afterok waited forever) -- and its log
    names the unfinished shards; the site options and the setup hook are accepted by a real sbatch."""
    from tests.hooks.gapsweep_test_hooks import pythonpath

    env = dict(cluster, GAPSWEEP=_gapsweep(), GAPSWEEP_TEST_WRITE_ERROR="3", GAPSWEEP_SETUP="echo site-hook",
               PYTHONPATH=pythonpath(os.pathsep.join([str(ROOT), cluster.get("PYTHONPATH", "")])),
               GAPSWEEP_PARTITION="debug", GAPSWEEP_TIME="00:20:00", GAPSWEEP_MERGE_TIME="00:05:00")
    out = tmp_path / "out"
    p = subprocess.run(["bash", str(ROOT / "slurm" / "submit.sh"), str(JOB), str(out), "--shards", "2",
                        "--mem", "500M"], env=env, capture_output=True, text=True, timeout=60, cwd=tmp_path)
    assert p.returncode == 0, p.stdout + p.stderr
    words = p.stdout.split()
    array_id, merge_id = words[words.index("array") + 1], words[words.index("merge") + 1]
    _wait(env, [array_id, merge_id])
    log = (out / "test_mixed.merge.out").read_text()
    assert "site-hook" in log
    assert "2 of 2 shard(s) missing or unfinished" in log and "shard 0" in log and "shard 1" in log, log
