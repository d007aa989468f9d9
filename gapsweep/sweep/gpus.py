"""Which GPU a rank of a sweep uses (docs/running.md, "GPUs"): several ranks per GPU under CUDA MPS by default,
the MPS daemon started and stopped by gapsweep itself where it may; one rank per GPU without MPS.

Policy. The ranks of a node that work (the coordinator, world rank 0, is left out when it does not work) are
numbered ``r = 0, 1, ...`` in node-local order; with ``G`` visible GPUs and ``K`` ranks allowed per GPU, working
rank ``r`` uses GPU ``r mod G`` if ``r < K G``, else none (it works CPU units: theory, Fokker-Planck, CPU GFMD).
``K`` is ``--ranks-per-gpu`` when given; by default (:func:`auto_per_gpu`) ``K = min(K_G, W // G, 48 // G)`` with
``W`` the working ranks of the node and ``K_G`` the measured best (:data:`MEASURED_PER_GPU`, else
:data:`DEFAULT_PER_GPU`: 8 per GPU on any number of GPUs) -- when CUDA MPS is usable (:func:`place`): an MPS
daemon this process can reach already runs, or none runs and ``nvidia-cuda-mps-control`` is on the PATH, in which
case node-local rank 0 starts one with its own pipe and log folders in a temporary folder (``CUDA_MPS_PIPE_DIRECTORY``,
``CUDA_MPS_LOG_DIRECTORY``, checked with one client in a separate process, told to every rank of the node before
any of them touches CUDA) and a watcher process
stops it (``quit``) and removes the folder once every rank of the node has exited -- also after a crash or a
kill. Otherwise ``K = 1`` and the log says why. 48 is the clients one MPS server admitted on a 4-GPU node (issue
26). A process outside MPI (serial runs, ``--shard`` processes) is working rank 0 of its node: start one per GPU
with ``CUDA_VISIBLE_DEVICES=i`` (benchmarks/bench_multi_gpu.py does).

Visible GPUs: ``CUDA_VISIBLE_DEVICES`` when set (its entries; ``""`` or ``-1``: none), else ``nvidia-smi -L``
(no nvidia-smi: none). The tests replace :func:`visible_count` to try the policy on machines without GPUs
(tests/hooks). Under MPI one rank per node looks and tells the others: start-up does not grow with the rank count.

No function here but :func:`select` creates a CUDA context or imports cupy: the coordinator and the CPU ranks never
touch a GPU. A GPU rank calls :func:`select` first, before any other CUDA call, so that its GPU is the current
device: cupy's ``with Device(i)`` sets the previous device back on exit, and since CUDA 12 setting a device opens
its context -- a GPU rank whose current device was still 0 opened a context on GPU 0 (issue 38: ~520 MiB on GPU 0
per GPU worker of GPUs 1-3 in SDE jobs). The memory of the GPUs (``memory``, for the checks of ``plan`` and
``run``) and their names come from ``nvidia-smi --query-gpu``, a separate process that opens no context in this one.
"""

from __future__ import annotations

import logging
import os
import shutil
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

__all__ = ["DEFAULT_PER_GPU", "MEASURED_PER_GPU", "MPS_CLIENTS", "Layout", "Mps", "Placement", "assign",
           "auto_per_gpu", "layout", "memory", "mps_processes", "place", "query", "rank_gpu", "select", "start_mps",
           "visible_count"]

log = logging.getLogger(__name__)

DEFAULT_PER_GPU = 8  # ranks per GPU under MPS by default where MEASURED_PER_GPU has no entry
# The best ranks per GPU measured for a GPU count where it differs from DEFAULT_PER_GPU (issue 38, jobs/pub on H200).
# With the surfaces made on the GPU and one farm for the launch, one GPU ran pub in 43.4 s with 8 per GPU against
# 53.8 s with 15 (benchmarks/results/farm/issue38/one_gpu_probe.json; 16 had been best with the surfaces made on
# the host, 53.0 s against 63.2 s: gpu_node_issue38_bb77f13.json); on two and four GPUs 8 was best there too.
MEASURED_PER_GPU: dict[int, int] = {}
_SMALL_GPU = 8e9  # bytes every GPU that runs MPS clients here is taken to hold (an H200: 141 GiB)
MPS_CLIENTS = 48  # clients one MPS server admits on a node (issue 26: 64 clients met "Maximum number of clients")


