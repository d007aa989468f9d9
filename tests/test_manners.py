"""Python-ecosystem manners: --version, help for every argument, a clean exit on a closed pipe, no matplotlib
backend chosen on import, the library logs (never prints) under "gapsweep", a clear error naming the extra
when an optional dependency is missing, no CUDA-driver noise from warp on a CPU-only machine."""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import gapsweep
from gapsweep import cli
from gapsweep.core.extras import MissingExtraError, require

ROOT = Path(__file__).resolve().parents[1]
ENV = {**os.environ, "PYTHONPATH": str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", "")}


def _run(*args: str, **kw) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "gapsweep", *args], capture_output=True, text=True, cwd=ROOT,
                          env=ENV, timeout=120, **kw)


def test_version_and_help():
    r = _run("--version")
    assert r.returncode == 0 and r.stdout.strip() == f"gapsweep {gapsweep.__version__}"
    r = _run("--help")
    assert r.returncode == 0 and "gapsweep demo" in r.stdout and "Exit codes" in r.stdout
    assert "Command-line interface (thin)" not in r.stdout  # no internal docstring


def test_every_argument_has_help():
    parser = cli._parser()
    subs = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    missing = []
    for name, sp in [("gapsweep", parser), *subs.choices.items()]:
        for a in sp._actions:
            if isinstance(a, (argparse._HelpAction, argparse._SubParsersAction)):
                continue
            if not a.help:
                missing.append(f"{name} {a.dest}")
    assert not missing, missing


def test_closed_pipe_exits_cleanly(tmp_path):
    # The reader is gone before gapsweep writes: no traceback, no "Broken pipe", exit 141 like a SIGPIPE kill.
    p = subprocess.Popen([sys.executable, "-m", "gapsweep", "plan", str(ROOT / "jobs" / "fig2_quick.toml")],
                         stdout=subprocess.PIPE, stderr=subprocess.PIPE, cwd=ROOT, env=ENV)
    p.stdout.close()
    err = p.stderr.read().decode()
    rc = p.wait(timeout=120)
    assert rc == 141, (rc, err)
    assert "Traceback" not in err and "BrokenPipe" not in err and "Broken pipe" not in err, err


def test_import_selects_no_matplotlib_backend():
    code = ("import sys, matplotlib, gapsweep.analysis, gapsweep.analysis.figures, gapsweep.analysis.report, "
            "gapsweep.demo, gapsweep.cli; "
            "assert 'matplotlib.pyplot' not in sys.modules, 'pyplot imported'; "
            "b = matplotlib.rcParams._get_backend_or_none(); assert b is None, b; print('ok')")
    env = {k: v for k, v in ENV.items() if k != "MPLBACKEND"}
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT, env=env, timeout=120)
    assert r.returncode == 0 and r.stdout.strip() == "ok", r.stderr[-2000:]


def test_library_logs_and_cli_configures(tmp_path, caplog):
    import logging

    assert not any(getattr(h, "_gapsweep_cli", False) for h in logging.getLogger("gapsweep").handlers)
    from gapsweep import sde

    with caplog.at_level(logging.DEBUG, logger="gapsweep"):
        if sde._cuda_driver_present():
            pytest.skip("an NVIDIA driver is present: nothing to silence")
        sde._warp()
    assert any("warp runs on the CPU only" in r.getMessage() for r in caplog.records)


def test_missing_extra_names_it(monkeypatch):
    monkeypatch.setitem(sys.modules, "warp", None)  # import warp -> ImportError
    from gapsweep import sde

    with pytest.raises(MissingExtraError, match=r"gapsweep\[sde\]"):
        sde._warp()
    with pytest.raises(MissingExtraError, match=r"'no_such_pkg'.*gapsweep\[all\]"):
        require("no_such_pkg", "a test feature")


def test_cupy_backend_without_cupy_names_gpu_extra():
    try:
        import cupy  # noqa: F401

        pytest.skip("cupy is installed")
    except ImportError:
        pass
    from gapsweep import gfmd, surface

    h = surface.self_affine(32, 0.3, lambda_l=0.25, lambda_s=1 / 8, rms_slope=1.0, seed=0)
    with pytest.raises(MissingExtraError, match=r"pip install 'gapsweep\[gpu\]'"):
        gfmd.solve(h, sigma0=1e-2, gamma0=1e-3, rho=2e-2, backend="cupy")
    # The same message in a plain interpreter (outside pytest's import machinery).
    r = subprocess.run([sys.executable, "-c", "import sys; from gapsweep.core.extras import require; "
                        "require('cupy', 'GFMD on the GPU')"], capture_output=True, text=True, env=ENV, timeout=60)
    assert r.returncode != 0 and "gapsweep[gpu]" in r.stderr


def test_warp_says_nothing_without_a_driver():
    pytest.importorskip("warp")
    from gapsweep import sde

    if sde._cuda_driver_present():
        pytest.skip("an NVIDIA driver is present")
    code = "from gapsweep import sde; wp = sde._warp(); print(wp.get_device('cpu'))"
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT, env=ENV, timeout=300)
    assert r.returncode == 0, r.stderr[-2000:]
    assert "CUDA" not in r.stderr and "cuda" not in r.stderr.lower(), r.stderr


def test_demo_job_ships_as_package_data():
    from gapsweep import jobs, spec

    p = jobs.path("demo")
    js = spec.load(p)
    assert js.name == "demo" and set(js.methods) >= {"theory", "gfmd", "sde", "fokker_planck"}
    assert (ROOT / "jobs" / "demo.toml").resolve() == p.resolve()
    assert np.isclose(js.surface["lambda_s"], 2.5e-3)
