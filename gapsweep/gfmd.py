"""Green's function molecular dynamics (GFMD) at fixed mean pressure with exponential repulsion (MODEL.md M3).

An elastic half-space (contact modulus ``E*``) is pressed with mean pressure ``sigma0`` onto a rigid periodic
rough surface ``h`` (``n x n`` grid, side ``length``); the surfaces repel with ``p(g) = (gamma0/rho) exp(-g/rho)``.

Formulation (M3, "Identities"). With ``<u> = 0`` and the mean gap ``g0`` eliminated exactly, the equilibrium
displacement minimises the reduced convex energy per area

    F(u) = (E*/4) sum_q q |u~(q)|^2 + sigma0 rho ln < exp(w) >,      w = (h - u) / rho,

whose gradient (per area, real space) is ``p_el - p + sigma0`` with ``p_el = IFFT[(E* q/2) u~]`` and the softmax
pressure ``p = sigma0 exp(w) / <exp(w)>``. Every exponential is taken after subtracting ``max(w)``, so nothing
over- or underflows whatever ``sigma0``, ``rho`` or ``h_rms/rho`` is (M7), and ``<p> = sigma0`` holds by
construction. The mean gap follows exactly from the log-sum-exp

    g0 = rho [ ln(gamma0 / (rho sigma0)) + max(w) + ln <exp(w - max(w))> ],

the gap is ``g = g0 + u - h`` and ``p = (gamma0/rho) exp(-g/rho)`` is the same field as the softmax.

Convergence (issue 3): ``residual = rms(p_el - (p - <p>)) / sigma0`` and ``load_error = |<p> - sigma0|/sigma0``;
``converged`` iff both are ``<= tol``. The residual is evaluated in Fourier space by Parseval, at no extra FFT.

Methods, one algorithm for every backend (numpy, pyFFTW, cupy); the unknowns are the Fourier modes ``u~(q)``:

- ``"cg"``: Polak-Ribiere+ nonlinear conjugate gradients, preconditioned with the Fourier-diagonal Hessian
  estimate ``M(q) = E* q/2 + sigma0/rho`` (elastic part exact, local part ``p/rho`` replaced by its mean).
- ``"lbfgs"``: limited-memory BFGS with ``M^-1`` as the initial inverse Hessian.
- ``"fire"``: GFMD proper, damped dynamics of the modes with masses ``M(q)`` (all modes then oscillate at about
  the same frequency, Campana & Muser 2006; Zhou, Moseler & Muser 2019) and FIRE damping.

Every method costs one rfft2/irfft2 pair per force evaluation: the descent direction is transformed once and
the line search moves along it in real space (the energy along a line needs no FFT), then the pressure of the
accepted point is transformed back. ``iterations`` counts these force evaluations. The default start is the
linear response ``u~ = h~ / (1 + eta zeta)`` of M4 (one preconditioned Newton step from ``u = 0``).

Kernels: fused numba loops on the CPU (numpy's SIMD exp); on the GPU one CUDA pass per step that does the
elementwise work and its reductions together and returns its scalars in one small device-to-host copy (the only
host synchronisation), see :class:`_CupyOps`; plain array code otherwise; FFTs from gapsweep.fft. On the GPU a
trial point is shifted by the previous point's max instead of its own when the two lie within 50 of each other
(``e <= e^50``, nothing overflows; the common factor cancels in ``p = sigma0 e / S``), else by its own max.
Default method "cg": fewest force evaluations and least time in docs/benchmarks_gfmd.md. User guide:
docs/gfmd.md.
"""

from __future__ import annotations

import functools
import importlib
import math
import os
import time
import warnings
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from gapsweep.fft import FFTBackend, available_backends, get_backend

__all__ = ["METHODS", "GFMDResult", "UnderResolvedWarning", "solve"]

METHODS = ("cg", "lbfgs", "fire")
DEFAULT_METHOD = "cg"  # decided by benchmarks/bench_gfmd.py speed (docs/benchmarks_gfmd.md)
STATUSES = ("converged", "max_iter", "non_finite", "stalled")


class UnderResolvedWarning(UserWarning):
    """The interaction range ``rho`` is shorter than the grid spacing (M7)."""


