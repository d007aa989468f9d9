"""The farm's timeline, for profiling (docs/benchmarks.md, issue 38): with ``GAPSWEEP_TRACE=DIR`` in the
environment every MPI rank of a farm writes ``DIR/rank<R>.farm<F>.json`` when it leaves the farm, ``F`` counting the
farms this process was in (0, 1, ...: a launch of several jobs, one farm each with ``--farm each``); without it
nothing is recorded (each hook is one attribute test). (Before, every farm of a launch wrote ``rank<R>.json`` and
the last job's farm overwrote the others': a profile of a several-job launch saw only its last job.)

A worker records the units it ran (``[unit, start, end, gpu unit, tasks in it, io]``, wall clock [s since the epoch],
so that the ranks of one node share a clock; ``io``: the seconds of the unit spent writing its rows (mpio) and
sending them to the coordinator, the rest is the tasks' own work) and the times it asked the coordinator for work
(``asks``: every ready message). The coordinator records the units of its own worker thread (where it works) as a
worker does, when it handled each worker's ready messages (``handled[worker]``: the k-th entry answers that
worker's k-th ask, MPI keeping the order of one sender's messages), the seconds it spent handling messages and
writing rows (``busy_s``), and how many rows it wrote (``rows``). Coordinator latency = handled - asked; a worker's
idle time = the gaps between its units.
"""

from __future__ import annotations

import itertools
import json
import os
import time
from pathlib import Path
from typing import Any

__all__ = ["Trace"]

_FARMS = itertools.count()  # the farms this process has been in (one Trace each)


class Trace:
    """One rank's record (see the module doc); ``on`` is False without ``GAPSWEEP_TRACE``."""

    def __init__(self, rank: int, gpu: int | None) -> None:
        self.dir = os.environ.get("GAPSWEEP_TRACE", "")
        self.on = bool(self.dir)
        self.rank, self.gpu = rank, gpu
        self.farm = next(_FARMS)
        self.t0 = time.time()
        self.units: list[list[Any]] = []
        self.asks: list[float] = []
        self.handled: dict[int, list[float]] = {}
        self.busy_s = 0.0
        self.rows = 0

    def ask(self) -> None:
        if self.on:
            self.asks.append(time.time())

    def unit(self, k: int, start: float, gpu_unit: bool, tasks: int = 0, io: float = 0.0) -> None:
        if self.on:
            self.units.append([k, start, time.time(), bool(gpu_unit), tasks, round(io, 6)])

    def handle(self, wid: int) -> None:
        if self.on:
            self.handled.setdefault(wid, []).append(time.time())

    def write(self) -> None:
        """Write ``DIR/rank<R>.farm<F>.json`` (a failure to write is not the run's: it is ignored)."""
        if not self.on:
            return
        rec = {"rank": self.rank, "farm": self.farm, "gpu": self.gpu, "pid": os.getpid(), "start": self.t0,
               "end": time.time(), "units": self.units, "asks": self.asks,
               "handled": {str(k): v for k, v in self.handled.items()},
               "busy_s": round(self.busy_s, 4), "rows": self.rows}
        try:
            Path(self.dir).mkdir(parents=True, exist_ok=True)
            Path(self.dir, f"rank{self.rank}.farm{self.farm}.json").write_text(json.dumps(rec))
        except OSError:
            pass
