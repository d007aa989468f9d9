"""Array passes of the hard-wall minimiser (gapsweep.gfmd._constrained): :class:`_PKOps` for any array
namespace (numpy, cupy) and the fused numba CPU variant :class:`_PKNumba` (one pass per operation, no
temporaries). The contact set is ``S = {p > 0}`` throughout."""

from __future__ import annotations

from typing import Any

import numpy as np

_NUMBA: Any = None


class _PKOps:
    """Passes written once for an array namespace ``xp``."""

    def __init__(self, xp: Any) -> None:
        self.xp = xp

    def contact_sum(self, u, h, p) -> tuple[int, float]:
        """``(|S|, sum_S (u - h))``."""
        xp = self.xp
        S = p > 0
        return int(xp.count_nonzero(S)), float(xp.sum(xp.where(S, u - h, 0.0)))

    def gap(self, u, h, gbar: float, p, g, gs) -> tuple[float, float]:
        """``g = u - h - gbar``, ``gs = g`` on S else 0; returns ``(sum_S g^2, min over the free surface of g)``
        (``inf`` when everything is in contact)."""
        xp = self.xp
        S = p > 0
        xp.subtract(u, h, out=g)
        g -= gbar
        gs[...] = xp.where(S, g, 0.0)
        free = xp.where(S, xp.inf, g)
        return float(xp.sum(gs * gs)), float(free.min())

    def zstats(self, z, gs, p) -> tuple[float, float]:
        """``(sum_S z, sum gs z)``."""
        xp = self.xp
        return float(xp.sum(xp.where(p > 0, z, 0.0))), float(xp.sum(gs * z))

    def zstats5(self, z, t, gs, p) -> tuple[float, float, float, float, float]:
        """``(sum_S z, sum gs z, sum_S t, sum gs t, sum gs)``."""
        xp = self.xp
        S = p > 0
        return (float(xp.sum(xp.where(S, z, 0.0))), float(xp.sum(gs * z)), float(xp.sum(xp.where(S, t, 0.0))),
                float(xp.sum(gs * t)), float(xp.sum(gs)))

    def direction(self, t, z, zbar: float, c: float, p) -> None:
        """``t = (z - zbar) + c t`` on S, 0 elsewhere."""
        xp = self.xp
        t[...] = xp.where(p > 0, (z - zbar) + c * t, 0.0)

    def rstats(self, r, t, gs, p) -> tuple[float, float, float, float]:
        """``(sum_S r, sum_S r t, sum_S t, sum gs t)``."""
        xp = self.xp
        S = p > 0
        rs = xp.where(S, r, 0.0)
        return (float(xp.sum(rs)), float(xp.sum(rs * t)), float(xp.sum(xp.where(S, t, 0.0))),
                float(xp.sum(gs * t)))

    def update(self, p, t, g, tau: float, tau_g: float) -> tuple[bool, int, float]:
        """``p = max(p - tau t, 0)``, then ``p = -tau_g g`` where ``p = 0`` and ``g < 0`` (overlap re-enters;
        ``tau_g`` a stiffness, pressure per length); returns ``(anything clipped, overlap count, sum p)``."""
        xp = self.xp
        trial = p - tau * t
        clipped = bool(xp.any(trial < 0))
        xp.maximum(trial, 0.0, out=p)
        ov = (p == 0) & (g < 0)
        n_ov = int(xp.count_nonzero(ov))
        if n_ov:
            p[...] = xp.where(ov, -tau_g * g, p)
        return clipped, n_ov, float(p.sum())

    def rescale(self, p, u, r, scale: float, tau: float, follow: bool) -> None:
        """``p *= scale``; with ``follow``: ``u = scale (u - tau r)`` (K is linear)."""
        p *= scale
        if follow:
            u -= tau * r
            u *= scale


def _have_numba() -> bool:
    try:
        import numba  # noqa: F401
    except ImportError:
        return False
    return True


