"""Run a benchmark script with the peer codes importable (tamaas, ContactMechanics, Adhesion) but gapsweep's own
stack first on the path: ``python benchmarks/_peers_run.py SCRIPT ARGS...`` with the project's venv python.

The peers live in a venv of their own (pip wheels that pin other versions; docs/environment.md); running a
comparison in that venv would time gapsweep on numpy's FFT and the generic kernels (no pyFFTW, no numba there), not
its default engine. So the peers' site-packages folder (``PEERS_SITE``, default: that of ``PEERS_PY``, default
/work/peers/bin/python) is appended to ``sys.path`` -- after the venv's own packages -- and SCRIPT runs as
``__main__``."""

from __future__ import annotations

import os
import runpy
import subprocess
import sys


def peers_site() -> str:
    site = os.environ.get("PEERS_SITE")
    if site:
        return site
    py = os.environ.get("PEERS_PY", "/work/peers/bin/python")
    return subprocess.run([py, "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"],
                          capture_output=True, text=True, check=True).stdout.strip()


if __name__ == "__main__":
    if len(sys.argv) < 2:
        raise SystemExit("usage: python benchmarks/_peers_run.py SCRIPT [ARGS...]")
    sys.path.append(peers_site())
    script, sys.argv = sys.argv[1], sys.argv[1:]
    runpy.run_path(script, run_name="__main__")
