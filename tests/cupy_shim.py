"""A numpy stand-in for the few cupy calls of the GPU branches that tests/test_gpu_shim.py drives on the CPU: the
free-boundary minimiser (gfmd._free with gfmd._cuda._FreeCupyOps and _PadFFT), the hard wall's cuFFT backend
(gapsweep.core.fft._CupyBackend.convolve), the passes of a rank's slabs (gfmd._cuda._SlabCupyOps; its cupy
ElementwiseKernel / ReductionKernel by name, tests/test_gfmd_ops.py), the exponential law's fused passes on one GPU
(gfmd._cuda._CupyOps, the chained CG included) and the batched stack's (gfmd.batched._FusedStack, bt_*). Not a GPU
emulator: arrays are numpy arrays of a subclass whose module reads "cupy" (so ``gfmd._ops._is_cupy`` takes them for
cupy's); the CUDA kernels that code launches are replaced by numpy versions of their documented results, and each
launch is checked against the parameter list of the kernel in gapsweep/gfmd/kernels.cu (a wrong argument count would
be a launch failure on the GPU). Kernel launches and host synchronisations are counted (``COUNTS``)."""

from __future__ import annotations

import collections
import re
import sys
import types
from pathlib import Path
from typing import Any

import numpy as np

import gapsweep.gfmd

COUNTS: collections.Counter = collections.Counter()
_SRC = Path(gapsweep.gfmd.__file__).with_name("kernels.cu").read_text(encoding="utf-8")


def _params(name: str) -> int:
    """Number of parameters of kernel ``name`` in kernels.cu."""
    m = re.search(r"\b" + name + r"\s*\(([^)]*)\)", _SRC, re.S)
    assert m, name
    return len([p for p in m.group(1).split(",") if p.strip()])


class ndarray(np.ndarray):
    def get(self, stream: Any = None, out: Any = None, blocking: bool = True) -> np.ndarray:
        COUNTS["sync"] += 1
        a = np.array(self.view(np.ndarray))
        if out is not None:
            out[...] = a
            return out
        return a


ndarray.__module__ = "cupy"


def _wrap(r: Any) -> Any:
    if isinstance(r, np.ndarray) and not isinstance(r, ndarray):
        return r.view(ndarray)
    if isinstance(r, tuple):
        return tuple(_wrap(x) for x in r)
    return r


def _fn(f: Any) -> Any:
    def g(*a: Any, **k: Any) -> Any:
        return _wrap(f(*a, **k))
    return g


def _kernel(name: str) -> Any:
    """numpy version of kernels.cu's ``name`` (only those the shimmed code paths launch)."""
    nparam = _params(name)

    def launch(grid: tuple, block: tuple, args: tuple) -> None:
        assert len(args) == nparam, (name, len(args), nparam)
        assert grid[0] >= 1 and block == (256,)
        COUNTS[name] += 1
        out = args[-1]
        if name == "gs_dot":
            a, b, diag, flags, nh, even = args[:6]
            nh = int(nh)
            j = np.arange(a.size) % nh
            w = np.where((j == 0) | (bool(even) & (j == nh - 1)), 1.0, 2.0)
            if int(flags) & 1:
                w = w * diag.ravel()
            av, bv = a.ravel(), b.ravel()
            out[0] = np.sum(w * (av.real * bv.real + av.imag * bv.imag))
        elif name == "gs_sumfinite":
            a = args[0].ravel()
            ok = np.isfinite(a)
            out[0], out[1] = np.sum(a[ok]), np.count_nonzero(~ok)
        elif name == "gs_moments":
            e, d = args[0].ravel(), args[1].ravel()
            out[0], out[1] = np.sum(e * d), np.sum(e * d * d)
        elif name in _BATCH:
            _batch_launch(name, int(grid[1]), args)
        elif name in _ONE:
            _ONE[name](args)
        else:
            raise AssertionError(f"kernel {name} not emulated")
    return launch


def _pweights(nh: int, even: Any, N: int) -> np.ndarray:
    """Parseval weights of a half spectrum's ``N`` modes, row-major with ``nh`` columns (kernels.cu PWEIGHT)."""
    j = np.arange(N) % nh
    return np.where((j == 0) | (bool(even) & (j == nh - 1)), 1.0, 2.0)