def _kernels() -> Any:
    global _NUMBA
    if _NUMBA is not None:
        return _NUMBA
    from gapsweep.core.numba_cache import njit

    # Branch-free loops (selects instead of jumps, so LLVM vectorises them) and reassociated sums (SIMD partial
    # sums): the results differ from the serial order only at round-off. No 'nnan'/'ninf' flags: the free
    # surface's minimum starts at inf and must stay exact.
    jit = njit(fastmath={"reassoc", "contract", "nsz"}, nogil=True)

    @jit
    def contact_sum(u, h, p):
        n = 0
        s = 0.0
        uf, hf, pf = u.ravel(), h.ravel(), p.ravel()
        for i in range(pf.size):
            on = pf[i] > 0
            n += 1 if on else 0
            s += (uf[i] - hf[i]) if on else 0.0
        return n, s

    @jit
    def gap(u, h, gbar, p, g, gs):
        s = 0.0
        mn = np.inf
        uf, hf, pf, gf, gsf = u.ravel(), h.ravel(), p.ravel(), g.ravel(), gs.ravel()
        for i in range(pf.size):
            v = uf[i] - hf[i] - gbar
            gf[i] = v
            on = pf[i] > 0
            w = v if on else 0.0
            gsf[i] = w
            s += w * w
            mn = min(mn, np.inf if on else v)
        return s, mn

    @jit
    def zstats(z, gs, p):
        s1 = 0.0
        s2 = 0.0
        zf, gsf, pf = z.ravel(), gs.ravel(), p.ravel()
        for i in range(pf.size):
            s1 += zf[i] if pf[i] > 0 else 0.0
            s2 += gsf[i] * zf[i]  # gs = 0 off S
        return s1, s2

    @jit
    def direction(t, z, zbar, c, p):
        tf, zf, pf = t.ravel(), z.ravel(), p.ravel()
        for i in range(pf.size):
            tf[i] = (zf[i] - zbar) + c * tf[i] if pf[i] > 0 else 0.0

    @jit
    def rstats(r, t, gs, p):
        a = 0.0
        b = 0.0
        c = 0.0
        d = 0.0
        rf, tf, gsf, pf = r.ravel(), t.ravel(), gs.ravel(), p.ravel()
        for i in range(pf.size):
            rs = rf[i] if pf[i] > 0 else 0.0
            a += rs
            b += rs * tf[i]  # t = 0 off S
            c += tf[i]
            d += gsf[i] * tf[i]
        return a, b, c, d

    @jit
    def update(p, t, g, tau, tau_g):
        n_clip = 0
        n_ov = 0
        s = 0.0
        pf, tf, gf = p.ravel(), t.ravel(), g.ravel()
        for i in range(pf.size):
            v = pf[i] - tau * tf[i]
            neg = v < 0
            n_clip += 1 if neg else 0
            v = 0.0 if neg else v
            ov = (v == 0.0) and (gf[i] < 0)
            n_ov += 1 if ov else 0
            v = -tau_g * gf[i] if ov else v
            pf[i] = v
            s += v
        return n_clip > 0, n_ov, s

    @jit
    def rescale(p, u, r, scale, tau, follow):
        pf, uf, rf = p.ravel(), u.ravel(), r.ravel()
        if follow:
            for i in range(pf.size):
                pf[i] *= scale
                uf[i] = scale * (uf[i] - tau * rf[i])
        else:
            for i in range(pf.size):
                pf[i] *= scale

    class K:
        pass

    for f in (contact_sum, gap, zstats, direction, rstats, update, rescale):
        setattr(K, f.__name__, staticmethod(f))
    _NUMBA = K
    return K


