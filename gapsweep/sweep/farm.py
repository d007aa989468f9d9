"""The task farm's scheduling: one queue of units by cost, workers with and without a GPU, a unit whose device
failed put back for another worker (docs/architecture.md, "The farm"; docs/running.md, "GPUs").

Pure logic -- no MPI, no GPU, no I/O -- so that every rule is tested in-process (tests/test_farm.py); the runner
(gapsweep.sweep.runner) moves the messages. The rules:

* **One queue.** Units (a task, a pressure chain, a set, a GPU batch) in cost order, largest first. A worker
  takes from the head; the coordinator's own worker thread (``tail=True``) takes from the tail, so that serving
  requests is never held up by a long unit.
* **GPU units go to GPU workers** (a worker whose ``gpu`` is set and whose device has not failed): a GPU worker
  takes the first GPU unit, and a CPU unit only when no GPU unit is left. A CPU worker takes CPU units only --
  unless no worker had a GPU at the start, then any worker takes any unit (a GPU task then meets the missing
  GPU itself: a failed row, or a device fault after which that worker takes no GPU unit).
* **Device faults are not task failures** (:func:`device_fault`): the worker's device is given up (it goes on as
  a CPU worker), the units it holds go back to the head of the queue, units sent to it before the fault are
  stale (``Worker.epoch``), and the rows already recorded are skipped when a unit runs again
  (:meth:`Farm.skip`). When no GPU worker is left, the GPU units still queued
  are taken out (:attr:`Farm.left`: their rows stay pending) and :attr:`Farm.no_gpu` says why in one line.
* **Units ahead.** A GPU worker may hold ``ahead`` GPU units beyond the one it runs (``--lookahead``), so that
  their host-side inputs (surfaces) are made on host threads while its GPU works -- only units that have such
  inputs (``ahead_ok``), and only while more GPU units are queued than there are other GPU workers; a worker
  that holds nothing is always served first. After a device fault it holds one unit at a time, as every CPU
  worker does.
* **A worker waits rather than leaves** while a GPU unit it could run is in flight elsewhere (that unit comes
  back if the device fails); it is told to stop once nothing it could run is queued or could come back.
* **A stop request** (signal, stop file) empties the queue; units in flight finish; a unit whose device fails
  after that is not queued again.

States of a worker: ``idle`` (not yet asked), ``waiting`` (asked, holds nothing), ``busy`` (holds units: the
one it runs and those ahead), ``stopped`` (told to leave). Its GPU: ``gpu`` (the device index, None for a CPU
worker) and ``lost`` (why the device was given up; "" while it works).
"""

from __future__ import annotations

from collections import deque
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field

__all__ = ["DeviceFault", "Farm", "Worker", "device_fault"]


class DeviceFault(RuntimeError):
    """A task could not run because its device failed (context lost, out of memory, MPS or driver refusal): the
    device's fault, not the task's. Raised by gapsweep.sweep.execute.run_task instead of a failed row."""


# Exception classes of the CUDA stacks whose every instance means the device (or its memory) is unusable.
_FAULT_TYPES = ("OutOfMemoryError", "CudaSupportError", "DeviceFault")
# CUDA runtime/driver/library codes that mean the device, its context or its memory failed (not a bad input:
# cudaErrorInvalidValue, a kernel's own bug, stays a task failure).
_FAULT_CODES = (
    "cudaErrorDevicesUnavailable", "cudaErrorNoDevice", "cudaErrorInsufficientDriver", "cudaErrorMemoryAllocation",
    "cudaErrorInitializationError", "cudaErrorLaunchFailure", "cudaErrorIllegalAddress", "cudaErrorECCUncorrectable",
    "cudaErrorHardwareStackError", "cudaErrorContextIsDestroyed", "cudaErrorDeviceUninitialized",
    "cudaErrorLaunchTimeout", "cudaErrorSystemNotReady", "cudaErrorSystemDriverMismatch", "cudaErrorCudartUnloading",
    "cudaErrorMpsConnectionFailed", "cudaErrorMpsRpcFailure", "cudaErrorMpsServerNotReady",
    "cudaErrorMpsMaxClientsReached", "cudaErrorMpsMaxConnectionsReached", "cudaErrorMpsClientTerminated",
    "cudaErrorDeviceNotLicensed", "cudaErrorUnsupportedPtxVersion", "cudaErrorStubLibrary",
    "CUDA_ERROR_OUT_OF_MEMORY", "CUDA_ERROR_NO_DEVICE", "CUDA_ERROR_INVALID_CONTEXT",
    "CUDA_ERROR_CONTEXT_IS_DESTROYED", "CUDA_ERROR_LAUNCH_FAILED", "CUDA_ERROR_ILLEGAL_ADDRESS",
    "CUDA_ERROR_ECC_UNCORRECTABLE", "CUDA_ERROR_NOT_INITIALIZED",
    "CUDA_ERROR_DEINITIALIZED", "CUDA_ERROR_DEVICE_UNAVAILABLE", "CUDA_ERROR_LAUNCH_TIMEOUT",
    "CUDA_ERROR_SYSTEM_DRIVER_MISMATCH", "CUDA_ERROR_MPS_", "CUFFT_ALLOC_FAILED", "CUBLAS_STATUS_ALLOC_FAILED",
    "CUBLAS_STATUS_NOT_INITIALIZED", "CURAND_STATUS_ALLOCATION_FAILED", "all CUDA-capable devices are busy",
)