def _re(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return a.real * b.real + a.imag * b.imag


def _bt_point(B: int, N: int, args: tuple) -> np.ndarray:
    W, d, c, shift, active, Wt, e = (np.asarray(a).reshape(B, -1) if np.ndim(a) > 1 else np.asarray(a)
                                      for a in args[:7])
    v = np.zeros((B, 4))
    v[:, 0] = -np.inf
    for b in np.flatnonzero(active):
        Wt[b] = W[b] + c[b] * d[b]
        e[b] = np.exp(Wt[b] - shift[b])
        v[b] = Wt[b].max(), e[b].sum(), (e[b] * d[b]).sum(), (e[b] * d[b] * d[b]).sum()
    return v


def _bt_cgupdate(B: int, N: int, args: tuple) -> np.ndarray:
    D, beta, minv, G, k, X, active, nh, even = args[:9]
    D, minv, G, X = (np.asarray(a).reshape(B, N) for a in (D, minv, G, X))
    w = _pweights(int(nh), even, N)
    kw = w * np.asarray(k).ravel()
    v = np.zeros((B, 3))
    for b in np.flatnonzero(np.asarray(active)):
        D[b] = beta[b] * D[b] - minv[b] * G[b]
        v[b] = (w * _re(G[b], D[b])).sum(), (kw * _re(D[b], X[b])).sum(), (kw * _re(D[b], D[b])).sum()
    return v


def _bt_accept(B: int, N: int, args: tuple) -> np.ndarray:
    X, D, alpha, E, c, k, G, Gold, active, nh, even = args[:11]
    X, D, E, G, Gold = (np.asarray(a).reshape(B, N) for a in (X, D, E, G, Gold))
    w = _pweights(int(nh), even, N)
    v = np.zeros((B, 1))
    for b in np.flatnonzero(np.asarray(active)):
        Gold[b] = G[b]
        X[b] += alpha[b] * D[b]
        G[b] = np.asarray(k).ravel() * X[b] - c[b] * E[b]
        G[b, 0] = 0.0
        v[b, 0] = (w * _re(G[b], G[b])).sum()
    return v


def _bt_moments(B: int, N: int, args: tuple) -> np.ndarray:
    e, d = (np.asarray(a).reshape(B, N) for a in args[:2])
    return np.stack([(e * d).sum(axis=1), (e * d * d).sum(axis=1)], axis=1)


def _bt_cgdots(B: int, N: int, args: tuple) -> np.ndarray:
    minv, G, Gold = (np.asarray(a).reshape(B, N) for a in args[:3])
    z = _pweights(int(args[3]), args[4], N) * minv
    return np.stack([(z * _re(G, G)).sum(axis=1), (z * _re(G, Gold)).sum(axis=1)], axis=1)


# the batch kernels of gfmd.batched._FusedStack: problem b's K results, as the partials of one block (the others
# hold the identities: 0, or -inf in bt_point's max slot)
_BATCH = {"bt_point": _bt_point, "bt_moments": _bt_moments, "bt_cgdots": _bt_cgdots,
          "bt_cgupdate": _bt_cgupdate, "bt_accept": _bt_accept}


def _batch_launch(name: str, B: int, args: tuple) -> None:
    v = _BATCH[name](B, int(args[-2]), args)
    part = np.asarray(args[-1]).reshape(B, v.shape[1], -1)
    part[...] = 0.0
    if name == "bt_point":
        part[:, 0, :] = -np.inf
    part[:, :, 0] = v


# the passes of gfmd._cuda._CupyOps (one GPU: the exponential law's solve, the chained CG included); arrays flat
def _f(a: Any) -> np.ndarray:
    return np.asarray(a).reshape(-1)


def _half(nh: Any, n: Any, N: Any) -> tuple[np.ndarray, np.ndarray]:
    """(Parseval weights, |q| in grid units) of the ``N`` modes of an ``n x nh`` half spectrum (kernels.cu)."""
    i = np.arange(int(N))
    r, j = i // int(nh), i % int(nh)
    even = int(n) % 2 == 0
    w = np.where((j == 0) | (even & (j == int(nh) - 1)), 1.0, 2.0)
    return w, np.hypot(np.minimum(r, int(n) - r).astype(float), j.astype(float))


def _gs_point(args: tuple, trial0: bool = False) -> None:
    if trial0:
        W, dt, cg, mo, S, sr, rho, Wt, e, shift = args[:10]
        s1, s2 = float(mo[0]) / S, float(mo[1]) / S
        curv = float(cg[2]) + sr * (s2 - s1 * s1)
        alpha = -float(cg[0]) / curv if curv > 0.0 else 1.0
        c, dm, flags = -alpha / rho, dt, 3
    else:
        W, dt, c, dm, Wt, e, shift, flags = args[:8]
    W, dt, dm, Wt, e = (_f(a) for a in (W, dt, dm, Wt, e))
    w = W + float(c) * dt if int(flags) & 1 else W.copy()
    if int(flags) & 1:
        Wt[:] = w
    e[:] = np.exp(w - float(shift))
    out = args[-1]
    out[0], out[1] = w.max(), e.sum()
    if int(flags) & 2:
        out[2], out[3] = (e * dm).sum(), (e * dm * dm).sum()
    if trial0:
        out[4] = alpha


def _gs_max(args: tuple) -> None:
    W, dt, c, flags = args[:4]
    args[-1][0] = (_f(W) + float(c) * _f(dt) if int(flags) & 1 else _f(W)).max()


def _stiff_minv(flags: int, k: Any, minv: Any, n: Any, ka: float, kb: float, sr: float, q: np.ndarray) -> tuple:
    if flags & 4:
        kk = ka * (kb * q)
        mi = 1.0 / (kk + sr)
        mi[0] = 0.0
        return kk, mi
    return _f(k), (None if minv is None else _f(minv))


def _gs_grad(args: tuple) -> None:
    X, D, alpha, E, c, k, G, minv, Gold, flags, n, ka, kb, sr, nh, _even, N = args[:17]
    flags = int(flags)
    X, D, E, G, Gold = (_f(a) for a in (X, D, E, G, Gold))
    w, q = _half(nh, n, N)
    if flags & 1:
        X += float(alpha) * D
    kk, mi = _stiff_minv(flags, k, minv if flags & 2 else None, n, ka, kb, sr, q)
    g = kk * X - float(c) * E
    g[0] = 0.0
    out = args[-1]
    out[0] = (w * _re(g, g)).sum()
    if flags & 2:
        z = w * mi
        out[1], out[2] = (z * _re(g, g)).sum(), (z * _re(g, Gold)).sum()  # Gold read before G is written
    G[:] = g


def _gs_cgdir(args: tuple) -> None:
    G, minv, D, beta, k, X, flags, n, ka, kb, sr, gs, zg_old, nh, _even, N = args[:16]
    flags = int(flags)
    G, D, X = (_f(a) for a in (G, D, X))
    w, q = _half(nh, n, N)
    if flags & 8:
        beta = max(0.0, (float(gs[1]) - float(gs[2])) / float(zg_old))
    kk, mi = _stiff_minv(flags, k, minv, n, ka, kb, sr, q)
    D[:] = float(beta) * D - mi * G
    out = args[-1]
    out[0], out[1], out[2] = (w * _re(G, D)).sum(), (w * kk * _re(D, X)).sum(), (w * kk * _re(D, D)).sum()


def _gs_field(args: tuple) -> None:
    h, hm, u, inv_rho, W = args[:5]
    _f(W)[:] = ((_f(h) - float(hm)) - _f(u)) * float(inv_rho)
    args[-1][0] = _f(W).max()


def _gs_final(args: tuple) -> None:
    W, e, cp, a0, rho, hs, thr = args[:7]
    W, e = _f(W), _f(e)
    e *= float(cp)
    W[:] = float(a0) - float(rho) * W
    out = args[-1]
    out[0], out[1] = e.sum(), np.count_nonzero(W + float(hs) < float(thr))
    out[2] = np.count_nonzero(~(np.isfinite(e) & np.isfinite(W)))


def _gs_linresp(args: tuple) -> None:
    H, s, sr, X, n, ka, kb, nh, N = args
    _, q = _half(nh, n, N)
    x = (_f(H) * float(s)) * (float(sr) / (float(ka) * (float(kb) * q) + float(sr)))
    x[0] = 0.0
    _f(X)[:] = x


def _gs_resid(args: tuple) -> None:
    Ur, Pr, s, n, ka, kb, nh, _even, N = args[:9]
    w, q = _half(nh, n, N)
    kk = float(ka) * (float(kb) * q)
    uu = _f(Ur) * float(s)
    f = kk * uu - _f(Pr) * float(s)
    f[0] = 0.0
    out = args[-1]
    out[0], out[1] = (w * _re(f, f)).sum(), (w * kk * _re(uu, uu)).sum()


_ONE = {"gs_point": _gs_point, "gs_trial0": (lambda a: _gs_point(a, True)), "gs_max": _gs_max, "gs_grad": _gs_grad,
        "gs_cgdir": _gs_cgdir, "gs_field": _gs_field, "gs_final": _gs_final, "gs_linresp": _gs_linresp,
        "gs_resid": _gs_resid}


class RawModule:
    def __init__(self, code: str, options: tuple = ()) -> None:
        assert code == _SRC

    def get_function(self, name: str) -> Any:
        fn = _kernel(name) if name in ("gs_dot", "gs_sumfinite", "gs_moments", *_BATCH, *_ONE) else (lambda *a: None)
        return fn


_ELEMENTWISE = {
    "gapsweep_free_axpy": (lambda a, x, y: np.add(y, a * x, out=y)),
    "gapsweep_free_grad": (lambda k, u, c, f: k * u - c * f),
    "gapsweep_free_trial": (lambda g, a, d: g + a * d),
    # gfmd._cuda._SlabCupyOps (output arrays passed: written in place, as cupy does)
    "gapsweep_slab_grad": (lambda k, X, E, c, G: np.subtract(k * X, c * E, out=G)),
    "gapsweep_slab_axpy": (lambda a, x, y: np.add(y, a * x, out=y)),
    "gapsweep_slab_dir": (lambda beta, minv, G, D: np.subtract(beta * D, minv * G, out=D)),
}

# the map expressions of gfmd._cuda._SlabCupyOps's reductions (summed over ``axis``)
_REDUCTION = {
    "gapsweep_slab_rdot": (lambda a, b: a.real * b.real + a.imag * b.imag),
    "gapsweep_slab_rkdot": (lambda a, b, k: k * (a.real * b.real + a.imag * b.imag)),
    "gapsweep_slab_m1": (lambda e, d: e * d),
    "gapsweep_slab_m2": (lambda e, d: e * d * d),
}


def ReductionKernel(in_params: str, out_params: str, map_expr: str, reduce_expr: str, post_map_expr: str,
                    identity: str, name: str) -> Any:
    n_in = len(in_params.split(","))
    f = _REDUCTION[name]
    assert reduce_expr == "a + b" and identity == "0", name

    def call(*args: Any, axis: Any = None) -> Any:
        assert len(args) == n_in, (name, len(args))
        COUNTS[name] += 1
        return _wrap(np.asarray(f(*(np.asarray(a) for a in args))).sum(axis=axis))
    return call


def ElementwiseKernel(in_params: str, out_params: str, operation: str, name: str) -> Any:
    n_in, n_out = len(in_params.split(",")), len(out_params.split(","))
    f = _ELEMENTWISE[name]

    def call(*args: Any) -> Any:
        assert len(args) in (n_in, n_in + n_out), (name, len(args))
        COUNTS[name] += 1
        return _wrap(f(*args))
    return call


class _Plan:
    def __init__(self, value_type: str, shape: tuple) -> None:
        self.value_type, self.shape = value_type, shape

    def __enter__(self) -> _Plan:  # ``with plan:`` (cupy: the plan the FFT calls inside use); counted
        COUNTS["plan_" + self.value_type] += 1
        return self

    def __exit__(self, *exc: Any) -> None:
        return None

    def fft(self, a: Any, out: Any, direction: int) -> None:
        COUNTS["cufft_" + self.value_type] += 1
        if self.value_type == "R2C":
            assert direction == -1 and a.shape == self.shape and a.flags.c_contiguous and out.flags.c_contiguous
            out[...] = np.fft.rfft2(a)
        else:
            assert direction == 1 and out.shape == self.shape and a.flags.c_contiguous and out.flags.c_contiguous
            out[...] = np.fft.irfft2(a, s=self.shape) * float(np.prod(self.shape))  # unnormalised, as cuFFT


def get_fft_plan(a: Any, shape: tuple | None = None, axes: tuple = (), value_type: str = "C2C") -> _Plan:
    return _Plan(value_type, tuple(shape) if shape is not None else tuple(a.shape))


class _Stream:
    ptr = 0

    def synchronize(self) -> None:
        COUNTS["stream_sync"] += 1


class _Pool:
    def total_bytes(self) -> int:
        return 0

    def free_all_blocks(self) -> None:
        pass


def modules() -> dict[str, types.ModuleType]:
    """``{name: module}`` to put into sys.modules: cupy, cupy.cuda, cupy.cuda.cufft, cupyx, cupyx.scipy(.fft)."""
    cp = types.ModuleType("cupy")
    for k, v in vars(np).items():
        if k.startswith("_") or isinstance(v, types.ModuleType):
            continue
        setattr(cp, k, _fn(v) if callable(v) and not isinstance(v, type) else v)
    cp.ndarray = ndarray
    cp.RawModule = RawModule
    cp.ElementwiseKernel = ElementwiseKernel
    cp.ReductionKernel = ReductionKernel
    cp.get_default_memory_pool = _Pool
    cp.asnumpy = lambda a, *x, **k: np.array(np.asarray(a).view(np.ndarray))
    fft = types.ModuleType("cupy.fft")
    for k in ("rfft2", "irfft2", "rfft", "irfft", "fft", "ifft", "fftfreq", "rfftfreq", "fft2", "ifft2"):
        setattr(fft, k, _fn(getattr(np.fft, k)))
    fft.config = types.SimpleNamespace(get_plan_cache=lambda: types.SimpleNamespace(clear=lambda: None))
    cp.fft = fft
    cuda = types.ModuleType("cupy.cuda")
    cufft = types.ModuleType("cupy.cuda.cufft")
    cufft.CUFFT_FORWARD, cufft.CUFFT_INVERSE = -1, 1
    cuda.cufft = cufft
    cuda.Device = lambda *a: types.SimpleNamespace(attributes={"MultiProcessorCount": 4}, id=0, use=lambda: None)
    cuda.runtime = types.SimpleNamespace(getDeviceCount=lambda: 1, memGetInfo=lambda: (1 << 34, 1 << 35),
                                         setDevice=lambda i: None)
    cuda.get_current_stream = _Stream
    cp.cuda = cuda
    cupyx = types.ModuleType("cupyx")  # no empty_pinned: the code falls back to ndarray.get
    scipy = types.ModuleType("cupyx.scipy")
    sfft = types.ModuleType("cupyx.scipy.fft")
    sfft.get_fft_plan = get_fft_plan
    scipy.fft = sfft
    cupyx.scipy = scipy
    return {"cupy": cp, "cupy.fft": fft, "cupy.cuda": cuda, "cupy.cuda.cufft": cufft, "cupyx": cupyx,
            "cupyx.scipy": scipy, "cupyx.scipy.fft": sfft}


def install(monkeypatch: Any) -> types.ModuleType:
    """Put the shim into sys.modules for one test (monkeypatch undoes it) and return the cupy stand-in."""
    mods = modules()
    for k, v in mods.items():
        monkeypatch.setitem(sys.modules, k, v)
    COUNTS.clear()
    return mods["cupy"]


def install_fresh(monkeypatch: Any, generic_kernels: bool = True) -> types.ModuleType:
    """:func:`install` after emptying gapsweep's FFT plan cache and compiled CUDA kernels (the shim's backends
    never reach other tests); ``generic_kernels``: the hard wall's passes as array expressions
    (``GAPSWEEP_GENERIC_KERNELS=1``; the fused kernels need a real GPU)."""
    from gapsweep.core import fft
    from gapsweep.gfmd import _cuda

    monkeypatch.setattr(fft, "_PLANS", {})
    monkeypatch.setattr(_cuda, "_CUPY_KERNELS", None)
    if generic_kernels:
        monkeypatch.setenv("GAPSWEEP_GENERIC_KERNELS", "1")
    return install(monkeypatch)
