"""Guards for the files a command writes (issue 19, item 1): no command deletes or replaces a store, a shard, a
kept-fields folder or any input it was not asked to write.

``--overwrite`` means "replace the file this command wrote before", never "replace whatever sits at that path":
a netCDF export onto its own input, or onto another store, would turn the only copy of the results into a view
of them. Stores are recognised by content (an HDF5 file whose ``format`` attribute is the store's), not by name,
so a store named ``x.nc`` is protected too.

One rule for every command that writes (issue 31, :func:`guard_output`): an output never replaces an input --
compared by device and inode, so no hard link, symlink or mount path of an input is replaced either -- nor a
folder; an existing output is replaced only with ``--overwrite`` and only when it is a file of the command's own
kind: ``run`` a gapsweep store, ``merge`` an earlier merge output of the same job (spec hash) that holds no done
row the new one lacks, ``export`` a netCDF file a gapsweep export wrote. Another job's finished store, a shard, a
plain HDF5 file or any other file is refused with one line naming it.
"""

from __future__ import annotations

import logging
import os
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import Any

from gapsweep.sweep.schema import FORMAT

__all__ = ["HDF5_SIGNATURE", "guard_file_output", "guard_output", "hdf5_attrs", "inside", "is_export", "is_store",
           "same_file"]

log = logging.getLogger("gapsweep.sweep.outputs")

HDF5_SIGNATURE = b"\x89HDF\r\n\x1a\n"


def same_file(a: str | Path, b: str | Path) -> bool:
    """Whether two paths name one file (symlinks, hard links, other mount paths included)."""
    try:
        return os.path.samefile(a, b)
    except OSError:
        return False


def inside(child: str | Path, parent: str | Path) -> bool:
    """Whether ``child`` is ``parent`` or lies (resolved, through symlinks) anywhere below it."""
    c, p = Path(child).resolve(), Path(parent).resolve()
    return c == p or p in c.parents


def is_store(path: str | Path) -> bool:
    """Whether ``path`` is a gapsweep store: an HDF5 file carrying the store's format attribute. An HDF5 file
    that cannot be opened counts as a store (it may be one being written or damaged; replacing it is not ours
    to decide)."""
    p = Path(path)
    try:
        with p.open("rb") as fh:
            head = fh.read(8)
    except OSError:
        return False
    if head != HDF5_SIGNATURE:
        return False
    import h5py

    try:
        with h5py.File(p, "r", locking=False) as f:
            return f.attrs.get("format") == FORMAT
    except Exception:  # unreadable HDF5: be safe
        return True


def guard_file_output(out: str | Path, inputs: Iterable[str | Path], what: str) -> None:
    """Refuse (``FileExistsError`` naming ``what`` and the path) to replace an input, a folder or a store by
    the file ``out``; anything else may be replaced (``--overwrite``, the caller's check)."""
    o = Path(out)
    for i in inputs:
        if same_file(o, i) or (not o.exists() and Path(i).resolve() == o.resolve()):
            raise FileExistsError(f"{what} {o}: is the input {i}; an output never replaces its input, choose "
                                  "another file")
    if not o.exists():
        return
    if o.is_dir():
        raise FileExistsError(f"{what} {o}: is a folder (a store's kept fields or another); name a file")
    if is_store(o):
        raise FileExistsError(f"{what} {o}: is a gapsweep store (HDF5 with format {FORMAT!r}); --overwrite "
                              "never replaces a store, choose another file")


def hdf5_attrs(path: str | Path) -> dict[str, Any] | None:
    """The file attributes of an HDF5 file (strings decoded), or None where ``path`` is not one that opens."""
    try:
        with Path(path).open("rb") as fh:
            if fh.read(8) != HDF5_SIGNATURE:
                return None
    except OSError:
        return None
    import h5py

    try:
        with h5py.File(path, "r", locking=False) as f:
            return {k: (v.decode("utf-8", "replace") if isinstance(v, bytes) else v) for k, v in f.attrs.items()}
    except Exception:  # unreadable HDF5
        return None


def is_export(path: str | Path) -> bool:
    """Whether ``path`` is a netCDF file written by ``gapsweep export`` (the store's format as attribute
    ``gapsweep_format``, a ``history`` saying it was opened from a store) and not a store."""
    a = hdf5_attrs(path)
    return a is not None and a.get("format") != FORMAT and a.get("gapsweep_format") == FORMAT \
        and str(a.get("history", "")).startswith("opened from ")


def guard_output(out: str | Path, inputs: Iterable[str | Path], what: str, *, overwrite: bool,
                 own: Callable[[Path], str | None]) -> None:
    """The rule for every command that writes (module docstring). ``own(out)`` says why an existing ``out`` is
    not of the command's own kind (a one-line reason) or None where ``--overwrite`` may replace it. Raises
    ``FileExistsError`` naming ``what`` and the path."""
    o = Path(out)
    for i in inputs:
        if same_file(o, i) or Path(i).resolve() == o.resolve():
            raise FileExistsError(f"{what} {o}: is the input {i} (the same file, by device and inode); an output "
                                  "never replaces an input, choose another file")
    if not o.exists() and not o.is_symlink():
        return
    if o.is_dir():
        raise FileExistsError(f"{what} {o}: is a folder; name a file")
    if not overwrite:
        raise FileExistsError(f"{what} {o}: exists (pass --overwrite to replace it)")
    why = own(o)
    if why is not None:
        raise FileExistsError(f"{what} {o}: {why}; --overwrite replaces only a file this command wrote, choose "
                              "another file")
