"""Launching a test's MPI worker script: the environment Open MPI needs in a test run (root allowed, more ranks
than cores) and one call that runs ``mpiexec -n RANKS python WORKER OUT`` with this checkout first on the path and
returns the JSON the worker wrote to OUT (tests/mpi/*_worker.py)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[2]
ENV = {"OMPI_ALLOW_RUN_AS_ROOT": "1", "OMPI_ALLOW_RUN_AS_ROOT_CONFIRM": "1",
       "OMPI_MCA_rmaps_base_oversubscribe": "1", "PYTHONUNBUFFERED": "1"}


def run_worker(worker: Path, out: Path, ranks: int, timeout: float = 300) -> dict[str, Any]:
    """Run ``worker`` on ``ranks`` MPI ranks; assert it exited 0 (its output in the message) and return its JSON."""
    env = dict(os.environ, **ENV)
    env["PYTHONPATH"] = os.pathsep.join([str(ROOT), env.get("PYTHONPATH", "")])
    p = subprocess.run(["mpiexec", "-n", str(ranks), sys.executable, str(worker), str(out)], env=env,
                       capture_output=True, text=True, timeout=timeout)
    assert p.returncode == 0, p.stdout + p.stderr
    return json.loads(out.read_text())