@dataclass
class GFMDResult:
    """Equilibrium of one GFMD run. Fields are numpy arrays on the host (``n x n``), lengths in units of
    ``length``, pressures in the units of ``sigma0``.

    ``iterations``: force evaluations (= rfft2/irfft2 pairs). ``status``: "converged", "max_iter",
    "non_finite" (a non-finite value appeared; the fields are those of the last finite state) or "stalled"
    (round-off floor: no descent direction left above ``tol``).
    """

    mean_gap: float
    gap: np.ndarray
    pressure: np.ndarray
    displacement: np.ndarray
    iterations: int
    converged: bool
    residual: float
    load_error: float
    wall_time: float
    method: str
    backend: str
    status: str
    sigma0: float = math.nan
    rho: float = math.nan
    gamma0: float = math.nan
    e_star: float = math.nan
    length: float = 1.0
    tol: float = math.nan
    history: list[float] = field(default_factory=list, repr=False)

    @property
    def n(self) -> int:
        return int(self.gap.shape[0])

    def histogram(self, bins: Any = 100, range: tuple[float, float] | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Gap histogram ``(edges, density)`` over the grid (M5); the density integrates to 1 over the bins.
        Binned where the gap lives (GPU for ``host=False`` runs); returned as numpy arrays."""
        if _is_cupy(self.gap):
            import cupy

            if not isinstance(bins, (int, np.integer, str)):
                bins = cupy.asarray(bins)
            density, edges = cupy.histogram(self.gap, bins=bins, range=range, density=True)
            return cupy.asnumpy(edges), cupy.asnumpy(density)
        density, edges = np.histogram(self.gap, bins=bins, range=range, density=True)
        return edges, density


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
        xp = self.xp
        s = 2.0 * xp.vdot(a.ravel(), b.ravel()).real - xp.vdot(a[:, 0], b[:, 0]).real
        if self.even:
            s = s - xp.vdot(a[:, -1], b[:, -1]).real
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
        return float(ed.sum()), float(self.xp.vdot(ed.ravel(), d.ravel()))

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
    import numba

    jit = numba.njit(cache=True, fastmath=False, nogil=True)

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


# CUDA source of the GPU kernels. Every kernel is one grid-stride pass over its arrays (a fixed grid of
# _CUDA_BLOCKS_PER_SM blocks per SM) that also reduces its scalars: warp shuffles, one partial per block, then
# the last block to finish sums the partials in block order (deterministic for a fixed grid) into ``out``.
# Slot k of a reduction is a max where bit k of ``mx`` is set (NaN propagates, as numpy's max), else a sum.
_CUDA_SRC = r"""
#define NT 256
#define FULL 0xffffffffu

__device__ __forceinline__ double neg_inf() { return __longlong_as_double(0xfff0000000000000LL); }
__device__ __forceinline__ double comb(double a, double b, bool mx) {
    return mx ? ((a != a || a > b) ? a : b) : a + b;
}
__device__ __forceinline__ double ident(unsigned mx, int k) { return ((mx >> k) & 1u) ? neg_inf() : 0.0; }
__device__ __forceinline__ double cdot(double2 a, double2 b) { return a.x * b.x + a.y * b.y; }

template <int K>
__device__ void block_reduce(double* v, unsigned mx, double (*sh)[NT / 32]) {
    const int lane = threadIdx.x & 31, wid = threadIdx.x >> 5;
#pragma unroll
    for (int k = 0; k < K; k++) {
        double x = v[k];
        for (int s = 16; s > 0; s >>= 1) x = comb(x, __shfl_down_sync(FULL, x, s), (mx >> k) & 1u);
        v[k] = x;
    }
    __syncthreads();  // sh may still be read by the previous call
    if (lane == 0) {
#pragma unroll
        for (int k = 0; k < K; k++) sh[k][wid] = v[k];
    }
    __syncthreads();
    if (wid == 0) {
#pragma unroll
        for (int k = 0; k < K; k++) {
            double x = lane < NT / 32 ? sh[k][lane] : ident(mx, k);
            for (int s = 16; s > 0; s >>= 1) x = comb(x, __shfl_down_sync(FULL, x, s), (mx >> k) & 1u);
            v[k] = x;
        }
    }
}

template <int K>
__device__ void grid_reduce(double* v, unsigned mx, double* part, unsigned int* count, double* out) {
    __shared__ double sh[K][NT / 32];
    __shared__ bool last;
    block_reduce<K>(v, mx, sh);
    if (threadIdx.x == 0) {
#pragma unroll
        for (int k = 0; k < K; k++) part[k * gridDim.x + blockIdx.x] = v[k];
        __threadfence();
        // atomicInc wraps to 0 on the last block: the counter is ready for the next kernel.
        last = atomicInc(count, gridDim.x - 1) == gridDim.x - 1;
    }
    __syncthreads();
    if (!last) return;
#pragma unroll
    for (int k = 0; k < K; k++) {
        double x = ident(mx, k);
        for (unsigned i = threadIdx.x; i < gridDim.x; i += NT)
            x = comb(x, __ldcg(part + k * gridDim.x + i), (mx >> k) & 1u);
        v[k] = x;
    }
    block_reduce<K>(v, mx, sh);
    if (threadIdx.x == 0) {
#pragma unroll
        for (int k = 0; k < K; k++) out[k] = v[k];
    }
}

#define KERNEL extern "C" __global__ void __launch_bounds__(NT, 8)  // <= 32 registers: 8 blocks per SM
#define KERNEL_H extern "C" __global__ void __launch_bounds__(NT, 6)  // <= 40 registers: no spills

#define GRID_LOOP(i, N) \
    for (unsigned long long i = (unsigned long long)blockIdx.x * NT + threadIdx.x; i < (N); \
         i += (unsigned long long)gridDim.x * NT)

// out[0] = max(wt), wt = W + c dt (flags & 1) or W.
KERNEL gs_max(const double* __restrict__ W, const double* __restrict__ dt, double c,
                                  int flags, unsigned long long N, double* part, unsigned int* count,
                                  double* out) {
    double v[1] = {neg_inf()};
    const bool trial = flags & 1;
    GRID_LOOP(i, N) {
        const double w = trial ? fma(c, dt[i], W[i]) : W[i];
        v[0] = comb(v[0], w, true);
    }
    grid_reduce<1>(v, 1u, part, count, out);
}

// Softmax point: wt = W + c dt (flags & 1: also written to Wt) or W; e = exp(wt - shift);
// out = (max wt, sum e, sum e dm, sum e dm^2) (the moments with flags & 2).
KERNEL gs_point(const double* __restrict__ W, const double* __restrict__ dt, double c,
                                    const double* __restrict__ dm, double* Wt, double* e, double shift,
                                    int flags, unsigned long long N, double* part, unsigned int* count,
                                    double* out) {
    double v[4] = {neg_inf(), 0.0, 0.0, 0.0};
    const bool trial = flags & 1, mom = flags & 2;
    GRID_LOOP(i, N) {
        const double w = trial ? fma(c, dt[i], W[i]) : W[i];
        if (trial) Wt[i] = w;
        const double x = exp(w - shift);
        e[i] = x;
        v[0] = comb(v[0], w, true);
        v[1] += x;
        if (mom) {
            const double y = x * dm[i];
            v[2] += y;
            v[3] += y * dm[i];
        }
    }
    grid_reduce<4>(v, 1u, part, count, out);
}

// out = (sum e d, sum e d^2).
KERNEL gs_moments(const double* __restrict__ e, const double* __restrict__ d,
                                      unsigned long long N, double* part, unsigned int* count, double* out) {
    double v[2] = {0.0, 0.0};
    GRID_LOOP(i, N) {
        const double y = e[i] * d[i];
        v[0] += y;
        v[1] += y * d[i];
    }
    grid_reduce<2>(v, 0u, part, count, out);
}

// Half spectra (n x nh, C order): Parseval weight 1 for column 0 (and nh - 1 for even n), else 2. Row r and
// column j are carried along the grid-stride loop instead of a division per element.
#define HALF_LOOP(i, r, j, N, nh)                                                                     \
    unsigned long long i = (unsigned long long)blockIdx.x * NT + threadIdx.x;                          \
    const unsigned long long stride_ = (unsigned long long)gridDim.x * NT;                             \
    const unsigned jstep_ = (unsigned)(stride_ % (nh)), rstep_ = (unsigned)(stride_ / (nh));           \
    unsigned j = (unsigned)(i % (nh)), r = (unsigned)(i / (nh));                                       \
    for (; i < (N); i += stride_, r += rstep_ + (j + jstep_ >= (nh)),                                  \
                    j = (j + jstep_ >= (nh)) ? j + jstep_ - (nh) : j + jstep_)
#define PWEIGHT(j, nh, even) (((j) == 0 || ((even) && (j) == (nh) - 1)) ? 1.0 : 2.0)

// Stiffness k = ka (kb |q|) of mode (r, j) on an n grid, |q| = hypot(min(r, n - r), j) (as _half_q).
__device__ __forceinline__ double stiff(unsigned r, unsigned j, unsigned n, double ka, double kb) {
    return ka * (kb * hypot((double)min(r, n - r), (double)j));
}

// out[0] = <a b> (flags & 1: <a diag b>).
KERNEL gs_dot(const double2* __restrict__ a, const double2* __restrict__ b,
                                  const double* __restrict__ diag, int flags, unsigned nh, int even,
                                  unsigned long long N, double* part, unsigned int* count, double* out) {
    double v[1] = {0.0};
    HALF_LOOP(i, r, j, N, nh) {
        double wgt = PWEIGHT(j, nh, even);
        if (flags & 1) wgt *= diag[i];
        v[0] += wgt * cdot(a[i], b[i]);
    }
    grid_reduce<1>(v, 0u, part, count, out);
}

// X += alpha D (flags & 1); G = k X - c E, G(q=0) = 0; out = (<G G>, <G minv G>, <G minv Gold>) (the last
// two with flags & 2, the CG dots of the next iteration). flags & 4: k and minv = 1/(k + sr) (0 at q = 0)
// computed from (ka, kb, sr) instead of read.
KERNEL_H gs_grad(double2* X, const double2* __restrict__ D, double alpha, const double2* __restrict__ E, double c,
               const double* __restrict__ k, double2* G, const double* __restrict__ minv, const double2* Gold,
               int flags, unsigned n, double ka, double kb, double sr, unsigned nh, int even,
               unsigned long long N, double* part, unsigned int* count, double* out) {
    double v[3] = {0.0, 0.0, 0.0};
    HALF_LOOP(i, r, j, N, nh) {
        double2 x = X[i];
        if (flags & 1) {
            const double2 d = D[i];
            x.x = fma(alpha, d.x, x.x);
            x.y = fma(alpha, d.y, x.y);
            X[i] = x;
        }
        const double2 ee = E[i];
        const double kk = (flags & 4) ? stiff(r, j, n, ka, kb) : k[i];
        double2 g = make_double2(kk * x.x - c * ee.x, kk * x.y - c * ee.y);
        if (i == 0) g = make_double2(0.0, 0.0);
        G[i] = g;
        const double wgt = PWEIGHT(j, nh, even);
        const double gg = cdot(g, g);
        v[0] += wgt * gg;
        if (flags & 2) {
            const double z = wgt * ((flags & 4) ? (i == 0 ? 0.0 : 1.0 / (kk + sr)) : minv[i]);
            v[1] += z * gg;
            v[2] += z * cdot(g, Gold[i]);
        }
    }
    grid_reduce<3>(v, 0u, part, count, out);
}

// D = beta D - minv G; out = (<G D>, <kD X>, <kD D>). flags & 4: k, minv on the fly as in gs_grad.
KERNEL_H gs_cgdir(const double2* __restrict__ G, const double* __restrict__ minv, double2* D, double beta,
                const double* __restrict__ k, const double2* __restrict__ X, int flags, unsigned n, double ka,
                double kb, double sr, unsigned nh, int even, unsigned long long N, double* part,
                unsigned int* count, double* out) {
    double v[3] = {0.0, 0.0, 0.0};
    HALF_LOOP(i, r, j, N, nh) {
        const double2 g = G[i], d0 = D[i];
        const double kk = (flags & 4) ? stiff(r, j, n, ka, kb) : k[i];
        const double mi = (flags & 4) ? (i == 0 ? 0.0 : 1.0 / (kk + sr)) : minv[i];
        const double2 d = make_double2(beta * d0.x - mi * g.x, beta * d0.y - mi * g.y);
        D[i] = d;
        const double wgt = PWEIGHT(j, nh, even);
        const double kw = wgt * kk;
        v[0] += wgt * cdot(g, d);
        v[1] += kw * cdot(d, X[i]);
        v[2] += kw * cdot(d, d);
    }
    grid_reduce<3>(v, 0u, part, count, out);
}
"""
_CUDA_BLOCKS_PER_SM = 8
_HALF_KERNELS = ("gs_dot", "gs_grad", "gs_cgdir")
_CUPY_KERNELS: Any = None
# A guessed exponent shift is used when the new max lies within this distance of it (e <= e^50: no overflow).
_SHIFT_SLACK = 50.0


def _cupy_kernels() -> Any:
    """The compiled module of :data:`_CUDA_SRC` (NVRTC, on first use; cupy caches it on disk)."""
    global _CUPY_KERNELS
    if _CUPY_KERNELS is None:
        import cupy

        mod = cupy.RawModule(code=_CUDA_SRC, options=("--std=c++14",))
        names = ("gs_max", "gs_point", "gs_moments", "gs_dot", "gs_grad", "gs_cgdir")
        _CUPY_KERNELS = {name: mod.get_function(name) for name in names}
    return _CUPY_KERNELS


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
        # Scalars come back through one pinned buffer: a bare async copy and a stream sync per pass.
        try:
            import cupyx

            self._host = cupyx.empty_pinned((4,), dtype=np.float64)
        except Exception:  # pragma: no cover - old cupy
            self._host = None
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
        if self._host is None:
            return self.res.get()[:nout].tolist()
        rt = self.xp.cuda.runtime
        stream = self.xp.cuda.get_current_stream()
        rt.memcpyAsync(self._host.ctypes.data, self.res.data.ptr, 8 * nout, rt.memcpyDeviceToHost, stream.ptr)
        stream.synchronize()
        return self._host[:nout].tolist()

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
        self._cg_cache = (G, gold if gold is not G else None, float(r[1]), float(r[2])) if flags & 2 else None
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
        r = self._launch("gs_cgdir", True, 3, G, minv, D, np.float64(beta), k, X, np.int32(fk), *geo)
        return float(r[0]), float(r[1]), float(r[2])

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


# ------------------------------------------------------------------------------------------------ helpers
def _positive(name: str, value: Any) -> float:
    if isinstance(value, bool):
        raise TypeError(f"{name} must be a real number, got {value!r}")
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise TypeError(f"{name} must be a real number, got {value!r}") from None
    if not (math.isfinite(v) and v > 0.0):
        raise ValueError(f"{name} must be finite and > 0, got {value!r}")
    return v


def _make_ops(xp: Any, n: int) -> _Ops:
    """Kernels for the namespace: numba on the CPU when installed, fused cupy kernels on the GPU (unless
    ``GAPSWEEP_GENERIC_KERNELS=1``), else the generic array code."""
    if os.environ.get("GAPSWEEP_GENERIC_KERNELS") == "1":
        return _Ops(xp, n)
    if xp is np:
        return _NumbaOps(xp, n) if _have_numba() else _Ops(xp, n)
    if xp.__name__ == "cupy":
        return _CupyOps(xp, n)
    return _Ops(xp, n)


def _is_cupy(a: Any) -> bool:
    return type(a).__module__.split(".")[0] == "cupy"


@functools.lru_cache(maxsize=8)
def _half_q_cached(xp_name: str, n: int, length: float):
    xp = importlib.import_module(xp_name)
    kx = xp.fft.fftfreq(n, d=1.0 / n)
    ky = xp.fft.rfftfreq(n, d=1.0 / n)
    return (2 * np.pi / length) * xp.hypot(kx[:, None], ky[None, :])


def _half_q(xp: Any, n: int, length: float):
    """``|q|`` on the rfft2 half grid (rad/length), built on the device and cached (read-only use)."""
    return _half_q_cached(xp.__name__, n, float(length))


def _transfer_modes(u: np.ndarray, n: int) -> np.ndarray:
    """Normalised half spectrum on an ``n`` grid of the displacement ``u`` given on another grid: modes that
    both grids carry are copied, the rest set to zero (surfaces are resolution independent, M2)."""
    m = u.shape[0]
    full = np.fft.fft2(u) / (m * m)
    kmax = (min(m, n) - 1) // 2  # strictly below both Nyquist frequencies
    ks = np.r_[0 : kmax + 1, -kmax:0]
    out = np.zeros((n, n), dtype=np.complex128)
    out[np.ix_(ks % n, ks % n)] = full[np.ix_(ks % m, ks % m)]
    return out[:, : n // 2 + 1]


# ------------------------------------------------------------------------------------------------ solver
class _Problem:
    """State shared by the methods: surface, operators and the current point ``(X, W, e, G)``.

    ``X = u~`` (half spectrum), ``W = (h - u)/rho`` and ``e = exp(W - m)`` (real space), ``S = sum e``, the
    Fourier gradient ``G = (E* q/2) u~ - p~`` and ``r2 = <G G>`` (M3)."""

    def __init__(self, h, x0, *, sigma0, rho, e_star, length, fft: FFTBackend, ops: _Ops) -> None:
        xp = fft.xp
        n = h.shape[0]
        self.xp, self.n, self.fft, self.ops = xp, n, fft, ops
        self.sigma0, self.rho = sigma0, rho
        self.k = 0.5 * e_star * _half_q(xp, n, length)  # elastic stiffness E* q / 2 per mode
        self.mass = self.k + sigma0 / rho  # Fourier-diagonal Hessian estimate M(q)
        self.minv = 1.0 / self.mass
        self.minv[0, 0] = 0.0  # <u> = 0: the q = 0 mode is not an unknown
        if hasattr(ops, "bind_stiffness"):  # GPU: k and M^-1 recomputed per mode beat reading them
            ops.bind_stiffness(self.k, self.minv, 0.5 * e_star, 2 * np.pi / length, sigma0 / rho)
        self.h = h
        self.X = x0
        self.X[0, 0] = 0.0
        self.W = (h - fft.irfft2(self.X)) * (1.0 / rho)
        self.Wt = xp.empty_like(self.W)
        self.e = xp.empty_like(self.W)
        self.et = xp.empty_like(self.W)
        self.G = xp.empty_like(self.X)
        self.G_old = xp.empty_like(self.X)
        self.nfev = 0
        self.m = ops.trial(self.W, self.W, 0.0, self.Wt)
        self.S, _, _ = ops.expstats(self.Wt, self.m, self.e)
        self.r2 = self._gradient(None, 0.0)

    def _gradient(self, D, alpha: float) -> float:
        """``X += alpha D`` and the Fourier gradient of the accepted point (its ``e``, ``S``): one rfft2.
        ``p~ = rfft2(p)/n^2 = sigma0 rfft2(e)/S``."""
        self.nfev += 1
        E = self.fft.rfft2(self.e)
        return self.ops.grad_step(self.X, self.X if D is None else D, alpha, E, self.sigma0 / self.S, self.k,
                                  self.G)

    def residual(self) -> float:
        """rms force imbalance over sigma0 (issue 3), by Parseval."""
        return math.sqrt(max(self.r2, 0.0)) / self.sigma0

    def line_search(self, D, phi0p: float, a: float, b: float, eta: float, alpha0: float | None = None,
                    max_trials: int = 40):
        """Find ``alpha > 0`` with ``|phi'(alpha)| <= eta |phi'(0)|`` for the convex ``phi(alpha) = F(X + alpha D)``.

        ``phi'(alpha) = a + alpha b - <p_alpha d>`` with ``a = <kD, X>``, ``b = <kD, D>`` (Fourier sums) and the
        softmax pressure at ``W - alpha d / rho``, ``d = irfft2(D)`` (real space): no further FFT. Newton steps
        inside a bracket, secant or bisection when Newton leaves it. Leaves the accepted point in (Wt, et)
        and returns ``(alpha, m, S, ok)``."""
        ops, rho, s0 = self.ops, self.rho, self.sigma0
        d = self.fft.irfft2(D)
        if alpha0 is None:
            s1, s2 = ops.moments(self.e, d)
            curv = b + (s0 / rho) * (s2 / self.S - (s1 / self.S) ** 2)
            alpha = -phi0p / curv if curv > 0 else 1.0
        else:
            alpha = alpha0
        lo, hi, dlo, dhi = 0.0, math.inf, phi0p, math.nan
        for _ in range(max_trials):
            if not math.isfinite(alpha) or alpha <= 0:
                break
            m = ops.trial(self.W, d, -alpha / rho, self.Wt)
            S, s1, s2 = ops.expstats(self.Wt, m, self.et, d)
            if not (math.isfinite(m) and math.isfinite(S) and math.isfinite(s1) and math.isfinite(s2)):
                hi = alpha
                alpha = 0.5 * (lo + alpha)
                continue
            dphi = a + alpha * b - s0 * s1 / S
            if abs(dphi) <= eta * abs(phi0p):
                return alpha, m, S, True
            if dphi < 0:
                lo, dlo = alpha, dphi
            else:
                hi, dhi = alpha, dphi
            if hi - lo <= 1e-13 * hi:
                break
            curv = b + (s0 / rho) * (s2 / S - (s1 / S) ** 2)
            new = alpha - dphi / curv if curv > 0 else math.inf
            if not (lo < new < hi):
                new = lo - dlo * (hi - lo) / (dhi - dlo) if math.isfinite(hi) else 4.0 * alpha
                if not (lo < new < hi):
                    new = 0.5 * (lo + hi)
            alpha = new
        if lo <= 0.0:
            return 0.0, 0.0, 0.0, False
        # Round-off or out of trials: take the last point known to lie downhill of the line minimum.
        m = ops.trial(self.W, d, -lo / rho, self.Wt)
        S, _, _ = ops.expstats(self.Wt, m, self.et)
        return lo, m, S, True

    def accept(self, alpha: float, D, m: float, S: float) -> None:
        """Move to ``X + alpha D`` (its real-space state is in Wt, et); keep the old gradient in G_old."""
        self.W, self.Wt = self.Wt, self.W
        self.e, self.et = self.et, self.e
        self.m, self.S = m, S
        self.G, self.G_old = self.G_old, self.G
        self.r2 = self._gradient(D, alpha)


def _check(pb: _Problem, tol: float, max_iter: int, history: list[float]) -> str | None:
    r = pb.residual()
    history.append(r)
    if not math.isfinite(r):
        return "non_finite"
    if r <= tol:
        return "converged"
    if pb.nfev >= max_iter:
        return "max_iter"
    return None


def _run_cg(pb: _Problem, tol: float, max_iter: int, history: list[float], eta: float = 0.1) -> str:
    """Preconditioned Polak-Ribiere+ nonlinear CG with the Newton line search of _Problem.line_search."""
    ops = pb.ops
    if hasattr(ops, "bind_cg"):  # GPU: the gradient pass also yields the next cg_dots (no extra pass)
        ops.bind_cg(pb.minv)
    D = pb.xp.zeros_like(pb.X)
    zg_old = 0.0
    restart = True
    while (status := _check(pb, tol, max_iter, history)) is None:
        zg, zg_cross = ops.cg_dots(pb.G, None if restart else pb.G_old, pb.minv)
        beta = 0.0 if restart else max(0.0, (zg - zg_cross) / zg_old)
        phi0p, a, b = ops.cg_update(pb.G, pb.minv, D, beta, pb.k, pb.X)
        if phi0p >= 0 and beta > 0:  # not a descent direction (round-off): restart along -M^-1 G
            phi0p, a, b = ops.cg_update(pb.G, pb.minv, D, 0.0, pb.k, pb.X)
        if not phi0p < 0:
            return "stalled" if math.isfinite(phi0p) else "non_finite"
        alpha, m, S, ok = pb.line_search(D, phi0p, a, b, eta)
        if not ok:
            if restart:
                return "stalled"
            restart = True
            continue
        restart = False
        zg_old = zg
        pb.accept(alpha, D, m, S)
    return status


def _clear(*lists: list) -> None:
    for lst in lists:
        lst.clear()


def _run_lbfgs(pb: _Problem, tol: float, max_iter: int, history: list[float], memory: int = 5,
               eta: float = 0.5) -> str:
    """L-BFGS (two-loop recursion, Nocedal & Wright Alg. 7.4) with ``H0 = gamma M^-1``, same line search."""
    ops = pb.ops
    s_hist: list = []
    y_hist: list = []
    r_hist: list[float] = []
    while (status := _check(pb, tol, max_iter, history)) is None:
        q = pb.G.copy()
        alphas = []
        for s, y, rr in zip(reversed(s_hist), reversed(y_hist), reversed(r_hist)):
            al = rr * ops.dot(s, q)
            alphas.append(al)
            ops.axpy(q, -al, y)
        q *= pb.minv
        if y_hist:
            yhy = ops.dot(y_hist[-1], pb.minv * y_hist[-1])
            if yhy > 0:
                q *= 1.0 / (r_hist[-1] * yhy)  # gamma = s.y / y.H0.y
        for s, y, rr, al in zip(s_hist, y_hist, r_hist, reversed(alphas)):
            ops.axpy(q, al - rr * ops.dot(y, q), s)
        D = -q
        phi0p = ops.dot(pb.G, D)
        if not phi0p < 0:
            _clear(s_hist, y_hist, r_hist)
            D = -(pb.minv * pb.G)
            phi0p = ops.dot(pb.G, D)
            if not phi0p < 0:
                return "stalled" if math.isfinite(phi0p) else "non_finite"
        kD = pb.k * D
        alpha, m, S, ok = pb.line_search(D, phi0p, ops.dot(kD, pb.X), ops.dot(kD, D), eta,
                                         alpha0=1.0 if s_hist else None)
        if not ok:
            if not s_hist:
                return "stalled"
            _clear(s_hist, y_hist, r_hist)
            continue
        pb.accept(alpha, D, m, S)
        s = alpha * D
        y = pb.G - pb.G_old
        sy = ops.dot(s, y)
        if sy > 0:
            s_hist.append(s)
            y_hist.append(y)
            r_hist.append(1.0 / sy)
            if len(s_hist) > memory:
                for lst in (s_hist, y_hist, r_hist):
                    lst.pop(0)
    return status


def _run_fire(pb: _Problem, tol: float, max_iter: int, history: list[float], dt0: float = 0.5,
              dt_max: float = 1.0, n_min: int = 5, f_inc: float = 1.1, f_dec: float = 0.5,
              alpha0: float = 0.1, f_alpha: float = 0.99) -> str:
    """Mass-weighted FIRE on the Fourier modes (Bitzek et al. 2006; Zhou, Moseler & Muser 2019): masses
    ``M(q)`` make the linearised dynamics of every mode oscillate at unit frequency, so ``dt ~ 1``.
    Semi-implicit Euler; one force evaluation per step."""
    ops, xp = pb.ops, pb.xp
    V = xp.zeros_like(pb.X)
    dt, alpha, npos = dt0, alpha0, 0
    while (status := _check(pb, tol, max_iter, history)) is None:
        F = -pb.G
        P = ops.dot(F, V)
        if P > 0:
            npos += 1
            if npos > n_min:
                dt = min(dt * f_inc, dt_max)
                alpha *= f_alpha
        else:
            npos = 0
            dt *= f_dec
            alpha = alpha0
            V[...] = 0
        Fm = F * pb.minv
        ops.axpy(V, dt, Fm)
        if P > 0:
            vnorm = math.sqrt(max(ops.dot(V, pb.mass * V), 0.0))
            fnorm = math.sqrt(max(ops.dot(F, Fm), 0.0))
            if fnorm > 0:
                V *= 1.0 - alpha
                ops.axpy(V, alpha * vnorm / fnorm, Fm)
        d = pb.fft.irfft2(V)
        m = ops.trial(pb.W, d, -dt / pb.rho, pb.Wt)
        S, _, _ = ops.expstats(pb.Wt, m, pb.et)
        if not (math.isfinite(S) and math.isfinite(m)):
            return "non_finite"
        pb.accept(dt, V, m, S)
    return status


_RUNNERS = {"cg": _run_cg, "lbfgs": _run_lbfgs, "fire": _run_fire}


def solve(
    heights: Any,
    *,
    sigma0: float,
    gamma0: float,
    rho: float,
    e_star: float = 1.0,
    length: float = 1.0,
    tol: float = 1e-6,
    method: str = "auto",
    backend: str = "auto",
    max_iter: int = 5000,
    initial: GFMDResult | np.ndarray | None = None,
    threads: int | None = None,
    host: bool = True,
) -> GFMDResult:
    """Equilibrium gap of an elastic half-space on the rigid surface ``heights`` at mean pressure ``sigma0``.

    Minimises the reduced energy of M3 (module docstring) until ``residual <= tol`` and
    ``load_error <= tol``. ``heights``: real square ``n x n`` array (numpy, or cupy for the GPU), units of
    ``length``. ``sigma0``, ``gamma0/rho`` and ``e_star`` are pressures in one unit; ``gamma0`` is an energy per
    area, ``rho`` a length. ``method``: "auto" (= "cg"), "cg", "lbfgs" or "fire". ``backend``: "auto" (cupy
    for a cupy array, else pyfftw when installed, else numpy), "numpy", "pyfftw" or "cupy". ``max_iter``: force
    evaluations allowed. ``initial``: an earlier result or a displacement field (any grid size: shared Fourier
    modes are carried over) to start from; default is the linear response of M4. ``threads``: FFTW threads.
    ``host=False`` leaves the fields of a cupy run on the GPU (skips three n x n device-to-host copies).
    Warns (UnderResolvedWarning) when ``rho < length/n`` (M7).
    """
    t_start = time.perf_counter()
    on_gpu = _is_cupy(heights)
    if not on_gpu:
        if isinstance(heights, (str, bytes)) or heights is None:
            raise TypeError(f"heights must be a 2-D real array, got {type(heights).__name__}")
        h_np = np.asarray(heights)
        if not (np.issubdtype(h_np.dtype, np.floating) or np.issubdtype(h_np.dtype, np.integer)):
            raise TypeError(f"heights must be a real array, got dtype {h_np.dtype}")
        shape = h_np.shape
    else:
        shape = heights.shape
    if len(shape) != 2 or shape[0] != shape[1]:
        raise ValueError(f"heights must be a square 2-D array (n x n), got shape {shape}")
    n = int(shape[0])
    if n < 2:
        raise ValueError(f"heights must be at least 2 x 2, got n={n}")
    sigma0 = _positive("sigma0", sigma0)
    gamma0 = _positive("gamma0", gamma0)
    rho = _positive("rho", rho)
    e_star = _positive("e_star", e_star)
    length = _positive("length", length)
    tol = _positive("tol", tol)
    if isinstance(max_iter, bool) or not isinstance(max_iter, (int, np.integer)) or max_iter < 1:
        raise ValueError(f"max_iter must be an integer >= 1, got {max_iter!r}")
    if not isinstance(method, str) or method not in ("auto", *METHODS):
        raise ValueError(f"method must be one of 'auto', 'cg', 'lbfgs', 'fire'; got {method!r}")
    method = DEFAULT_METHOD if method == "auto" else method
    if not isinstance(backend, str) or backend not in ("auto", "numpy", "pyfftw", "cupy"):
        raise ValueError(f"backend must be one of 'auto', 'numpy', 'pyfftw', 'cupy'; got {backend!r}")
    if backend == "auto":
        backend = "cupy" if on_gpu else ("pyfftw" if "pyfftw" in available_backends() else "numpy")
    fft = get_backend(backend, n, threads=threads)
    xp = fft.xp

    h = fft.asarray(heights)
    if not bool(xp.all(xp.isfinite(h))):
        raise ValueError("heights contain NaN or inf")
    dx = length / n
    if rho < dx:
        warnings.warn(
            f"rho/dx = {rho / dx:.3g} < 1 (rho={rho:g}, dx={dx:g}): the interaction range is under-resolved; "
            "the solver still converges but the mean gap carries a discretisation error (refine n)",
            UnderResolvedWarning,
            stacklevel=2,
        )
    h = h - h.mean()  # only h - <h> matters: <h> shifts g0 by a constant; report the gap of h - <h>
    h_shift = float(xp.asarray(heights, dtype=xp.float64).mean())

    if initial is None:
        Hq = fft.rfft2(h) * (1.0 / (n * n))
        k = 0.5 * e_star * _half_q(xp, n, length)
        x0 = Hq * ((sigma0 / rho) / (k + sigma0 / rho))  # linear response of M4: h~ / (1 + eta zeta)
    else:
        u0 = initial.displacement if isinstance(initial, GFMDResult) else initial
        u0 = fft.to_host(u0) if _is_cupy(u0) else np.asarray(u0, dtype=np.float64)
        if u0.ndim != 2 or u0.shape[0] != u0.shape[1] or not np.all(np.isfinite(u0)):
            raise ValueError("initial must be a GFMDResult or a finite square displacement field")
        if u0.shape[0] == n:
            x0 = xp.array(fft.rfft2(xp.asarray(u0)) * (1.0 / (n * n)))
        else:
            x0 = xp.asarray(_transfer_modes(u0, n))
    x0 = xp.array(x0, dtype=xp.complex128)

    ops = _make_ops(xp, n)
    history: list[float] = []
    # Non-finite values are caught by the status checks (residual, fields), not by numpy warnings.
    with np.errstate(all="ignore"):
        pb = _Problem(h, x0, sigma0=sigma0, rho=rho, e_star=e_star, length=length, fft=fft, ops=ops)
        status = _RUNNERS[method](pb, tol, max_iter, history)

        # Fields from the Fourier state (fresh transform, no accumulated drift between X and W).
        u = xp.array(fft.irfft2(pb.X))
        w = (h - u) * (1.0 / rho)
        e = xp.empty_like(w)
        m = float(w.max())
        S, _, _ = pb.ops.expstats(w, m, e)
        lse = m + math.log(S / (n * n)) if S > 0 else math.nan  # S >= 1 whenever m is finite
        g0 = rho * (math.log(gamma0 / (rho * sigma0)) + lse)
        p = e * (sigma0 * n * n / S) if S > 0 else e * math.nan
        gap = (g0 - h_shift) - rho * w  # g = g0 + u - h with the caller's h (mean included)
    load_error = abs(float(p.mean()) / sigma0 - 1.0)
    residual = history[-1] if history else math.inf
    fields_ok = math.isfinite(g0) and bool(xp.all(xp.isfinite(gap))) and bool(xp.all(xp.isfinite(p)))
    if not fields_ok:
        status = "non_finite"
    converged = status == "converged" and load_error <= tol and fields_ok
    if status == "converged" and not converged:
        status = "stalled"
    if host:
        gap, p, u = fft.to_host(gap), fft.to_host(p), fft.to_host(u)
    fft.synchronize()
    return GFMDResult(
        mean_gap=g0 - h_shift,
        gap=gap,
        pressure=p,
        displacement=u,
        iterations=pb.nfev,
        converged=converged,
        residual=residual,
        load_error=load_error,
        wall_time=time.perf_counter() - t_start,
        method=method,
        backend=backend,
        status=status,
        sigma0=sigma0,
        rho=rho,
        gamma0=gamma0,
        e_star=e_star,
        length=length,
        tol=tol,
        history=history,
    )
