"""The store lease: an application-level, exclusive claim on a store (``docs/reliability.md``).

HDF5's own file lock is not enough: it is taken only after a file opened with mode ``"w"`` has been truncated,
it is switched off by ``HDF5_USE_FILE_LOCKING=FALSE`` (needed on many cluster file systems) and the ``mpio``
driver does not take it at all. So every writer (serial, MPI rank 0 for the rank-0 and the mpio writer, merge)
first creates ``<store>.lease`` with ``O_CREAT | O_EXCL`` -- atomic on local and NFSv3+ file systems -- holding
host, pid, process start time, run id and start time as JSON, and removes it when it is done.

The lease is keyed by the *file*, not by the path as typed (issue 19): the lease file sits beside the store's
resolved path (a symlink, or a symlinked folder, leads to the same lease), and when the store exists a second
lease keyed by its identity -- device and inode -- is taken in a host-local folder (``$GAPSWEEP_LEASE_DIR``,
default ``<tmp>/gapsweep-leases``): a hard link or another mount path of the same file finds it. The runner
checks the identity again after opening the store (:meth:`Lease.bind`), so a store created or replaced under
the lease is covered too. The identity lease is only as wide as the host (device numbers of a network file
system differ between nodes); across nodes the path lease beside the store does the work.

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

from gapsweep.sweep import limits, provenance

__all__ = ["Lease", "LeaseError", "acquire", "identity_path", "lease_path", "read"]

log = logging.getLogger("gapsweep.lease")


class LeaseError(RuntimeError):
    """The store is leased by another run (alive, stale or on another host)."""


def lease_path(store: str | Path) -> Path:
    """``<store>.lease`` beside the store's resolved path (symlinks followed, so every path to it agrees)."""
    p = Path(store).resolve()
    return p.with_name(p.name + ".lease")


def _registry() -> Path:
    import tempfile

    return Path(os.environ.get("GAPSWEEP_LEASE_DIR") or Path(tempfile.gettempdir(), "gapsweep-leases"))


def identity_path(store: str | Path) -> Path | None:
    """The host-local lease keyed by the store file's device and inode (None while the store does not exist)."""
    try:
        st = os.stat(store)
    except OSError:
        return None
    return _registry() / f"{socket.gethostname()}-{st.st_dev}-{st.st_ino}.lease"


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
    return _read_file(lease_path(store))


def _read_file(p: Path) -> dict[str, Any] | None:
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
    ident: Path | None = None
    info: dict[str, Any] | None = None
    break_lease: bool = False

    def release(self) -> None:
        with limits.deferred():  # a signal here must not leave half the lease behind
            if self.ident is not None:
                _release_file(self.ident, self.run_id)
                self.ident = None
            _release_file(self.path, self.run_id)

    def mark_interrupted(self) -> None:
        """Say in the lease files that this run has recorded its interruption in the store: if the process is
        then killed before it can release them (Open MPI's mpiexec SIGKILLs its ranks 1 s after forwarding a
        signal), the next run takes the lease over without --break-lease -- the holder is gone and said so."""
        with limits.deferred():
            for p in (self.path, self.ident):
                if p is None:
                    continue
                try:
                    info = json.loads(p.read_text())
                    if info.get("run_id") != self.run_id:
                        continue
                    tmp = p.with_name(p.name + f".mark-{self.run_id}")
                    tmp.write_text(json.dumps({**info, "interrupted": True}))
                    os.replace(tmp, p)
                except (OSError, ValueError) as e:
                    log.warning("lease %s: cannot mark it interrupted (%s)", p, e)

    def bind(self, store: str | Path) -> None:
        """Check the store's identity again (after it was opened, created or replaced): hold the identity lease
        of the file now at ``store``; raise :class:`LeaseError` when another run holds that file."""
        ident = identity_path(store)
        if ident == self.ident:
            return
        if ident is not None:
            try:
                _take(ident, {**(self.info or {}), "run_id": self.run_id}, store, self.break_lease, self.path)
            except OSError as e:  # no usable lease folder on this host: the path lease still holds
                log.warning("store %s: cannot take its identity lease %s (%s); a second run through a hard link "
                            "of this file would not be detected", store, ident, e)
                return
        if self.ident is not None:
            _release_file(self.ident, self.run_id)
        self.ident = ident

    def __enter__(self) -> Lease:
        return self

    def __exit__(self, *exc: Any) -> None:
        self.release()