def visible_count() -> int:
    """Number of GPUs this process may use (see the module docstring)."""
    vis = os.environ.get("CUDA_VISIBLE_DEVICES")
    if vis is not None:
        return len([x for x in vis.split(",") if x.strip() and x.strip() != "-1"])
    if not shutil.which("nvidia-smi"):
        return 0
    try:
        out = subprocess.run(["nvidia-smi", "-L"], capture_output=True, text=True, timeout=20).stdout
    except (OSError, subprocess.SubprocessError):
        return 0
    return sum(1 for line in out.splitlines() if line.startswith("GPU "))


def _visible_ids() -> list[str] | None:
    """The entries of ``CUDA_VISIBLE_DEVICES`` (None: unset, every GPU of the node is visible)."""
    vis = os.environ.get("CUDA_VISIBLE_DEVICES")
    if vis is None:
        return None
    return [x.strip() for x in vis.split(",") if x.strip() and x.strip() != "-1"]


def query() -> list[dict[str, Any]]:
    """The visible GPUs as ``nvidia-smi --query-gpu`` reports them: ``index``, ``uuid``, ``name`` and
    ``memory`` [bytes], in the order CUDA numbers them in this process (``CUDA_VISIBLE_DEVICES`` by index or
    UUID). Empty without nvidia-smi (or when it fails). Creates no CUDA context."""
    if not shutil.which("nvidia-smi"):
        return []
    try:
        out = subprocess.run(["nvidia-smi", "--query-gpu=index,uuid,name,memory.total",
                              "--format=csv,noheader,nounits"], capture_output=True, text=True, timeout=20).stdout
    except (OSError, subprocess.SubprocessError):
        return []
    gpus = []
    for line in out.splitlines():
        parts = [x.strip() for x in line.split(",")]
        if len(parts) == 4 and parts[0].isdigit():
            try:
                mem = int(float(parts[3]) * 2**20)  # MiB
            except ValueError:
                mem = 0
            gpus.append({"index": parts[0], "uuid": parts[1], "name": parts[2], "memory": mem})
    ids = _visible_ids()
    if ids is None:
        return gpus
    by = {g["index"]: g for g in gpus} | {g["uuid"]: g for g in gpus}
    return [by[i] for i in ids if i in by]


def memory() -> int:
    """Memory of the smallest visible GPU [bytes] (0: unknown -- no nvidia-smi, or no GPU). No CUDA context."""
    return min((g["memory"] for g in query() if g["memory"]), default=0)


def assign(working_rank: int | None, n_gpus: int, per_gpu: int = 1) -> int | None:
    """GPU index of node-local working rank ``working_rank`` (None: a rank that does not work) with ``n_gpus``
    visible GPUs and at most ``per_gpu`` ranks per GPU; None: this rank works CPU units only."""
    if not isinstance(per_gpu, int) or isinstance(per_gpu, bool) or not 1 <= per_gpu <= MPS_CLIENTS:
        raise ValueError(f"--ranks-per-gpu: expected an integer in [1, {MPS_CLIENTS}] (the clients one MPS server "
                         f"admits), got {per_gpu!r}")
    if working_rank is None or n_gpus <= 0 or working_rank >= n_gpus * per_gpu:
        return None
    return working_rank % n_gpus


def rank_gpu(comm: Any, coordinator_works: bool, per_gpu: int | None = 1) -> int | None:
    """This rank's GPU (collective over ``comm`` when it is not None: every rank must call it); :func:`place`."""
    return place(comm, coordinator_works, per_gpu).gpu


