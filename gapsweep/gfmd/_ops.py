"""Array operations of the GFMD solver (docs/model.md M3): the backend-neutral :class:`_Ops` (numpy or cupy
namespace) and its fused numba CPU variant :class:`_NumbaOps`."""

from __future__ import annotations

from typing import Any

import numpy as np

from gapsweep.core.vec import rdot


def remember_pair(s_hist: list, y_hist: list, r_hist: list, s: Any, y: Any, sy: float, memory: int) -> None:
    """The L-BFGS memory (Nocedal & Wright, Alg. 7.4; docs/gfmd.md "Methods"): keep the step ``s`` and gradient
    change ``y`` with ``1/(s.y)`` when the curvature ``s.y > 0`` (else the pair would spoil the inverse-Hessian
    estimate), at most ``memory`` pairs, the oldest dropped."""
    if sy > 0:
        s_hist.append(s)
        y_hist.append(y)
        r_hist.append(1.0 / sy)
        if len(s_hist) > memory:
            for lst in (s_hist, y_hist, r_hist):
                lst.pop(0)


# ------------------------------------------------------------------------------------------------ kernels
class _Ops:
    """Reductions and fused updates, written once for any array namespace ``xp`` (numpy or cupy).

    Half spectra hold normalised coefficients ``u~`` (M2); ``dot`` is the grid mean ``<A B>`` by Parseval."""

    def __init__(self, xp: Any, n: int) -> None:
        self.xp = xp
        self.n = n
        self.even = n % 2 == 0

    def dot(self, a, b) -> float:
        """``<A B>`` for half spectra: columns other than ky = 0 (and ky = n/2 for even n) stand for
        themselves and their conjugates, hence weight 2."""
        s = 2.0 * rdot(a, b) - rdot(a[:, 0], b[:, 0])
        if self.even:
            s = s - rdot(a[:, -1], b[:, -1])
        return float(s)

    def trial(self, w, d, c: float, out) -> float:
        """``out = w + c d``; returns ``max(out)``."""
        self.xp.multiply(d, c, out=out)
        out += w
        return float(out.max())

    def expstats(self, w, m: float, e, d=None) -> tuple[float, float, float]:
        """``e = exp(w - m)``; returns ``(sum e, sum e d, sum e d^2)`` (zeros without ``d``)."""
        xp = self.xp
        xp.subtract(w, m, out=e)
        xp.exp(e, out=e)
        s = float(e.sum())
        if d is None:
            return s, 0.0, 0.0
        return (s, *self.moments(e, d))

    def moments(self, e, d) -> tuple[float, float]:
        """``(sum e d, sum e d^2)``."""
        ed = e * d
        return float(ed.sum()), rdot(ed, d)

    def grad(self, X, E, c: float, k, G) -> None:
        """``G = k X - c E`` with ``G(q=0) = 0``."""
        self.xp.multiply(k, X, out=G)
        G -= c * E
        G[0, 0] = 0.0

    def grad_step(self, X, D, alpha: float, E, c: float, k, G) -> float:
        """``X += alpha D``, then :meth:`grad`; returns ``<G G>``."""
        if alpha != 0.0:
            self.axpy(X, alpha, D)
        self.grad(X, E, c, k, G)
        return self.dot(G, G)

    def axpy(self, y, a: float, x) -> None:
        """``y += a x``."""
        y += a * x

    def cg_dots(self, G, G_old, minv) -> tuple[float, float]:
        """``(<Z G>, <Z G_old>)`` with ``Z = M^-1 G``."""
        Z = minv * G
        return self.dot(Z, G), (self.dot(Z, G_old) if G_old is not None else 0.0)

    def cg_update(self, G, minv, D, beta: float, k, X) -> tuple[float, float, float]:
        """``D = beta D - M^-1 G``; returns ``(<G D>, <kD X>, <kD D>)``."""
        D *= beta
        D -= minv * G
        kD = k * D
        return self.dot(G, D), self.dot(kD, X), self.dot(kD, D)


_NUMBA: Any = None


def _have_numba() -> bool:
    try:
        import numba  # noqa: F401
    except ImportError:
        return False
    return True


