"""Surfaces of GFMD tasks solved over every rank (``[methods.gfmd] distributed = true``,
gapsweep.sweep.collective; docs/gfmd.md "One solve over several processes"): each rank holds only its rows.

* A synthetic surface (docs/model.md M2) is made in place: each rank generates its rows with
  ``gapsweep.surfaces.synthetic.self_affine_rows``, bit for bit the rows of ``self_affine`` (numpy; on GPUs,
  ``backend = "cupy"``, to FFT round-off), and no rank forms the whole map. Its ``h_rms`` and spectral ``g_rms``
  (M2) come from reductions over the ranks (:func:`rows_rms`), equal to those of the whole map to round-off.
* A measured map (``[surface] kind = "file"``, gapsweep.sweep.filesurface) is read whole by rank 0 alone and
  its rows are sent to the other ranks in bounded chunks (:func:`scatter_rows`): the readers of the map formats
  (text, ``.npz``, SurfaceTopography's) load whole files, the detrending (a plane fit) and the SHA-256 check
  need every height, and the rms values are those of the map's spectrum taken for its boundaries
  (``theory.spectrum.map_spectrum``, as for a single process), so rank 0 computes them and broadcasts them.

Row transfers go in chunks of at most :data:`CHUNK_BYTES` (a message never holds more than that, a receiver
never a buffer larger). Every function here is collective: every rank calls it in the same order."""

from __future__ import annotations

import math
from collections.abc import Callable, Iterator
from typing import Any

import numpy as np

from gapsweep.core.slab import block

__all__ = ["CHUNK_BYTES", "TAG_ROWS", "row_chunks", "rows_rms", "scatter_rows", "surface_rows"]

CHUNK_BYTES = 64 << 20  # bytes of one row message (scatter of a map, gather of kept fields)
TAG_ROWS = 71  # MPI tag of row messages (the farm's tags are 1..6; a collective run has no farm)


def row_chunks(rows: slice, ncols: int, itemsize: int = 8, chunk_bytes: int | None = None) -> Iterator[slice]:
    """Consecutive row blocks of ``rows`` of at most ``chunk_bytes`` (at least one row each)."""
    step = max(1, int(CHUNK_BYTES if chunk_bytes is None else chunk_bytes) // max(1, ncols * itemsize))
    for a in range(rows.start, rows.stop, step):
        yield slice(a, min(a + step, rows.stop))


def scatter_rows(whole: np.ndarray | None, comm: Any, chunk_bytes: int | None = None) -> np.ndarray:
    """Rank 0's ``whole`` map (``None`` on the other ranks) split in row slabs (``gapsweep.core.slab.slab_rows``):
    this rank's rows, a new float64 array. The rows of rank ``r`` go in chunks (:func:`row_chunks`)."""
    size, rank = comm.Get_size(), comm.Get_rank()
    shape = comm.bcast(None if whole is None else tuple(int(v) for v in whole.shape), root=0)
    mine = block(shape[0], size, rank)
    if rank == 0:
        w = np.ascontiguousarray(whole, dtype=np.float64)
        for r in range(1, size):
            for c in row_chunks(block(shape[0], size, r), shape[1], chunk_bytes=chunk_bytes):
                comm.Send(w[c], dest=r, tag=TAG_ROWS)
        return np.array(w[mine])
    out = np.empty((mine.stop - mine.start, shape[1]), dtype=np.float64)
    for c in row_chunks(mine, shape[1], chunk_bytes=chunk_bytes):
        comm.Recv(out[c.start - mine.start:c.stop - mine.start], source=0, tag=TAG_ROWS)
    return out


def rows_rms(h: Any, n: int, length: float, comm: Any) -> tuple[float, float]:
    """``(h_rms, g_rms)`` of an ``n x n`` synthetic surface whose rows ``h`` (numpy or cupy) are split over
    ``comm``: ``h_rms = sqrt(<(h - <h>)^2>)`` and the spectral ``g_rms = sqrt(sum_q q^2 |h~(q)|^2)`` with
    ``h~ = FFT[h]/n^2`` (docs/model.md M2; ``surfaces.synthetic.rms_height`` / ``rms_slope`` of the whole map, to
    round-off: the sums run in another order). Lengths in the units of ``length``; ``g_rms`` dimensionless."""
    from gapsweep.core.slab import Reducer, SlabFFT

    red = Reducer(comm)
    fft = SlabFFT((n, n), comm, backend="cupy" if not isinstance(h, np.ndarray) else "numpy")
    xp = fft.xp
    total = float(n) * n
    mean = red.sum(float(xp.sum(h))) / total
    h_rms = math.sqrt(red.sum(float(xp.sum((h - mean) ** 2))) / total)
    hq = fft.rfft2(h)
    hq /= total
    kx, ky = fft.wavenumbers()
    q2 = (2 * math.pi / float(length)) ** 2 * (kx * kx + ky * ky)
    local = float(xp.sum(q2 * fft.weights() * (hq.real ** 2 + hq.imag ** 2)))
    return h_rms, math.sqrt(red.sum(local))


def surface_rows(t: Any, n: int, sp: dict[str, Any], comm: Any, backend: str = "numpy", *,
                 map_rms: Callable[[np.ndarray, dict[str, Any]], tuple[float, float]]
                 ) -> tuple[Any, tuple[float, float]]:
    """This rank's rows of task ``t``'s surface on its ``n``-row grid and the whole surface's ``(h_rms, g_rms)``
    (module docstring). ``backend``: "numpy", or "cupy" for a synthetic surface made on this rank's GPU.
    ``map_rms(heights, sp)``: the rms values of a whole file map (``Context``'s, run by rank 0). A file surface
    that does not load fails on every rank with rank 0's error."""
    if sp.get("kind") != "file":
        from gapsweep.surfaces.synthetic import self_affine_rows

        h = self_affine_rows(n, t.hurst, comm=comm, seed=t.seed, backend=backend, **sp)
        return h, rows_rms(h, n, sp["length"], comm)
    whole, rms, err = None, None, None
    if comm.Get_rank() == 0:
        from gapsweep.sweep.filesurface import file_surface_heights

        try:
            whole = file_surface_heights(sp)
            rms = map_rms(whole, sp)
        except Exception as e:  # the same error on every rank below: the task fails together
            err = (type(e), str(e))
    err = comm.bcast(err, root=0)
    if err is not None:
        try:
            e = err[0](err[1])
        except Exception:  # an exception type that takes other arguments
            e = RuntimeError(f"{err[0].__name__}: {err[1]}")
        raise e
    rms = comm.bcast(rms, root=0)
    h = scatter_rows(whole, comm)
    del whole
    if backend == "cupy":
        import cupy

        h = cupy.asarray(h)
    return h, rms
