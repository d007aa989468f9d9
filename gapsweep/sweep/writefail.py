"""A failed HDF5 write (full disk, file-size limit; issue 31): one line for the user, and the file's objects kept
alive to the end of the process, which then leaves without HDF5's exit handlers (``cli.main``: os._exit), because
HDF5 may crash when the objects of a file whose write failed are closed or released.

Every writer of HDF5 files (the store, kept fields, merge, the netCDF export) raises :func:`write_failed` inside the
``except`` of its failed write. Imports only h5py and the schema, so any sweep module may use it."""

from __future__ import annotations

import os
import re
from pathlib import Path
from typing import Any

import h5py

from gapsweep.sweep.schema import StoreWriteError

__all__ = ["KEEP_TYPES", "io_failed", "one_line", "reserve", "write_failed"]

# Set when an HDF5 write or close failed in this process: the library may then crash while tearing down at
# interpreter exit (seen with ENOSPC / EFBIG), so the CLI ends such a process with os._exit after its message.
_io_failed = False
_kept: list[Any] = []
# objects kept alive after a failed write; gapsweep.sweep.store adds its Store (which holds an h5py.File)
KEEP_TYPES: list[type] = [h5py.File, h5py.Group, h5py.Dataset]


def io_failed() -> bool:
    """Whether an HDF5 write failed in this process (see ``_io_failed``)."""
    return _io_failed


def one_line(msg: str) -> str:
    """An HDF5 error message in one line: its long "(... file write failed: time = ..., errno = 28, error message
    = 'No space left on device', ...)" part (which holds a newline) reduced to the error message and errno; the
    text around it is kept."""
    m = re.search(r"errno = (\d+), error message = '([^']*)'", msg)
    if m:
        start = msg.rfind(" (", 0, m.start())
        while start > 0 and msg.rfind(" (", 0, start) > 0 and msg.count("(", 0, start) > msg.count(")", 0, start):
            start = msg.rfind(" (", 0, start)  # the outermost parenthesis around the HDF5 text
        depth, end = 0, len(msg)
        for k in range(start + 1, len(msg)):
            depth += {"(": 1, ")": -1}.get(msg[k], 0)
            if depth == 0:
                end = k + 1
                break
        if start >= 0:
            msg = f"{msg[:start]} ({m.group(2)}, errno {m.group(1)}){msg[end:]}"
    return " ".join(msg.split())


def write_failed(msg: str) -> StoreWriteError:
    """The error to raise after a failed HDF5 write (called inside the ``except``): the objects of every open HDF5
    file (and the failing frames) are kept alive to the end of the process."""
    global _io_failed
    import gc
    import sys

    _io_failed = True
    _kept.append(sys.exc_info()[2])
    types = tuple(KEEP_TYPES)
    _kept.extend(o for o in gc.get_objects() if isinstance(o, types))
    return StoreWriteError(one_line(msg))


def reserve(tmp: Path, nbytes: int) -> str | None:
    """Whether ``nbytes`` can be written to the file ``tmp`` (``os.posix_fallocate``: blocks reserved, not
    written, where the file system allows; the file is removed again): None, or the error's text (no space, a
    file-size limit). Writers call it before HDF5 writes that the library cannot fail cleanly: a collective mpio
    close waits forever after a failed write, and h5netcdf's clean-up of a variable whose write failed crashed
    HDF5 2.0 (a segmentation fault of ``gapsweep export`` under a 4 KiB file-size limit, plain-user stack)."""
    try:
        fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644)
        try:
            os.posix_fallocate(fd, 0, max(int(nbytes), 1))
        finally:
            os.close(fd)
            Path(tmp).unlink(missing_ok=True)
    except OSError as e:
        return f"{e.strerror or e} (~{nbytes / 1e6:.1f} MB needed in {Path(tmp).parent})"
    return None
