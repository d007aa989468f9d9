"""The Slurm scripts and ``gapsweep submit`` on a real single-node Slurm cluster (recipe in docs/running.md:
slurmctld + slurmd + munge, brought up here in a temporary directory; skipped unless slurmctld/slurmd/munged are
installed and we are root): a 3-shard array job plus the merge job chained with afterany equals a single-run
store; so does an MPI job; a job that reaches its time limit is requeued and completes with nothing lost, the
merge waiting for its last attempt; arrays are throttled (%K) and split at the cluster's MaxArraySize (4 here);
a second submission of a store is refused.

The cluster is configured with ``MaxArraySize=4`` and ``AuthInfo=cred_expire=10``: Slurm holds a requeued job
for ``cred_expire`` seconds (default 120) before it may start again; 10 keeps the requeue test short. When that
hold ends nothing in the cluster changes, so no event starts a scheduling pass: the job waited for the main
scheduler's periodic pass (every ``sched_interval`` s, default 60) or a backfill pass (``bf_interval``, default 30,
and only after a change), 29-42 s of the test's 89-104 s. ``SchedulerParameters=sched_interval=2,bf_interval=2``
starts it within about 2 s of the hold's end, and the other tests' jobs as soon (a pass costs nothing here)."""

from __future__ import annotations

import json
import os
import shutil
import signal
import socket
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
MaxArraySize=4
AuthInfo=cred_expire=10
SchedulerParameters=sched_interval=2,bf_interval=2
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


def _free_ports(n: int) -> list[int]:
    """``n`` distinct TCP ports free on this machine now: each test run's controller and node daemon listen on
    their own, so that test runs side by side on one machine (three root rounds at once, issue 40) do not talk to
    each other's cluster (fixed ports made the second run's sbatch reach the first run's controller, and the first
    run's teardown cut the others off)."""
    socks = []
    try:
        for _ in range(n):
            s = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
            s.bind(("127.0.0.1", 0))
            socks.append(s)
        return [s.getsockname()[1] for s in socks]
    finally:
        for s in socks:
            s.close()


@pytest.fixture(scope="module")
def cluster(tmp_path_factory):
    d = tmp_path_factory.mktemp("slurm")
    for sub in ("state", "spool"):
        (d / sub).mkdir()
    if not _munge_ok():
        Path("/run/munge").mkdir(parents=True, exist_ok=True)
        shutil.chown("/run/munge", "munge", "munge")
        # not checked: a test run beside this one may have started it a moment ago (then this start fails)
        subprocess.run(["runuser", "-u", "munge", "--", "munged"], timeout=30, capture_output=True)
        for _ in range(50):
            if _munge_ok():
                break
            time.sleep(0.1)
    conf = d / "slurm.conf"
    port, port2 = _free_ports(2)
    conf.write_text(CONF.format(d=d, cpus=os.cpu_count() or 2, port=port, port2=port2))
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
        # munged, if this fixture started it, stays: it is the machine's one authentication daemon, and another
        # test run's cluster may be using it now (stopping it cut that run off)


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
    log = (out / f"test_mixed.merge-{merge_id}.out").read_text()  # a log per job (issue 40)
    assert "site-hook" in log
    assert "2 of 2 shard(s) missing or unfinished" in log and "shard 0" in log and "shard 1" in log, log


# test_theory.toml without the discrete form: 24 tasks of one cost, results independent of the split
FLAT = JOB.parent.joinpath("test_theory.toml").read_text().replace(
    'forms = ["paper", "continuum", "discrete"]', 'forms = ["paper", "continuum"]').replace("\nn = 64\n", "\n")


def _submit(env, job, out, *args, cwd):
    return subprocess.run([*_gapsweep().split(), "submit", str(job), str(out), *args], env=env,
                          capture_output=True, text=True, timeout=120, cwd=cwd)


def _ids(stdout: str) -> list[str]:
    w = stdout.split()
    return [*w[w.index("array") + 1].split(","), w[w.index("merge") + 1]]


