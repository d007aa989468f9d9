"""Slab decomposition of a periodic ``nx x ny`` grid over the ranks of a communicator, and the distributed real
2-D FFT on it (docs/gfmd.md, "One solve over several processes"; docs/model.md M1, M2).

Real space: rank ``r`` holds the rows ``slab_rows(nx, comm)`` (axis 0, x) with all ``ny`` columns. Fourier
space: rank ``r`` holds a block of the ``ny//2 + 1`` columns of the half spectrum (``ky >= 0``) with all ``nx``
rows (``kx``), stored transposed, ``(columns, nx)`` C-contiguous, so that both 1-D transforms run along the last,
contiguous axis. The forward transform is a local ``rfft`` along y of the rank's rows, one all-to-all that
transposes the blocks, and an ``fft`` along x of the rank's columns; the inverse runs the same steps backwards:

    rfft2(a)[ky, kx] = sum_r a(r) exp(-i q.r)      (unnormalised, as gapsweep.core.fft; layout (ky, kx))

Engines: numpy (pocketfft) around ``comm.Alltoallv`` of mpi4py on the CPU; cupy (cuFFT) around an all-to-all of
NCCL send/recv pairs (``cupy.cuda.nccl``, in one group) on GPUs, one GPU per rank. Scalars are combined by
:class:`Reducer` (one ``Allgather`` of a few numbers per call, reduced on every rank in rank order, so every rank
takes the same decisions from bit-identical values).

This module never imports mpi4py: the communicator is passed in by the caller (an ``mpi4py.MPI.Comm``); only its
methods are called."""

from __future__ import annotations

import math
from typing import Any

import numpy as np

__all__ = ["Reducer", "SlabFFT", "block", "check_comm", "slab_cols", "slab_rows"]

_EXTRA = "pip install 'gapsweep[distributed]'"
DEFAULT_CHUNK = 1 << 26  # elements per chunk of 1-D transforms (64 Mi complex = 1 GiB)


def check_comm(comm: Any) -> tuple[int, int]:
    """``(size, rank)`` of an mpi4py communicator; a clear error for anything else."""
    if comm is None or not (hasattr(comm, "Get_size") and hasattr(comm, "Get_rank") and hasattr(comm, "Allgather")):
        raise TypeError(f"comm must be an mpi4py communicator (e.g. mpi4py.MPI.COMM_WORLD), got {comm!r}; "
                        f"distributed solves need mpi4py: {_EXTRA}")
    return int(comm.Get_size()), int(comm.Get_rank())


def block(n: int, size: int, rank: int) -> slice:
    """The ``rank``-th of ``size`` contiguous blocks of ``range(n)``: the first ``n % size`` blocks have one
    element more (as ``numpy.array_split``)."""
    q, r = divmod(int(n), int(size))
    start = rank * q + min(rank, r)
    return slice(start, start + q + (1 if rank < r else 0))


def slab_rows(n_rows: int, comm: Any) -> slice:
    """This rank's rows (axis 0) of a grid with ``n_rows`` rows split over ``comm`` (mpi4py conventions: every
    rank calls it; blocks differ by at most one row, rank order). Works for any ``n_rows >= comm.size``."""
    size, rank = check_comm(comm)
    if isinstance(n_rows, bool) or not isinstance(n_rows, (int, np.integer)) or n_rows < size:
        raise ValueError(f"n_rows must be an integer >= the number of ranks ({size}), got {n_rows!r}")
    return block(int(n_rows), size, rank)


