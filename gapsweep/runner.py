"""Running a job: one process, or an MPI task farm with a dynamic coordinator (docs/running.md).

* Serial (``gapsweep run JOB --store PATH``): units largest-first, each row written and flushed as it finishes.
* MPI (``mpiexec -n P gapsweep run ...``): rank 0 is the coordinator. Workers ask for work; rank 0 hands out
  units from the head of the cost-sorted queue (largest first). When P is small (default: P <= 4) rank 0 also
  works, in a thread that takes units from the tail (smallest first) so that serving requests is never held up
  by a long unit; MPI calls stay on rank 0's main thread.
* Writer: with an MPI-enabled h5py every rank opens the store with ``driver="mpio"``; the structure is created
  collectively up front and each rank writes its own rows (independent I/O). Otherwise (or with
  ``--writer rank0`` / ``GAPSWEEP_WRITER=rank0``) workers send their rows to rank 0, which writes them: the same
  file content.
* Any exception outside a task on any rank ends the job with ``comm.Abort(1)`` (a rank leaving a collective call
  would otherwise hang the others). Exceptions inside a task are recorded in its row and the sweep goes on.
"""

from __future__ import annotations

import json
import os
import queue
import socket
import sys
import threading
import time
import traceback
from collections import deque
from pathlib import Path
from typing import Any

from gapsweep import provenance
from gapsweep import spec as specmod
from gapsweep.store import Store, StoreError, open_read
from gapsweep.tasks import STATUS, Context, Task, TaskResult, Unit, expand, make_units, run_unit, shard_units

__all__ = ["RunError", "parse_shard", "plan", "run"]

TAG_READY, TAG_WORK, TAG_ROW = 1, 2, 3
_MPI_ENV = ("OMPI_COMM_WORLD_SIZE", "PMI_SIZE", "PMIX_RANK", "MPI_LOCALNRANKS", "PMI_RANK")


class RunError(RuntimeError):
    """The run cannot start as asked (store exists, belongs to another job, writer unavailable)."""


def parse_shard(text: str | None) -> tuple[int, int] | None:
    """``"i/n"`` -> (i, n); ``"slurm"`` -> from ``SLURM_ARRAY_TASK_ID`` (minus ``SLURM_ARRAY_TASK_MIN``) and
    ``SLURM_ARRAY_TASK_COUNT``; None -> None."""
    if text is None:
        return None
    if text == "slurm":
        try:
            i = int(os.environ["SLURM_ARRAY_TASK_ID"]) - int(os.environ.get("SLURM_ARRAY_TASK_MIN", "0"))
            n = int(os.environ["SLURM_ARRAY_TASK_COUNT"])
        except (KeyError, ValueError):
            raise ValueError("--shard slurm: SLURM_ARRAY_TASK_ID and SLURM_ARRAY_TASK_COUNT must be set "
                             "(run inside a Slurm array job)") from None
    else:
        try:
            a, b = text.split("/")
            i, n = int(a), int(b)
        except ValueError:
            raise ValueError(f"--shard: expected i/n (0 <= i < n) or 'slurm', got {text!r}") from None
    if not (n >= 1 and 0 <= i < n):
        raise ValueError(f"--shard: expected i/n with 0 <= i < n, got {i}/{n}")
    return i, n


def _comm(mpi: str) -> Any:
    """COMM_WORLD when launched by an MPI launcher (or ``mpi="on"``) and its size is > 1, else None."""
    if mpi == "off" or (mpi == "auto" and not any(k in os.environ for k in _MPI_ENV)):
        return None
    from mpi4py import MPI

    comm = MPI.COMM_WORLD
    return comm if comm.size > 1 else None


def _select(spec: specmod.JobSpec, shard: tuple[int, int] | None) -> tuple[list[Task], list[Unit]]:
    """Tasks of the job (or of one shard) in canonical order and their units (indices into that list)."""
    tasks_all = expand(spec)
    units = make_units(tasks_all)
    if shard is not None:
        units = shard_units(units, *shard)
    sel = sorted({i for u in units for i in u.tasks})
    remap = {old: new for new, old in enumerate(sel)}
    return [tasks_all[i] for i in sel], [Unit(tuple(remap[i] for i in u.tasks), u.cost, u.gpu) for u in units]