@pytest.mark.slow
def test_time_limit_requeue_completes_nothing_lost(cluster, tmp_path):
    """One shard of 24 tasks of ~2.2 s (53 s of work) under a 1-minute limit, warned 20 s before it: the run
    stops cleanly at the warning and the job requeues itself (same job id), resuming the store, until it is
    done; the merge (afterany) runs only after the last attempt, and the merged store equals a single run."""
    job = tmp_path / "flat.toml"
    job.write_text(FLAT)
    ref = tmp_path / "ref.h5"
    runner.run(job, ref, progress="none", mpi="off")
    env = dict(cluster, GAPSWEEP=_gapsweep(), GAPSWEEP_TEST_DELAY="2.2")
    out = tmp_path / "out"
    p = _submit(env, job, out, "--shards", "1", "--time", "1", "--signal-lead", "20", cwd=tmp_path)
    assert p.returncode == 0, p.stdout + p.stderr
    ids = _ids(p.stdout)
    _wait(env, ids, timeout=240)
    logs = "\n".join(f"{f.name}:\n{f.read_text()}" for f in sorted(out.glob("*.out")))
    rec = json.loads((out / "flat.shard0.h5.requeue").read_text())
    assert rec["job"] == ids[0] and rec["requeues"] >= 1, logs
    runs = json.loads(store.read_attrs(out / "flat.shard0.h5")["runs"])
    assert len(runs) == rec["requeues"] + 1 and all(r.get("interrupted") == "SIGTERM" for r in runs[:-1]), runs
    assert runs[-1].get("finished"), runs
    assert store.diff(out / "flat.h5", ref) == [], logs
    assert "merged 1 shard(s)" in logs and "incomplete" not in logs, logs


def _scontrol_job(env, jid: str) -> str:
    return subprocess.run(["scontrol", "show", "job", jid], env=env, capture_output=True, text=True,
                          timeout=20).stdout


def test_throttle_split_and_second_submission_refused(cluster, tmp_path):
    """Held (SBATCH_ARGS=--hold): 6 shards at MaxArraySize 4 are two arrays (0-3 and 0-1, every index below 4),
    each throttled to 2 running (ArrayTaskThrottle=2, %2 in squeue); the merge depends on both. A second
    submission for the same store is refused naming the queued jobs. Released, the shards (offsets 0 and 4 of
    6) run and the merge equals a single run."""
    job = tmp_path / "flat.toml"
    job.write_text(FLAT)
    ref = tmp_path / "ref.h5"
    runner.run(job, ref, progress="none", mpi="off")
    env = dict(cluster, GAPSWEEP=_gapsweep(), SBATCH_ARGS="--hold")
    out = tmp_path / "out"
    p = _submit(env, job, out, "--shards", "6", "--max-running", "2", cwd=tmp_path)
    assert p.returncode == 0, p.stdout + p.stderr
    ids = _ids(p.stdout)
    try:
        assert len(ids) == 3
        a0, a1, merge_id = ids
        for a, last in ((a0, 3), (a1, 1)):
            info = _scontrol_job(env, a)
            assert "ArrayTaskThrottle=2" in info, info
            assert f"ArrayTaskId=0-{last}%2" in info or f"ArrayTaskId=0-{last}" in info, info
        q = subprocess.run(["squeue", "-h", "-o", "%i", "-j", f"{a0},{a1}"], env=env, capture_output=True,
                           text=True, timeout=20).stdout
        assert f"{a0}_[0-3%2]" in q and f"{a1}_[0-1%2]" in q, q
        assert f"afterany:{a0}" in _scontrol_job(env, merge_id) and f"{a1}" in _scontrol_job(env, merge_id)
        p2 = _submit(env, job, out, "--shards", "6", cwd=tmp_path)
        assert p2.returncode == 1 and "queued or running already" in p2.stderr, p2.stderr
        for jid in ids:
            assert jid in p2.stderr or f"{jid}_" in p2.stderr, p2.stderr
    except BaseException:
        subprocess.run(["scancel", *ids], env=env, timeout=20)
        raise
    subprocess.run(["scontrol", "release", ",".join(ids)], env=env, check=True, timeout=20)
    _wait(env, ids, timeout=240)
    logs = "\n".join(f"{f.name}:\n{f.read_text()}" for f in sorted(out.glob("*.out")))
    shards = sorted(f.name for f in out.glob("flat.shard*.h5"))
    assert shards == [f"flat.shard{i}.h5" for i in range(6)], logs
    assert [store.read_attrs(out / f"flat.shard{i}.h5")["shard"] for i in range(6)] == [f"{i}/6" for i in range(6)]
    assert store.diff(out / "flat.h5", ref) == [], logs
