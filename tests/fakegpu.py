"""A fake GPU method for the farm's device-fault tests (test-only plug-in; no production code knows it).

Method ``fakegpu``: every task needs a GPU (``needs_gpu``), its tasks form pressure chains (each result
depends on the previous one of its chain, as GFMD's warm starts do), and a task run on a worker without a GPU
raises (the farm must never give one to a CPU worker). Its result is a closed form of the task's parameters and
of its chain's earlier steps, so it does not depend on which worker ran it.

Device faults are injected by the test through ``FAKEGPU_BROKEN`` (read here, in the test's plug-in):
``"1"`` -- the device of GPU 1 refuses every task (``cudaErrorDevicesUnavailable``, as a full MPS server
does); ``"1@2"`` -- GPU 1 fails at its third task (after two rows of a chain are recorded); ``"0,1"`` -- both.
``FAKEGPU_BARRIER=DIR`` makes the schedule deterministic where a test needs it: a task on GPU 1 first creates
``DIR/gpu1``, and a task on GPU 0 waits for that file (at most 60 s), so GPU 1 surely holds a unit.

Run as a script it is ``gapsweep`` with the plug-in registered (how the MPI tests launch it):
``mpiexec -n 3 python tests/fakegpu.py run JOB --store S``.
"""

from __future__ import annotations

import math
import os
import sys
import time
from pathlib import Path

from gapsweep.sweep.methods.base import Method, grid_tasks, register
from gapsweep.sweep.schema import TaskResult

# theory (CPU units) beside fakegpu (4 GPU chains of 4 tasks)
JOB = """
[job]
name = "farm-faults"
[grid]
hurst = [0.3, 0.8]
rho = [2e-3]
sigma0 = {min = 1e-4, max = 1.0, num = 4, scale = "log"}
seeds = [0, 1]
[surface]
lambda_l = 0.25
lambda_s = 0.04
rms_slope = 1.0
[material]
gamma0 = 1e-3
[methods.theory]
forms = ["paper"]
[methods.fakegpu]
"""


class CUDARuntimeError(RuntimeError):
    """Named as cupy's, with cupy's message for an MPS server that refuses a client."""


def _broken() -> dict[int, int]:
    """GPU -> how many tasks it runs before it fails."""
    out = {}
    for x in os.environ.get("FAKEGPU_BROKEN", "").split(","):
        if x.strip():
            g, _, after = x.partition("@")
            out[int(g)] = int(after or 0)
    return out


_ran: dict[int, int] = {}


def _barrier(gpu: int) -> None:
    d = os.environ.get("FAKEGPU_BARRIER")
    if not d:
        return
    flag = Path(d, "gpu1")
    if gpu == 1:
        flag.touch()
    elif gpu == 0:
        end = time.monotonic() + 60
        while not flag.exists() and time.monotonic() < end:
            time.sleep(0.01)


@register
class FakeGPU(Method):
    name = "fakegpu"
    order = 50
    columns = ("mean_gap",)
    variables = {"mean_gap": ("fakegpu_mean_gap", "a closed form, for the farm's tests", {"units": "1"})}  # noqa: RUF012

    def expand(self, spec):
        yield from grid_tasks(spec, self.name, with_hist=False, chain=True, sort=True, reverse=True)

    def cost(self, t):
        return 10.0  # larger than the theory tasks: the GPU units head the queue

    def needs_gpu(self, t):
        return True

    def gpu_memory(self, t):
        return 1e6  # so that `plan` and `run` check the GPUs' memory

    def run(self, t, ctx, prev):
        if ctx.gpu is None:
            raise AssertionError("a GPU task ran on a worker without a GPU")
        _barrier(ctx.gpu)
        broken = _broken()
        if ctx.gpu in broken:
            n = _ran.get(ctx.gpu, 0)
            _ran[ctx.gpu] = n + 1
            if n >= broken[ctx.gpu]:
                raise CUDARuntimeError("cudaErrorDevicesUnavailable: CUDA-capable device(s) is/are busy or "
                                       "unavailable")
        g = (prev or 0.0) + math.log(t.sigma0) * (t.seed + 1) + t.hurst * t.rho
        return TaskResult("done", "", {"mean_gap": g}), g


if __name__ == "__main__":
    from gapsweep.cli import main

    sys.exit(main(sys.argv[1:]))
