"""GPU kernels of the GFMD solver (docs/model.md M3): :class:`_CupyOps`, one fused CUDA pass per operation (one
GPU), and :class:`_SlabCupyOps`, fused cupy passes of a rank's slabs (gfmd.distributed). The
CUDA C source lives in ``kernels.cu`` next to this module (package data), compiled by NVRTC on first use."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np

from gapsweep.gfmd._ops import Parseval, _Ops

# CUDA source of the GPU kernels. Every kernel is one grid-stride pass over its arrays (a fixed grid of
# _CUDA_BLOCKS_PER_SM blocks per SM) that also reduces its scalars: warp shuffles, one partial per block, then
# the last block to finish sums the partials in block order (deterministic for a fixed grid) into ``out``.
# Slot k of a reduction is a max where bit k of ``mx`` is set (NaN propagates, as numpy's max), else a sum.
_CUDA_SRC = Path(__file__).with_name("kernels.cu").read_text(encoding="utf-8")
_CUDA_BLOCKS_PER_SM = 8
_HALF_KERNELS = ("gs_dot", "gs_grad", "gs_cgdir", "gs_linresp", "gs_resid")
_CUPY_KERNELS: Any = None  # device id -> {kernel name: function}: a module is loaded per device (issue 36)
# A guessed exponent shift is used when the new max lies within this distance of it (e <= e^50: no overflow).
_SHIFT_SLACK = 50.0
# Result slots of the chained CG (offsets into _CupyOps.slots): gradient pass, direction pass, moments, first trial.
SLOT_GRAD, SLOT_CGDIR, SLOT_MOM, SLOT_TRIAL = 0, 4, 8, 12
_NSLOTS = 20


# Work area of one cuFFT double-precision 2-D plan (R2C or C2R) of an n x n grid, in half spectra (16 n (n/2+1)
# bytes), read off n = 4096 and 8192 (benchmarks/bench_gfmd_limit.py; docs/benchmarks_gfmd.md, "GPU at the
# limit"); the estimates below were checked against the measured peak at n = 16384 and 32768. At n <= 2048 cuFFT
# took no work area from cupy's pool, and the estimate is 2 arrays above the measured peak.
_CUFFT_WORK = 1.0
# Grid-sized arrays of one solve besides cuFFT's work areas and the caller's surface, per (interaction, method),
# on the GPU: "real" n x n float64, "half" n x (n/2+1) complex128 spectra, "halfreal" n x (n/2+1) float64. The
# exponential law's are counted from gfmd/_softmax.py::_solve_lean; the L-BFGS and FIRE counts of half spectra
# were read off the pool's high-water mark at n = 4096 and checked at n = 16384 and 2048: docs/benchmarks_gfmd.md,
# "GPU at the limit". The hard wall's (issue 30) are counted from gfmd/_constrained.py (its peak is in the
# iteration, _loop on _RealSpace): the centred heights h; p, t, g, gs, r, z, u; |q|, K^-1 and M = E* q/2 (half a grid
# each); the cuFFT backend's one C2R input buffer (gapsweep.core.fft._CupyBackend.convolve transforms into it,
# multiplies in place and writes C2R straight into the caller's array): 10.5, plus 1 of margin for the pool's
# fragmentation. The result's residual, contact set and elastic energy (<p u>/2) need real fields only, fewer
# than the iteration frees. tests/test_gfmd_memory.py traces the same code on numpy against this count. The plan
# before (K^-1 twice, the Parseval weights, rfft2's and irfft2's output buffers, a temporary spectrum per
# convolution, spectra in the result) measured 18.13 at n = 4096 and 16384.
_ARRAYS = {
    # W, Wt, e, et, cuFFT's real output; X, G, D, cuFFT's complex input copy and output; k, M, M^-1, cached |q|;
    # + 1 half-size real array that whole solves hold beyond these: the pool after a solve exceeded the count by
    # exactly 8 n (n/2 + 1) bytes for "cg" and "pcg" at 16384^2 and 32768^2 on an H200
    # (benchmarks/results/gfmd/mem_gpu_one.json); taken for the other methods too (the same stiffness code)
    ("exponential", "cg"): {"real": 5, "half": 5, "halfreal": 5},
    ("exponential", "lbfgs"): {"real": 5, "half": 20, "halfreal": 5},  # + G_old, 5 (s, y) pairs, temporaries
    ("exponential", "fire"): {"real": 5, "half": 9, "halfreal": 5},  # + G_old, V, F, F/M, temporaries
    # heights centred, p, u, t, g, gs, z, r; |q|, K^-1, M (+ 1 as above); the C2R input buffer; 1 of margin
    ("hard_wall", "pcg"): {"real": 8, "halfreal": 4, "half": 1, "margin": 1.0},
}
_DEFAULT_METHOD = {"exponential": "cg", "hard_wall": "pcg"}


def solve_memory(n: int, *, interaction: str = "exponential", method: str = "auto",
                 heights_on_gpu: bool = True) -> dict[str, Any]:
    """GPU memory (bytes) one solve of an ``n x n`` grid needs with ``gfmd.solve`` on a cupy array (docs/gfmd.md;
    for the sweep's planning: refuse what does not fit, saying how much it needs).

    ``interaction``: "exponential" (``method`` "cg" = "auto", "lbfgs", "fire") or "hard_wall" (``method`` "pcg" =
    "auto", the GPU default; other methods were not measured). ``heights_on_gpu``: count the caller's surface
    (True when it is passed as a cupy array, as the sweep does). Returns ``{"bytes": total, "arrays": total in
    real n x n float64 arrays, "parts": {name: bytes}}``; fields returned to the host need none (the exponential
    law's reuse the solver's buffers). Needs no GPU. Add the CUDA context (~0.5 GB) for the whole process."""
    if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n < 2:
        raise ValueError(f"n must be an integer >= 2, got {n!r}")
    if interaction not in _DEFAULT_METHOD:
        raise ValueError(f"interaction must be one of {', '.join(map(repr, _DEFAULT_METHOD))}, got {interaction!r}")
    method = _DEFAULT_METHOD[interaction] if method == "auto" else method
    if (interaction, method) not in _ARRAYS:
        allowed = ["auto", *(m for law, m in _ARRAYS if law == interaction)]
        raise ValueError(f"method must be one of {', '.join(map(repr, allowed))} for interaction {interaction!r}, "
                         f"got {method!r}")
    n = int(n)
    real, half = 8 * n * n, 16 * n * (n // 2 + 1)
    a = _ARRAYS[(interaction, method)]
    parts = {"solver real fields": int(a.get("real", 0) * real), "solver half spectra": a.get("half", 0) * half,
             "stiffness and preconditioner": a.get("halfreal", 0) * half // 2,
             "margin (memory pool fragmentation)": int(a.get("margin", 0) * real),
             "cuFFT work areas (R2C + C2R plans)": int(2 * _CUFFT_WORK * half),
             "heights": real if heights_on_gpu else 0}
    total = sum(parts.values())
    return {"bytes": total, "arrays": total / real, "parts": parts}


def _cupy_kernels() -> Any:
    """The functions of the compiled module of :data:`_CUDA_SRC` on the current device (NVRTC, on first use; cupy
    caches it on disk). A function belongs to the module loaded on one device: launched from another it fails,
    so they are kept per device."""
    global _CUPY_KERNELS
    import cupy

    if _CUPY_KERNELS is None:
        _CUPY_KERNELS = {}
    dev = int(cupy.cuda.Device().id)
    if dev not in _CUPY_KERNELS:
        mod = cupy.RawModule(code=_CUDA_SRC, options=("--std=c++14",))
        names = ("gs_max", "gs_point", "gs_moments", "gs_dot", "gs_grad", "gs_cgdir",
                 "gs_sumfinite", "gs_field", "gs_final", "gs_linresp", "gs_resid",  # set-up and result passes
                 "gs_trial0",  # chained CG
                 "pk_contact_sum", "pk_gap", "pk_zstats", "pk_direction", "pk_rstats", "pk_update", "pk_rescale",
                 "bt_point", "bt_moments", "bt_cgdots", "bt_cgupdate", "bt_accept")  # bt_*: gfmd/batched.py
        _CUPY_KERNELS[dev] = {name: mod.get_function(name) for name in names}
    return _CUPY_KERNELS[dev]


def _reduction_buffers(ops: Any, xp: Any) -> None:
    """The buffers of the fused reduction kernels on ``ops``: ``_sms`` (the GPU's multiprocessor count), ``part``
    (per-block partial sums, 4 per block), ``count`` (the blocks done: the last one sums the parts), ``res`` (up
    to 4 results) and ``_host`` (pinned host memory they come back to in one copy; None on a cupy without it)."""
    ops._sms = xp.cuda.Device().attributes["MultiProcessorCount"]
    ops.part = xp.empty(4 * _CUDA_BLOCKS_PER_SM * ops._sms, dtype=xp.float64)
    ops.count = xp.zeros(1, dtype=xp.uint32)
    ops.res = xp.zeros(4, dtype=xp.float64)
    try:
        import cupyx

        ops._host = cupyx.empty_pinned((4,), dtype=np.float64)
    except Exception:  # pragma: no cover - old cupy
        ops._host = None


def _fetch(ops: Any, nout: int) -> list[float]:
    """The first ``nout`` results of the last fused reduction (``ops.res``) on the host: one asynchronous copy into
    the pinned buffer and one synchronisation (a plain ``get`` without pinned memory)."""
    if ops._host is None:
        return ops.res.get()[:nout].tolist()
    rt = ops.xp.cuda.runtime
    stream = ops.xp.cuda.get_current_stream()
    rt.memcpyAsync(ops._host.ctypes.data, ops.res.data.ptr, 8 * nout, rt.memcpyDeviceToHost, stream.ptr)
    stream.synchronize()
    return ops._host[:nout].tolist()


class _DeviceMax:
    """``max(w + c d)`` of a pending trial point (:meth:`_CupyOps.trial`): known once :meth:`_CupyOps.expstats`
    ran the point's single fused pass; ``float()`` before that costs a separate max pass."""

    __slots__ = ("c", "d", "ops", "out", "value", "w")

    def __init__(self, ops: _CupyOps, w, d, c: float, out) -> None:
        self.ops, self.w, self.d, self.c, self.out = ops, w, d, c, out
        self.value: float | None = None

    def __float__(self) -> float:
        if self.value is None:
            self.value = self.ops._max(self.w, self.d, self.c)
        return self.value

    def __repr__(self) -> str:
        return f"_DeviceMax({self.value!r})"


class _CupyOps(_Ops):
    """GPU variant of :class:`_Ops`: one fused CUDA pass per operation (elementwise work and its reductions
    together, :data:`_CUDA_SRC`) and one small device-to-host copy of its scalars, the only host
    synchronisation. A trial point costs one pass: ``exp(w - m)`` is shifted by the max of the previous point
    (``m`` moves little along a line search) and the new max comes out of the same pass; only when it lies
    more than ``_SHIFT_SLACK`` away is the pass repeated with the exact shift. The sums returned are those of
    the stored ``e`` (any common factor cancels in ``p = sigma0 e / S``). In CG the gradient pass also returns
    the next iteration's ``<Z G>``, ``<Z G_old>`` (see :meth:`bind_cg`)."""

    def __init__(self, xp: Any, n: int) -> None:
        super().__init__(xp, n)
        self.K = _cupy_kernels()
        self.nh = n // 2 + 1
        sms = xp.cuda.Device().attributes["MultiProcessorCount"]
        # Grid-stride kernels: exactly as many blocks as can be resident at once (no tail wave).
        self.grid = {}
        for name, fn in self.K.items():
            regs = -(-int(getattr(fn, "num_regs", 32) or 32) // 8) * 8
            per_sm = max(1, min(_CUDA_BLOCKS_PER_SM, 65536 // (regs * 256)))
            size = n * (self.nh if name in _HALF_KERNELS else n)
            self.grid[name] = (int(max(1, min(-(-size // 256), per_sm * sms))),)
        self.part = xp.empty(4 * max(g[0] for g in self.grid.values()), dtype=xp.float64)
        self.count = xp.zeros(1, dtype=xp.uint32)
        self.res = xp.zeros(4, dtype=xp.float64)
        self.slots = xp.zeros(_NSLOTS, dtype=xp.float64)  # chained CG: one result slot per queued pass
        # Scalars come back through one pinned buffer: a bare async copy and a stream sync per pass.
        try:
            import cupyx

            self._host = cupyx.empty_pinned((4,), dtype=np.float64)
            self._host_slots = cupyx.empty_pinned((_NSLOTS,), dtype=np.float64)
        except Exception:  # pragma: no cover - old cupy
            self._host = self._host_slots = None
        self._stiff: tuple | None = None  # (k, minv, ka, kb, sr) of the bound problem
        self._nr = np.uint64(n * n)
        self._nhalf = np.uint64(n * self.nh)
        self._geo = (np.uint32(self.nh), np.int32(self.even))
        self._guess: float | None = None  # last max of a trial point: the next shift
        self._cg_minv = None
        self._last_G = None
        self._cg_cache: tuple | None = None

    # -- launch helpers
    def _launch(self, name: str, half: bool, nout: int, *args) -> list[float]:
        """Run kernel ``name`` and return its ``nout`` scalars (the one host synchronisation). Array arguments
        must be C-contiguous: all are allocated here, by _Problem or by the FFT backend."""
        if half:
            args = (*args, *self._geo, self._nhalf, self.part, self.count, self.res)
        else:
            args = (*args, self._nr, self.part, self.count, self.res)
        self.K[name](self.grid[name], (256,), args)
        return _fetch(self, nout)

    # -- set-up and result passes of one solve (gfmd/_softmax.py, GPU branch): one pass each, no temporaries
    def sum_finite(self, a) -> tuple[float, int]:
        """``(sum of the finite entries of a, number of non-finite entries)`` of a real n x n field."""
        r = self._launch("gs_sumfinite", False, 2, self.xp.ascontiguousarray(a, dtype=self.xp.float64))
        return float(r[0]), int(r[1])

    def field(self, h, hm: float, u, inv_rho: float, W) -> float:
        """``W = ((h - hm) - u) inv_rho`` (M3: ``w = (h - u)/rho`` of the centred surface); returns ``max W``."""
        return float(self._launch("gs_field", False, 1, h, np.float64(hm), u, np.float64(inv_rho), W)[0])

    def final(self, W, e, cp: float, a0: float, rho: float, hs: float, thr: float) -> tuple[float, int, int]:
        """Result fields in place: ``p = cp e`` (into ``e``), ``gap = a0 - rho W`` (into ``W``); returns
        ``(sum p, #{gap + hs < thr}, #{non-finite gap or p})``."""
        r = self._launch("gs_final", False, 3, W, e, *(np.float64(x) for x in (cp, a0, rho, hs, thr)))
        return float(r[0]), int(r[1]), int(r[2])

    def linresp(self, H, s: float, sr: float, ka: float, kb: float, X) -> None:
        """``X = (s H) sr / (ka kb |q| + sr)``, 0 at q = 0: the linear response of M4 from ``H = rfft2(h)``."""
        self.K["gs_linresp"](self.grid["gs_linresp"], (256,),
                             (H, np.float64(s), np.float64(sr), X, np.uint32(self.n), np.float64(ka), np.float64(kb),
                              np.uint32(self.nh), self._nhalf))

    def resid(self, Ur, Pr, s: float, ka: float, kb: float) -> tuple[float, float]:
        """``(<F F>, <U k U>)`` with ``U = s Ur``, ``F = k U - s Pr`` (0 at q = 0), ``k = ka kb |q|``."""
        r = self._launch("gs_resid", True, 2, Ur, Pr, np.float64(s), np.uint32(self.n), np.float64(ka),
                         np.float64(kb))
        return float(r[0]), float(r[1])

    def bind_stiffness(self, k, minv, ka: float, kb: float, sr: float) -> None:
        """``k = ka (kb |q|)`` and ``minv = 1/(k + sr)`` (0 at q = 0) of _Problem: the half-spectrum kernels
        compute them per mode instead of reading two arrays when given exactly these ``k``, ``minv``."""
        self._stiff = (k, minv, np.float64(ka), np.float64(kb), np.float64(sr))

    def _stiff_args(self, k, minv) -> tuple:
        """``(flag 4 or 0, n, ka, kb, sr)`` for gs_grad/gs_cgdir."""
        st = self._stiff
        if st is not None and k is st[0] and (minv is None or minv is st[1]):
            return 4, (np.uint32(self.n), st[2], st[3], st[4])
        return 0, (np.uint32(self.n), np.float64(0), np.float64(0), np.float64(0))

    def bind_cg(self, minv) -> None:
        """CG: let every gradient pass also return ``<Z G>`` and ``<Z G_old>`` (``Z = minv G``, ``G_old`` the
        gradient of the previous pass) for the next :meth:`cg_dots`."""
        self._cg_minv = minv

    # -- half spectra
    def dot(self, a, b) -> float:
        return self._wdot(a, b, None)

    def _wdot(self, a, b, diag) -> float:
        a, b = self.xp.ascontiguousarray(a), self.xp.ascontiguousarray(b)
        flags = np.int32(0 if diag is None else 1)
        diag = self.res if diag is None else diag
        return float(self._launch("gs_dot", True, 1, a, b, diag, flags)[0])

    def grad_step(self, X, D, alpha: float, E, c: float, k, G) -> float:
        flags = 1 if alpha != 0.0 else 0
        gold, minv = G, self.res
        if self._cg_minv is not None:
            flags |= 2
            minv = self._cg_minv
            gold = self._last_G if self._last_G is not None and self._last_G is not G else G
        fk, geo = self._stiff_args(k, minv if flags & 2 else None)
        r = self._launch("gs_grad", True, 3, X, D, np.float64(alpha), E, np.float64(c), k, G, minv, gold,
                         np.int32(flags | fk), *geo)
        # gold is G when CG keeps one gradient array (the kernel reads the old value before writing the new one)
        self._cg_cache = (G, gold, float(r[1]), float(r[2])) if flags & 2 else None
        self._last_G = G
        return float(r[0])

    def grad(self, X, E, c: float, k, G) -> None:
        self.grad_step(X, X, 0.0, E, c, k, G)

    def cg_dots(self, G, G_old, minv) -> tuple[float, float]:
        hit = self._cg_cache
        if hit is not None and hit[0] is G and minv is self._cg_minv and (G_old is None or G_old is hit[1]):
            return hit[2], (hit[3] if G_old is not None else 0.0)
        zg = self._wdot(G, G, minv)
        return zg, (self._wdot(G, G_old, minv) if G_old is not None else 0.0)

    def cg_update(self, G, minv, D, beta: float, k, X) -> tuple[float, float, float]:
        fk, geo = self._stiff_args(k, minv)
        r = self._launch("gs_cgdir", True, 3, G, minv, D, np.float64(beta), k, X, np.int32(fk), *geo, self.res,
                         np.float64(1.0))
        return float(r[0]), float(r[1]), float(r[2])

    # -- chained CG (_solvers._ChainedDirections): passes queued without reading their scalars, each into its own
    # slot of one device buffer; one copy and one synchronisation read them all.
    def _enqueue(self, name: str, half: bool, slot: int, *args) -> None:
        out = self.slots[slot:]
        if half:
            args = (*args, *self._geo, self._nhalf, self.part, self.count, out)
        else:
            args = (*args, self._nr, self.part, self.count, out)
        self.K[name](self.grid[name], (256,), args)

    def chain_grad(self, X, D, alpha: float, E, c: float, k, G) -> None:
        """:meth:`grad_step` of CG with one gradient array (``G_old`` is ``G``), queued: slot ``GRAD`` receives
        ``(<G G>, <Z G>, <Z G_old>)``."""
        fk, geo = self._stiff_args(k, self._cg_minv)
        self._enqueue("gs_grad", True, SLOT_GRAD, X, D, np.float64(alpha), E, np.float64(c), k, G, self._cg_minv,
                      G, np.int32(1 | 2 | fk), *geo)

    def chain_cgdir(self, G, minv, D, k, X, zg_old: float | None) -> None:
        """:meth:`cg_update` queued, ``beta = max(0, (zg - zc)/zg_old)`` from slot ``GRAD`` on the device (0 when
        ``zg_old`` is None: a restart); slot ``CGDIR`` receives ``(phi0p, a, b)``."""
        fk, geo = self._stiff_args(k, minv)
        flags = fk | (8 if zg_old is not None else 0)
        self._enqueue("gs_cgdir", True, SLOT_CGDIR, G, minv, D, np.float64(0.0), k, X, np.int32(flags), *geo,
                      self.slots[SLOT_GRAD:], np.float64(1.0 if zg_old is None else zg_old))

    def chain_moments(self, e, d) -> None:
        """:meth:`moments` queued into slot ``MOM``."""
        self._enqueue("gs_moments", False, SLOT_MOM, e, d)

    def chain_trial(self, W, d, S: float, sr: float, rho: float, Wt, e) -> float:
        """The first line-search trial from slots ``CGDIR`` and ``MOM`` (kernels.cu, gs_trial0), queued into slot
        ``TRIAL`` = ``(max, S, s1, s2, alpha)``; returns the exponent shift it used."""
        shift = self._guess if self._guess is not None else 0.0
        self._enqueue("gs_trial0", False, SLOT_TRIAL, W, d, self.slots[SLOT_CGDIR:], self.slots[SLOT_MOM:],
                      np.float64(S), np.float64(sr), np.float64(rho), Wt, e, np.float64(shift))
        return shift

    def chain_read(self) -> np.ndarray:
        """Every slot, after one device-to-host copy and one synchronisation."""
        if self._host_slots is None:
            return self.slots.get()
        rt = self.xp.cuda.runtime
        stream = self.xp.cuda.get_current_stream()
        rt.memcpyAsync(self._host_slots.ctypes.data, self.slots.data.ptr, 8 * self.slots.size,
                       rt.memcpyDeviceToHost, stream.ptr)
        stream.synchronize()
        return self._host_slots.copy()

    def retrial(self, W, d, c: float, Wt, e, shift: float) -> tuple[float, float, float]:
        """The first trial again with the exact shift (its max lay more than ``_SHIFT_SLACK`` from the guess):
        ``(S, s1, s2)``."""
        r = self._point(W, d, c, d, Wt, e, shift, 3)
        return float(r[1]), float(r[2]), float(r[3])

    # -- real space
    def _max(self, w, d, c: float) -> float:
        return float(self._launch("gs_max", False, 1, w, d, np.float64(c), np.int32(1))[0])

    def trial(self, w, d, c: float, out) -> _DeviceMax:
        # Deferred: the point, its exponential, its max and its moments are one pass in expstats.
        return _DeviceMax(self, w, d, float(c), out)

    def _point(self, W, dt, c: float, dm, Wt, e, shift: float, flags: int) -> np.ndarray:
        return self._launch("gs_point", False, 4, W, dt, np.float64(c), dm, Wt, e, np.float64(shift),
                            np.int32(flags))

    def expstats(self, w, m, e, d=None) -> tuple[float, float, float]:
        p = m if isinstance(m, _DeviceMax) and m.ops is self and m.out is w and m.w is not None else None
        if p is None:  # plain e = exp(w - m) with the caller's shift
            W, dt, c, flags, shift = w, w, 0.0, 0, float(m)
        else:
            W, dt, c, flags = p.w, p.d, p.c, 1
            if p.value is None and self._guess is None:
                p.value = self._max(W, dt, c)
            shift = p.value if p.value is not None else self._guess
        if d is not None:
            flags |= 2
        r = self._point(W, dt, c, W if d is None else d, w, e, shift, flags)
        if p is not None:
            mx = float(r[0])
            if p.value is None and math.isfinite(mx) and abs(mx - shift) > _SHIFT_SLACK:
                r = self._point(W, dt, c, W if d is None else d, w, e, mx, flags)  # exact shift
            p.value = mx
            p.w = p.d = None  # release the arrays
            if math.isfinite(mx):
                self._guess = mx
        return float(r[1]), (float(r[2]) if d is not None else 0.0), (float(r[3]) if d is not None else 0.0)

    def moments(self, e, d) -> tuple[float, float]:
        r = self._launch("gs_moments", False, 2, e, d)
        return float(r[0]), float(r[1])


class _SlabCupyOps(_Ops):
    """:class:`_Ops` on one rank's slabs on a GPU (gfmd.distributed; Parseval weights along axis 0, the rank's
    columns ``[ky, kx]``): the local halves of the passes as fused cupy kernels without grid-sized temporaries
    (the weighted Parseval sums reduce each spectrum row on the device, then the few row sums are weighted);
    the reducer, the trial point and the exponentials are :class:`_Ops`'s."""

    def __init__(self, xp: Any, n: int, *, red: Any, weights: Parseval, owner: bool) -> None:
        if weights.axis != 0:
            raise ValueError("_SlabCupyOps: the Parseval weights must run along the rows (a rank's columns)")
        super().__init__(xp, n, red=red, weights=weights, owner=owner)
        self.w1 = None  # the rows' weights on the device, made at the first sum (the row count is the arrays')
        red_k, ew = xp.ReductionKernel, xp.ElementwiseKernel
        self._rdot = red_k("complex128 a, complex128 b", "float64 y", "a.real() * b.real() + a.imag() * b.imag()",
                           "a + b", "y = a", "0", "gapsweep_slab_rdot")
        self._rkdot = red_k("complex128 a, complex128 b, float64 k", "float64 y",
                            "k * (a.real() * b.real() + a.imag() * b.imag())", "a + b", "y = a", "0",
                            "gapsweep_slab_rkdot")
        self._m1 = red_k("float64 e, float64 d", "float64 y", "e * d", "a + b", "y = a", "0", "gapsweep_slab_m1")
        self._m2 = red_k("float64 e, float64 d", "float64 y", "e * d * d", "a + b", "y = a", "0", "gapsweep_slab_m2")
        self._grad = ew("float64 k, complex128 X, complex128 E, float64 c", "complex128 G", "G = k * X - c * E",
                        "gapsweep_slab_grad")
        self._axpy = ew("float64 a, complex128 x", "complex128 y", "y = y + a * x", "gapsweep_slab_axpy")
        self._dir = ew("float64 beta, float64 minv, complex128 G", "complex128 D", "D = beta * D - minv * G",
                       "gapsweep_slab_dir")

    def _rows(self, a) -> Any:
        if self.w1 is None or self.w1.size != a.shape[0]:
            self.w1 = self.weights.vector(self.xp, a.shape[0])
        return self.w1

    def _ldot(self, a, b) -> float:
        return float(self._rows(a) @ self._rdot(a, b, axis=1))

    def _lk(self, a, b, k) -> float:
        return float(self._rows(a) @ self._rkdot(a, b, k, axis=1))

    def _lmoments(self, e, d) -> tuple[float, float]:
        # per-row sums, then the few row sums: cupy reduces a whole array to one scalar in a single block
        # (28 ms at 4096^2 on an H200, 20x a row-wise reduction), so never reduce to a scalar in one kernel
        return float(self._m1(e, d, axis=1).sum()), float(self._m2(e, d, axis=1).sum())

    def grad(self, X, E, c: float, k, G) -> None:
        self._grad(k, X, E, float(c), G)
        if self.owner:
            G[0, 0] = 0.0

    def axpy(self, y, a: float, x) -> None:
        self._axpy(float(a), x, y)

    def _lcg_dots(self, G, G_old, minv) -> tuple[float, float]:
        return self._lk(G, G, minv), (self._lk(G, G_old, minv) if G_old is not None else 0.0)

    def _lcg_update(self, G, minv, D, beta: float, k, X) -> tuple[float, float, float]:
        self._dir(float(beta), minv, G, D)
        return self._ldot(G, D), self._lk(D, X, k), self._lk(D, D, k)


class _PKCupy:
    """GPU passes of the hard-wall minimiser (gapsweep/gfmd/_constrained.py; the interface of
    ``_constrained_ops._PKOps``): one fused CUDA pass per operation (kernels.cu, "hard wall"), rounded as the numba
    passes, instead of a chain of cupy expressions with temporaries and a synchronisation per scalar. Any
    ``nx x ny`` grid. Scalars come back in one small copy per pass; ``direction`` and ``rescale`` return none and
    do not synchronise."""

    def __init__(self, xp: Any) -> None:
        self.xp = xp
        self.K = _cupy_kernels()
        self._n = None
        _reduction_buffers(self, xp)

    def _grid(self, size: int) -> tuple[int]:
        return (int(max(1, min(-(-size // 256), _CUDA_BLOCKS_PER_SM * self._sms))),)

    def _run(self, name: str, nout: int, a, *args) -> list[float]:
        size = a.size
        self.K[name](self._grid(size), (256,), (*args, np.uint64(size), self.part, self.count, self.res))
        return _fetch(self, nout)

    @staticmethod
    def _c(a):
        if not a.flags.c_contiguous:  # every array of the minimiser is allocated C-contiguous
            raise ValueError("hard-wall GPU passes need C-contiguous arrays")
        return a

    def contact_sum(self, u, h, p) -> tuple[int, float]:
        r = self._run("pk_contact_sum", 2, p, self._c(u), self._c(h), self._c(p))
        return int(r[0]), float(r[1])

    def gap(self, u, h, gbar: float, p, g, gs) -> tuple[float, float]:
        r = self._run("pk_gap", 2, p, self._c(u), self._c(h), np.float64(gbar), self._c(p), self._c(g), self._c(gs))
        return float(r[0]), -float(r[1])

    def zstats(self, z, gs, p) -> tuple[float, float]:
        r = self._run("pk_zstats", 2, p, self._c(z), self._c(gs), self._c(p))
        return float(r[0]), float(r[1])

    def direction(self, t, z, zbar: float, c: float, p) -> None:
        self.K["pk_direction"](self._grid(p.size), (256,), (self._c(t), self._c(z), np.float64(zbar), np.float64(c),
                                                             self._c(p), np.uint64(p.size)))

    def rstats(self, r, t, gs, p) -> tuple[float, float, float, float]:
        v = self._run("pk_rstats", 4, p, self._c(r), self._c(t), self._c(gs), self._c(p))
        return float(v[0]), float(v[1]), float(v[2]), float(v[3])

    def update(self, p, t, g, tau: float, tau_g: float) -> tuple[bool, int, float]:
        v = self._run("pk_update", 3, p, self._c(p), self._c(t), self._c(g), np.float64(tau), np.float64(tau_g))
        return v[0] > 0, int(v[1]), float(v[2])

    def rescale(self, p, u, r, scale: float, tau: float, follow: bool) -> None:
        self.K["pk_rescale"](self._grid(p.size), (256,), (self._c(p), self._c(u), self._c(r), np.float64(scale),
                                                           np.float64(tau), np.int32(bool(follow)), np.uint64(p.size)))


class _PadFFT:
    """cuFFT 2-D plans of the doubled ``2nx x 2ny`` grid of a free map (:class:`gapsweep.gfmd._grid.FreeGrid` on
    the GPU): the map is copied into the corner of a zero-padded buffer (the padding is written once) and one
    R2C plan runs over the whole doubled grid; the inverse is one C2R plan whose map block is read out. cupy.fft's
    axis-by-axis transforms with ``n=`` padding copy, pad and transpose their arrays on every call (about a dozen
    passes over the doubled grid per pair, issue 30: the free hard wall 6.2x and the exponential law 41x a
    periodic solve at N = 4096); here a pair is the two plans plus the copies of the map block in and out.
    Buffers: the padded real input and output and the C2R input (C2R destroys it), 3 doubled grids."""

    def __init__(self, xp: Any, shape: tuple[int, int]) -> None:
        from cupy.cuda import cufft
        from cupyx.scipy.fft import get_fft_plan

        nx, ny = (int(v) for v in shape)
        self.xp, self.nx, self.ny = xp, nx, ny
        self.scale = 1.0 / (4 * nx * ny)
        self.rin = xp.zeros((2 * nx, 2 * ny), dtype=xp.float64)  # map block written per call, padding stays 0
        self.cin = xp.empty((2 * nx, ny + 1), dtype=xp.complex128)
        self.rout = xp.empty((2 * nx, 2 * ny), dtype=xp.float64)
        self.fwd_plan = get_fft_plan(self.rin, axes=(0, 1), value_type="R2C")
        self.inv_plan = get_fft_plan(self.cin, shape=(2 * nx, 2 * ny), axes=(0, 1), value_type="C2R")
        self.F, self.I = cufft.CUFFT_FORWARD, cufft.CUFFT_INVERSE

    def fwd(self, a: Any, out: Any = None) -> Any:
        """Unnormalised rfft2 of ``a`` zero-padded to the doubled grid, into ``out`` (or a new array)."""
        self.rin[: self.nx, : self.ny] = a
        if out is None:
            out = self.xp.empty(self.cin.shape, dtype=self.xp.complex128)
        self.fwd_plan.fft(self.rin, out, self.F)
        return out

    def inv_sum(self, b: Any, scale: float = 1.0) -> Any:
        """The map block of ``scale`` times the unnormalised inverse (the plain sum over modes) of the half
        spectrum ``b`` (not modified): a view of the plan's output buffer, valid until the next call."""
        if scale == 1.0:
            self.xp.copyto(self.cin, b)
        else:
            self.xp.multiply(b, scale, out=self.cin)
        self.inv_plan.fft(self.cin, self.rout, self.I)
        return self.rout[: self.nx, : self.ny]

    def convolve(self, a: Any, m: Any, out: Any = None) -> Any:
        """The map block of ``irfft2(rfft2(pad(a)) m)`` (``m`` real on the half spectrum, the inverse's
        normalisation already in it) into ``out`` (or a new array): two plans and three passes."""
        self.rin[: self.nx, : self.ny] = a
        self.fwd_plan.fft(self.rin, self.cin, self.F)
        self.cin *= m
        self.inv_plan.fft(self.cin, self.rout, self.I)
        if out is None:
            return self.xp.ascontiguousarray(self.rout[: self.nx, : self.ny])
        out[...] = self.rout[: self.nx, : self.ny]
        return out


class _FreeCupyOps:
    """Passes of the free-boundary L-BFGS (gapsweep/gfmd/_free.py) on the GPU, the interface of ``_free._HostOps``:
    Parseval dots of the doubled grid's half spectra in one fused pass each (kernels.cu ``gs_dot``, with an
    optional real diagonal), means of the map's fields in one pass (``gs_sumfinite``, ``gs_moments``), in-place
    ``y += a x`` and the gradient ``k U - c F`` as single element-wise kernels. The generic expressions these
    replace (``xp.sum(w * (a.real * b.real + a.imag * b.imag))`` and the like) made four temporaries and five
    passes per dot over the doubled grid, two dozen times per L-BFGS iteration (issue 30: 41 ms per evaluation at
    N = 4096 against 1.2 ms periodic)."""

    def __init__(self, xp: Any, half_shape: tuple[int, int], even: bool) -> None:
        self.xp = xp
        self.K = _cupy_kernels()
        rows, nh = (int(v) for v in half_shape)
        self._nhalf = np.uint64(rows * nh)
        self._geo = (np.uint32(nh), np.int32(bool(even)))
        _reduction_buffers(self, xp)
        self._axpy = xp.ElementwiseKernel("float64 a, complex128 x", "complex128 y", "y = y + a * x",
                                          "gapsweep_free_axpy")
        self._grad = xp.ElementwiseKernel("float64 k, complex128 u, float64 c, complex128 f", "complex128 g",
                                          "g = k * u - c * f", "gapsweep_free_grad")
        self._trial = xp.ElementwiseKernel("float64 g, float64 a, float64 d", "float64 t", "t = g + a * d",
                                           "gapsweep_free_trial")

    def _grid(self, size: int) -> tuple[int]:
        return (int(max(1, min(-(-size // 256), _CUDA_BLOCKS_PER_SM * self._sms))),)

    def _run(self, name: str, size: int, nout: int, *args) -> list[float]:
        self.K[name](self._grid(size), (256,), (*args, self.part, self.count, self.res))
        return _fetch(self, nout)

    def _c(self, a: Any, dtype: Any) -> Any:
        return self.xp.ascontiguousarray(a, dtype=dtype)

    def dot(self, a: Any, b: Any) -> float:
        """``<A B>`` of two half spectra (Parseval weights)."""
        c = self.xp.complex128
        return float(self._run("gs_dot", int(self._nhalf), 1, self._c(a, c), self._c(b, c), self.res, np.int32(0),
                               *self._geo, self._nhalf)[0])

    def kdot(self, a: Any, k: Any, b: Any) -> float:
        """``<A k B>`` with ``k`` real on the half spectrum."""
        c = self.xp.complex128
        return float(self._run("gs_dot", int(self._nhalf), 1, self._c(a, c), self._c(b, c),
                               self._c(k, self.xp.float64), np.int32(1), *self._geo, self._nhalf)[0])

    def axpy(self, y: Any, a: float, x: Any) -> None:
        """``y += a x`` in place."""
        self._axpy(np.float64(a), x, y)

    def grad(self, k: Any, U: Any, c: float, F: Any) -> Any:
        """``k U - c F`` (a new array)."""
        return self._grad(k, U, np.float64(c), F)

    def trial(self, g: Any, a: float, d: Any) -> Any:
        """``g + a d`` (a new array)."""
        return self._trial(g, np.float64(a), d)

    def mean(self, a: Any) -> float:
        """Mean of a real field (NaN if any entry is not finite)."""
        a = self._c(a, self.xp.float64)
        s, bad = self._run("gs_sumfinite", a.size, 2, a, np.uint64(a.size))
        return s / a.size if bad == 0 else math.nan

    def mean_product(self, p: Any, d: Any) -> float:
        """Mean of ``p d`` over a real field."""
        f = self.xp.float64
        p, d = self._c(p, f), self._c(d, f)
        return float(self._run("gs_moments", p.size, 2, p, d, np.uint64(p.size))[0]) / p.size
