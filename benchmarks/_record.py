"""Provenance of benchmark results (issue 40 item 11; docs/benchmarks.md "How numbers are checked").

Every benchmark script names the code it measures (``CODE_PATHS``: files or folders of this repository) and
calls :func:`track` once at its start::

    sys.path.insert(0, str(Path(__file__).resolve().parent))
    import _record  # noqa: E402
    CODE_PATHS = ["gapsweep/gfmd", "gapsweep/core"]
    _record.track(CODE_PATHS)

At the script's exit every result file it wrote (files under ``benchmarks/results/`` and under the paths given
to its ``--out``/``--out-dir``/``--json``/``--csv`` options, modified since the start, that this process opened
for writing -- or that a child wrote and no other tracked run has stamped since) is stamped with
:func:`record`: the project's commit (of *this* repository: ``git -C <repo root> rev-parse HEAD``, never an
enclosing repository's; where GAPSWEEP_COMMIT holds a 40-hex commit, that one, for a copy of the working tree
without .git such as a lent GPU machine gets, else None), its commit time, whether the code paths had uncommitted
changes, the command, the machine, the date and the library versions, and ``code_paths``. A JSON file holding an
object gets a ``"provenance"`` key; any other file a sidecar ``<file>.provenance.json``. A script whose result is
its standard output (redirected into a file) is tracked with ``header=True``: the record is printed first, as a
line ``# provenance: {...}``.

``scripts/check_docs.py`` reads these records: a cited result whose code paths changed after its commit is
stale, and fails the check.
"""

from __future__ import annotations

import atexit
import json
import os
import platform
import re
import shlex
import signal
import socket
import subprocess
import sys
import time
from importlib import metadata
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "benchmarks" / "results"
SIDECAR = ".provenance.json"
HEADER = "# provenance: "
OUT_OPTIONS = ("--out", "--out-dir", "--outdir", "--json", "--csv", "--log")
# distributions whose versions a result records (those installed)
PACKAGES = ("gapsweep", "numpy", "scipy", "h5py", "pandas", "numba", "pyFFTW", "mpi4py", "warp-lang", "cupy",
            "cupy-cuda13x", "cupy-cuda12x", "cupy-cuda11x", "nvidia-nccl-cu12", "nvidia-nccl-cu13",
            "SurfaceTopography", "ContactMechanics", "tamaas")


def _git(root: Path, *args: str, timeout: float = 30) -> str | None:
    """``git -C root ARGS``'s stripped output, or None when it fails, is missing or outlasts ``timeout`` s
    (also scripts/check_docs.py's provenance check)."""
    try:
        p = subprocess.run(["git", "-C", str(root), *args], capture_output=True, text=True, timeout=timeout)
    except (OSError, subprocess.SubprocessError):
        return None
    return p.stdout.strip() if p.returncode == 0 else None


def project_commit(root: Path = ROOT) -> str | None:
    """The commit checked out in the repository whose top is ``root``; None when ``root`` is not the top of a
    git checkout (a source archive unpacked inside another repository must not take that repository's commit)."""
    top = _git(root, "rev-parse", "--show-toplevel")
    if top is None or Path(top).resolve() != Path(root).resolve():
        return None
    return _git(root, "rev-parse", "--verify", "HEAD")


def _machine() -> dict[str, Any]:
    out: dict[str, Any] = {"hostname": socket.gethostname(), "platform": platform.platform(),
                           "cpus": os.cpu_count()}
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                out["cpu"] = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    try:
        p = subprocess.run(["nvidia-smi", "--query-gpu=name,driver_version,memory.total", "--format=csv,noheader"],
                           capture_output=True, text=True, timeout=20)
        if p.returncode == 0 and p.stdout.strip():
            out["gpus"] = [x.strip() for x in p.stdout.strip().splitlines()]
    except (OSError, subprocess.SubprocessError):
        pass
    return out