def device_fault(e: BaseException) -> str:
    """Why ``e`` is a device fault (one line: the exception's type and message), or "" if it is not one.

    A device fault is an exception of a CUDA stack (cupy, numba, warp, cuFFT/cuBLAS) that says the device, its
    context or its memory failed: out of memory, no device, context lost, the MPS server's or the driver's
    refusal (``_FAULT_TYPES``, ``_FAULT_CODES``); the chain of causes is searched too. A host ``MemoryError`` or a
    bad input is not one."""
    seen: set[int] = set()
    cur: BaseException | None = e
    while cur is not None and id(cur) not in seen:
        seen.add(id(cur))
        text = f"{type(cur).__name__}: {cur}"
        low = text.lower()
        if type(cur).__name__ in _FAULT_TYPES or any(code in text for code in _FAULT_CODES) or (
                "cuda" in low and "out of memory" in low):  # e.g. warp's "CUDA error 2: out of memory"
            return text.splitlines()[0][:300]
        cur = cur.__cause__ or cur.__context__
    return ""


@dataclass
class Worker:
    """One worker of the farm (an MPI rank, or the coordinator's own thread)."""

    gpu: int | None = None  # the GPU it drives (None: a CPU worker)
    tail: bool = False  # takes units from the tail of the queue (the coordinator's own worker)
    ahead: int = 0  # units a GPU worker holds beyond the one it runs (their inputs are made while it runs)
    lost: str = ""  # why its GPU was given up (a device fault); "" while it has one or never had one
    units: list[int] = field(default_factory=list)  # held: the one it runs first, then the ones ahead
    started: bool = False  # it has asked for work
    stopped: bool = False
    epoch: int = 0  # counts its device faults: a unit sent before the last one is stale

    @property
    def has_gpu(self) -> bool:
        return self.gpu is not None and not self.lost

    @property
    def cap(self) -> int:
        """Units it may hold: 1, plus ``ahead`` while it has a GPU."""
        return 1 + (self.ahead if self.has_gpu else 0)

    @property
    def unit(self) -> int | None:
        """The unit it runs (the first it holds), or None."""
        return self.units[0] if self.units else None

    @property
    def state(self) -> str:
        if self.stopped:
            return "stopped"
        if self.units:
            return "busy"
        return "waiting" if self.started else "idle"


