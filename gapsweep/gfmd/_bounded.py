"""The "bounded" minimiser: a hard wall with an adhesive energy (``HardWallAdhesive``) at fixed mean pressure,
compressive or tensile (docs/gfmd.md, "Hard wall with adhesion"; docs/model.md "Hard wall with exponential
adhesion"), on one process (numpy, pyFFTW or one GPU through cupy) or split over the ranks of a communicator
(``gfmd.distributed.solve(..., interaction="hard_wall_adhesive")``: the same code on a
:class:`gapsweep.gfmd.distributed.SlabGrid`, every scalar combined over the ranks).

Unknown: the gap ``g`` itself (real space, its mean included), bound ``g >= 0``; the displacement is
``u = g - <g> + h - <h>``, so ``u~ = (g + h)~`` for ``q != 0``. The energy per area

    F(g) = (E*/4) sum_{q != 0} q |u~(q)|^2 + <V(g)> + sigma0 <g>

has the gradient (per pixel, ``dF = <G dg>``) ``G = p_el + V'(g) + sigma0`` with ``p_el = IFFT[(E* q/2) u~]``.
Its KKT conditions are the equilibrium: ``G = 0`` where ``g > 0`` (``p_el = p - sigma0`` with ``p = -V'``),
``G = lambda >= 0`` where ``g = 0`` (the contact pressure), and ``<p> = sigma0`` follows from ``<p_el> = 0``. No
equality constraint: the load enters through the linear term, so tensile loads need no special treatment and a
body that loses every contact at a tensile load runs away (status "detached").

Algorithm: projected L-BFGS in the spirit of L-BFGS-B (Byrd, Lu, Nocedal & Zhu, SIAM J. Sci. Comput. 16, 1190,
1995), simplified to a diagonal bound: the free set ``F = {g > eps} | {G <= 0}``; the search direction is the
L-BFGS two-loop recursion on the projected gradient ``P_F G`` with the initial inverse Hessian
``P_F C P_F``, ``C = (E* q/2)^-1`` the half-space compliance (exact for a free surface; ``q = 0`` takes the
lowest mode's value), restricted to ``F``; an Armijo backtracking search along the projected path
``max(g + alpha d, 0)``; pairs ``(s, y)`` restricted to the pixels free at both ends and kept only when
``s.y > 0`` (``V`` is concave: negative-curvature pairs are dropped); at most ``memory`` pairs (10 on one
process), the oldest pair's arrays reused for the next one. Each iteration is two FFT pairs (the
preconditioner of the direction and of the newest ``y``) plus one forward transform per line-search trial and one
inverse for the new gradient.

Memory (:func:`memory_plan`): the solve runs in fixed buffers, every elementwise pass in row chunks of at most
``_CHUNK`` elements (no grid-sized temporary): real fields ``g, G, d, t`` (the direction and the trial step),
half spectra ``U = u~`` and one scratch ``S``, the stiffness ``E* q/2`` (half a real field), the free-set mask
(1/8), ``2 memory`` pair fields, and the FFT's own scratch; the surface is the caller's array (not copied, not
centred: the ``q = 0`` mode is dropped where ``u~`` is formed).

Convergence on the returned fields: ``residual = rms(P G) / P_ref`` with the projected gradient ``P G`` (``G``
where ``g > 0``, ``min(G, 0)`` where ``g = 0``) and ``P_ref = max(|sigma0|, w/rho)``; ``load_error = |<p> -
sigma0| / P_ref`` (bounded by the residual); ``converged`` iff both ``<= tol``. Statuses: "converged", "stalled"
(no progress for ``_STALL_WINDOW`` iterations, or no descent left above round-off), "detached" (tensile load
and every gap beyond ``_DETACHED`` ranges: beyond pull-off), "max_iter", "non_finite".

Tensile loads (docs/gfmd.md "Tensile loads"): without ``initial`` the body first finds its zero-load equilibrium
from the flat body touching the highest summit, then the load is lowered in steps (each warm-started from the
last, halved when a step does not converge, the pull-off bracketed to ``_MIN_STEP`` of ``w/rho``), as the smooth
laws' continuation does (gfmd._smooth)."""

from __future__ import annotations

import logging
import math
import time
from typing import Any

import numpy as np

from gapsweep.core import deadline
from gapsweep.core.vec import axpy, rdot
from gapsweep.gfmd._coarse import Start
from gapsweep.gfmd._continuation import next_load, record
from gapsweep.gfmd._grid import Grid
from gapsweep.gfmd._ops import _is_cupy
from gapsweep.gfmd._result import GFMDResult, fields_to_host, final_status