def plan(job: str | Path | specmod.JobSpec, shard: tuple[int, int] | None = None, ranks: int = 1) -> str:
    """Text summary of a job: tasks per method, units, cost estimate (core-seconds and wall time on ``ranks``)."""
    spec = job if isinstance(job, specmod.JobSpec) else specmod.load(job)
    tasks, units = _select(spec, shard)
    lines = [f"job {spec.name!r}: {len(tasks)} tasks in {len(units)} units"
             + (f" (shard {shard[0]}/{shard[1]})" if shard else "")]
    by: dict[str, list[float]] = {}
    for u in units:
        for i in u.tasks:
            by.setdefault(tasks[i].method, [])
    from gapsweep.tasks import estimate_cost

    for t in tasks:
        by[t.method].append(estimate_cost(t))
    for m, c in by.items():
        lines.append(f"  {m:14s} {len(c):7d} tasks  ~{sum(c):10.1f} core-s  (max {max(c):.2f} s per task)")
    total = sum(u.cost for u in units)
    longest = max((u.cost for u in units), default=0.0)
    lines.append(f"  estimated cost ~{total:.1f} core-s; on {ranks} rank(s) ~{max(total / ranks, longest):.1f} s "
                 "wall (rough model, see docs/jobs.md)")
    return "\n".join(lines)


def _store_path(path: str | Path, shard: tuple[int, int] | None) -> Path:
    p = str(path)
    if shard is not None:
        p = p.replace("{i}", str(shard[0])).replace("{n}", str(shard[1]))
    return Path(p)


def _decide(path: Path, spec: specmod.JobSpec, tasks: list[Task], shard_text: str, resume: bool,
            overwrite: bool) -> tuple[str, list[int]]:
    """('create' | 'resume' | 'noop', task indices to run). Raises RunError when the store cannot be used."""
    if not path.exists() or overwrite:
        return "create", list(range(len(tasks)))
    try:
        with open_read(path) as f:
            sha, shard = f.attrs.get("spec_sha256"), f.attrs.get("shard")
            ids = [x.decode() for x in f["tasks"].fields("task_id")[...]] if f["tasks"].shape[0] else []
            st = f["results"].fields("status")[...] if ids else []
    except (OSError, StoreError, KeyError) as e:
        raise RunError(f"store {path} exists but cannot be read as a gapsweep store ({e}); "
                       "pass --overwrite to replace it") from None
    if sha != spec.sha256 or shard != shard_text or ids != [t.task_id for t in tasks]:
        raise RunError(f"store {path} was written for another job spec or shard; pass --overwrite to replace "
                       "it or choose another --store")
    todo = [i for i, s in enumerate(st) if s == STATUS["pending"]]
    if not todo:
        return "noop", []
    if not resume:
        raise RunError(f"store {path} exists with {len(todo)} of {len(tasks)} tasks pending: pass --resume to "
                       "finish it or --overwrite to start again")
    return "resume", todo