@dataclass
class Farm:
    """The coordinator's view of the farm: the queue, the workers and what came back (see the module doc).

    ``gpu_units[k]``: unit ``k`` needs a GPU; ``order``: the units to run, largest first; ``workers``: worker id
    -> :class:`Worker`; ``ahead_ok[k]``: unit ``k`` may be held ahead (default: every unit). Each event method
    returns the dispatches it made possible: ``(worker id, unit)`` to send (``unit`` None: tell that worker to
    stop)."""

    gpu_units: Sequence[bool]
    order: Iterable[int]
    workers: dict[int, Worker]
    queue: deque = field(init=False)
    recorded: dict[int, set[int]] = field(default_factory=dict)  # unit -> its task rows recorded so far
    left: list[int] = field(default_factory=list)  # GPU units taken out because no GPU is left
    no_gpu: str = ""  # the one line that says so
    faults: list[tuple[int, int | None, str]] = field(default_factory=list)  # (worker, its GPU, reason)
    stopping: bool = False
    ahead_ok: Sequence[bool] | None = None  # unit k may be held ahead (its inputs are made ahead); None: all

    def __post_init__(self) -> None:
        self.queue = deque(self.order)
        if self.ahead_ok is None:
            self.ahead_ok = [True] * len(self.gpu_units)
        self.any_gpu = any(w.gpu is not None for w in self.workers.values())

    # -- events ---------------------------------------------------------------------------------------------
    def request(self, wid: int, done: int | None = None) -> list[tuple[int, int | None]]:
        """Worker ``wid`` asks for work: its first request (``done`` None), or after finishing unit ``done``."""
        w = self.workers[wid]
        if done is not None and done in w.units:
            w.units.remove(done)
        w.started = True
        return self.dispatch()

    def row(self, k: int, i: int) -> None:
        """Task row ``i`` of unit ``k`` was recorded (kept if the unit has to run again)."""
        self.recorded.setdefault(k, set()).add(i)

    def fault(self, wid: int, reason: str) -> list[tuple[int, int | None]]:
        """Worker ``wid``'s device failed while it ran its first unit: the device is given up, every unit it
        holds goes back to the head of the queue in its order (not after a stop request), units sent to it
        before are stale (``epoch``), and it asks again as a CPU worker (no message needed)."""
        w = self.workers[wid]
        held, w.units = w.units, []
        w.lost = reason or "device fault"
        w.epoch += 1
        self.faults.append((wid, w.gpu, w.lost))
        if not self.stopping:
            self.queue.extendleft(reversed(held))
        w.started = True
        return self.dispatch()

    def stop(self) -> list[tuple[int, int | None]]:
        """A stop request: nothing more is handed out; the units held finish."""
        self.stopping = True
        self.queue.clear()
        return self.dispatch()

    # -- queries --------------------------------------------------------------------------------------------
    def skip(self, k: int) -> frozenset[int]:
        """The task rows of unit ``k`` already recorded (by a worker whose device failed during it)."""
        return frozenset(self.recorded.get(k, ()))

    def can_run(self, w: Worker, k: int) -> bool:
        return not self.gpu_units[k] or self._gpu_capable(w)

    def _gpu_capable(self, w: Worker) -> bool:
        """``w`` may run GPU units: it has a GPU -- or no worker had one and its device has not failed."""
        return w.has_gpu or (not self.any_gpu and not w.lost)

    def busy(self) -> bool:
        """Some worker has not been told to stop."""
        return any(not w.stopped for w in self.workers.values())

    def gpu_workers(self) -> list[int]:
        return [wid for wid, w in self.workers.items() if w.has_gpu and not w.stopped]

    # -- the rules ------------------------------------------------------------------------------------------
    def dispatch(self) -> list[tuple[int, int | None]]:
        """Serve the workers that asked (in id order): first a unit to each that holds none, then units ahead
        to GPU workers up to their ``cap``; a stop to one that holds nothing where nothing it could run is
        queued or may come back."""
        self._check_gpus()
        out: list[tuple[int, int | None]] = []
        live = [wid for wid in sorted(self.workers) if self.workers[wid].started and not self.workers[wid].stopped]
        for wid in live:  # one unit to each worker that holds none
            w = self.workers[wid]
            if not w.units and (k := self._pick(w)) is not None:
                w.units.append(k)
                out.append((wid, k))
        for wid in live:  # then units ahead, while that leaves a GPU unit for every other GPU worker
            w = self.workers[wid]
            while w.units and len(w.units) < w.cap and (k := self._pick_ahead(w)) is not None:
                w.units.append(k)
                out.append((wid, k))
        for wid in live:
            w = self.workers[wid]
            if not w.units and (self.stopping or not self._may_come(w)):
                w.stopped = True
                out.append((wid, None))
        return out

    def _pick(self, w: Worker) -> int | None:
        """The unit for ``w`` (removed from the queue), or None."""
        q = self.queue
        order = range(len(q) - 1, -1, -1) if w.tail else range(len(q))
        j = None
        if w.has_gpu:  # GPU units first: only GPU workers can run them, they are the critical path
            j = next((j for j in order if self.gpu_units[q[j]]), None)
        if j is None:
            j = next((j for j in order if self.can_run(w, q[j])), None)
        if j is None:
            return None
        k = q[j]
        del q[j]
        return k

    def _pick_ahead(self, w: Worker) -> int | None:
        """A GPU unit for ``w`` to hold ahead (one whose inputs can be made ahead, ``ahead_ok``), if more GPU units
        are queued than there are other GPU workers; else None."""
        others = sum(1 for o in self.workers.values() if o is not w and not o.stopped and self._gpu_capable(o))
        q = self.queue
        if sum(1 for k in q if self.gpu_units[k]) <= others:
            return None
        order = range(len(q) - 1, -1, -1) if w.tail else range(len(q))
        j = next((j for j in order if self.gpu_units[q[j]] and self.ahead_ok[q[j]]), None)
        if j is None:
            return None
        k = q[j]
        del q[j]
        return k

    def _may_come(self, w: Worker) -> bool:
        """A GPU unit ``w`` could run is held by another worker (it comes back if that worker's device fails)."""
        return any(o is not w and self.gpu_units[k] and self.can_run(w, k) for o in self.workers.values()
                   for k in o.units)

    def _check_gpus(self) -> None:
        """No GPU worker left: take the queued GPU units out (their rows stay pending) and say why, once."""
        if any(self._gpu_capable(w) and not w.stopped for w in self.workers.values()):
            return
        gone = [k for k in self.queue if self.gpu_units[k]]
        if not gone:
            return
        self.queue = deque(k for k in self.queue if not self.gpu_units[k])
        self.left.extend(gone)
        if not self.no_gpu:
            why = "; ".join(f"{_who(w, g)}: {r}" for w, g, r in self.faults) or "no GPU worker"
            self.no_gpu = f"no GPU left ({why})"


def _who(wid: int, gpu: int | None) -> str:
    return f"GPU {gpu}" if gpu is not None else f"worker {wid}"