def _release_file(p: Path, run_id: str) -> None:
    try:
        info = json.loads(p.read_text())
    except (OSError, ValueError):
        return
    if info.get("run_id") == run_id:
        with contextlib.suppress(FileNotFoundError):
            p.unlink()


def _orphan(old: dict[str, Any]) -> bool:
    """An identity lease whose path lease is gone (released or broken): left behind by a killed run, holds
    nothing -- removed without asking (the path lease is what --break-lease speaks for)."""
    lp = old.get("lease")
    if not lp or old["alive"] is True:
        return False
    other = _read_file(Path(lp))
    return other is None or other.get("run_id") != old.get("run_id")


def _take(p: Path, info: dict[str, Any], store: str | Path, break_lease: bool, main: Path | None) -> None:
    """Create the lease file ``p`` holding ``info`` (O_EXCL), or raise :class:`LeaseError` naming the holder.
    ``main``: for an identity lease, the path lease it belongs with."""
    via = ""
    if main is not None:
        info = {**info, "lease": str(main), "store": str(Path(store).resolve())}
    for _ in range(3):
        try:
            fd = os.open(p, os.O_CREAT | os.O_EXCL | os.O_WRONLY | getattr(os, "O_NOFOLLOW", 0), 0o644)
        except FileExistsError:
            old = _read_file(p)
            if old is None:  # released in between: try again
                continue
            if main is not None:
                if old.get("run_id") == info["run_id"]:
                    return  # ours already
                via = f" through another path ({old.get('store')}: the same file, device and inode)"
            if main is not None and _orphan(old):
                log.debug("removing the orphaned identity lease %s", p)
            elif old["alive"] is True:
                raise LeaseError(f"store {store} is in use by {describe(old)}{via}; wait for it to finish or "
                                 f"stop it (lease file {p})") from None
            elif old["alive"] is False and old.get("interrupted"):
                log.info("taking over the lease of %s: %s recorded its interruption in the store", store,
                         describe(old))
            elif not break_lease:
                raise LeaseError(f"store {store} is leased by {describe(old)}{via}: if that run is really gone, "
                                 f"pass --break-lease (lease file {p})") from None
            else:
                log.warning("breaking the lease of %s held by %s", store, describe(old))
            # rename first: of two processes breaking the same lease only one succeeds
            with contextlib.suppress(FileNotFoundError):
                os.replace(p, p.with_name(p.name + f".broken-{info['run_id']}"))
                os.unlink(p.with_name(p.name + f".broken-{info['run_id']}"))
            continue
        try:
            with os.fdopen(fd, "w") as fh:
                json.dump(info, fh)
                fh.flush()
                os.fsync(fh.fileno())
        except OSError as e:
            p.unlink(missing_ok=True)
            raise LeaseError(f"store {store}: cannot write its lease file {p} ({e.strerror})") from None
        return
    raise LeaseError(f"store {store}: could not take the lease {p} (another process keeps taking it)")


def acquire(store: str | Path, *, break_lease: bool = False, purpose: str = "run") -> Lease:
    """Take the lease of ``store`` or raise :class:`LeaseError` naming the holder.

    ``break_lease`` takes over a lease whose holder is not alive on this host or is on another host; a live
    holder on this host is never broken. The path lease is taken first, then (when the store exists) the
    identity lease; failing the second releases the first."""
    p = lease_path(store)
    p.parent.mkdir(parents=True, exist_ok=True)
    run_id = uuid.uuid4().hex[:12]
    info = {"host": socket.gethostname(), "pid": os.getpid(), "proc_start": _proc_start(os.getpid()),
            "run_id": run_id, "started": provenance.now(), "purpose": purpose}
    with limits.deferred():  # a signal between creating the lease file and owning it would leave it stale
        _take(p, info, store, break_lease, None)
        held = Lease(p, run_id, None, info, break_lease)
        try:
            reg = _registry()
            if not reg.is_dir():
                with contextlib.suppress(OSError):  # shared by the users of this host, like /tmp
                    reg.mkdir(parents=True, exist_ok=True)
                    reg.chmod(0o1777)
            held.bind(store)
        except BaseException:
            held.release()
            raise
    return held