def _versions() -> dict[str, str]:
    out = {"python": platform.python_version()}
    for name in PACKAGES:
        try:
            out[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            continue
    if "gapsweep" not in out:  # a checkout on PYTHONPATH, not installed
        try:
            sys.path.insert(0, str(ROOT))
            import gapsweep

            out["gapsweep"] = gapsweep.__version__
        except Exception:
            pass
    return out


def record(code_paths: list[str], argv: list[str] | None = None, root: Path = ROOT) -> dict[str, Any]:
    """The provenance of a result measured now (module docstring). ``code_paths``: files or folders relative to
    ``root``; each must exist (a misspelt path would make the staleness check blind)."""
    missing = [p for p in code_paths if not (root / p).exists()]
    if missing:
        raise ValueError(f"CODE_PATHS: no such file or folder in {root}: {', '.join(missing)}")
    commit, source = project_commit(root), "git"
    env_commit = os.environ.get("GAPSWEEP_COMMIT", "")
    if re.fullmatch(r"[0-9a-f]{40}", env_commit):
        # a copy of the checkout (a lent GPU machine gets the working tree, without .git or with the .git of an
        # older commit than the files it holds): the commit the caller says it is a copy of wins
        # (benchmarks/remeasure_gpu.sh passes git rev-parse HEAD); dirty unknown
        commit, source = env_commit, "GAPSWEEP_COMMIT"
        if _git(root, "cat-file", "-e", f"{commit}^{{commit}}") is not None:
            # the copy's .git knows that commit: its code must be that commit's (a command that expanded
            # $(git rev-parse HEAD) on the lent machine named the .git's commit, not the files' one)
            differ = _git(root, "diff", "--name-only", commit, "--", *code_paths)
            if differ:
                raise ValueError(f"GAPSWEEP_COMMIT={commit[:12]}: the code measured differs from that commit "
                                 f"({', '.join(differ.splitlines()[:3])}): pass the commit this tree is a copy of, "
                                 "expanded where the commit was made (git rev-parse HEAD there)")
    rec: dict[str, Any] = {"commit": commit, "commit_source": source if commit else None,
                           "commit_time": None, "dirty": None,
                           "command": shlex.join([Path(sys.executable).name, *(sys.argv if argv is None else argv)]),
                           "cwd": os.getcwd(), "machine": _machine(),
                           "date": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()), "versions": _versions(),
                           "code_paths": list(code_paths)}
    if source == "git" and commit is not None:
        t = _git(root, "show", "-s", "--format=%ct", commit)
        rec["commit_time"] = int(t) if t and t.isdigit() else None
        status = _git(root, "status", "--porcelain", "--", *code_paths)
        rec["dirty"] = bool(status) if status is not None else None
    return rec


def stamp(path: str | Path, rec: dict[str, Any]) -> Path:
    """Attach ``rec`` to the result file ``path``: a ``"provenance"`` key of a JSON object, else a sidecar
    ``<path>.provenance.json``. Returns the file written."""
    path = Path(path)
    if path.suffix == ".json":
        try:
            data = json.loads(path.read_text(encoding="utf-8"))
        except (OSError, ValueError):
            data = None
        if isinstance(data, dict):
            data["provenance"] = rec
            tmp = path.with_name(f".{path.name}.tmp{os.getpid()}")
            tmp.write_text(json.dumps(data, indent=1) + "\n", encoding="utf-8")
            os.replace(tmp, path)
            return path
    side = path.with_name(path.name + SIDECAR)
    side.write_text(json.dumps(rec, indent=1) + "\n", encoding="utf-8")
    return side


def read(path: str | Path) -> dict[str, Any] | None:
    """The provenance recorded for a result file (its ``"provenance"`` key, its sidecar, or a ``# provenance:``
    line of a text file); None when it has none."""
    path = Path(path)
    side = path.with_name(path.name + SIDECAR)
    if side.is_file():
        try:
            return json.loads(side.read_text(encoding="utf-8"))
        except ValueError:
            return None
    try:
        text = path.read_text(encoding="utf-8", errors="replace")
    except OSError:
        return None
    if path.suffix == ".json":
        try:
            data = json.loads(text)
        except ValueError:
            return None
        rec = data.get("provenance") if isinstance(data, dict) else None
        return rec if isinstance(rec, dict) else None
    for line in text.splitlines()[:50]:
        if line.startswith(HEADER):
            try:
                return json.loads(line[len(HEADER):])
            except ValueError:
                return None
    return None


def _out_paths(argv: list[str]) -> list[Path]:
    out = []
    for i, a in enumerate(argv):
        for opt in OUT_OPTIONS:
            if a == opt and i + 1 < len(argv):
                out.append(Path(argv[i + 1]))
            elif a.startswith(opt + "="):
                out.append(Path(a.split("=", 1)[1]))
    return out


