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

Neither file is enough alone (issue 31): a job with its own ``$TMPDIR`` or ``$GAPSWEEP_LEASE_DIR`` (Slurm gives
each job one) does not see the identity lease of another, and a hard link in another folder has another path
lease. So the holder also keeps an open-file-description lock (``F_OFD_SETLK``, :class:`FileLock`) on one byte
of the store file itself, far beyond its end: every path to the file (hard link, symlink, bind mount, another
``$TMPDIR``) meets it, the kernel drops it when the holder dies (no stale state), HDF5's own ``flock`` lock is
independent of it (local file systems), and on NFS v4 / Lustre with ``flock`` it reaches other nodes. Where the
file system has no such locks (``ENOLCK``, ``EOPNOTSUPP``) the files above still hold, with a warning.

A lease whose process is gone (same host, pid dead or reused) is *stale*: it is reported and broken only when
asked (``--break-lease``). A lease of another host cannot be checked from here; breaking it is the user's call.
"""

from __future__ import annotations

import contextlib
import errno
import json
import logging
import os
import socket
import struct
import uuid
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from gapsweep.sweep import limits, provenance

__all__ = ["FileLock", "Lease", "LeaseError", "acquire", "identity_path", "lease_path", "read", "remove_leftovers"]

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


_PID_MAX = 1 << 22  # Linux's pid_max limit (kernel.pid_max <= 2^22)


def _pid(v: Any) -> int | None:
    """The pid a lease names, or None where it names none that can be alive (missing, not an integer, <= 0,
    beyond pid_max: a damaged or hand-written lease is stale, never an error)."""
    try:
        pid = int(v)
    except (TypeError, ValueError, OverflowError):
        return None
    return pid if 0 < pid <= _PID_MAX else None


def _alive(info: dict[str, Any]) -> bool | None:
    """True/False for a lease of this host, None for another host (cannot tell)."""
    if info.get("host") != socket.gethostname():
        return None
    pid = _pid(info.get("pid"))
    if pid is None:
        return False
    try:
        os.kill(pid, 0)
    except (ProcessLookupError, OverflowError, ValueError):
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
    except (ValueError, RecursionError):
        info = {"host": "?", "pid": -1, "run_id": "?", "started": "?", "damaged": True}
    if not isinstance(info.get("host"), str):
        info["host"] = "?"  # a lease of unknown host cannot be judged from here: breakable with --break-lease
    info["alive"] = _alive(info)
    return info


def describe(info: dict[str, Any]) -> str:
    state = {True: "alive", False: "no longer running", None: "on another host, cannot be checked"}[info["alive"]]
    return (f"run {info.get('run_id')} (host {info.get('host')}, pid {info.get('pid')}, started "
            f"{info.get('started')}; {state})")


# The byte the lock covers: far beyond any store's end, so that no data access (HDF5, MPI-IO) ever locks it.
_LOCK_AT = 1 << 62
_NO_LOCKS = (errno.EINVAL, errno.ENOLCK, errno.EOPNOTSUPP, errno.ENOTSUP, errno.ENOSYS, errno.EBADF)


class FileLock:
    """An exclusive open-file-description lock (Linux ``F_OFD_SETLK``) on one byte of a store file: held while
    this object keeps its descriptor, dropped by the kernel when the process ends, met through every path to the
    file (the same inode). :meth:`take` returns False where another description (process) holds it."""

    def __init__(self) -> None:
        self.fd: int | None = None
        self.ino: tuple[int, int] | None = None

    @staticmethod
    def _flock(kind: int) -> bytes:
        # struct flock: l_type, l_whence, l_start, l_len, l_pid (0 for OFD locks); native alignment
        return struct.pack("@hhqqi", kind, os.SEEK_SET, _LOCK_AT, 1, 0).ljust(32, b"\0")

    def take(self, path: str | Path) -> bool | None:
        """True: locked (or already ours); False: held by another process; None: not supported here."""
        import fcntl

        setlk = getattr(fcntl, "F_OFD_SETLK", None)
        if setlk is None:
            return None
        try:
            fd = os.open(path, os.O_RDWR | getattr(os, "O_CLOEXEC", 0))
        except OSError as e:
            log.debug("store %s: cannot open it to lock it (%s)", path, e)
            return None
        st = os.fstat(fd)
        if self.fd is not None and self.ino == (st.st_dev, st.st_ino):
            os.close(fd)
            return True
        try:
            fcntl.fcntl(fd, setlk, self._flock(fcntl.F_WRLCK))
        except OSError as e:
            os.close(fd)
            if e.errno in (errno.EAGAIN, errno.EACCES):
                return False
            if e.errno in _NO_LOCKS:
                return None
            raise
        self.release()
        self.fd, self.ino = fd, (st.st_dev, st.st_ino)
        return True

    def release(self) -> None:
        if self.fd is not None:
            with contextlib.suppress(OSError):
                os.close(self.fd)  # closing the description drops its lock
            self.fd = self.ino = None


def locked(path: str | Path) -> bool:
    """Whether another process holds the writer's lock on the file at ``path`` (False where none, or where the
    file system has no such locks)."""
    lk = FileLock()
    try:
        return lk.take(path) is False
    finally:
        lk.release()


@dataclass
class Lease:
    """A held lease; :meth:`release` (or the context manager) removes the file if it is still ours."""

    path: Path
    run_id: str
    ident: Path | None = None
    info: dict[str, Any] | None = None
    break_lease: bool = False
    lock: FileLock | None = None

    def release(self) -> None:
        with limits.deferred():  # a signal here must not leave half the lease behind
            if self.lock is not None:
                self.lock.release()
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
                    if not isinstance(info, dict) or info.get("run_id") != self.run_id:
                        continue
                    tmp = p.with_name(p.name + f".mark-{self.run_id}")
                    tmp.write_text(json.dumps({**info, "interrupted": True}))
                    os.replace(tmp, p)
                except FileNotFoundError:
                    continue  # released, or never taken from this host
                except (OSError, ValueError) as e:
                    log.warning("lease %s: cannot mark it interrupted (%s)", p, e)

    def bind(self, store: str | Path) -> None:
        """Check the store's identity again (after it was opened, created or replaced): hold the identity lease
        of the file now at ``store`` and the lock on the file itself; raise :class:`LeaseError` when another run
        holds that file."""
        ident = identity_path(store)
        if ident != self.ident:
            self._take_identity(store, ident)
        self._lock_file(store)

    def _take_identity(self, store: str | Path, ident: Path | None) -> None:
        if ident is not None:
            try:
                _take(ident, {**(self.info or {}), "run_id": self.run_id}, store, self.break_lease, self.path)
            except OSError as e:  # no usable lease folder on this host: the path lease and the file lock hold
                log.debug("store %s: cannot take its identity lease %s (%s)", store, ident, e)
                return
        if self.ident is not None:
            _release_file(self.ident, self.run_id)
        self.ident = ident

    def _lock_file(self, store: str | Path) -> None:
        if not Path(store).exists():
            return
        if self.lock is None:
            self.lock = FileLock()
        got = self.lock.take(store)
        if got is False:
            raise LeaseError(f"store {store} is in use by another writer (alive: it holds the lock on the file "
                             "itself, through this or another path: a hard link, symlink or mount of the same "
                             "file); wait for it to finish or stop it") from None
        if got is None:
            log.warning("store %s: the file itself cannot be locked (no file locks on its file system, or no write "
                        "permission); a second run through another path (a hard link, another $TMPDIR) is detected "
                        "only by the lease files", store)

    def __enter__(self) -> Lease:
        return self

    def __exit__(self, *exc: Any) -> None:
        self.release()


def mark_ended(store: str | Path, run_id: str) -> None:
    """Any rank of an MPI job that is about to abort (issue 31): mark the run's lease files (found from the
    store's path and the run id every rank knows) as ended -- the job does not survive ``MPI_Abort`` -- so that
    the next run takes them over, without --break-lease, once their holder (rank 0) is seen dead."""
    paths = [lease_path(store)]
    ident = identity_path(store)
    if ident is not None:
        paths.append(ident)
    Lease(paths[0], run_id, paths[1] if len(paths) > 1 else None).mark_interrupted()


def _release_file(p: Path, run_id: str) -> None:
    try:
        info = json.loads(p.read_text())
    except (OSError, ValueError, RecursionError):
        return
    if isinstance(info, dict) and info.get("run_id") == run_id:
        with contextlib.suppress(FileNotFoundError):
            p.unlink()


def _orphan(old: dict[str, Any]) -> bool:
    """An identity lease whose path lease is gone (released or broken): left behind by a killed run, holds
    nothing -- removed without asking (the path lease is what --break-lease speaks for)."""
    lp = old.get("lease")
    if not lp or not isinstance(lp, str) or old["alive"] is True:
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
            elif main is None and old["alive"] is False and not os.path.lexists(store):
                # a holder seen dead on this host that never created the store (killed at start-up: mpiexec
                # SIGKILLs its ranks 1 s after forwarding a signal) had nothing to protect; its temporary files,
                # if any, are removed as leftovers by the taker (remove_leftovers)
                log.info("taking over the lease of %s: %s is gone and never created the store", store,
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


def remove_leftovers(store: str | Path, *, held: bool = False) -> list[str]:
    """Remove the hidden temporary files of ``store`` (``.<name>.tmp-*``: a store's creation, a merge or an export
    written under a temporary name and renamed into place) that a killed writer left behind (issue 40 item 7: up
    to the store's size, for good, named by nothing). Every such writer holds the store's lease for the whole life
    of its temporary file, so one is left over when no live lease holds the store: ``held`` (the caller holds it
    now) or a lease file whose holder is gone (or none). A lease of another host cannot be checked: its files are
    kept. Returns the names removed (each logged)."""
    p = Path(store)
    try:
        d = p.resolve().parent
        found = sorted(d.glob(f".{glob_escape(p.name)}.tmp-*"))  # listed before the lease is read (see below)
    except OSError:
        return []
    if not found:
        return []
    if not held:
        # a file listed before a live holder took the lease is not its own (the holder creates it under the lease,
        # with a name of its own: pid, run id); a live or unknown holder now may own one listed: keep them all
        info = read(p)
        if info is not None and info["alive"] is not False:
            return []
    out = []
    for f in found:
        try:
            size = f.stat().st_size
            f.unlink()
        except FileNotFoundError:
            continue
        except OSError as e:
            log.warning("store %s: cannot remove the temporary file %s left by a killed writer (%s)", p, f.name,
                        e.strerror)
            continue
        log.warning("store %s: removed %s (%d bytes), the temporary file of a store creation, merge or export "
                    "that was killed", p, f.name, size)
        out.append(f.name)
    return out


def glob_escape(name: str) -> str:
    """``name`` with the glob metacharacters escaped (a store may be called ``a[1].h5``)."""
    import glob

    return glob.escape(name)