def slab_cols(ny: int, comm: Any) -> slice:
    """This rank's columns of the half spectrum (``ny//2 + 1`` columns, ``ky >= 0``)."""
    size, rank = check_comm(comm)
    return block(ny // 2 + 1, size, rank)


class Reducer:
    """Scalar reductions over the communicator: :meth:`many` gathers a short vector of every rank (one
    ``Allgather``) and sums / takes minima / maxima over the ranks in rank order on every rank."""

    def __init__(self, comm: Any) -> None:
        self.comm = comm
        self.size, self.rank = check_comm(comm)
        self.calls = 0  # collective calls made (benchmarks report them per force evaluation)

    def many(self, sums: tuple = (), mins: tuple = (), maxs: tuple = ()) -> tuple[list[float], list[float],
                                                                                   list[float]]:
        a, b = len(sums), len(mins)
        v = np.array([*sums, *mins, *maxs], dtype=np.float64)
        out = np.empty((self.size, v.size), dtype=np.float64)
        self.comm.Allgather(v, out)
        self.calls += 1
        s = [float(x) for x in _ordered_sum(out[:, :a])]
        lo = [float(x) for x in out[:, a:a + b].min(axis=0)]
        hi = [float(x) for x in out[:, a + b:].max(axis=0)]
        return s, lo, hi

    def sum(self, *values: float) -> Any:
        s = self.many(sums=values)[0]
        return s[0] if len(values) == 1 else s

    def min(self, value: float) -> float:
        return self.many(mins=(value,))[1][0]

    def max(self, value: float) -> float:
        return self.many(maxs=(value,))[2][0]

    def any(self, flag: bool) -> bool:
        return self.max(1.0 if flag else 0.0) > 0

    def bcast(self, value: Any, root: int) -> Any:
        return self.comm.bcast(value, root=root)


def _ordered_sum(a: np.ndarray) -> np.ndarray:
    """Column sums of ``a`` added row by row (rank order), the same on every rank."""
    s = np.zeros(a.shape[1], dtype=np.float64)
    for row in a:
        s = s + row
    return s


class SlabFFT:
    """Distributed, unnormalised real 2-D FFT of an ``nx x ny`` grid split in row slabs (module docstring).

    ``rfft2(a)``: ``a`` the rank's rows ``(n_rows_local, ny)`` (real) -> the rank's columns of the half
    spectrum, ``(n_cols_local, nx)`` complex (layout ``[ky, kx]``). ``irfft2(A)``: the inverse (unscaled sum, the
    real field of the coefficients ``A``). ``backend``: "numpy" (CPU, mpi4py Alltoallv) or "cupy" (one GPU per
    rank, NCCL). ``chunk``: the 1-D transforms run over chunks of at most this many elements. Each call is
    collective: every rank must call it in the same order. Memory: the send and receive buffers (each the size of
    the rank's spectrum less its own block, which goes straight to its place) and the result; the input is not
    modified. On one rank nothing is exchanged."""

    def __init__(self, shape: tuple[int, int], comm: Any, backend: str = "numpy", chunk: int | None = None) -> None:
        self.size, self.rank = check_comm(comm)
        self.chunk = int(DEFAULT_CHUNK if chunk is None else chunk)  # elements per chunk of 1-D transforms
        nx, ny = (int(v) for v in shape)
        self.shape = (nx, ny)
        self.nyh = ny // 2 + 1
        if nx < self.size or self.nyh < self.size:
            raise ValueError(f"grid {nx} x {ny} is too small for {self.size} ranks: needs nx >= {self.size} and "
                             f"ny//2 + 1 >= {self.size}")
        self.comm = comm
        self.rows = [block(nx, self.size, r) for r in range(self.size)]
        self.cols = [block(self.nyh, self.size, r) for r in range(self.size)]
        self.row, self.col = self.rows[self.rank], self.cols[self.rank]
        self.nr = self.row.stop - self.row.start
        self.nc = self.col.stop - self.col.start
        self.real_shape = (self.nr, ny)
        self.spec_shape = (self.nc, nx)
        nrs = [s.stop - s.start for s in self.rows]
        ncs = [s.stop - s.start for s in self.cols]
        # element counts (complex numbers) of the blocks: forward sends (nc_s x nr) to s, receives (nc x nr_s)
        self._f_send = [ncs[s] * self.nr for s in range(self.size)]
        self._f_recv = [self.nc * nrs[s] for s in range(self.size)]
        self._nrs, self._ncs = nrs, ncs
        if backend not in ("numpy", "cupy"):
            raise ValueError(f"backend must be 'numpy' or 'cupy' for a distributed FFT, got {backend!r}")
        self.backend = backend
        if backend == "cupy":
            from gapsweep.core.extras import require

            self.xp = require("cupy", "distributed GFMD on GPUs")
            self._nccl = _nccl_comm(comm, self.size, self.rank) if self.size > 1 else None
        else:
            self.xp = np
            self._nccl = None
        self.exchanges = 0  # all-to-all exchanges done (two per force evaluation)

    # ------------------------------------------------------------------ the exchange
    def _alltoall(self, send: Any, scounts: list[int], recv: Any, rcounts: list[int]) -> None:
        """Complex blocks between the ranks, the own block left out of both buffers (the transforms place it
        directly): ``send`` holds the block for rank s at offset ``sum(scounts[:s])`` over the other ranks;
        likewise ``recv``."""
        if self.size == 1:
            return
        self.exchanges += 1
        scounts = [0 if s == self.rank else c for s, c in enumerate(scounts)]
        rcounts = [0 if s == self.rank else c for s, c in enumerate(rcounts)]
        sd = np.concatenate([[0], np.cumsum(scounts)[:-1]]).astype(np.int64)
        rd = np.concatenate([[0], np.cumsum(rcounts)[:-1]]).astype(np.int64)
        if self._nccl is None:
            sf, rf = send.view(np.float64), recv.view(np.float64)
            self.comm.Alltoallv([sf, (2 * np.asarray(scounts), 2 * sd)], [rf, (2 * np.asarray(rcounts), 2 * rd)])
            return
        _nccl_alltoall(self.xp, self._nccl, self.rank, self.size, send, sd, scounts, recv, rd, rcounts)

    # ------------------------------------------------------------------ transforms
    def _chunks(self, rows: int, length: int) -> list[slice]:
        """Row chunks of at most ``chunk`` elements (1-D transforms of a chunk at a time: FFT plans and their work
        areas stay chunk-sized, and no intermediate grid-sized array is formed)."""
        step = max(1, self.chunk // max(length, 1))
        return [slice(i, min(i + step, rows)) for i in range(0, rows, step)]

    def rfft2(self, a: Any, out: Any = None) -> Any:
        """Unnormalised forward transform of the rank's rows ``a`` (``real_shape``) -> ``spec_shape`` (into
        ``out``, a C-contiguous complex128 array of that shape, when given: no result array is allocated).

        Passes over the spectrum: the ``rfft`` along y, one transposing copy (the rank's own block straight into
        ``out``, the others into the send buffer), the exchange, one copy of the received blocks into ``out``, and
        the ``fft`` along x in place."""
        xp = self.xp
        nx, ny = self.shape
        if tuple(a.shape) != self.real_shape:
            raise ValueError(f"rank {self.rank}: expected rows of shape {self.real_shape}, got {tuple(a.shape)}")
        out = xp.empty(self.spec_shape, dtype=xp.complex128) if out is None else _checked(out, self.spec_shape, xp)
        send = xp.empty(self.nr * self.nyh - self._f_send[self.rank], dtype=xp.complex128)
        blocks = self._blocks(send, self._f_send, self._ncs, self.nr)
        own = out[:, self.row]
        for ch in self._chunks(self.nr, ny):  # rfft along y of a chunk of rows, its columns into the blocks
            b = xp.fft.rfft(a[ch], axis=1)
            for s, cs in enumerate(self.cols):  # block for rank s: its columns, transposed (nc_s, nr)
                _transpose_into(xp, (own if s == self.rank else blocks[s])[:, ch], b[:, cs])
            del b
        del blocks
        recv = xp.empty(self.nc * nx - self._f_recv[self.rank], dtype=xp.complex128)
        self._alltoall(send, self._f_send, recv, self._f_recv)
        del send
        for s, blk in enumerate(self._blocks(recv, self._f_recv, [self.nc] * self.size, None)):
            if blk is not None:
                out[:, self.rows[s]] = blk
        del recv
        for ch in self._chunks(self.nc, nx):  # fft along x of a chunk of the rank's columns, in place
            _fft_inplace(xp, out[ch])
        return out

    def irfft2(self, A: Any, norm: str = "forward", out: Any = None) -> Any:
        """Inverse of :meth:`rfft2`: the rank's rows of the real field. ``norm="forward"`` (default): the unscaled
        sum (``irfft2(rfft2(a)) = nx ny a``, gapsweep.core.fft's convention); ``"backward"``: numpy's ``irfft2``
        (scaled by ``1/(nx ny)``, the same operations as ``numpy.fft.irfft2``: ifft along x, then irfft along y).
        ``out``: a C-contiguous float64 array of ``real_shape`` to write the result into (not ``A``'s memory).
        ``A`` is not modified. Passes: the ``ifft`` along x, one copy of its rows into the send blocks (the own
        block, transposed, straight into the half-spectrum rows), the exchange, one transposing copy of the
        received blocks, the ``irfft`` along y."""
        xp = self.xp
        nx, ny = self.shape
        if tuple(A.shape) != self.spec_shape:
            raise ValueError(f"rank {self.rank}: expected spectrum columns of shape {self.spec_shape}, "
                             f"got {tuple(A.shape)}")
        b = xp.empty((self.nr, self.nyh), dtype=xp.complex128)
        own = b[:, self.col]
        send = xp.empty(self.nc * nx - self._f_recv[self.rank], dtype=xp.complex128)
        blocks = self._blocks(send, self._f_recv, [self.nc] * self.size, None)
        for ch in self._chunks(self.nc, nx):  # ifft along x of a chunk of columns, its rows into the blocks
            c = xp.fft.ifft(A[ch], axis=1, norm=norm)
            for s, rs in enumerate(self.rows):  # block for rank s: its rows (nc, nr_s)
                if s == self.rank:
                    _transpose_into(xp, own[:, ch], c[:, rs])
                else:
                    blocks[s][ch] = c[:, rs]
            del c
        del blocks
        recv = xp.empty(self.nr * self.nyh - self._f_send[self.rank], dtype=xp.complex128)
        self._alltoall(send, self._f_recv, recv, self._f_send)
        del send
        for s, blk in enumerate(self._blocks(recv, self._f_send, self._ncs, self.nr)):
            if blk is not None:
                _transpose_into(xp, b[:, self.cols[s]], blk)
        del recv
        out = xp.empty(self.real_shape, dtype=xp.float64) if out is None else _checked(out, self.real_shape, xp)
        for ch in self._chunks(self.nr, self.nyh):  # irfft along y of a chunk of rows
            out[ch] = xp.fft.irfft(b[ch], n=ny, axis=1, norm=norm)
        return out

    def _blocks(self, buf: Any, counts: list[int], rows: list[int], cols: int | None) -> list[Any]:
        """Views of the exchange buffer ``buf`` (the own block left out): the block of rank ``s`` has
        ``counts[s]`` elements, shaped ``(rows[s], cols)`` (``cols=None``: ``counts[s] // rows[s]``); ``None``
        for the own rank."""
        views: list[Any] = []
        off = 0
        for s in range(self.size):
            if s == self.rank:
                views.append(None)
                continue
            n = counts[s]
            views.append(buf[off:off + n].reshape(rows[s], n // rows[s] if cols is None and rows[s] else cols or 0))
            off += n
        return views

    # ------------------------------------------------------------------ wave vectors
    def wavenumbers(self) -> tuple[Any, Any]:
        """Integer wave numbers of the rank's spectrum: ``kx`` shape ``(1, nx)``, ``ky`` shape ``(nc, 1)``."""
        xp = self.xp
        nx = self.shape[0]
        kx = xp.fft.fftfreq(nx, d=1.0 / nx)[None, :]
        ky = xp.arange(self.col.start, self.col.stop, dtype=xp.float64)[:, None]
        return kx, ky

    def q(self, lx: float, ly: float) -> Any:
        """``|q|`` on the rank's spectrum (rad/length), shape ``spec_shape``."""
        kx, ky = self.wavenumbers()
        return self.xp.sqrt((kx * (2 * math.pi / lx)) ** 2 + (ky * (2 * math.pi / ly)) ** 2)

    def weights(self) -> Any:
        """Parseval weights of the rank's half-spectrum columns, shape ``(nc, 1)``: 1 for ``ky = 0`` and (even
        ``ny``) ``ky = ny/2``, else 2 (the column stands for its conjugate mirror too)."""
        xp = self.xp
        ky = np.arange(self.col.start, self.col.stop)
        w = np.where((ky == 0) | ((self.shape[1] % 2 == 0) & (ky == self.nyh - 1)), 1.0, 2.0)
        return xp.asarray(w[:, None])

    @property
    def owns_zero(self) -> bool:
        """Whether this rank holds the ``q = 0`` mode (index ``[0, 0]`` of its spectrum)."""
        return self.col.start == 0


TILED_TRANSPOSE = True  # cupy: the transposing copies through the tiled kernel below (False: cupy's strided copy)
_TRANSPOSE_SRC = r"""
extern "C" __global__ void transpose_z(const double2* __restrict__ src, long long lds, double2* __restrict__ dst,
                                       long long ldd, int rows, int cols) {
    // dst[j, i] = src[i, j] for i < rows, j < cols (leading dimensions lds, ldd in elements); a 32 x 32 tile
    // through shared memory, so that both the reads and the writes are coalesced
    __shared__ double2 tile[32][33];
    const int bx = blockIdx.x * 32, by = blockIdx.y * 32, tx = threadIdx.x, ty = threadIdx.y;
    for (int k = ty; k < 32; k += 8) {
        const int i = by + k, j = bx + tx;
        if (i < rows && j < cols) tile[k][tx] = src[(long long)i * lds + j];
    }
    __syncthreads();
    for (int k = ty; k < 32; k += 8) {
        const int j = bx + k, i = by + tx;
        if (i < rows && j < cols) dst[(long long)j * ldd + i] = tile[tx][k];
    }
}
"""
_TRANSPOSE_KERNEL: list[Any] = []


def _transpose_into(xp: Any, dst: Any, src: Any) -> None:
    """``dst[...] = src.T`` for 2-D complex128 views whose rows are contiguous (slices of C-contiguous arrays).
    On cupy a tiled transpose kernel (a strided elementwise copy reads or writes uncoalesced); on numpy the plain
    assignment."""
    rows, cols = src.shape
    if tuple(dst.shape) != (cols, rows):
        raise ValueError(f"transpose of {src.shape} into {dst.shape}")
    if xp is np or not TILED_TRANSPOSE or rows == 0 or cols == 0 or src.dtype != xp.complex128 \
            or dst.dtype != xp.complex128 or src.strides[1] != 16 or dst.strides[1] != 16:
        dst[...] = src.T
        return
    if not _TRANSPOSE_KERNEL:
        _TRANSPOSE_KERNEL.append(xp.RawKernel(_TRANSPOSE_SRC, "transpose_z"))
    grid = ((cols + 31) // 32, (rows + 31) // 32)
    _TRANSPOSE_KERNEL[0](grid, (32, 8), (src, np.int64(src.strides[0] // 16), dst, np.int64(dst.strides[0] // 16),
                                          np.int32(rows), np.int32(cols)))


def _fft_inplace(xp: Any, x: Any) -> None:
    """``x[...] = fft(x)`` along the last axis (unnormalised). On cupy through cupyx's ``overwrite_x``: cuFFT
    transforms the contiguous chunk in place, no result array and no copy back; on numpy the plain transform and
    one copy (as before: the CPU path's numbers stay the same)."""
    if xp is np:
        x[...] = np.fft.fft(x, axis=-1)
        return
    import cupyx.scipy.fft as cfft

    y = cfft.fft(x, axis=-1, overwrite_x=True)
    if y.data.ptr != x.data.ptr:  # not done in place (a cupy without it): copy back
        x[...] = y


def _checked(out: Any, shape: tuple[int, int], xp: Any) -> Any:
    if tuple(out.shape) != tuple(shape) or not out.flags.c_contiguous:
        raise ValueError(f"out must be a C-contiguous array of shape {shape}, got {tuple(out.shape)}")
    return out


# ---------------------------------------------------------------------------------------------- NCCL (GPUs)
_NCCL: dict[tuple, Any] = {}


def _nccl_comm(comm: Any, size: int, rank: int) -> Any:
    """An NCCL communicator over the ranks of ``comm`` (one GPU per rank, the current cupy device), made once per
    communicator and device and kept for the process (creating one takes a collective set-up); the unique id
    travels over ``comm``. Collective the first time."""
    import cupy
    from cupy.cuda import nccl

    handle = comm.py2f() if hasattr(comm, "py2f") else id(comm)
    key = (handle, size, rank, cupy.cuda.Device().id)
    if key not in _NCCL:
        uid = nccl.get_unique_id() if rank == 0 else None
        uid = comm.bcast(uid, root=0)
        _NCCL[key] = nccl.NcclCommunicator(size, uid, rank)
    return _NCCL[key]


def _nccl_alltoall(cupy: Any, nc: Any, rank: int, size: int, send: Any, sd: Any, scounts: list[int], recv: Any,
                   rd: Any, rcounts: list[int]) -> None:
    """All-to-all of complex blocks through NCCL point-to-point calls in one group (NCCL has no all-to-all
    collective): the own block is a device copy; complex numbers travel as pairs of float64."""
    from cupy.cuda import nccl

    stream = cupy.cuda.get_current_stream()
    sf, rf = send.view(cupy.float64), recv.view(cupy.float64)
    own = rcounts[rank]
    if own:
        rf[2 * rd[rank]:2 * (rd[rank] + own)] = sf[2 * sd[rank]:2 * (sd[rank] + scounts[rank])]
    nccl.groupStart()
    for s in range(size):
        if s == rank:
            continue
        if scounts[s]:
            nc.send(sf[2 * sd[s]:].data.ptr, 2 * scounts[s], nccl.NCCL_FLOAT64, s, stream.ptr)
        if rcounts[s]:
            nc.recv(rf[2 * rd[s]:].data.ptr, 2 * rcounts[s], nccl.NCCL_FLOAT64, s, stream.ptr)
    nccl.groupEnd()
