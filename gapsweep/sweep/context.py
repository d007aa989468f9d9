"""Per-rank execution context of the sweep: the surface cache shared by the tasks of a rank, the rms values and
spectra of the cached surfaces, the rank's GPU, and the helpers every method uses to turn samples into a
store row (histograms, the moments fed to theory/SDE/FP).

Physics is only called here (surfaces, spectra); no method is named.
"""

from __future__ import annotations

import math
import os
from collections import OrderedDict
from pathlib import Path
from typing import Any

import numpy as np

from gapsweep.sweep.schema import Task

__all__ = ["Context", "extra", "hist", "host", "moments", "use_gpu"]


class Context:
    """Per-rank state: surface cache (one surface per (hurst, seed, n) and surface parameters), the GPU this
    rank may use, the test hook ``GAPSWEEP_TEST_DELAY`` (seconds per task) and the fault-injection seam ``_fail``
    (sigma0 values whose tasks raise; empty unless a test fills it, tests/hooks)."""

    def __init__(self, rank: int = 0, gpu: int | None = None, max_surfaces: int = 4) -> None:
        self.rank = rank
        self.gpu = gpu
        self.fields_dir: Path | None = None  # where GFMD tasks keep their fields (set by the runner)
        self._surfaces: OrderedDict[tuple, np.ndarray] = OrderedDict()
        self._rms: dict[tuple, tuple[float, float]] = {}  # (h_rms, g_rms) of the cached surfaces
        self._spectra: dict[tuple, Any] = {}  # discrete spectra of the cached surfaces (theory, M4)
        self._on_gpu: dict[tuple, Any] = {}  # GPU copies of the cached surfaces (GFMD with backend = "cupy")
        self._rows: tuple[tuple, Any, tuple[float, float]] | None = None  # (key, rows, rms): one distributed surface
        self.writer = "serial"  # how kept fields are written under MPI: mpio | rank0 (set by the runner)
        self._max = max_surfaces
        self.warmed: set[tuple] = set()  # kinds of task whose method was warmed up (runner.warm_up)
        self._pool: Any = None  # host threads making surfaces ahead (prefetch), on GPU workers
        self._ahead: dict[tuple, Any] = {}  # surface key -> its future
        self._delay = float(os.environ.get("GAPSWEEP_TEST_DELAY", "0") or 0)
        self._fail: set[float] = set()  # sigma0 values whose tasks fail: a fault-injection seam (tests/hooks)
        self._selected = False  # this rank's GPU was made the current CUDA device (select_gpu)
        # synthetic surfaces of GPU GFMD tasks made on the GPU (issue 38; GAPSWEEP_GPU_SURFACES=0: on the host)
        self.gpu_surfaces = os.environ.get("GAPSWEEP_GPU_SURFACES", "1") != "0"
        self._made_on_gpu: OrderedDict[tuple, tuple[int, Any]] = OrderedDict()  # key -> (device, cupy heights)

    def select_gpu(self) -> int:
        """Make this rank's GPU (``gpu``, 0 where None) the current CUDA device before the first CUDA call of a
        GPU method (gapsweep.sweep.gpus.select: no context on another GPU, issue 38), once; returns its index."""
        dev = self.gpu or 0
        if not self._selected:
            from gapsweep.sweep import gpus

            self._selected = not gpus.select(dev)
        return dev

    def surface(self, t: Task, n: int) -> np.ndarray:
        """The surface of ``t`` on an ``n x n`` grid, generated once per rank (M2), or taken from
        :meth:`prefetch` where that made it ahead."""
        sp = t.surface_params()
        key = self._key(t, n, sp)
        h = self._surfaces.get(key)
        if h is None:
            fut = self._ahead.pop(key, None)
            if fut is not None:
                h, self._rms[key] = fut.result()
            else:
                h = _make_surface(t, n, sp)
            self._surfaces[key] = h
            while len(self._surfaces) > self._max:
                old = self._surfaces.popitem(last=False)[0]
                self._rms.pop(old, None)
                self._rms.pop((*old, "spectrum"), None)
                self._spectra.pop(old, None)
                self._on_gpu.pop(old, None)
        else:
            self._surfaces.move_to_end(key)
        return h

    def prefetch(self, t: Task, n: int) -> None:
        """Start making the surface of ``t`` and its rms values on a host thread (:meth:`ahead` threads), so that
        they are ready when a task needs them: a GPU worker's host work overlaps its GPU's. The same functions
        make them, so they are the same bits. No-op without threads, when it is cached or on its way, or when its
        GPU makes it (:meth:`makes_on_gpu`)."""
        if self._pool is None or self.makes_on_gpu(t):
            return
        key = self._key(t, n, t.surface_params())
        if key not in self._surfaces and key not in self._ahead:
            self._ahead[key] = self._pool.submit(_surface_and_rms, t, n, t.surface_params())

    def ahead(self, threads: int) -> None:
        """Use ``threads`` host threads for :meth:`prefetch` (0: none)."""
        if threads > 0 and self._pool is None:
            from concurrent.futures import ThreadPoolExecutor

            self._pool = ThreadPoolExecutor(threads, thread_name_prefix="gapsweep-surface")

    def close(self) -> None:
        """Stop the prefetch threads (surfaces on their way are dropped)."""
        if self._pool is not None:
            self._pool.shutdown(wait=False, cancel_futures=True)
            self._pool = None
        self._ahead.clear()

    def surface_rms(self, t: Task, n: int) -> tuple[float, float]:
        """``(h_rms, g_rms)`` of :meth:`surface` (M2), computed once per cached surface (``g_rms`` costs an FFT).
        A measured map's are those of the heights solved (:func:`_rms`); its spectral moments are
        :meth:`surface_spectrum_rms`. A surface made on the GPU (:meth:`surface_on_gpu`): its values computed
        there by the same formulas (:func:`_rms_gpu`), no host copy made."""
        sp = t.surface_params()
        key = self._key(t, n, sp)
        made = self._made_on_gpu.get(key)
        if made is not None and key not in self._surfaces:
            self._made_on_gpu.move_to_end(key)
            if key not in self._rms:
                self._rms[key] = _rms_gpu(made[1], sp)
            return self._rms[key]
        h = self.surface(t, n)
        if key not in self._rms:
            self._rms[key] = _rms(h, sp)
        return self._rms[key]

    def surface_spectrum_rms(self, t: Task, n: int) -> tuple[float, float]:
        """:func:`spectrum_rms` of :meth:`surface`, computed once per cached surface ((NaN, NaN) for a synthetic
        surface, whose heights it does not need)."""
        sp = t.surface_params()
        if sp.get("kind") != "file":
            return math.nan, math.nan
        h = self.surface(t, n)
        key = (*self._key(t, n, sp), "spectrum")
        if key not in self._rms:
            self._rms[key] = spectrum_rms(h, sp)
        return self._rms[key]

    def spectrum(self, t: Task, n: int) -> Any:
        """Discrete spectrum (``theory.spectrum.from_heights``) of :meth:`surface`, computed once per cached
        surface: the discrete theory of every pressure of one surface shares it (M4)."""
        from gapsweep.theory import spectrum

        sp = t.surface_params()
        h = self.surface(t, n)
        key = self._key(t, n, sp)
        if key not in self._spectra:
            self._spectra[key] = spectrum.from_heights(h, sp["length"], lambda_l=sp["lambda_l"])
        return self._spectra[key]

    def makes_on_gpu(self, t: Task) -> bool:
        """Whether :meth:`surface_on_gpu` makes ``t``'s surface on the GPU itself (issue 38): a synthetic surface
        of a task on a grid, unless the task keeps its fields (their heights are the host surface's) or
        ``GAPSWEEP_GPU_SURFACES=0``. The host made it before, the GPU workers' host threads being what bounded a
        node of many GPU workers (docs/benchmarks.md, "Issue 38")."""
        return (self.gpu_surfaces and t.n > 0 and t.opt("surface.kind") != "file" and not t.opt("keep_fields")
                and t.opt("backend") == "cupy")

    def surface_on_gpu(self, t: Task, n: int) -> Any:
        """:meth:`surface` as a cupy array on the current GPU, copied there once per cached surface (a pressure
        chain solved one task at a time then copies its surface to the GPU once, not once per task). Where
        :meth:`makes_on_gpu`: made on the GPU by ``surfaces.self_affine(backend="cupy")`` -- the same modes, equal
        to the host surface to FFT round-off (~1e-15 relative), no host copy -- and cached there (as many as the
        host cache holds)."""
        import cupy

        if self.makes_on_gpu(t):
            sp = t.surface_params()
            key = self._key(t, n, sp)
            dev = cupy.cuda.Device().id
            made = self._made_on_gpu.get(key)
            if made is None or made[0] != dev:
                from gapsweep.surfaces import synthetic as surface

                h = surface.self_affine(n, t.hurst, seed=t.seed, backend="cupy", **sp)
                self._rms.pop(key, None)  # of another device's copy: computed again from this one
                made = self._made_on_gpu[key] = (dev, h)
                while len(self._made_on_gpu) > self._max:
                    old = self._made_on_gpu.popitem(last=False)[0]
                    if old not in self._surfaces:
                        self._rms.pop(old, None)
            self._made_on_gpu.move_to_end(key)
            return made[1]
        h = self.surface(t, n)  # caches (and evicts) the host surface and, with it, its GPU copy
        key = self._key(t, n, t.surface_params())
        dev = cupy.cuda.Device().id
        cached = self._on_gpu.get(key)
        if cached is None or cached[0] != dev:
            cached = (dev, cupy.asarray(h))
            self._on_gpu[key] = cached
        return cached[1]

    def surface_rows(self, t: Task, n: int, comm: Any) -> Any:
        """This rank's rows (``gapsweep.core.slab.slab_rows``) of :meth:`surface` for a task solved over every
        rank of ``comm`` (gapsweep.sweep.slabs: a synthetic surface made in place, no rank holding the whole map;
        on this rank's GPU for ``backend = "cupy"``). Collective. One such surface is cached (a pressure chain
        makes it once); making another drops it first, so a rank never holds two."""
        from gapsweep.sweep.slabs import surface_rows

        sp = t.surface_params()
        backend = "cupy" if t.opt("backend") == "cupy" else "numpy"
        key = (*self._key(t, n, sp), "rows", comm.Get_size(), comm.Get_rank(), backend)
        if self._rows is None or self._rows[0] != key:
            self._rows = None
            h, rms = surface_rows(t, n, sp, comm, backend, map_rms=_rms_and_spectrum)
            if hasattr(h, "setflags"):
                h.setflags(write=False)
            self._rows = (key, h, rms)
        return self._rows[1]

    def surface_rows_rms(self, t: Task, n: int, comm: Any) -> tuple[float, float]:
        """``(h_rms, g_rms)`` of the whole surface of :meth:`surface_rows` (reduced over the ranks; a file map's
        from rank 0, which reads it). Collective when the rows are not cached yet."""
        self.surface_rows(t, n, comm)
        return tuple(self._rows[2][:2])

    def surface_rows_spectrum_rms(self, t: Task, n: int, comm: Any) -> tuple[float, float]:
        """:func:`spectrum_rms` of the whole file map of :meth:`surface_rows` (rank 0's, sent to every rank); (NaN,
        NaN) for a synthetic surface. Collective when the rows are not cached yet."""
        self.surface_rows(t, n, comm)
        rms = self._rows[2]
        return (float(rms[2]), float(rms[3])) if len(rms) == 4 else (math.nan, math.nan)

    @staticmethod
    def _key(t: Task, n: int, sp: dict[str, Any]) -> tuple:
        # list values (a file surface's [x, y] pixel size or length) as tuples: the key must be hashable
        return (t.hurst, t.seed, n, tuple(sorted((k, tuple(v) if isinstance(v, list) else v) for k, v in sp.items())))