def _written_since(t0: float, places: list[Path]) -> list[Path]:
    found: set[Path] = set()
    for place in places:
        files = [place] if place.is_file() else (place.rglob("*") if place.is_dir() else [])
        for f in files:
            try:
                if f.is_file() and not f.name.endswith(SIDECAR) and f.stat().st_mtime >= t0:
                    found.add(f.resolve())
            except OSError:
                continue
    return sorted(found)


def track(code_paths: list[str], *, header: bool = False) -> dict[str, Any]:
    """Record this run's provenance now; at exit, stamp every result file it wrote (module docstring).
    ``header``: also print the record as the first line of standard output (for a result that is the output)."""
    rec = record(code_paths)
    rank = next((os.environ[v] for v in ("OMPI_COMM_WORLD_RANK", "PMI_RANK", "PMIX_RANK") if v in os.environ), "0")
    if rank != "0":  # under MPI rank 0 alone stamps (and prints)
        return rec
    t0 = time.time() - 1.0  # file systems with coarse time stamps
    if header:
        print(HEADER + json.dumps(rec), flush=True)

    own = _OpenedForWriting()
    sys.addaudithook(own)

    def at_exit() -> None:
        mine = own.paths()
        for f in _written_since(t0, [RESULTS, *_out_paths(sys.argv)]):
            if f not in mine and _claimed(f):
                continue  # written and stamped by another tracked run at the same time: its record, not ours
            try:
                stamp(f, rec)
            except OSError as e:
                print(f"benchmarks/_record.py: cannot stamp {f}: {e}", file=sys.stderr)

    atexit.register(at_exit)
    _exit_on_sigterm()
    return rec


def _exit_on_sigterm() -> None:
    """A run stopped by ``timeout`` (SIGTERM; the GPU stages of benchmarks/gpu_challenge_refine.sh are cut so on
    purpose and keep what they wrote) exits through ``SystemExit``, so that the stamping at exit still runs:
    Python's default for SIGTERM ends the process without running ``atexit``. A handler the script installed
    itself is left alone."""
    if signal.getsignal(signal.SIGTERM) is not signal.SIG_DFL:
        return

    def stop(signum: int, frame: Any) -> None:
        raise SystemExit(128 + signum)

    try:
        signal.signal(signal.SIGTERM, stop)
    except ValueError:  # not the main thread: the default stays
        pass


class _OpenedForWriting:
    """An audit hook (``sys.addaudithook``) collecting the files this process opens for writing or renames into
    place: the result files a run wrote itself, told apart from those another run wrote at the same time. Paths
    are kept as given (with the working folder) and resolved only at exit: the hook sees every open."""

    _WRITE = os.O_WRONLY | os.O_RDWR | os.O_CREAT | os.O_APPEND | os.O_TRUNC

    def __init__(self) -> None:
        self.raw: list[tuple[str, str]] = []

    def __call__(self, event: str, args: tuple) -> None:
        try:
            if event == "open":
                path, mode, flags = args
                if isinstance(mode, str):
                    writes = any(c in mode for c in "wax+")
                else:
                    writes = isinstance(flags, int) and bool(flags & self._WRITE)
                if writes and isinstance(path, (str, bytes, os.PathLike)):
                    self.raw.append((os.fsdecode(path), os.getcwd()))
            elif event == "os.rename":
                self.raw.append((os.fsdecode(args[1]), os.getcwd()))
        except Exception:  # an audit hook must never break the benchmark it watches
            pass

    def paths(self) -> set[Path]:
        out = set()
        for p, cwd in self.raw:
            try:
                out.add((Path(cwd) / p).resolve())
            except OSError:
                continue
        return out


def _claimed(f: Path) -> bool:
    """Whether a result file this process did not write carries a record made after it was written (by the
    tracked run that wrote it): a JSON object with its ``provenance`` key, a text file with its header line, or a
    sidecar newer than the file. A file a child process wrote (no record) is this run's to stamp."""
    side = f.with_name(f.name + SIDECAR)
    try:
        if side.is_file():
            return side.stat().st_mtime >= f.stat().st_mtime
    except OSError:
        return False
    return (read(f) is not None and f.suffix == ".json") or _has_header(f)


def _has_header(f: Path) -> bool:
    try:
        with open(f, encoding="utf-8", errors="replace") as fh:
            return any(line.startswith(HEADER) for _, line in zip(range(50), fh))
    except OSError:
        return False
