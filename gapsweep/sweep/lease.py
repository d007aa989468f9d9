"""The store lease: an application-level, exclusive claim on a store (``docs/reliability.md``).

HDF5's own file lock is not enough: it is taken only after a file opened with mode ``"w"`` has been truncated,
it is switched off by ``HDF5_USE_FILE_LOCKING=FALSE`` (needed on many cluster file systems) and the ``mpio``
driver does not take it at all. So every writer (serial, MPI rank 0 for the rank-0 and the mpio writer, merge)
first creates ``<store>.lease`` with ``O_CREAT | O_EXCL`` -- atomic on local and NFSv3+ file systems -- holding
host, pid, process start time, run id and start time as JSON, and removes it when it is done.

A lease whose process is gone (same host, pid dead or reused) is *stale*: it is reported and broken only when
asked (``--break-lease``). A lease of another host cannot be checked from here; breaking it is the user's call.
"""

from __future__ import annotations

import contextlib
import json
import logging
import os
import socket
import uuid
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from gapsweep.sweep import provenance

__all__ = ["Lease", "LeaseError", "acquire", "lease_path", "read"]

log = logging.getLogger("gapsweep.lease")


class LeaseError(RuntimeError):
    """The store is leased by another run (alive, stale or on another host)."""


def lease_path(store: str | Path) -> Path:
    p = Path(store)
    return p.with_name(p.name + ".lease")


def _proc_stat(pid: int) -> list[str]:
    """Fields of /proc/<pid>/stat after the command name (state first); [] where unknown."""
    try:
        return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    except (OSError, IndexError):
        return []


def _proc_start(pid: int) -> str:
    """Start time of a process (clock ticks since boot, /proc/<pid>/stat field 22); '' where unknown."""
    f = _proc_stat(pid)
    return f[19] if len(f) > 19 else ""


def _alive(info: dict[str, Any]) -> bool | None:
    """True/False for a lease of this host, None for another host (cannot tell)."""
    if info.get("host") != socket.gethostname():
        return None
    pid = int(info.get("pid", -1))
    if pid <= 0:
        return False
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        pass
    stat = _proc_stat(pid)
    if stat and stat[0] in ("Z", "X"):  # killed, not yet reaped
        return False
    start = info.get("proc_start", "")
    return not (start and len(stat) > 19 and stat[19] != start)  # pid reused by another process


def read(store: str | Path) -> dict[str, Any] | None:
    """The lease of a store as a dict (``alive``: True/False/None added), or None when there is none."""
    p = lease_path(store)
    try:
        text = p.read_text()
    except FileNotFoundError:
        return None
    try:
        info = json.loads(text)
        if not isinstance(info, dict):
            raise ValueError
    except ValueError:
        info = {"host": "?", "pid": -1, "run_id": "?", "started": "?", "damaged": True}
    info["alive"] = _alive(info)
    return info


def describe(info: dict[str, Any]) -> str:
    state = {True: "alive", False: "no longer running", None: "on another host, cannot be checked"}[info["alive"]]
    return (f"run {info.get('run_id')} (host {info.get('host')}, pid {info.get('pid')}, started "
            f"{info.get('started')}; {state})")


@dataclass
class Lease:
    """A held lease; :meth:`release` (or the context manager) removes the file if it is still ours."""

    path: Path
    run_id: str

    def release(self) -> None:
        try:
            info = json.loads(self.path.read_text())
        except (OSError, ValueError):
            return
        if info.get("run_id") == self.run_id:
            with contextlib.suppress(FileNotFoundError):
                self.path.unlink()

    def __enter__(self) -> Lease:
        return self

    def __exit__(self, *exc: Any) -> None:
        self.release()


def acquire(store: str | Path, *, break_lease: bool = False, purpose: str = "run") -> Lease:
    """Take the lease of ``store`` or raise :class:`LeaseError` naming the holder.

    ``break_lease`` takes over a lease whose holder is not alive on this host or is on another host; a live
    holder on this host is never broken."""
    p = lease_path(store)
    p.parent.mkdir(parents=True, exist_ok=True)
    run_id = uuid.uuid4().hex[:12]
    info = {"host": socket.gethostname(), "pid": os.getpid(), "proc_start": _proc_start(os.getpid()),
            "run_id": run_id, "started": provenance.now(), "purpose": purpose}
    for _ in range(3):
        try:
            fd = os.open(p, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o644)
        except FileExistsError:
            old = read(store)
            if old is None:  # released in between: try again
                continue
            if old["alive"] is True:
                raise LeaseError(f"store {store} is in use by {describe(old)}; wait for it to finish or stop "
                                 f"it (lease file {p})") from None
            if not break_lease:
                raise LeaseError(f"store {store} is leased by {describe(old)}: if that run is really gone, "
                                 f"pass --break-lease (lease file {p})") from None
            log.warning("breaking the lease of %s held by %s", store, describe(old))
            # rename first: of two processes breaking the same lease only one succeeds
            with contextlib.suppress(FileNotFoundError):
                os.replace(p, p.with_name(p.name + f".broken-{run_id}"))
                os.unlink(p.with_name(p.name + f".broken-{run_id}"))
            continue
        try:
            with os.fdopen(fd, "w") as fh:
                json.dump(info, fh)
                fh.flush()
                os.fsync(fh.fileno())
        except OSError as e:
            p.unlink(missing_ok=True)
            raise LeaseError(f"store {store}: cannot write its lease file {p} ({e.strerror})") from None
        return Lease(p, run_id)
    raise LeaseError(f"store {store}: could not take the lease {p} (another process keeps taking it)")
