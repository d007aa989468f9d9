"""Issue 19 item 12: numba's cache of gapsweep's kernels goes to a per-user folder, never into the source tree;
issue 29 item 6: without changing anything process-wide (no NUMBA_CACHE_DIR set, other code's cache untouched)."""

from __future__ import annotations

import os
import subprocess
import sys
import time
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PYCACHE = ROOT / "gapsweep" / "gfmd" / "__pycache__"

CODE = """
import os, numpy as np
import gapsweep
before = dict(os.environ)
from gapsweep.gfmd import _ops
k = _ops._numba_kernels()
a = np.ones((4, 3), complex)
print(os.path.dirname(k.dot._cache._cache_path))
print(k.dot(a, a, True))
print(dict(os.environ) == before and os.environ.get("NUMBA_CACHE_DIR", "-") == before.get("NUMBA_CACHE_DIR", "-"))
"""

# a user's own cached function beside gapsweep's: numba's default (its own __pycache__), not gapsweep's folder
USER = """
import numba, numpy as np, gapsweep
from gapsweep.gfmd import _ops
a = np.ones((4, 3), complex)
_ops._numba_kernels().dot(a, a, True)

@numba.njit(cache=True)
def twice(x):
    return 2 * x

print(twice(3))
print(twice._cache._cache_path)
"""


def _env(tmp_path: Path, **kw: str) -> dict[str, str]:
    e = {k: v for k, v in os.environ.items() if k not in ("NUMBA_CACHE_DIR", "XDG_CACHE_HOME")}
    e.update(HOME=str(tmp_path / "home"), PYTHONPATH=str(ROOT), **kw)
    return e


def _new_in_tree(since: float) -> list[Path]:
    return [p for p in PYCACHE.glob("*.nb[ic]") if p.stat().st_mtime >= since] if PYCACHE.is_dir() else []


@pytest.mark.timeout(300)
@pytest.mark.parametrize("how", ["home", "xdg", "explicit"])
def test_numba_cache_outside_the_tree(tmp_path, how):
    """Compiling a cached GFMD kernel writes its index and code into ~/.cache/gapsweep/numba (or
    $XDG_CACHE_HOME/gapsweep/numba, or the user's own $NUMBA_CACHE_DIR), and nothing new into the package's
    __pycache__ (numba's default, which the old code used)."""
    pytest.importorskip("numba")
    kw = {"xdg": {"XDG_CACHE_HOME": str(tmp_path / "xdg")}, "explicit": {"NUMBA_CACHE_DIR": str(tmp_path / "nc")},
          "home": {}}[how]
    want = {"home": tmp_path / "home" / ".cache" / "gapsweep" / "numba",
            "xdg": tmp_path / "xdg" / "gapsweep" / "numba", "explicit": tmp_path / "nc"}[how]
    (tmp_path / "home").mkdir()
    t0 = time.time() - 1
    p = subprocess.run([sys.executable, "-c", CODE], env=_env(tmp_path, **kw), capture_output=True, text=True,
                       timeout=280, cwd=tmp_path)
    assert p.returncode == 0, p.stderr
    lines = p.stdout.split()
    assert Path(lines[0]) == want
    assert float(lines[1]) == 4 * (1 + 2 + 1)  # |a|^2 = 1 with half-spectrum weights 1, 2, 1 (even n), 4 rows
    assert lines[2] == "True"  # the process environment is as it was: nothing set for children
    assert list(want.rglob("*.nbi")) and list(want.rglob("*.nbc"))
    assert _new_in_tree(t0) == []


@pytest.mark.timeout(300)
def test_other_code_keeps_numbas_default(tmp_path):
    """A user's own ``cache=True`` function in the same process caches where numba puts it without gapsweep
    (beside its source: numba's in-tree locator), and gapsweep's folder gets none of it."""
    pytest.importorskip("numba")
    (tmp_path / "home").mkdir()
    script = tmp_path / "user_code.py"
    script.write_text(USER)
    p = subprocess.run([sys.executable, str(script)], env=_env(tmp_path), capture_output=True, text=True,
                       timeout=280, cwd=tmp_path)
    assert p.returncode == 0, p.stderr
    lines = p.stdout.split()
    assert lines[0] == "6"
    assert Path(lines[1]) == tmp_path / "__pycache__"
    assert list((tmp_path / "__pycache__").glob("user_code.twice-*.nbi"))
    mine = tmp_path / "home" / ".cache" / "gapsweep" / "numba"
    assert list(mine.rglob("*.nbi")) and not list(mine.rglob("user_code*"))