def _numba_kernels() -> Any:
    """Fused single-pass CPU kernels (numba, serial: sweeps run one rank per core). Compiled on first use,
    cached on disk. ``exp`` stays with numpy, whose SIMD exp is ~3x faster than numba's scalar one here."""
    global _NUMBA
    if _NUMBA is not None:
        return _NUMBA
    from gapsweep.core.extras import require

    require("numba", "the fused CPU kernels of GFMD")
    from gapsweep.core.numba_cache import njit

    jit = njit(fastmath=False, nogil=True)

    @jit
    def wsum(nh, even, j):  # pragma: no cover - compiled
        return 1.0 if (j == 0 or (even and j == nh - 1)) else 2.0

    @jit
    def dot(a, b, even):
        n0, nh = a.shape
        s = 0.0
        for i in range(n0):
            for j in range(nh):
                x, y = a[i, j], b[i, j]
                s += wsum(nh, even, j) * (x.real * y.real + x.imag * y.imag)
        return s

    @jit
    def trial(w, d, c, out):
        m = -np.inf
        wf, df, of = w.ravel(), d.ravel(), out.ravel()
        for i in range(wf.size):
            v = wf[i] + c * df[i]
            of[i] = v
            if v > m:
                m = v
        return m

    @jit
    def moments(e, d):
        s1 = 0.0
        s2 = 0.0
        ef, df = e.ravel(), d.ravel()
        for i in range(ef.size):
            t = ef[i] * df[i]
            s1 += t
            s2 += t * df[i]
        return s1, s2

    @jit
    def grad(X, D, alpha, E, c, k, G, even):
        """X += alpha D; G = k X - c E, G[0,0] = 0; returns <G G>."""
        n0, nh = X.shape
        s = 0.0
        for i in range(n0):
            for j in range(nh):
                x = X[i, j] + alpha * D[i, j]
                X[i, j] = x
                g = k[i, j] * x - c * E[i, j]
                if i == 0 and j == 0:
                    g = 0.0
                G[i, j] = g
                s += wsum(nh, even, j) * (g.real * g.real + g.imag * g.imag)
        return s

    @jit
    def cg_dots(G, G_old, minv, even):
        n0, nh = G.shape
        s1 = 0.0
        s2 = 0.0
        for i in range(n0):
            for j in range(nh):
                wz = wsum(nh, even, j) * minv[i, j]
                g, go = G[i, j], G_old[i, j]
                s1 += wz * (g.real * g.real + g.imag * g.imag)
                s2 += wz * (g.real * go.real + g.imag * go.imag)
        return s1, s2

    @jit
    def cg_update(G, minv, D, beta, k, X, even):
        n0, nh = G.shape
        gd = 0.0
        a = 0.0
        b = 0.0
        for i in range(n0):
            for j in range(nh):
                dd = beta * D[i, j] - minv[i, j] * G[i, j]
                D[i, j] = dd
                g, x = G[i, j], X[i, j]
                wk = wsum(nh, even, j)
                gd += wk * (g.real * dd.real + g.imag * dd.imag)
                kk = wk * k[i, j]
                a += kk * (dd.real * x.real + dd.imag * x.imag)
                b += kk * (dd.real * dd.real + dd.imag * dd.imag)
        return gd, a, b

    class K:
        pass

    for f in (dot, trial, moments, grad, cg_dots, cg_update):
        setattr(K, f.__name__, staticmethod(f))
    _NUMBA = K
    return K


class _NumbaOps(_Ops):
    """CPU variant of :class:`_Ops`: the same operations as fused numba loops without temporaries."""

    def __init__(self, xp: Any, n: int) -> None:
        super().__init__(xp, n)
        self.K = _numba_kernels()

    def dot(self, a, b) -> float:
        return float(self.K.dot(a, b, self.even))

    def trial(self, w, d, c: float, out) -> float:
        return float(self.K.trial(w, d, float(c), out))

    def expstats(self, w, m: float, e, d=None) -> tuple[float, float, float]:
        np.subtract(w, m, out=e)
        np.exp(e, out=e)
        if d is None:
            return float(e.sum()), 0.0, 0.0
        s1, s2 = self.K.moments(e, d)
        return float(e.sum()), float(s1), float(s2)

    def moments(self, e, d) -> tuple[float, float]:
        s1, s2 = self.K.moments(e, d)
        return float(s1), float(s2)

    def grad(self, X, E, c: float, k, G) -> None:
        self.K.grad(X, X, 0.0, E, float(c), k, G, self.even)

    def grad_step(self, X, D, alpha: float, E, c: float, k, G) -> float:
        return float(self.K.grad(X, D, float(alpha), E, float(c), k, G, self.even))

    def cg_dots(self, G, G_old, minv) -> tuple[float, float]:
        s1, s2 = self.K.cg_dots(G, G if G_old is None else G_old, minv, self.even)
        return float(s1), (float(s2) if G_old is not None else 0.0)

    def cg_update(self, G, minv, D, beta: float, k, X) -> tuple[float, float, float]:
        gd, a, b = self.K.cg_update(G, minv, D, float(beta), k, X, self.even)
        return float(gd), float(a), float(b)


def _is_cupy(a: Any) -> bool:
    return type(a).__module__.split(".")[0] == "cupy"
