"""The growth probe of a store (gapsweep.sweep.budget.probe_growth, docs/reliability.md): it answers "can this
file grow by n bytes" with an OSError exactly when the write would fail (a file-size limit here), and no
process leaves a scratch file beside the store, even one SIGKILLed in the middle of the probe (Open MPI kills
ranks 1 s after forwarding a signal; a 1 MB ``.s.h5.probe-<pid>`` was found beside an interrupted store)."""

from __future__ import annotations

import os
import resource
import signal
import subprocess
import sys
from pathlib import Path

import pytest

from gapsweep.sweep import budget

ROOT = Path(__file__).resolve().parent.parent


def _child(code: str, cwd: Path, fsize: int | None = None) -> subprocess.CompletedProcess:
    def limit() -> None:
        if fsize is not None:
            resource.setrlimit(resource.RLIMIT_FSIZE, (fsize, fsize))
            signal.signal(signal.SIGXFSZ, signal.SIG_IGN)  # a write past the limit fails with EFBIG instead

    return subprocess.run([sys.executable, "-c", code], cwd=cwd, capture_output=True, text=True, timeout=60,
                          env={**os.environ, "PYTHONPATH": str(ROOT)}, preexec_fn=limit)


@pytest.mark.parametrize("unnamed", [True, False])
def test_probe_leaves_nothing_and_sees_the_size_limit(tmp_path, monkeypatch, unnamed):
    """Under a 4 MiB file-size limit: a store of 1 MiB can grow by 1 MiB, one of 3.5 MiB cannot (EFBIG); the
    folder holds only the store afterwards, with unnamed scratch files and with the named fallback."""
    store = tmp_path / "s.h5"
    store.write_bytes(b"x" * (1 << 20))
    flag = "" if unnamed else "import os; del os.O_TMPFILE; "
    code = (f"{flag}from gapsweep.sweep import budget; import errno\n"
            "budget.probe_growth('s.h5')\n"
            "try:\n    budget.probe_growth('s.h5', size=7 << 19)\nexcept OSError as e:\n"
            "    print('refused', errno.errorcode[e.errno])\n")
    p = _child(code, tmp_path, fsize=4 << 20)
    assert p.returncode == 0, p.stderr
    assert p.stdout.split() == ["refused", "EFBIG"]
    assert sorted(x.name for x in tmp_path.iterdir()) == ["s.h5"]


@pytest.mark.parametrize("unnamed", [True, False])
def test_probe_killed_midway_leaves_nothing(tmp_path, unnamed):
    """The process SIGKILLs itself with the scratch file open and written (the moment mpiexec's kill meets a
    rank's probe): nothing is left in the folder."""
    (tmp_path / "s.h5").write_bytes(b"x" * 1000)
    flag = "" if unnamed else "del os.O_TMPFILE; "
    code = (f"import os, signal; {flag}from pathlib import Path; from gapsweep.sweep import budget\n"
            "fd = budget._scratch(Path('s.h5')); os.write(fd, b'\\0' * (1 << 20)); os.fsync(fd)\n"
            "os.kill(os.getpid(), signal.SIGKILL)\n")
    p = _child(code, tmp_path)
    assert p.returncode == -signal.SIGKILL, p.stderr
    assert sorted(x.name for x in tmp_path.iterdir()) == ["s.h5"]


def test_probe_in_a_folder_without_write_permission_raises(tmp_path):
    """No permission to create files beside the store: an OSError (the caller reports the store as unable to
    grow), not a silent pass."""
    if os.geteuid() == 0:
        pytest.skip("root writes anywhere")
    (tmp_path / "s.h5").write_bytes(b"x")
    tmp_path.chmod(0o500)
    try:
        with pytest.raises(OSError):
            budget.probe_growth(tmp_path / "s.h5")
    finally:
        tmp_path.chmod(0o700)