class Progress:
    """Rank 0's progress: a tqdm bar on a terminal, plain log lines (every ``every`` s) otherwise."""

    def __init__(self, total: int, mode: str = "auto", every: float = 10.0) -> None:
        self.total, self.count = total, dict.fromkeys(STATUS, 0)
        self.t0 = self.last = time.monotonic()
        self.every = every
        tty = sys.stderr.isatty()
        self.mode = ("bar" if tty else "log") if mode == "auto" else mode
        self.bar = None
        if self.mode == "bar" and total:
            try:
                from tqdm import tqdm
            except ImportError:  # the `progress` extra is not installed: log lines instead of a bar
                self.mode = "log"
            else:
                self.bar = tqdm(total=total, unit="task", dynamic_ncols=True, file=sys.stderr)

    def update(self, res: TaskResult) -> None:
        self.count[res.status] += 1
        if self.bar is not None:
            self.bar.update(1)
            self.bar.set_postfix(failed=self.count["failed"], not_conv=self.count["not_converged"], refresh=False)
        elif self.mode == "log":
            t = time.monotonic()
            if t - self.last >= self.every:
                self.last = t
                print(self.line(), file=sys.stderr, flush=True)

    def line(self) -> str:
        n = sum(self.count.values())
        el = time.monotonic() - self.t0
        eta = el / n * (self.total - n) if n else float("nan")
        return (f"[gapsweep] {n}/{self.total} finished ({self.count['done']} done, {self.count['failed']} failed, "
                f"{self.count['not_converged']} not converged), {self.total - n} remaining, "
                f"elapsed {el:.1f} s, ETA {eta:.1f} s")

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()
        if self.mode != "none":
            print(self.line(), file=sys.stderr, flush=True)


def _gpu_index(comm: Any) -> int | None:
    """The GPU of this rank (node-local rank if < number of visible GPUs) or None."""
    vis = os.environ.get("CUDA_VISIBLE_DEVICES")
    if vis is not None:
        n = len([x for x in vis.split(",") if x.strip() and x.strip() != "-1"])
    else:
        import shutil
        import subprocess

        if not shutil.which("nvidia-smi"):
            return None
        try:
            out = subprocess.run(["nvidia-smi", "-L"], capture_output=True, text=True, timeout=20).stdout
        except (OSError, subprocess.SubprocessError):
            return None
        n = sum(1 for line in out.splitlines() if line.startswith("GPU "))
    local = 0
    if comm is not None:
        from mpi4py import MPI

        local = comm.Split_type(MPI.COMM_TYPE_SHARED).rank
    return local if local < n else None