def _make_surface(t: Task, n: int, sp: dict[str, Any]) -> np.ndarray:
    """The heights of ``t``'s surface on an ``n x n`` grid (read-only array): a file's map or a synthetic one."""
    if sp.get("kind") == "file":
        from gapsweep.sweep.filesurface import file_surface_heights

        h = file_surface_heights(sp)
    else:
        from gapsweep.surfaces import synthetic as surface

        h = surface.self_affine(n, t.hurst, seed=t.seed, **sp)
    h.setflags(write=False)
    return h


def _rms(h: np.ndarray, sp: dict[str, Any]) -> tuple[float, float]:
    """``(h_rms, g_rms)`` of heights ``h`` (see Context.surface_rms). A file map's are those of the heights as
    solved (issue 36: the spectrum's moments differ, 1.5-3x on instrument maps, and are not what a user
    normalises by): ``h_rms = sqrt(<(h - <h>)^2>)`` and the finite-difference rms slope with the map's boundaries
    (``Topography.rms_slope``); the spectral moments are :func:`spectrum_rms`."""
    if sp.get("kind") == "file":
        from gapsweep.surfaces.topography import Topography

        length = sp["length"] if isinstance(sp["length"], (list, tuple)) else (sp["length"], sp["length"])
        topo = Topography(np.asarray(h, dtype=float), (float(length[0]), float(length[1])),
                          periodic=bool(sp.get("periodic", True)))
        return topo.rms_height(), topo.rms_slope()
    from gapsweep.surfaces import synthetic as surface

    return surface.rms_height(h), surface.rms_slope(h, sp["length"])


