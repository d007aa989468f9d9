"""Array operations of the GFMD solver (docs/model.md M3), written once: :class:`_Ops`, the exponential law's
passes for any array namespace (numpy or cupy), any reducer (:data:`LOCAL` on one process, a sum / max over the
ranks on a rank's slabs: :class:`gapsweep.core.slab.Reducer`) and any explicit Parseval weights
(:class:`Parseval`: the full grid's half spectrum or a rank's columns of it); fused kernels replace named passes
of it: :class:`_NumbaOps` here (the CPU default of one process), ``gfmd._cuda._CupyOps`` (one GPU) and
``gfmd._cuda._SlabCupyOps`` (a rank's slabs on a GPU). ``gfmd.batched._Stack`` runs the same passes over a stack
of problems (a leading batch axis: its local sums, maxes and dots per problem)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from gapsweep.core.vec import rdot


class _Local:
    """The reducer of one process: every scalar is already the global one (the interface of
    :class:`gapsweep.core.slab.Reducer`: ``sum`` of one value returns it, of several a list; ``max``)."""

    @staticmethod
    def sum(*values: float) -> Any:
        return values[0] if len(values) == 1 else list(values)

    @staticmethod
    def max(value: float) -> float:
        return value


LOCAL = _Local()


@dataclass(frozen=True)
class Parseval:
    """Parseval weights of (a part of) a half spectrum (docs/model.md M2): a mode stands for itself and its
    conjugate mirror (weight 2) except on the self-conjugate lines ``ky = 0`` and, for even ``ny``, ``ky = ny/2``
    (weight 1). ``axis``: the axis of ``ky`` in the arrays (1 for the full grid's ``rfft2`` layout ``[kx, ky]``, 0
    for a rank's columns ``[ky, kx]``); ``ones``: the indices along it of the self-conjugate lines held."""

    axis: int
    ones: tuple[int, ...]

    @classmethod
    def half(cls, ny: int) -> Parseval:
        """The full grid's half spectrum ``(nx, ny//2 + 1)``."""
        return cls(1, (0, ny // 2) if ny % 2 == 0 else (0,))

    @classmethod
    def columns(cls, w: Any) -> Parseval:
        """A rank's columns, from their weights ``w`` of shape ``(nc, 1)`` (``SlabFFT.weights``)."""
        w = np.asarray(w.get() if hasattr(w, "get") else w).ravel()
        return cls(0, tuple(int(i) for i in np.flatnonzero(w == 1.0)))

    def vector(self, xp: Any, m: int) -> Any:
        """The weights of the ``m`` lines along ``axis`` as a device vector."""
        w = np.full(m, 2.0)
        w[list(self.ones)] = 1.0
        return xp.asarray(w)

    def dot(self, a: Any, b: Any) -> float:
        """``sum_q w_q Re(conj(a_q) b_q)`` over the arrays held (no reduction over ranks): twice the plain sum
        less the self-conjugate lines."""
        s = 2.0 * rdot(a, b)
        for i in self.ones:
            ix = (i,) if self.axis == 0 else (slice(None), i)
            s = s - rdot(a[ix], b[ix])
        return float(s)

    def stack_dot(self, a: Any, b: Any) -> Any:
        """:meth:`dot` of every problem of a stack ``(B, ...)`` of half spectra (gfmd.batched): ``B`` sums, on
        the arrays' device."""
        s = 2.0 * _re_sum(a, b, (1, 2))
        for i in self.ones:
            ix = (slice(None), i) if self.axis == 0 else (slice(None), slice(None), i)
            s = s - _re_sum(a[ix], b[ix], (1,))
        return s


def _re_sum(a: Any, b: Any, axes: tuple[int, ...]) -> Any:
    return (a.real * b.real + a.imag * b.imag).sum(axis=axes)


# ------------------------------------------------------------------------------------------------ kernels
class _Ops:
    """The exponential law's passes (docs/model.md M3), written once for any array namespace ``xp`` (numpy or
    cupy), reducer ``red`` and Parseval weights ``weights`` (:class:`Parseval`; default: the full ``n x n``
    grid's half spectrum). ``owner``: whether these arrays hold the ``q = 0`` mode (index ``[0, 0]``).

    Half spectra hold normalised coefficients ``u~`` (M2); ``dot`` is the grid mean ``<A B>`` by Parseval.
    Every pass returns global scalars: its local sums go through ``red`` together, one collective per pass on
    slabs. Fused variants override the local halves named ``_l*`` or a whole pass."""

    def __init__(self, xp: Any, n: int, *, red: Any = LOCAL, weights: Parseval | None = None,
                 owner: bool = True) -> None:
        self.xp = xp
        self.n = n
        self.even = n % 2 == 0
        self.red = red
        self.weights = Parseval.half(n) if weights is None else weights
        self.owner = owner

    # -- local halves (the arrays held here, no reduction); the four primitives below are the only places where a
    # sum or max is taken, so a stack of problems (gfmd.batched._Stack: a leading batch axis) overrides just them
    def _lsum(self, a) -> Any:
        return float(a.sum())

    def _lmax(self, a) -> Any:
        return float(a.max())

    def _lrdot(self, a, b) -> Any:
        return rdot(a, b)

    def _ldot(self, a, b) -> Any:
        return self.weights.dot(a, b)

    def _lmoments(self, e, d) -> tuple[Any, Any]:
        ed = e * d
        return self._lsum(ed), self._lrdot(ed, d)

    def _lcg_dots(self, G, G_old, minv) -> tuple[float, float]:
        Z = minv * G
        return self._ldot(Z, G), (self._ldot(Z, G_old) if G_old is not None else 0.0)

    def _ldirection(self, G, minv, D, beta: Any) -> None:
        """``D = beta D - M^-1 G`` in place."""
        D *= beta
        D -= minv * G

    def _lcg_update(self, G, minv, D, beta: float, k, X) -> tuple[float, float, float]:
        self._ldirection(G, minv, D, beta)
        kD = k * D
        return self._ldot(G, D), self._ldot(kD, X), self._ldot(kD, D)

    # -- the passes
    def dot(self, a, b) -> float:
        """``<A B>`` for half spectra (weights: :class:`Parseval`)."""
        return self.red.sum(self._ldot(a, b))

    def trial(self, w, d, c: float, out) -> float:
        """``out = w + c d``; returns ``max(out)``."""
        self.xp.multiply(d, c, out=out)
        out += w
        return self.red.max(self._lmax(out))

    def expstats(self, w, m: float, e, d=None) -> tuple[float, float, float]:
        """``e = exp(w - m)``; returns ``(sum e, sum e d, sum e d^2)`` (zeros without ``d``)."""
        xp = self.xp
        xp.subtract(w, m, out=e)
        xp.exp(e, out=e)
        s = self._lsum(e)
        if d is None:
            return self.red.sum(s), 0.0, 0.0
        return tuple(self.red.sum(s, *self._lmoments(e, d)))

    def moments(self, e, d) -> tuple[float, float]:
        """``(sum e d, sum e d^2)``."""
        return tuple(self.red.sum(*self._lmoments(e, d)))

    def grad(self, X, E, c: float, k, G) -> None:
        """``G = k X - c E`` with ``G(q=0) = 0``."""
        self.xp.multiply(k, X, out=G)
        G -= c * E
        if self.owner:
            G[..., 0, 0] = 0.0  # (a leading batch axis: every problem's)

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
        zg, zc = self.red.sum(*self._lcg_dots(G, G_old, minv))
        return zg, zc

    def cg_update(self, G, minv, D, beta: float, k, X) -> tuple[float, float, float]:
        """``D = beta D - M^-1 G``; returns ``(<G D>, <kD X>, <kD D>)``."""
        return tuple(self.red.sum(*self._lcg_update(G, minv, D, beta, k, X)))


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
