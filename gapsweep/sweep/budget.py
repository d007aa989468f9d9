"""Resource estimates of a job: store size on disk and peak memory per rank (``gapsweep plan``,
``docs/reliability.md``). Rough upper bounds, meant to refuse what cannot fit before anything runs."""

from __future__ import annotations

import errno
import os
import shutil
from pathlib import Path

from gapsweep.sweep import methods as registry
from gapsweep.sweep.schema import RESULT_DTYPE, TASK_DTYPE, Task

__all__ = ["BASE_MEMORY", "TASK_LIST_BYTES", "disk_free", "memory_total", "peak_memory", "store_bytes"]

BASE_MEMORY = 300e6  # interpreter, numpy/scipy/h5py/numba, FFT plans [bytes]
CUDA_CONTEXT = 0.5e9  # a CUDA context and cupy's pools per process on the GPU [bytes]
TASK_LIST_BYTES = 1600  # one expanded Task with its options, on every rank (measured: ~1.5 kB) [bytes]


def store_bytes(n_tasks: int, bins: int, spec_text_len: int = 0, plugin_columns: int = 0) -> int:
    """Size of a store of ``n_tasks`` rows and ``bins`` histogram bins (and ``plugin_columns`` 8-byte plug-in
    columns, docs/store.md): all datasets are allocated at creation (docs/store.md), plus attributes and HDF5
    metadata [bytes]."""
    per_row = (TASK_DTYPE.itemsize + RESULT_DTYPE.itemsize + 8 * plugin_columns
               + 2 * (2 * bins + 1) * 8)  # gap + pressure histograms
    return int(n_tasks * per_row + 2 * spec_text_len + 64 * 1024)


def task_memory(t: Task) -> float:
    """Peak working memory of one task [bytes] (the method plug-in's order-of-magnitude model)."""
    return registry.get(t.method).memory(t)


def gpu_memory(tasks: list[Task], ranks_per_gpu: int = 1) -> float:
    """GPU memory one GPU needs [bytes]: its ``ranks_per_gpu`` ranks each holding the largest GPU task (the
    method's ``gpu_memory``; gfmd: ``gapsweep.gfmd._cuda.solve_memory``) and a CUDA context (0.5 GB). 0 without
    GPU tasks."""
    per = max((registry.get(t.method).gpu_memory(t) for t in tasks), default=0.0)
    return ranks_per_gpu * (per + CUDA_CONTEXT) if per else 0.0


def gpu_memory_total() -> int:
    """Memory of this process's GPU [bytes] (0 when there is none or cupy is missing). Opens a CUDA context: the
    farm does not call it (gapsweep.sweep.gpus.memory reads nvidia-smi instead)."""
    try:
        import cupy

        return int(cupy.cuda.Device().mem_info[1])
    except Exception:  # no cupy, no driver, no device: nothing to check against
        return 0


def peak_memory(tasks: list[Task]) -> float:
    """Peak resident memory of one rank [bytes]: base + the task list + the largest task."""
    return BASE_MEMORY + TASK_LIST_BYTES * len(tasks) + max((task_memory(t) for t in tasks), default=0.0)


def memory_total() -> int:
    """Physical memory of this machine [bytes] (0 if unknown)."""
    try:
        return os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
    except (ValueError, OSError, AttributeError):  # pragma: no cover
        return 0


def disk_free(path: str | Path) -> int:
    """Free bytes on the file system that holds ``path`` (or its nearest existing parent)."""
    p = Path(path).absolute()
    while not p.exists() and p != p.parent:
        p = p.parent
    return shutil.disk_usage(p).free


def human(n: float) -> str:
    for unit in ("B", "kB", "MB", "GB", "TB"):
        if abs(n) < 1000 or unit == "TB":
            return f"{n:.0f} {unit}" if unit == "B" else f"{n:.1f} {unit}"
        n /= 1000
    return f"{n:.1f} TB"  # pragma: no cover


PROBE_BYTES = 1 << 20


def probe_growth(path: str | Path, nbytes: int = PROBE_BYTES, size: int | None = None) -> None:
    """Check that the store at ``path`` can grow by ``nbytes``: write that many bytes to a scratch file beside
    it (full disk) and one byte at offset ``size + nbytes`` (file-size limit; ``size``: the store's size, or
    the size a new store will have), then remove it. Raises OSError.

    HDF5 does not survive a failed metadata write (a store can be left unreadable), so metadata updates of an
    existing store (its run record) are made only after this check (docs/reliability.md)."""
    p = Path(path)
    if size is None:
        size = p.stat().st_size if p.exists() else 0
    fd = _scratch(p)
    try:
        os.write(fd, b"\0" * nbytes)
        os.pwrite(fd, b"\0", size + nbytes)
        os.fsync(fd)
    finally:
        os.close(fd)


# errors of open(O_TMPFILE) that mean "this filesystem or kernel has no unnamed files" (NFS, Lustre, old kernels)
_NO_TMPFILE = (errno.EOPNOTSUPP, errno.EISDIR, errno.EINVAL)


def _scratch(p: Path) -> int:
    """A file descriptor for writing a scratch file in ``p``'s folder (same filesystem, same quota) that no
    crash leaves behind: unnamed (``O_TMPFILE``) where the filesystem has it, else created as
    ``.<name>.probe-<pid>`` and unlinked before anything is written (its blocks stay allocated while the
    descriptor is open). A process SIGKILLed mid-probe -- Open MPI kills the ranks 1 s after forwarding a
    signal, while they write their run record -- used to leave a 1 MB file beside the store."""
    flag = getattr(os, "O_TMPFILE", 0)
    if flag:
        try:
            return os.open(p.parent, flag | os.O_WRONLY, 0o600)
        except OSError as e:
            if e.errno not in _NO_TMPFILE:
                raise
    probe = p.with_name(f".{p.name}.probe-{os.getpid()}")
    fd = os.open(probe, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
    probe.unlink(missing_ok=True)
    return fd