def _rms_gpu(h: Any, sp: dict[str, Any]) -> tuple[float, float]:
    """:func:`_rms` of a synthetic surface held on the GPU (cupy), by the formulas of ``surfaces.rms_height`` and
    ``surfaces.rms_slope`` (M2): ``h_rms = sqrt(<(h - <h>)^2>)``, ``g_rms = sqrt(sum_q q^2 |h~(q)|^2)`` over the
    half spectrum (rfft2, cuFFT; a plan of its own, dropped after use). Equal to the host values to round-off."""
    import cupy
    from cupyx.scipy.fft import get_fft_plan

    n = h.shape[0]
    length = float(sp["length"])
    h_rms = float(cupy.sqrt(cupy.mean((h - h.mean()) ** 2)))
    kx = cupy.asarray(np.fft.fftfreq(n, d=1.0 / n))
    ky = cupy.asarray(np.fft.rfftfreq(n, d=1.0 / n))
    w = np.full(n // 2 + 1, 2.0)
    w[0] = 1.0
    if n % 2 == 0:
        w[-1] = 1.0
    plan = get_fft_plan(h, shape=(n, n), axes=(0, 1), value_type="R2C")
    with plan:
        hq = cupy.fft.rfft2(h) / h.size
    q2w = (2 * np.pi / length) ** 2 * (kx[:, None] ** 2 + ky[None, :] ** 2) * cupy.asarray(w)[None, :]
    g_rms = float(cupy.sqrt(cupy.sum(q2w * (hq.real ** 2 + hq.imag ** 2))))
    del hq, q2w, plan
    return h_rms, g_rms


def spectrum_rms(h: np.ndarray, sp: dict[str, Any]) -> tuple[float, float]:
    """A file map's spectral moments ``(h_rms_spectrum, g_rms_spectrum)``: those of its spectrum taken right for
    its boundaries (``theory.spectrum.map_spectrum``, which Persson's theory of the map uses); (NaN, NaN) for a
    synthetic surface (its ``h_rms``, ``g_rms`` are already the spectrum's)."""
    if sp.get("kind") != "file":
        return math.nan, math.nan
    from gapsweep.theory.spectrum import map_spectrum

    ms = map_spectrum(h, sp["length"], periodic=sp.get("periodic", True))
    return float(ms.h_rms), float(ms.g_rms)


def _rms_and_spectrum(h: np.ndarray, sp: dict[str, Any]) -> tuple[float, float, float, float]:
    """``(h_rms, g_rms, h_rms_spectrum, g_rms_spectrum)`` of a whole file map (:func:`_rms`, :func:`spectrum_rms`)."""
    return (*_rms(h, sp), *spectrum_rms(h, sp))


def _surface_and_rms(t: Task, n: int, sp: dict[str, Any]) -> tuple[np.ndarray, tuple[float, float]]:
    h = _make_surface(t, n, sp)
    return h, _rms(h, sp)


def moments(t: Task, ctx: Context) -> tuple[float, float]:
    """(h_rms, g_rms) fed to theory/SDE/FP: continuum values of the spectrum, or those of the discrete surface
    on the smallest grid that carries lambda_s (M2: the mode set does not depend on the grid)."""
    from gapsweep.surfaces import synthetic as surface

    sp = t.surface_params()
    if t.opt("h_rms") == "continuum":
        if "rms_height" in sp:
            return sp["rms_height"], math.nan
        g = sp["rms_slope"]
        return surface.continuum_rms_height(t.hurst, lambda_l=sp["lambda_l"], lambda_s=sp["lambda_s"],
                                            rms_slope=g, lambda_r=sp.get("lambda_r")), g
    n = 2 * int(math.floor(sp["length"] / sp["lambda_s"] * (1 + 1e-9))) + 2
    return ctx.surface_rms(t, n)


def extra(t: Task) -> dict[str, Any]:
    return {k[6:]: v for k, v in t.options if k.startswith("extra.")}


def hist(t: Task, samples: Any, exclude_zero: bool = False) -> tuple[np.ndarray, np.ndarray, int]:
    """Histogram ``(edges, density, count)`` of the finite samples over the job's bins and range (``"auto"``:
    the samples' min..max). A cupy array is binned on its GPU with the same edges (only the counts come back).
    ``exclude_zero`` (hard wall): the points at exactly 0 (the contact atom, stored apart) are left out and the
    density of the others integrates to their fraction ``1 - atom``."""
    from gapsweep.gfmd._ops import _is_cupy

    if exclude_zero:
        size = samples.size
        samples = samples[samples != 0.0]
        edges, dens, count = hist(t, samples)
        return edges, dens * (count / size if size else 0.0), count
    if _is_cupy(samples):
        return hist_device(t, samples)
    finite = samples[np.isfinite(samples)]
    rng = t.opt("range")
    r = None if rng == "auto" else tuple(rng)
    if r is None and finite.size and finite.min() == finite.max():
        r = (finite.min() - 0.5, finite.max() + 0.5)
    dens, edges = np.histogram(finite, bins=t.opt("bins"), range=r)
    total = dens.sum()
    width = np.diff(edges)
    density = dens / (total * width) if total else np.zeros_like(width)
    return edges, density, int(total)


def hist_device(t: Task, samples: Any) -> tuple[np.ndarray, np.ndarray, int]:
    """:func:`_hist` of a cupy array: numpy's edges for the range, counts on the GPU (bin ``k`` holds
    ``edges[k] <= x < edges[k+1]``, the last bin closed, as numpy's)."""
    import cupy

    finite = samples[cupy.isfinite(samples)]
    rng = t.opt("range")
    if rng != "auto":
        r = (float(rng[0]), float(rng[1]))
    elif finite.size:
        lo, hi = float(finite.min()), float(finite.max())
        r = (lo - 0.5, hi + 0.5) if lo == hi else (lo, hi)
    else:
        r = (0.0, 1.0)  # numpy's default range for no data
    edges = np.histogram_bin_edges(np.empty(0), bins=t.opt("bins"), range=r)
    counts, _ = cupy.histogram(finite, bins=cupy.asarray(edges))
    dens = cupy.asnumpy(counts)
    total = dens.sum()
    width = np.diff(edges)
    density = dens / (total * width) if total else np.zeros_like(width)
    return edges, density, int(total)


def host(a: Any) -> np.ndarray:
    return a.get() if hasattr(a, "get") and not isinstance(a, np.ndarray) else np.asarray(a)


def use_gpu(t: Task, ctx: Context) -> None:
    """Make this rank's GPU current for a GFMD task with ``backend = "cupy"`` (clear error without cupy)."""
    if t.opt("backend") == "cupy":
        from gapsweep.core.extras import require

        cupy = require("cupy", 'GFMD on the GPU (backend = "cupy")')
        cupy.cuda.Device(ctx.select_gpu()).use()  # this rank's GPU, current before any other CUDA call