def run(job: str | Path | specmod.JobSpec, store: str | Path, *, resume: bool = False, overwrite: bool = False,
        shard: tuple[int, int] | None = None, writer: str = "auto", progress: str = "auto",
        coordinator_works: str = "auto", mpi: str = "auto") -> dict[str, Any]:
    """Run a job into a store (serially or as an MPI task farm). Returns a summary dict on every rank.

    ``writer``: auto | mpio | rank0 (env ``GAPSWEEP_WRITER`` overrides auto); ``progress``: auto | bar | log |
    none; ``coordinator_works``: auto (rank 0 works when P <= 4) | yes | no; ``mpi``: auto | on | off."""
    spec = job if isinstance(job, specmod.JobSpec) else specmod.load(job)
    comm = _comm(mpi)
    rank, size = (comm.rank, comm.size) if comm is not None else (0, 1)
    if os.environ.get("GAPSWEEP_TEST_PIDDIR"):  # test hook: lets a test kill -9 one particular rank
        Path(os.environ["GAPSWEEP_TEST_PIDDIR"], f"rank{rank}.pid").write_text(str(os.getpid()))
    tasks, units = _select(spec, shard)
    path = _store_path(store, shard)
    shard_text = f"{shard[0]}/{shard[1]}" if shard else ""

    # Decide on rank 0 (file system checks once), then share: every rank raises the same error.
    decision: Any = None
    if rank == 0:
        try:
            decision = _decide(path, spec, tasks, shard_text, resume, overwrite)
        except Exception as e:  # every rank must learn about it, or the others wait in bcast forever
            decision = e if isinstance(e, RunError) else RunError(f"store {path}: {type(e).__name__}: {e}")
    if comm is not None:
        decision = comm.bcast(decision, root=0)
    if isinstance(decision, RunError):
        raise decision
    mode, todo_list = decision
    summary: dict[str, Any] = {"store": str(path), "tasks": len(tasks), "todo": len(todo_list), "mode": mode,
                               "mpi_size": size, "rank": rank, **dict.fromkeys(STATUS, 0)}
    if mode == "noop":
        if rank == 0 and progress != "none":
            print(f"[gapsweep] {path}: all {len(tasks)} tasks finished already; nothing to do", file=sys.stderr)
        return summary

    req = os.environ.get("GAPSWEEP_WRITER", "auto") if writer == "auto" else writer
    if req not in ("auto", "mpio", "rank0"):
        raise RunError(f"writer must be auto, mpio or rank0, got {req!r}")
    import h5py

    if comm is None:
        wmode = "serial"
    elif req == "rank0" or (req == "auto" and not h5py.get_config().mpi):
        wmode = "rank0"
    elif not h5py.get_config().mpi:
        raise RunError("writer 'mpio' needs h5py built with MPI (h5py.get_config().mpi is False)")
    else:
        wmode = "mpio"
    summary["writer"] = wmode
    if rank == 0:
        path.parent.mkdir(parents=True, exist_ok=True)

    # Static attributes and the run record come from rank 0 so that every rank writes identical values.
    hosts = sorted(set(comm.allgather(socket.gethostname()))) if comm is not None else [socket.gethostname()]
    attrs = provenance.store_attrs(spec, shard=shard_text) if rank == 0 else None
    record = {"started": provenance.now(), "finished": None, "mpi_size": size, "hosts": hosts, "writer": wmode,
              "mode": mode, "todo": len(todo_list)}
    if comm is not None:
        attrs, record = comm.bcast((attrs, record), root=0)

    need_gpu = any(u.gpu for u in units)
    ctx = Context(rank=rank, gpu=_gpu_index(comm) if need_gpu else None)
    ctx.fields_dir = _fields_dir(path)  # kept GFMD fields, if the spec asks (gapsweep.dataset)
    todo = set(todo_list)
    work = [k for k, u in enumerate(units) if any(i in todo for i in u.tasks)]

    st: Store | None = None
    try:
        if wmode == "mpio" or rank == 0:
            c = comm if wmode == "mpio" else None
            st = (Store.create(path, tasks, attrs, spec.histogram["bins"], comm=c) if mode == "create"
                  else Store.open(path, comm=c))
            runs = json.loads(st.f.attrs.get("runs", "[]"))
            st.set_attrs({"runs": json.dumps([*runs, record])})
            st.f.flush()  # collective under mpio; makes the run record survive a kill -9
        if os.environ.get("GAPSWEEP_TEST_ABORT_RANK", "") == str(rank):
            raise RuntimeError(f"injected error on rank {rank} (GAPSWEEP_TEST_ABORT_RANK)")
        prog = Progress(len(todo), progress if rank == 0 else "none")
        if comm is None:
            for k in work:
                for i, res in run_unit(tasks, units[k], ctx, todo):
                    st.write(i, res)
                    prog.update(res)
        elif rank == 0:
            works = coordinator_works == "yes" or (coordinator_works == "auto" and size <= 4)
            gpus = comm.gather(ctx.gpu, root=0)
            if (not works and coordinator_works != "no" and gpus[0] is not None
                    and any(units[k].gpu for k in work) and all(g is None for g in gpus[1:])):
                # One GPU per node and it is rank 0's: rank 0 must work, or GPU units would find no taker.
                works = True
            _coordinate(comm, tasks, units, work, todo, ctx, st, prog, works, wmode, gpus)
        else:
            comm.gather(ctx.gpu, root=0)
            _work(comm, tasks, units, todo, ctx, st, wmode)
        prog.close()
        for k in STATUS:
            summary[k] = prog.count[k]
        if comm is not None:
            counts = comm.bcast(prog.count if rank == 0 else None, root=0)
            for k in STATUS:
                summary[k] = counts[k]
            comm.Barrier()
        if st is not None:
            record["finished"] = provenance.now() if rank == 0 else None
            if comm is not None and wmode == "mpio":
                record = comm.bcast(record, root=0)
            runs = json.loads(st.f.attrs.get("runs", "[]"))
            runs[-1] = record
            st.set_attrs({"runs": json.dumps(runs), "finished": record["finished"]})
            st.close()
            st = None
    except BaseException:
        if comm is not None:
            sys.stderr.write(f"[gapsweep] rank {rank}: fatal error, aborting the MPI job\n")
            traceback.print_exc()
            sys.stderr.flush()
            comm.Abort(1)
        raise
    finally:
        if st is not None and comm is None:
            st.close()
    return summary