METHODS = ("plbfgs",)
log = logging.getLogger("gapsweep.gfmd")
_MEMORY = 10  # L-BFGS pairs on one process (the distributed solve takes its ``memory`` keyword)
_CHUNK = 1 << 22  # elements per chunk of the elementwise passes (32 MiB of float64): their only temporaries
_FFT_OUT = int(np.__version__.split(".")[0]) >= 2  # numpy's FFTs take out= (else a result array and a copy)
_CHUNK_GPU = 1 << 25  # on GPUs (256 MiB): fewer kernel launches per pass (a 65536^2 slab of 4 ranks: 32 chunks)
_DETACHED = 30.0  # every gap beyond this many ranges at a tensile load: the body has left
_STALL_WINDOW = 60  # iterations without the residual falling below 0.9 x its best and without energy decrease
_STALL_ENERGY = 1e-13  # relative energy change that counts as round-off
_ARMIJO = 1e-4
_MAX_BACKTRACK = 50
# Continuation to tensile loads (fractions of the law's pressure scale w/rho):
_STEP_TOL = 1e-7  # residual of the intermediate loads
_FIRST_STEP = 1 / 64
_MIN_STEP = 1e-4


# ---------------------------------------------------------------------------------------------- memory
def memory_plan(shape: tuple[int, int], ranks: int = 1, *, memory: int = _MEMORY, tensile: bool = False,
                backend: str = "numpy", chunk: int | None = None) -> dict[str, Any]:
    """Peak bytes per process of a solve of an ``nx x ny`` grid over ``ranks`` processes (one process: ranks=1),
    counted from the code (module docstring; docs/gfmd.md "Hard wall with adhesion", memory). ``A``: one float64
    field of the process's rows (``ceil(nx/ranks) ny``), a half spectrum of its columns ``S`` (complex128,
    ``ceil((ny/2+1)/ranks) nx``, about ``A``). Parts: the solver's fixed buffers (``g, G, d, t``: 4 A; ``U``,
    scratch ``S``: 2 S; ``E* q/2``: S/2; free mask A/8; pairs ``2 memory`` A), 2 A more while a tensile load is
    followed (``tensile``: the last two equilibria of the continuation), the chunked passes' temporaries (at most
    4 chunks of ``_CHUNK`` complex numbers), the surface (the caller's array, counted apart as ``array_bytes``),
    and the transform's scratch by ``backend``:

    - distributed (``ranks > 1``, or ``backend`` "slab" / "slab-cupy": any :class:`SlabGrid`): the slab
      transform's inverse holds the rows' half spectrum (``nr (ny/2+1)`` complex), the send buffer and either one
      chunk of 1-D transforms (``gapsweep.core.slab.DEFAULT_CHUNK`` complex numbers) or the receive buffer (each
      buffer the spectrum less the own block; measured with tracemalloc, tests/mpi/test_bounded_mpi.py); on GPUs
      both (cupy's pool keeps the chunk's freed block) and cuFFT's work areas of the three cached 1-D plans (R2C,
      C2C, C2R), each counted as one chunk (not yet measured on a GPU);
    - "numpy" (one process): numpy's ``rfft2``/``irfft2`` make two spectra per call;
    - "pyfftw": the planned pair's four aligned buffers (two real fields, two spectra);
    - "cupy" (one GPU): the planned pair's three buffers (two spectra, one real field) and the two 2-D plans'
      work areas (one spectrum each, as measured for ``gfmd._cuda``).

    Returns ``{"bytes_per_rank", "array_bytes" (the surface's rows), "arrays" (bytes_per_rank / A),
    "grid_arrays" (the same without the parts of fixed size: chunks and numpy's buffers), "parts"}``."""
    from gapsweep.core.slab import DEFAULT_CHUNK

    if backend not in ("numpy", "pyfftw", "cupy", "slab", "slab-cupy"):
        raise ValueError(f"backend must be 'numpy', 'pyfftw', 'cupy', 'slab' or 'slab-cupy', got {backend!r}")
    nx, ny = (int(v) for v in shape)
    ranks = int(ranks)
    nr, nc = -(-nx // ranks), -(-(ny // 2 + 1) // ranks)
    a, s = 8.0 * nr * ny, 16.0 * nc * nx
    c = (_CHUNK_GPU if "cupy" in backend else _CHUNK) if chunk is None else int(chunk)
    spec_rows, spec_cols = (nc, nx) if ranks > 1 or backend.startswith("slab") else (nx, ny // 2 + 1)
    ch = 16.0 * max(min(max(1, c // ny) * ny, nr * ny),  # the elements of one chunk of rows (_Ops.chunks)
                    min(max(1, c // spec_cols) * spec_cols, spec_rows * spec_cols))
    parts = {"surface (caller's rows)": a, "real fields g, G, d, t": 4 * a, "spectra U, S": 2 * s,
             "stiffness E* q/2": s / 2, "free-set mask": a / 8, f"L-BFGS pairs ({memory})": 2.0 * memory * a,
             "continuation (tensile)": 2 * a if tensile else 0.0, "chunked passes' temporaries": 4 * ch}
    if ranks > 1 or backend == "slab" or backend == "slab-cupy":
        slab_chunk = 16.0 * min(DEFAULT_CHUNK, max(nr * (ny // 2 + 1), nc * nx))
        # the inverse's peak: the rows' half spectrum b, the send buffer and either one chunk of the 1-D inverse
        # transforms or the receive buffer (the forward transform holds less: send and a chunk or receive)
        send, recv = 16.0 * (nc * nx - nc * nr), 16.0 * (nr * (ny // 2 + 1) - nr * nc)
        gpu = backend in ("cupy", "slab-cupy")
        # on GPUs cupy's pool keeps the freed chunk's block when the receive buffer is allocated: both count
        parts["slab transform (rows' spectrum, send, receive or one chunk)"] = (
            16.0 * nr * (ny // 2 + 1) + send + (slab_chunk + recv if gpu else max(slab_chunk, recv)))
        if gpu:
            parts["cuFFT work areas (3 cached 1-D plans)"] = 3 * slab_chunk
    elif backend == "numpy":
        parts["numpy FFT temporaries"] = 2 * s
    elif backend == "pyfftw":
        parts["pyFFTW buffers"] = 2 * a + 2 * s
    else:  # "cupy", one GPU
        parts["cuFFT buffers"] = a + 2 * s
        parts["cuFFT work areas (R2C + C2R plans)"] = 2 * s
    if "cupy" not in backend:  # numpy's casting buffers of the masked passes (bool x float), 8192 elements each
        parts["numpy ufunc buffers"] = 3 * 8.0 * np.getbufsize()
    total = sum(parts.values())
    fixed = parts["chunked passes' temporaries"] + parts.get("numpy ufunc buffers", 0.0)
    return {"bytes_per_rank": total, "array_bytes": a, "arrays": total / a, "grid_arrays": (total - fixed) / a,
            "parts": parts}


def solve_memory(shape: tuple[int, int], ranks: int = 1, **kw: Any) -> int:
    """Bytes a solve holds at its peak per process, the surface included (:func:`memory_plan`). ``65536^2``
    with 10 pairs: 26 arrays (about 0.9 TB) on one process; over 4 GPUs with 2 pairs about 15 arrays of 8.6 GB."""
    return int(math.ceil(memory_plan(shape, ranks, **kw)["bytes_per_rank"]))


# ---------------------------------------------------------------------------------------------- passes
class _Ops:
    """Transforms into given buffers and chunked reductions on a :class:`Grid` or a
    :class:`~gapsweep.gfmd.distributed.SlabGrid` (then every returned scalar is combined over the ranks, several
    in one collective)."""

    def __init__(self, grid: Grid) -> None:
        self.grid, self.xp = grid, grid.xp
        self.slab = getattr(grid, "slab", None)
        self.red = getattr(grid, "red", None)
        self.n = grid.size
        self.real_shape = tuple(grid.real_shape)
        nx, ny = grid.shape
        xp = self.xp
        if self.slab is not None:
            self.spec_shape = tuple(self.slab.spec_shape)
            self.w = xp.asarray(grid._w, dtype=xp.float64)  # (nc, 1): one weight per spectrum row
        else:
            self.spec_shape = (nx, ny // 2 + 1)
            w = np.full(ny // 2 + 1, 2.0)
            w[0] = 1.0
            if ny % 2 == 0:
                w[-1] = 1.0
            self.w = xp.asarray(w[None, :])

    def chunks(self, shape: tuple[int, ...]) -> list[slice]:
        rows, cols = shape
        step = max(1, (_CHUNK if self.xp is np else _CHUNK_GPU) // max(cols, 1))
        return [slice(i, min(i + step, rows)) for i in range(0, rows, step)]

    def reduce(self, sums: tuple = (), mins: tuple = (), maxs: tuple = ()) -> tuple[list, list, list]:
        if self.red is None:
            return [float(v) for v in sums], [float(v) for v in mins], [float(v) for v in maxs]
        return self.red.many(sums=tuple(float(v) for v in sums), mins=tuple(float(v) for v in mins),
                             maxs=tuple(float(v) for v in maxs))

    def total(self, *values: float) -> list[float]:
        return self.reduce(sums=values)[0]

    def fwd(self, a: Any, out: Any) -> Any:
        """``out = rfft2(a) / (nx ny)`` (the normalised coefficients), the ``q = 0`` mode included."""
        xp, g = self.xp, self.grid
        if self.slab is not None:
            self.slab.rfft2(a, out=out)
            out *= 1.0 / self.n
        elif g._fft is not None:
            xp.multiply(g._fft.rfft2(a), 1.0 / self.n, out=out)
        elif xp is np and _FFT_OUT:  # numpy >= 2: straight into out, the 1/(nx ny) in the transform
            np.fft.rfft2(a, norm="forward", out=out)
        else:
            out[...] = xp.fft.rfft2(a)
            out *= 1.0 / self.n
        return out

    def inv(self, A: Any, out: Any) -> Any:
        """``out`` = the real field of the coefficients ``A`` (``A`` unchanged)."""
        xp, g = self.xp, self.grid
        if self.slab is not None:
            self.slab.irfft2(A, out=out)
        elif g._fft is not None:
            xp.copyto(out, g._fft.irfft2(A))
        else:  # (numpy 2.4's irfft2 with out= returns garbage for 2-D input: not used)
            out[...] = xp.fft.irfft2(A, s=g.shape, norm="forward")
        return out

    def ldot(self, a: Any, b: Any) -> float:
        """This process's ``sum a b`` of two real fields (no temporary; on cupy a device scalar, read by the
        reduction that combines it)."""
        return rdot(a, b) if self.xp is np else self.xp.vdot(a.ravel(), b.ravel())  # a device scalar: no sync

    def dot(self, a: Any, b: Any) -> float:
        return self.total(self.ldot(a, b))[0]

    def lsdot(self, A: Any, B: Any, k: Any = None) -> float:
        """This process's Parseval sum ``sum w Re(conj A (k B))`` over its spectrum rows (chunked)."""
        s = 0.0
        w = self.w
        for ch in self.chunks(A.shape):
            a, b = A[ch], B[ch] if k is None else B[ch] * k[ch]
            wc = w[ch] if w.shape[0] > 1 else w
            s += (wc * (a.real * b.real + a.imag * b.imag)).sum()
        return s


# ---------------------------------------------------------------------------------------------- the state
class _Lean:
    """One grid, surface, law and load: the fixed buffers of the module docstring and the passes on them."""

    def __init__(self, grid: Grid, law: Any, h: Any, e_star: float, memory: int) -> None:
        self.ops = ops = _Ops(grid)
        self.grid, self.law, self.h, self.memory = grid, law, h, memory
        xp = self.xp = grid.xp
        k, grid.q = grid.q, None  # E* q/2 in the grid's |q| array (this grid serves this solve only)
        k *= 0.5 * e_star
        pos = k[k > 0]
        kmin = ops.reduce(mins=(float(pos.min()) if pos.size else math.inf,))[1][0]
        del pos
        if not math.isfinite(kmin):
            kmin = 0.5 * e_star
        grid.set_mode0(k, kmin)  # the preconditioner's q = 0 value; every product with k has u~(0) = 0
        self.k = k
        self.g = xp.empty(ops.real_shape)
        self.G = xp.empty(ops.real_shape)
        self.d = xp.empty(ops.real_shape)
        self.t = xp.empty(ops.real_shape)
        self.U = xp.empty(ops.spec_shape, dtype=xp.complex128)
        self.S = xp.empty(ops.spec_shape, dtype=xp.complex128)
        self.free = xp.empty(ops.real_shape, dtype=bool)
        self.sigma0 = 0.0
        self.f = math.nan
        self.nfev = 0

    # -- the state at g
    def evaluate(self) -> None:
        """``U``, the energy ``f`` and the gradient ``G`` of the gap in ``g`` (clipped at 0 in place)."""
        xp, ops, law, g = self.xp, self.ops, self.law, self.g
        for ch in ops.chunks(g.shape):
            xp.maximum(g[ch], 0.0, out=g[ch])
            xp.add(g[ch], self.h[ch], out=self.t[ch])
        ops.fwd(self.t, self.U)
        self.grid.set_mode0(self.U, 0.0)
        sv = sg = 0.0
        for ch in ops.chunks(g.shape):
            sv += law.energy(g[ch], xp).sum()
            sg += g[ch].sum()
        el, sv, sg = ops.total(ops.lsdot(self.U, self.U, self.k), sv, sg)
        self.f = 0.5 * el + (sv + self.sigma0 * sg) / ops.n
        self.gradient()

    def gradient(self) -> None:
        """``G = IFFT[k U] + V'(g) + sigma0`` (``S`` as scratch)."""
        xp, ops = self.xp, self.ops
        xp.multiply(self.U, self.k, out=self.S)
        self.grid.set_mode0(self.S, 0.0)
        ops.inv(self.S, self.G)
        for ch in ops.chunks(self.g.shape):
            self.G[ch] += self.law.force(self.g[ch], xp)
            self.G[ch] += self.sigma0
        self.nfev += 1

    def stats(self, compliance: float) -> tuple[float, float, float]:
        """``(sum (P G)^2, sum (g - max(g - c G, 0))^2, min g)`` over the grid (one collective)."""
        xp, g, G = self.xp, self.g, self.G
        s1 = s2 = 0.0
        mn = None  # per-chunk sums and minima stay on the device until the one collective
        for ch in self.ops.chunks(g.shape):
            gc, Gc = g[ch], G[ch]
            pg = xp.where(gc > 0, Gc, xp.minimum(Gc, 0.0))
            s1 += (pg * pg).sum()
            xp.multiply(Gc, -compliance, out=pg)
            pg += gc
            xp.maximum(pg, 0.0, out=pg)
            xp.subtract(gc, pg, out=pg)
            s2 += (pg * pg).sum()
            if gc.size:
                mn = gc.min() if mn is None else xp.minimum(mn, gc.min())
        (s1, s2), (mn,), _ = self.ops.reduce(sums=(s1, s2), mins=(math.inf if mn is None else mn,))
        return s1, s2, mn

    def set_free(self, eps: float) -> None:
        """``free = (g > eps) | (G <= 0)``: all but the eps-active set."""
        xp = self.xp
        for ch in self.ops.chunks(self.g.shape):
            xp.greater(self.g[ch], eps, out=self.free[ch])
            self.free[ch] |= self.G[ch] <= 0

    def precondition(self, x: Any) -> None:
        """``x <- P_F C P_F x`` in place (``S`` as scratch)."""
        x *= self.free
        self.ops.fwd(x, self.S)
        self.S /= self.k
        self.ops.inv(self.S, x)
        x *= self.free

    def trial(self, alpha: float) -> tuple[float, float]:
        """The step ``t = max(g + alpha d, 0) - g``, its spectrum in ``S``; returns ``(F(g + t) - F(g), <G t>)``:
        the energy change summed from the changes of each term (``dU``, ``expm1``), so that it keeps its relative
        precision when it is far below the energy itself (near convergence the energy's round-off would otherwise
        decide the line search)."""
        xp, ops, law, g, t = self.xp, self.ops, self.law, self.g, self.t
        sv = sg = sd = 0.0
        for ch in ops.chunks(g.shape):
            gc, tc = g[ch], t[ch]
            xp.multiply(self.d[ch], alpha, out=tc)
            tc += gc
            xp.maximum(tc, 0.0, out=tc)
            tc -= gc
            sv += (law.energy(gc, xp) * xp.expm1(tc * (-1.0 / law.rho))).sum()
            sg += tc.sum()
            sd += ops.ldot(self.G[ch], tc)
        ops.fwd(t, self.S)
        self.grid.set_mode0(self.S, 0.0)
        el = 0.0
        w = ops.w
        for ch in ops.chunks(self.S.shape):  # sum w Re(conj S k (U + S/2))
            b = self.S[ch] * 0.5
            b += self.U[ch]
            b *= self.k[ch]
            a = self.S[ch]
            wc = w[ch] if w.shape[0] > 1 else w
            el += (wc * (a.real * b.real + a.imag * b.imag)).sum()
        el, sv, sg, sd = ops.total(el, sv, sg, sd)
        return el + (sv + self.sigma0 * sg) / ops.n, sd / ops.n


def _axpy(xp: Any, ops: _Ops, a: float, x: Any, y: Any) -> None:
    """``y += a x`` in chunks (numpy: gapsweep.core.vec.axpy, cache-sized chunks on this thread)."""
    if xp is np:
        axpy(a, x, y)
        return
    for ch in ops.chunks(y.shape):
        y[ch] += x[ch] * a


def _plbfgs(st: _Lean, p_ref: float, tol: float, max_iter: int, history: list[float], scale: float,
            compliance: float) -> str:
    """Projected L-BFGS from the state in ``st`` (module docstring) until ``residual <= tol``; ``st`` holds the
    last point. ``max_iter`` counts iterations (each one gradient evaluation)."""
    xp, ops = st.xp, st.ops
    pairs = _BoundedPairs(st)
    best = [math.inf, math.inf, 0]
    it = 0
    with np.errstate(all="ignore"):
        while True:
            deadline.check()
            s_pg, s_step, gmin = st.stats(compliance)
            res = math.sqrt(max(s_pg / ops.n, 0.0)) / p_ref
            history.append(res)
            status = _stop(st, res, tol, gmin, it, max_iter, best)
            if status is not None:
                return status
            it += 1
            # eps-active set (Bertsekas, SIAM J. Control Optim. 20, 221, 1982): pixels within eps of the bound
            # and pushed onto it go to it straight (d = -g there); without it a pixel a round-off above the
            # bound, which the preconditioned direction moves upward, stalls the iteration. eps: the gap that
            # one projected-gradient step with the pixel compliance dx/E* would close, at most rho/100.
            eps = min(0.01 * st.law.range(), math.sqrt(max(s_step / ops.n, 0.0)))
            st.set_free(eps)
            slope = pairs.direction()
            if not slope < 0:
                pairs.clear()
                xp.copyto(st.d, st.G)
                st.precondition(st.d)
                _direction(st)
                slope = ops.dot(st.G, st.d) / ops.n
                if not slope < 0:
                    return "stalled" if math.isfinite(slope) else "non_finite"
            df = _line_search(st, scale, bool(pairs.s))
            if df is None:
                if not pairs.s:
                    return "stalled"
                pairs.clear()
                continue
            pairs.step(df)


def _stop(st: _Lean, res: float, tol: float, gmin: float, it: int, max_iter: int, best: list) -> str | None:
    """The status at which the iteration stops here, or None to go on: converged at ``res <= tol``, detached
    (tension, every gap beyond the law's range), max_iter, stalled (no progress in residual or energy within
    ``_STALL_WINDOW`` iterations; ``best`` = [best residual, best energy, its iteration], updated)."""
    ops, law = st.ops, st.law
    if not math.isfinite(res) or not math.isfinite(st.f):
        return "non_finite"
    if res <= tol:
        return "converged"
    if st.sigma0 < 0 and gmin > _DETACHED * law.range():
        return "detached"
    if it >= max_iter:
        return "max_iter"
    f_scale = _STALL_ENERGY * (abs(st.f) + abs(st.sigma0 * ops.total(float(st.g.sum()))[0] / ops.n) + law.work)
    if res < 0.9 * best[0] or best[1] - st.f > f_scale:
        best[:] = [min(res, best[0]), min(st.f, best[1]), it]
    elif it - best[2] >= _STALL_WINDOW:
        return "stalled"
    return None


def _line_search(st: _Lean, scale: float, curved: bool) -> float | None:
    """Armijo backtracking along the projected path from ``alpha = 1`` (without curvature pairs yet, ``curved``
    False: a first step that moves no pixel by more than the surface's rms ``scale``); the energy change of the
    accepted step, or None when none was accepted (``st.t``, ``st.S`` hold the accepted step's changes)."""
    xp, ops, d = st.xp, st.ops, st.d
    alpha = 1.0
    if not curved:
        dmax = ops.reduce(maxs=(max((float(xp.abs(d[ch]).max()) for ch in ops.chunks(d.shape)
                                     if d[ch].size), default=0.0),))[2][0]
        if dmax > 0:
            alpha = min(1.0, scale / dmax)
    for _ in range(_MAX_BACKTRACK):
        df, dec = st.trial(alpha)
        st.nfev += 1
        if math.isfinite(df) and df <= _ARMIJO * dec:
            return df
        alpha *= 0.5
    return None


class _BoundedPairs:
    """The projected L-BFGS's curvature pairs ``(s, y, 1/(s.y))`` on the pixels free at both ends of a step, at
    most ``st.memory`` of them, the oldest pair's arrays reused for the next (no new grid arrays once full)."""

    def __init__(self, st: _Lean) -> None:
        self.st = st
        self.s: list = []
        self.y: list = []
        self.r: list[float] = []

    def clear(self) -> None:
        self.s.clear(), self.y.clear(), self.r.clear()

    def direction(self) -> float:
        """``st.d``: the two-loop recursion on the free set with the compliance preconditioner as the initial
        inverse Hessian, scaled by ``y.Py/(s.y)`` of the newest pair; returns the slope ``<G d>``."""
        st = self.st
        xp, ops, n, d = st.xp, st.ops, st.ops.n, st.d
        xp.multiply(st.G, st.free, out=d)
        alphas = []
        for s, y, r in zip(reversed(self.s), reversed(self.y), reversed(self.r)):
            al = r * ops.dot(s, d) / n
            alphas.append(al)
            _axpy(xp, ops, -al, y, d)
        st.precondition(d)
        if self.y:
            xp.copyto(st.t, self.y[-1])
            st.precondition(st.t)
            yhy = ops.dot(self.y[-1], st.t) / n
            if yhy > 0:
                d *= 1.0 / (self.r[-1] * yhy)
        for s, y, r, al in zip(self.s, self.y, self.r, reversed(alphas)):
            _axpy(xp, ops, al - r * ops.dot(y, d) / n, s, d)
        _direction(st)
        return ops.dot(st.G, d) / n

    def step(self, df: float) -> None:
        """Take the accepted step (``st.t``, ``st.S``, energy change ``df``), evaluate the gradient there and keep
        the new pair where its curvature is positive."""
        st = self.st
        xp, ops, g, G, t, free = st.xp, st.ops, st.g, st.G, st.t, st.free
        if len(self.s) >= st.memory:
            s_new, y_new = self.s.pop(0), self.y.pop(0)
            self.r.pop(0)
        else:
            s_new, y_new = xp.empty_like(g), xp.empty_like(g)
        xp.copyto(y_new, G)  # G at the old point
        st.U += st.S
        g += t  # exactly 0 where the projection put the step onto the bound (t = -g there)
        st.f += df
        st.gradient()
        ss = yy = sy = 0.0
        for ch in ops.chunks(g.shape):  # pairs restricted to the pixels free at both ends
            both = free[ch] & ((g[ch] > 0) | (G[ch] <= 0))
            xp.multiply(t[ch], both, out=s_new[ch])
            xp.subtract(G[ch], y_new[ch], out=y_new[ch])
            y_new[ch] *= both
            ss += ops.ldot(s_new[ch], s_new[ch])
            yy += ops.ldot(y_new[ch], y_new[ch])
            sy += ops.ldot(s_new[ch], y_new[ch])
        ss, yy, sy = ops.total(ss, yy, sy)
        if sy > 1e-12 * math.sqrt(max(ss * yy, 0.0)):
            self.s.append(s_new), self.y.append(y_new), self.r.append(ops.n / sy)


def _direction(st: _Lean) -> None:
    """``d <- -(d where free, g elsewhere)``: the quasi-Newton step on the free set, straight to the bound on the
    eps-active set."""
    xp = st.xp
    for ch in st.ops.chunks(st.d.shape):
        xp.negative(xp.where(st.free[ch], st.d[ch], st.g[ch]), out=st.d[ch])


class _Solver:
    """One grid, surface and law: solves at any load from any start and follows loads by continuation."""

    def __init__(self, grid: Grid, law: Any, h: Any, e_star: float, max_iter: int, memory: int = _MEMORY) -> None:
        self.grid, self.law, self.h, self.max_iter = grid, law, h, max_iter
        self.st = _Lean(grid, law, h, e_star, memory)
        ops = self.st.ops
        sh = sh2 = 0.0
        for ch in ops.chunks(h.shape):
            sh += float(h[ch].sum())
        hbar = ops.total(sh)[0] / ops.n
        for ch in ops.chunks(h.shape):
            hc = h[ch] - hbar
            sh2 += float((hc * hc).sum())
        self.scale = max(math.sqrt(max(ops.total(sh2)[0] / ops.n, 0.0)), law.range())
        self.compliance = min(grid.lx / grid.shape[0], grid.ly / grid.shape[1]) / e_star
        self.nit = 0
        self.history: list[float] = []
        self.info: dict[str, float] = {}

    def at(self, sigma0: float, g: Any = None, tol: float = 1e-6, budget: int | None = None) -> tuple[_Lean, str]:
        """Minimise at ``sigma0`` from the gap ``g`` (copied; None: the gap already in the state)."""
        st = self.st
        if g is not None:
            st.xp.copyto(st.g, g)
        st.sigma0 = sigma0
        st.evaluate()
        left = max(self.max_iter - self.nit, 1)
        n0 = len(self.history)
        status = _plbfgs(st, self.law.pressure_scale(sigma0), tol, left if budget is None else min(budget, left),
                         self.history, self.scale, self.compliance)
        self.nit += max(len(self.history) - n0 - 1, 0)
        return st, status

    def follow(self, s_from: float, g_from: Any, target: float, tol: float) -> tuple[_Lean | None, str]:
        """Quasi-static unloading from the equilibrium ``g_from`` at ``s_from`` to ``target < s_from``: each
        step warm-started from the last accepted one (secant predictor, projected), halved when it does not
        converge to ``_STEP_TOL``; the steps double while two in a row converge. At the smallest step
        (``_MIN_STEP`` of ``w/rho``) the target is tried once from the last attached state: converged, the
        equilibrium after a jump (counted in ``info["jumps"]``); else "detached" (the branch ends: pull-off
        lies between ``info["last_attached_load"]`` and one smallest step below). Holds two gap fields beside the
        state (the last two equilibria)."""
        xp, ops, st = self.grid.xp, self.st.ops, self.st
        pscale = self.law.max_tension
        ds = -min(s_from - target, pscale * _FIRST_STEP)
        ds_min = pscale * _MIN_STEP
        s_k, g_k, g_prev, ds_prev = s_from, xp.array(g_from), None, 0.0
        have_prev = False
        accepted = attempts = jumps = 0
        res: _Lean | None = None
        status = "max_iter"
        while s_k > target and self.nit < self.max_iter:
            attempts += 1
            s_new, step, final = next_load(s_k, ds, target, pscale)
            if not have_prev:
                xp.copyto(st.g, g_k)
            else:
                c = step / ds_prev
                for ch in ops.chunks(st.g.shape):  # secant predictor, projected onto g >= 0 by evaluate()
                    xp.subtract(g_k[ch], g_prev[ch], out=st.g[ch])
                    st.g[ch] *= c
                    st.g[ch] += g_k[ch]
            res, status = self.at(s_new, None, tol if final else max(tol, _STEP_TOL))
            if status == "converged":
                if g_prev is None:
                    g_prev = xp.empty_like(g_k)
                g_prev, g_k = g_k, g_prev
                xp.copyto(g_k, st.g)
                have_prev, ds_prev, s_k = True, step, s_new
                accepted += 1
                ds = 2 * step
                if final:
                    break
                continue
            if status == "non_finite" or self.nit >= self.max_iter:
                break
            if abs(step) <= ds_min * (1 + 1e-9):
                res, status = self.at(target, g_k, tol)
                if status == "converged":
                    jumps += 1
                elif status != "non_finite":
                    status = "detached"
                break
            ds = 0.5 * step
        record(self.info, s_from=s_from, accepted=accepted, ds_min=ds_min, attempts=attempts, jumps=jumps,
               status=status, target=target, s_k=s_k)
        return res, status


def minimise(heights: Any, law: Any, *, sigma0: float, e_star: float, length: Any, tol: float, method: str,
             backend: str, max_iter: int, initial: Any, threads: int | None, host: Any, t_start: float,
             periodic: bool = True, grid: Grid | None = None, memory: int = _MEMORY) -> GFMDResult:
    """``law`` (a hard wall with an adhesive energy) on the periodic grid ``heights`` (inputs validated by
    ``gfmd.solve``; on a :class:`SlabGrid` this process's rows, validated by ``gfmd.distributed.solve``).
    ``initial``: a GFMDResult (its gap), a gap field (this process's rows) or a coarse-to-fine start
    (``gfmd._coarse.Start``: the body surface ``z~``, the gap ``z - h``); default the flat body touching the
    highest summit, solved at ``sigma0 >= 0`` directly and, at a tensile load, at zero load and then unloaded
    (:meth:`_Solver.follow`). A tensile solve from ``initial`` that detaches or stalls follows the load down
    from ``initial`` when that is a converged result at a higher load. ``max_iter`` counts iterations;
    ``memory``: L-BFGS pairs."""
    if not periodic:
        raise ValueError(f"interaction {law.name!r} runs on periodic surfaces only (periodic=True); free "
                         "boundaries are not implemented for it yet (docs/gfmd.md, 'Hard wall with adhesion')")
    if grid is None:
        grid = Grid(heights.shape, length, backend, threads, _is_cupy(heights))
    xp = grid.xp
    h = grid.asarray(heights)
    if not grid.all_finite(h):
        raise ValueError("heights contain NaN or inf")
    g_init = start_z = None
    if isinstance(initial, Start):  # coarse-to-fine start (gfmd._coarse.Start): the body surface's spectrum z~
        start_z, initial = initial.take(), None
    if initial is not None:
        g_init = initial.gap if isinstance(initial, GFMDResult) else initial
        g_init = xp.asarray(g_init, dtype=xp.float64)
        ok = tuple(g_init.shape) == tuple(grid.real_shape) and bool(xp.all(xp.isfinite(g_init)))
        if not grid.agree(ok):
            raise ValueError(f"initial must be a GFMDResult or a finite gap field of shape {grid.real_shape}")
    sv = _Solver(grid, law, h, e_star, max_iter, memory)
    step_tol = max(tol, _STEP_TOL)
    if start_z is not None:  # the gap g = z - h of the prolonged body surface (clipped at 0 by the solver)
        sv.st.ops.inv(start_z, sv.st.g)
        del start_z
        sv.st.g -= h
        st, status = sv.at(sigma0, None, tol)
    elif g_init is None:
        hmax = grid.amax(h)
        xp.subtract(hmax, h, out=sv.st.g)  # flat body touching the highest summit
        if sigma0 < 0:
            st, status = sv.at(0.0, None, step_tol)
            if status == "converged":
                st2, status = sv.follow(0.0, st.g, sigma0, tol)
                st = st2 if st2 is not None else st
        else:
            st, status = sv.at(sigma0, None, tol)
    else:
        st, status = sv.at(sigma0, g_init, tol)
        s_init = float(getattr(initial, "sigma0", math.nan))
        if (status in ("detached", "stalled") and isinstance(initial, GFMDResult) and initial.converged
                and sigma0 < 0 and s_init > sigma0 and sv.nit < max_iter):
            log.info("%s: %s at sigma0=%g from the initial state; following the load from %g", law.name, status,
                     sigma0, s_init)
            st2, status = sv.follow(s_init, xp.maximum(g_init, 0.0), sigma0, tol)
            st = st2 if st2 is not None else st
    del g_init
    return _result(sv, status, sigma0, e_star, length, tol, host, t_start)


def _result(sv: _Solver, status: str, sigma0: float, e_star: float, length: Any, tol: float, host: Any,
            t_start: float) -> GFMDResult:
    """The result of the state's gap: fields and convergence recomputed from it (issue 9)."""
    grid, law, st = sv.grid, sv.law, sv.st
    xp, ops = grid.xp, st.ops
    p_ref = law.pressure_scale(sigma0)
    nfev = st.nfev
    with np.errstate(all="ignore"):
        st.sigma0 = sigma0
        st.evaluate()  # g clipped at 0, U and G of the returned gap
        s_pg, _, _ = st.stats(sv.compliance)
        residual = math.sqrt(max(s_pg / ops.n, 0.0)) / p_ref
        # pressure on the body (into d): the multiplier G where g = 0 (clipped at 0: its negative part is in the
        # residual), the adhesive tension -V'(g) everywhere
        p, g = st.d, st.g
        sp = se = sg = 0.0
        nc = 0
        for ch in ops.chunks(g.shape):
            contact = g[ch] <= 0
            xp.multiply(xp.maximum(st.G[ch], 0.0), contact, out=p[ch])
            p[ch] -= law.force(g[ch], xp)
            sp += p[ch].sum()
            se += law.energy(g[ch], xp).sum()
            sg += g[ch].sum()
            nc += xp.count_nonzero(contact)
        fin = sum(int(xp.count_nonzero(~xp.isfinite(a[ch]))) for a in (g, p) for ch in ops.chunks(g.shape))
        el = ops.lsdot(st.U, st.U, st.k)
        sp, se, sg, nc, el, fin = ops.total(sp, se, sg, nc, el, fin)
        load_error = abs(sp / ops.n - sigma0) / p_ref
        u = ops.inv(st.U, st.t)  # u~(0) = 0: <u> = 0
        st.S = st.G = st.free = None
        elastic = 0.5 * el
        e_int = se / ops.n
        area = round(nc) / ops.n
        g0 = sg / ops.n
    fields_ok = math.isfinite(residual) and fin == 0
    status, _ = final_status(status, fields_ok, residual, load_error, tol)
    converged = status == "converged"
    dx = min(grid.lx / grid.shape[0], grid.ly / grid.shape[1])
    log.debug("%s: %s after %d iterations, residual %.3g", law.name, status, sv.nit, residual)
    gap, p, u = fields_to_host(grid, host, g, p, u)
    grid.synchronize()
    return GFMDResult(
        mean_gap=g0, gap=gap, pressure=p, displacement=u, iterations=sv.nit, converged=converged,
        residual=residual, load_error=load_error, wall_time=time.perf_counter() - t_start, method="plbfgs",
        backend=grid.backend, status=status, sigma0=sigma0, rho=law.rho, e_star=e_star, length=length, tol=tol,
        history=sv.history, interaction=law.name, params=law.params(), contact_area=area, elastic_energy=elastic,
        contact_criterion=law.contact_criterion,
        diagnostics={"pressure_scale": p_ref, "interaction_energy": e_int, "evaluations": nfev,
                     "mu_rho": law.mu_rho(dx, e_star), "lbfgs_pairs": st.memory, **sv.info},
    )