def auto_per_gpu(n_gpus: int, working: int, mps: bool, cap: int = MPS_CLIENTS) -> int:
    """Ranks per GPU by default on a node of ``n_gpus`` GPUs and ``working`` working ranks: ``min(K_G, working //
    n_gpus, 48 // n_gpus, cap)`` under MPS (``K_G``: :data:`MEASURED_PER_GPU`, else :data:`DEFAULT_PER_GPU`;
    ``cap``: what the GPU memory allows), else 1; at least 1."""
    if not mps or n_gpus <= 0:
        return 1
    best = MEASURED_PER_GPU.get(n_gpus, DEFAULT_PER_GPU)
    return max(1, min(best, working // n_gpus, MPS_CLIENTS // n_gpus, cap))


_MPS_NAMES = ("nvidia-cuda-mps-control", "nvidia-cuda-mps-server")


def mps_processes() -> list[int]:
    """Process ids of the MPS control daemons and servers running on this node (any user; from /proc)."""
    out = []
    for d in Path("/proc").glob("[0-9]*"):
        try:
            if (d / "comm").read_text().strip() in {n[:15] for n in _MPS_NAMES}:  # comm: 15 characters at most
                out.append(int(d.name))
        except (OSError, ValueError):
            continue
    return out


def _pipe_dir() -> Path:
    return Path(os.environ.get("CUDA_MPS_PIPE_DIRECTORY") or "/tmp/nvidia-mps")


@dataclass
class Mps:
    """An MPS control daemon gapsweep started: its folder (``pipe``, ``log`` below it) and the watcher that stops
    it. ``stop`` is for callers outside the farm (tests, benchmarks); the farm leaves it to the watcher."""

    folder: Path
    control: str
    watcher: Any = None

    @property
    def env(self) -> dict[str, str]:
        return {"CUDA_MPS_PIPE_DIRECTORY": str(self.folder / "pipe"),
                "CUDA_MPS_LOG_DIRECTORY": str(self.folder / "log")}

    def watch(self, pids: list[int]) -> None:
        """Stop the daemon (``quit``, then remove its folder) once every process of ``pids`` has exited: a
        detached process (its own session, no inherited output), so that it outlives a crash of this one."""
        self.watcher = subprocess.Popen([sys.executable, "-c", _WATCH, self.control, str(self.folder), *map(str, pids)],
                                        env={**os.environ, **self.env}, stdin=subprocess.DEVNULL,
                                        stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True,
                                        close_fds=True)

    def stop(self) -> None:
        """Quit the daemon now and remove its folder (also when ``watch`` was never called)."""
        _quit(self.control, self.folder, {**os.environ, **self.env})


# The watcher: wait until the ranks are gone, then quit the daemon (graceful: it waits for its clients) and clean up.
_WATCH = """
import os, sys, time
control, folder, pids = sys.argv[1], sys.argv[2], [int(p) for p in sys.argv[3:]]
def alive(p):
    try:
        os.kill(p, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    try:  # a zombie (exited, not yet reaped by its parent) is gone for us
        return open(f"/proc/{p}/stat").read().rsplit(")", 1)[1].split()[0] != "Z"
    except OSError:
        return True
while any(alive(p) for p in pids):
    time.sleep(0.1)
import subprocess, shutil
try:
    subprocess.run([control], input="quit\\n", text=True, timeout=120, capture_output=True)
finally:
    shutil.rmtree(folder, ignore_errors=True)
"""


def _quit(control: str, folder: Path, env: dict[str, str]) -> None:
    if not (folder / "pipe" / "control").exists():  # no daemon listens there: nothing to quit
        shutil.rmtree(folder, ignore_errors=True)
        return
    try:
        subprocess.run([control], input="quit\n", text=True, timeout=120, capture_output=True, env=env)
    except (OSError, subprocess.SubprocessError) as e:
        log.warning("MPS: could not stop the daemon of %s: %s", folder, e)
    shutil.rmtree(folder, ignore_errors=True)


def start_mps() -> tuple[Mps | None, str]:
    """Start an MPS control daemon with its own pipe and log folders (a new temporary folder): ``(Mps, "")``, or
    ``(None, why not)`` -- no ``nvidia-cuda-mps-control`` on the PATH, an MPS process already runs that this
    process cannot reach, or the daemon did not start (its folder is removed then)."""
    control = shutil.which("nvidia-cuda-mps-control")
    if not control:
        return None, "no nvidia-cuda-mps-control on the PATH"
    running = mps_processes()
    if running:
        return None, f"an MPS daemon runs (process {running[0]}) whose pipe folder {_pipe_dir()} this run cannot reach"
    folder = Path(tempfile.mkdtemp(prefix="gapsweep-mps-"))
    m = Mps(folder, control)
    for d in ("pipe", "log"):
        (folder / d).mkdir()
    try:
        r = subprocess.run([control, "-d"], env={**os.environ, **m.env}, stdin=subprocess.DEVNULL,
                           stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True, timeout=60)
        ok, why = r.returncode == 0, (r.stderr or "").strip()[:200] or f"exit {r.returncode}"
    except (OSError, subprocess.SubprocessError) as e:
        ok, why = False, str(e)[:200]
    end = time.monotonic() + 10
    while ok and not (folder / "pipe" / "control").exists() and time.monotonic() < end:
        time.sleep(0.02)  # -d returns once the daemon forked; its control pipe follows
    if not ok or not (folder / "pipe" / "control").exists():
        m.stop()
        return None, f"nvidia-cuda-mps-control -d failed: {why if not ok else 'no control pipe after 10 s'}"
    return m, ""


_PROBE = "import cupy; cupy.cuda.runtime.setDevice(0); cupy.cuda.runtime.memGetInfo()"


def _probe_mps(m: Mps) -> str:
    """One client of the new daemon, in a separate process (this one stays without a CUDA context): "" when it
    connects, else why not -- a daemon whose server refuses clients (an old GPU, a container without the rights)
    would turn every GPU task into a device fault. Skipped without cupy."""
    import importlib.util

    if importlib.util.find_spec("cupy") is None:
        return ""
    try:
        r = subprocess.run([sys.executable, "-c", _PROBE], env={**os.environ, **m.env}, capture_output=True,
                           text=True, timeout=120, stdin=subprocess.DEVNULL)
    except (OSError, subprocess.SubprocessError) as e:
        return f"a client of the daemon failed: {e}"[:300]
    if r.returncode:
        last = (r.stderr.strip().splitlines() or [f"exit {r.returncode}"])[-1]
        return f"a client of the daemon failed: {last}"[:300]
    return ""


@dataclass
class Placement:
    """Where a rank runs: its ``gpu`` (None: CPU units only), the ranks per GPU of its node (``per_gpu``), the MPS
    daemon this rank started (``mps``, node-local rank 0 only) and one line on MPS for the log (``note``)."""

    gpu: int | None
    per_gpu: int
    mps: Mps | None = None
    note: str = ""
    env: dict[str, str] = field(default_factory=dict)


def _node_plan(n: int, working: int, per_gpu: int | None, cap: int) -> tuple[int, Mps | None, str]:
    """Node-local rank 0: the ranks per GPU and the MPS daemon to start (see the module doc)."""
    want = per_gpu if per_gpu is not None else auto_per_gpu(n, working, True, cap)
    if n <= 0 or min(want, -(-working // max(n, 1))) <= 1:
        return (want if per_gpu is not None else 1), None, ""
    if mps_processes():
        if (_pipe_dir() / "control").exists():
            return want, None, f"MPS: using the running daemon of {_pipe_dir()}"
        why = f"an MPS daemon runs whose pipe folder {_pipe_dir()} this run cannot reach"
    else:
        m, why = start_mps()
        if m is not None:
            why = _probe_mps(m)
            if not why:
                return want, m, f"MPS: started a daemon for this run ({m.folder})"
            m.stop()
    if per_gpu is not None:
        return want, None, f"MPS: not used ({why}): {want} ranks per GPU share it by time slices"
    return 1, None, f"MPS: not used ({why}): one rank per GPU"


def place(comm: Any, coordinator_works: bool, per_gpu: int | None = None, need: float = 0.0) -> Placement:
    """This rank's :class:`Placement` (collective over ``comm`` when it is not None: every rank must call it).
    ``per_gpu`` None: the default (:func:`auto_per_gpu`, MPS started where it may), with no more ranks per GPU
    than its memory holds at ``need`` bytes each (gapsweep.sweep.budget.gpu_memory). Outside MPI: working rank 0,
    no MPS."""
    if comm is None:
        k = per_gpu if per_gpu is not None else 1
        return Placement(assign(0, visible_count(), k), k)
    from mpi4py import MPI

    node = comm.Split_type(MPI.COMM_TYPE_SHARED)
    m = None
    try:
        root_here = node.allreduce(1 if comm.rank == 0 else 0, op=MPI.SUM) > 0
        working = node.size - (1 if root_here and not coordinator_works else 0)
        pids = node.gather(os.getpid(), root=0)
        plan = None
        if node.rank == 0:
            n = visible_count()
            try:
                # the memory (one more nvidia-smi call) only where the default's ranks could need more than 8 GB
                big = per_gpu is None and n > 0 and need * auto_per_gpu(n, working, True) > _SMALL_GPU
                have = memory() if big else 0
                cap = max(1, int(0.9 * have // need)) if have else MPS_CLIENTS
                k, m, note = _node_plan(n, working, per_gpu, cap)
                if m is not None:
                    m.watch(pids)  # before any rank connects: the daemon never outlives the ranks
            except Exception as e:  # the other ranks wait in bcast: never leave them there
                if m is not None:
                    m.stop()
                k, m, note = per_gpu or 1, None, f"MPS: not used ({type(e).__name__}: {e})"
            plan = (n, k, m.env if m is not None else {}, note)
        n, k, env, note = node.bcast(plan, root=0)  # one look per node
        os.environ.update(env)  # before this rank's first CUDA call: its clients connect to that daemon
        local = node.rank
    finally:
        node.Free()
    if not coordinator_works and root_here:
        if comm.rank == 0:
            return Placement(None, k, m, note, env)
        local -= 1  # node-local ranks are ordered by world rank, so world rank 0 is local rank 0 here
    return Placement(assign(local, n, k), k, m, note, env)


def select(gpu: int | None) -> str:
    """Make ``gpu`` this process's current CUDA device (cupy's), before any other CUDA call of a GPU rank (see the
    module doc); "" when done or not needed (None, no cupy), else why not (a device fault: the rank's first GPU
    task meets it again and the farm gives its units to other workers)."""
    if gpu is None:
        return ""
    import importlib.util

    if "cupy" not in sys.modules and importlib.util.find_spec("cupy") is None:
        return ""
    try:
        import cupy

        cupy.cuda.runtime.setDevice(gpu)
    except Exception as e:  # no driver, a device held or failed: the tasks report it
        log.warning("GPU %d: could not make it the current device: %s", gpu, e)
        return f"{type(e).__name__}: {e}"[:300]
    return ""


@dataclass(frozen=True)
class Layout:
    """A farm layout for one node (docs/running.md, "Which layout"): ``ranks`` MPI ranks, of which ``gpu_workers``
    drive one GPU each and ``cpu_workers`` run CPU units; rank 0 coordinates (and works itself only where
    ``coordinator_works``)."""

    ranks: int
    gpu_workers: int
    cpu_workers: int
    coordinator_works: bool

    def args(self) -> str:
        """The mpiexec and gapsweep options that give this layout."""
        if self.ranks == 1:
            return "gapsweep run (one process, no mpiexec)"
        extra = "" if self.coordinator_works == (self.ranks <= 4) else (
            " --coordinator-works " + ("yes" if self.coordinator_works else "no"))
        bind = " --bind-to none" if self.gpu_workers else ""
        return f"mpiexec -n {self.ranks}{bind} gapsweep run ...{extra}"


def layout(n_gpus: int, cores: int, gpu_units: int, cpu_units: int) -> Layout:
    """The layout to pick on a node of ``n_gpus`` GPUs and ``cores`` cores for a job of ``gpu_units`` GPU units and
    ``cpu_units`` CPU units: one GPU worker per GPU (capped by the GPU units; one process and one CUDA context
    per GPU, no MPS needed), one rank per remaining core for the CPU units (capped by their count), and a
    coordinator that only coordinates; on up to 4 cores the coordinator works too, and one worker is a single
    process. Without a visible GPU, GPU units get no worker (they need a GPU node)."""
    g = min(n_gpus, gpu_units) if n_gpus > 0 else 0
    if cores <= 4:  # a small machine: the coordinator works too (the default up to 4 ranks)
        p = max(g, min(cores, g + cpu_units), 1)
        return Layout(p, g, p - g, True)
    c = max(0, min(cores - g - 1, cpu_units))
    if g + c <= 1:  # one worker: a single process does it all (serial run)
        return Layout(1, g, 1 - g, True)
    return Layout(1 + g + c, g, c, False)