def _coordinate(comm: Any, tasks: list[Task], units: list[Unit], work: list[int], todo: set[int], ctx: Context,
                st: Store | None, prog: Progress, works: bool, wmode: str, gpus: list[int | None]) -> None:
    """Rank 0: hand out units largest-first to workers, optionally work on the smallest ones in a thread,
    write rows sent by workers (rank0 writer) and track progress."""
    from mpi4py import MPI

    q = deque(work)  # unit indices, largest first
    lock = threading.Lock()
    # GPU units wait for a GPU rank only if some rank that works has one; otherwise any rank takes them.
    any_gpu = any(g is not None for r, g in enumerate(gpus) if r > 0 or works)

    def take(from_tail: bool, gpu_ok: bool) -> int | None:
        with lock:
            order = range(len(q) - 1, -1, -1) if from_tail else range(len(q))
            for j in order:
                if not units[q[j]].gpu or gpu_ok or not any_gpu:
                    k = q[j]
                    del q[j]
                    return k
        return None

    results: queue.Queue = queue.Queue()

    def local_worker() -> None:
        try:
            while (k := take(True, gpus[0] is not None)) is not None:
                for item in run_unit(tasks, units[k], ctx, todo):
                    results.put(item)
        except BaseException as e:  # surfaced on the main thread, which aborts the job
            results.put(e)
        results.put(None)

    thread = None
    if works:
        thread = threading.Thread(target=local_worker, name="gapsweep-rank0-worker", daemon=True)
        thread.start()
    local_alive = works
    active = set(range(1, comm.size))

    def handle(item: Any, local: bool) -> None:
        i, res = item
        # rank0 writer: rank 0 writes every row; mpio: workers wrote theirs, rank 0 writes its own.
        if st is not None and (wmode != "mpio" or local):
            st.write(i, res)
        prog.update(res)

    status = MPI.Status()
    while active or local_alive:
        progressed = False
        while active and comm.Iprobe(source=MPI.ANY_SOURCE, tag=MPI.ANY_TAG, status=status):
            src, tag = status.Get_source(), status.Get_tag()
            msg = comm.recv(source=src, tag=tag)
            if tag == TAG_ROW:
                handle(msg, False)
            elif tag == TAG_READY:
                k = take(False, gpus[src] is not None)
                comm.send(k, dest=src, tag=TAG_WORK)
                if k is None:
                    active.discard(src)
            progressed = True
        while local_alive:
            try:
                item = results.get_nowait()
            except queue.Empty:
                break
            progressed = True
            if item is None:
                local_alive = False
            elif isinstance(item, BaseException):
                raise item
            else:
                handle(item, True)
        if not progressed:
            if local_alive:
                time.sleep(2e-4)
            elif active:
                comm.Probe(source=MPI.ANY_SOURCE, tag=MPI.ANY_TAG)
    if thread is not None:
        thread.join()


def _work(comm: Any, tasks: list[Task], units: list[Unit], todo: set[int], ctx: Context, st: Store | None,
          wmode: str) -> None:
    """Worker rank: ask for a unit, run it, write (mpio) or send (rank0 writer) each row as it finishes."""
    comm.send(None, dest=0, tag=TAG_READY)
    while (k := comm.recv(source=0, tag=TAG_WORK)) is not None:
        for i, res in run_unit(tasks, units[k], ctx, todo):
            if wmode == "mpio":
                st.write(i, res)
                res = TaskResult(res.status, "", {})  # rank 0 only counts it
            comm.send((i, res), dest=0, tag=TAG_ROW)
        comm.send(None, dest=0, tag=TAG_READY)


def _fields_dir(store: str | Path) -> Path:
    from gapsweep.dataset import fields_dir

    return fields_dir(store)