class _PKNumba(_PKOps):
    """Fused numba passes (serial), same results as :class:`_PKOps` up to summation order."""

    def __init__(self, xp: Any) -> None:
        super().__init__(xp)
        self.K = _kernels()

    def contact_sum(self, u, h, p):
        n, s = self.K.contact_sum(u, h, p)
        return int(n), float(s)

    def gap(self, u, h, gbar, p, g, gs):
        s, mn = self.K.gap(u, h, float(gbar), p, g, gs)
        return float(s), float(mn)

    def zstats(self, z, gs, p):
        a, b = self.K.zstats(z, gs, p)
        return float(a), float(b)

    def zstats5(self, z, t, gs, p):
        a, b, c, d, e = spectral_kernels().zstats5(z, t, gs, p)
        return float(a), float(b), float(c), float(d), float(e)

    def direction(self, t, z, zbar, c, p):
        self.K.direction(t, z, float(zbar), float(c), p)

    def rstats(self, r, t, gs, p):
        a, b, c, d = self.K.rstats(r, t, gs, p)
        return float(a), float(b), float(c), float(d)

    def update(self, p, t, g, tau, tau_g):
        clipped, n_ov, s = self.K.update(p, t, g, float(tau), float(tau_g))
        return bool(clipped), int(n_ov), float(s)

    def rescale(self, p, u, r, scale, tau, follow):
        self.K.rescale(p, u, r, float(scale), float(tau), bool(follow))


_SPECTRAL: Any = None


def spectral_kernels() -> Any:
    """Fused passes of ``_constrained._InFourier`` (numba, serial): ``zstats5`` on the real fields, the rest
    on the half spectra of ``_constrained._SpectralFFTW``."""
    global _SPECTRAL
    if _SPECTRAL is not None:
        return _SPECTRAL
    from gapsweep.core.numba_cache import njit

    jit = njit(fastmath={"reassoc", "contract", "nsz"}, nogil=True)

    @jit
    def zstats5(z, t, gs, p):
        s1 = 0.0
        s2 = 0.0
        s3 = 0.0
        s4 = 0.0
        s5 = 0.0
        zf, tf, gsf, pf = z.ravel(), t.ravel(), gs.ravel(), p.ravel()
        for i in range(pf.size):
            on = pf[i] > 0
            s1 += zf[i] if on else 0.0
            s2 += gsf[i] * zf[i]  # gs = 0 off S
            s3 += tf[i] if on else 0.0
            s4 += gsf[i] * tf[i]
            s5 += gsf[i]
        return s1, s2, s3, s4, s5

    @jit
    def copy_mul(P, src, kmul, cin):  # P = src, cin = kmul P
        Pf, sf, kf, cf = P.ravel(), src.ravel(), kmul.ravel(), cin.ravel()
        for i in range(Pf.size):
            v = sf[i]
            Pf[i] = v
            cf[i] = kf[i] * v

    @jit
    def copy_energy(T, src, kw):  # T = src; returns sum kw |T|^2
        Tf, sf, kf = T.ravel(), src.ravel(), kw.ravel()
        s = 0.0
        for i in range(Tf.size):
            v = sf[i]
            Tf[i] = v
            s += kf[i] * (v.real * v.real + v.imag * v.imag)
        return s

    @jit
    def step_mul(P, T, tau, scale, kmul, cin):  # P = scale (P - tau T), cin = kmul P
        Pf, Tf, kf, cf = P.ravel(), T.ravel(), kmul.ravel(), cin.ravel()
        for i in range(Pf.size):
            v = scale * (Pf[i] - tau * Tf[i])
            Pf[i] = v
            cf[i] = kf[i] * v

    class K:
        pass

    for f in (zstats5, copy_mul, copy_energy, step_mul):
        setattr(K, f.__name__, staticmethod(f))
    _SPECTRAL = K
    return K


def make_ops(xp: Any) -> _PKOps:
    """Numba passes on the CPU when numba is installed (unless ``GAPSWEEP_GENERIC_KERNELS=1``), else generic."""
    import os

    if xp is np and _have_numba() and os.environ.get("GAPSWEEP_GENERIC_KERNELS") != "1":
        return _PKNumba(xp)
    if getattr(xp, "__name__", "") == "cupy" and os.environ.get("GAPSWEEP_GENERIC_KERNELS") != "1":
        from gapsweep.gfmd._cuda import _PKCupy  # fused CUDA passes (issue 22, item 2)

        return _PKCupy(xp)
    return _PKOps(xp)
