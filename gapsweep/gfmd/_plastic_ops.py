"""Fused numba passes of the capped hard wall's iteration (gapsweep.gfmd._plastic, CPU): each pass one loop over
the grid, no temporaries. Arrays are C-contiguous float64 (``F`` uint8); the generic array code in _plastic is
the reference they are tested against (tests/test_plastic.py)."""

from __future__ import annotations

from typing import Any

_K: Any = None


def kernels() -> Any:
    global _K
    if _K is not None:
        return _K
    import types

    from gapsweep.core.numba_cache import njit

    jit = njit(fastmath={"reassoc", "contract", "nsz"}, nogil=True)

    @jit
    def kkt1(u, h, p, H):
        """``(|S|, sum_S (u - h), max_{p=0} (h - u), min_{p=H} (h - u))``, S = {0 < p < H}."""
        uf, hf, pf = u.ravel(), h.ravel(), p.ravel()
        n_s = 0
        sd = 0.0
        lower = -1e308
        upper = 1e308
        for i in range(pf.size):
            d = uf[i] - hf[i]
            pi = pf[i]
            if pi <= 0.0:
                if -d > lower:
                    lower = -d
            elif pi >= H:
                if -d < upper:
                    upper = -d
            else:
                n_s += 1
                sd += d
        return n_s, sd, lower, upper

    @jit
    def kkt2(u, h, p, H, g0, gs, F, F_old):
        """``g = g0 + u - h``; the free set ``F`` (S and the violators) into ``F``, ``gs = g`` on F else 0;
        returns ``(sum_S g^2, overlap, lift, |F|, F == F_old)``."""
        uf, hf, pf, gf, ff, fo = u.ravel(), h.ravel(), p.ravel(), gs.ravel(), F.ravel(), F_old.ravel()
        s2 = 0.0
        overlap = 0.0
        lift = 0.0
        n_f = 0
        same = True
        for i in range(pf.size):
            g = g0 + uf[i] - hf[i]
            pi = pf[i]
            f = 0
            if pi <= 0.0:
                if g < 0.0:
                    f = 1
                    if -g > overlap:
                        overlap = -g
            elif pi >= H:
                if g > 0.0:
                    f = 1
                    if g > lift:
                        lift = g
            else:
                f = 1
                s2 += g * g
            if f != fo[i]:
                same = False
            ff[i] = f
            gf[i] = g if f else 0.0
            n_f += f
        return s2, overlap, lift, n_f, same

    @jit
    def dot(a, b):
        af, bf = a.ravel(), b.ravel()
        s = 0.0
        for i in range(af.size):
            s += af[i] * bf[i]
        return s

    @jit
    def direction(t, z, F, c):
        """``t = z + c t`` on F, 0 elsewhere; returns ``sum t``."""
        tf, zf, ff = t.ravel(), z.ravel(), F.ravel()
        s = 0.0
        for i in range(tf.size):
            if ff[i]:
                v = zf[i] + c * tf[i]
                tf[i] = v
                s += v
            else:
                tf[i] = 0.0
        return s

    @jit
    def centre(t, F, mean, gs):
        """``t -= mean`` on F; returns ``sum gs t``."""
        tf, ff, gf = t.ravel(), F.ravel(), gs.ravel()
        s = 0.0
        for i in range(tf.size):
            if ff[i]:
                tf[i] -= mean
                s += gf[i] * tf[i]
        return s

    @jit
    def step(p, t, tau, H):
        """``trial = p - tau t`` into ``p``; returns whether any value left ``[0, H]`` (not clipped here)."""
        pf, tf = p.ravel(), t.ravel()
        out = False
        for i in range(pf.size):
            v = pf[i] - tau * tf[i]
            pf[i] = v
            if v < 0.0 or v > H:
                out = True
        return out

    @jit
    def follow(u, r, tau):
        uf, rf = u.ravel(), r.ravel()
        for i in range(uf.size):
            uf[i] -= tau * rf[i]

    @jit
    def proj_total(trial, F, H, lam, out):
        """``out = clip(trial - lam, 0, H)`` on F (else trial); returns ``(sum out, #(0 < out < H) on F)``."""
        tf, ff, of = trial.ravel(), F.ravel(), out.ravel()
        s = 0.0
        n = 0
        for i in range(tf.size):
            v = tf[i]
            if ff[i]:
                v -= lam
                if v <= 0.0:
                    v = 0.0
                elif v >= H:
                    v = H
                else:
                    n += 1
            of[i] = v
            s += v
        return s, n

    _K = types.SimpleNamespace(kkt1=kkt1, kkt2=kkt2, dot=dot, direction=direction, centre=centre, step=step,
                               follow=follow, proj_total=proj_total)
    return _K
