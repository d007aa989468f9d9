
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
        const double wgt = PWEIGHT(j, nh, even);
        const double gg = cdot(g, g);
        v[0] += wgt * gg;
        if (flags & 2) {
            const double z = wgt * ((flags & 4) ? (i == 0 ? 0.0 : 1.0 / (kk + sr)) : minv[i]);
            v[1] += z * gg;
            // Gold may be G itself (CG on the GPU keeps one gradient array): read before the store below.
            v[2] += z * cdot(g, Gold[i]);
        }
        G[i] = g;
    }
    grid_reduce<3>(v, 0u, part, count, out);
}

// D = beta D - minv G; out = (<G D>, <kD X>, <kD D>). flags & 4: k, minv on the fly as in gs_grad.
// flags & 8: beta = max(0, (zg - zc) / zg_old) from the gradient pass's results gs = (<G G>, zg, zc) on the
// device (the chained CG of _solvers._ChainedDirections: no host round trip between the gradient and the direction).
KERNEL_H gs_cgdir(const double2* __restrict__ G, const double* __restrict__ minv, double2* D, double beta,
                const double* __restrict__ k, const double2* __restrict__ X, int flags, unsigned n, double ka,
                double kb, double sr, const double* __restrict__ gs, double zg_old, unsigned nh, int even,
                unsigned long long N, double* part, unsigned int* count, double* out) {
    double v[3] = {0.0, 0.0, 0.0};
    if (flags & 8) beta = fmax(0.0, __ddiv_rn(__dsub_rn(gs[1], gs[2]), zg_old));
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

// First trial of a chained CG line search: the step alpha = -phi0p / curv (1 if curv <= 0) of
// _solvers._Problem.line_search, curv = b + sr (s2/S - (s1/S)^2), from the direction pass's results
// cg = (phi0p, a, b) and the moments mo = (s1, s2) on the device, rounded as the host rounds it (no fma); then
// the trial point as gs_point with flags 3 (c = -alpha/rho). out = (max wt, sum e, sum e d, sum e d^2, alpha).
KERNEL gs_trial0(const double* __restrict__ W, const double* __restrict__ dt, const double* __restrict__ cg,
                 const double* __restrict__ mo, double S, double sr, double rho, double* Wt, double* e, double shift,
                 unsigned long long N, double* part, unsigned int* count, double* out) {
    const double s1 = __ddiv_rn(mo[0], S), s2 = __ddiv_rn(mo[1], S);
    const double curv = __dadd_rn(cg[2], __dmul_rn(sr, __dsub_rn(s2, __dmul_rn(s1, s1))));
    const double alpha = curv > 0.0 ? __ddiv_rn(-cg[0], curv) : 1.0;
    const double c = __ddiv_rn(-alpha, rho);
    double v[4] = {neg_inf(), 0.0, 0.0, 0.0};
    GRID_LOOP(i, N) {
        const double w = fma(c, dt[i], W[i]);
        Wt[i] = w;
        const double x = exp(w - shift);
        e[i] = x;
        v[0] = comb(v[0], w, true);
        v[1] += x;
        const double y = x * dt[i];
        v[2] += y;
        v[3] += y * dt[i];
    }
    grid_reduce<4>(v, 1u, part, count, out);
    if (blockIdx.x == 0 && threadIdx.x == 0) out[4] = alpha;
}

// ------------------------------------------------------------------------------------------- set-up, result
// Set-up and result passes of one solve on the GPU (gapsweep/gfmd/_softmax.py, GPU branch): each replaces a chain
// of array expressions (one pass and often one temporary each) by one pass without temporaries.

// out = (sum of the finite a, number of non-finite a).
KERNEL gs_sumfinite(const double* __restrict__ a, unsigned long long N, double* part, unsigned int* count,
                    double* out) {
    double v[2] = {0.0, 0.0};
    GRID_LOOP(i, N) {
        const double x = a[i];
        if (isfinite(x)) v[0] += x; else v[1] += 1.0;
    }
    grid_reduce<2>(v, 0u, part, count, out);
}

// W = ((h - hm) - u) * inv_rho (the CPU's order of operations); out[0] = max W.
KERNEL gs_field(const double* __restrict__ h, double hm, const double* __restrict__ u, double inv_rho, double* W,
                unsigned long long N, double* part, unsigned int* count, double* out) {
    double v[1] = {neg_inf()};
    GRID_LOOP(i, N) {
        const double w = ((h[i] - hm) - u[i]) * inv_rho;
        W[i] = w;
        v[0] = comb(v[0], w, true);
    }
    grid_reduce<1>(v, 1u, part, count, out);
}

// Result fields in place: p = e cp (into e), gap = a0 - rho W (into W);
// out = (sum p, #{gap + hs < thr}, #{gap or p not finite}).
KERNEL gs_final(double* W, double* e, double cp, double a0, double rho, double hs, double thr,
                unsigned long long N, double* part, unsigned int* count, double* out) {
    double v[3] = {0.0, 0.0, 0.0};
    GRID_LOOP(i, N) {
        const double p = e[i] * cp;
        e[i] = p;
        const double g = __dsub_rn(a0, __dmul_rn(rho, W[i]));  // no fma: as numpy rounds it
        W[i] = g;
        v[0] += p;
        v[1] += (__dadd_rn(g, hs) < thr) ? 1.0 : 0.0;
        v[2] += (isfinite(p) && isfinite(g)) ? 0.0 : 1.0;
    }
    grid_reduce<3>(v, 0u, part, count, out);
}

// Linear response of M4 from the half spectrum H = rfft2(h): X = (s H) (sr / (k + sr)), X(q=0) = 0,
// k = ka (kb |q|) per mode (as gs_grad). No reduction.
extern "C" __global__ void __launch_bounds__(NT) gs_linresp(const double2* __restrict__ H, double s, double sr,
                                                           double2* X, unsigned n, double ka, double kb,
                                                           unsigned nh, unsigned long long N) {
    HALF_LOOP(i, r, j, N, nh) {
        const double f = sr / (stiff(r, j, n, ka, kb) + sr);
        const double2 hh = H[i];
        X[i] = i == 0 ? make_double2(0.0, 0.0) : make_double2((hh.x * s) * f, (hh.y * s) * f);
    }
}

// Residual and elastic energy of the result: U = s Ur, P = s Pr, F = k U - P (0 at q = 0);
// out = (<F F>, <U k U>) (Parseval weights), k = ka (kb |q|) per mode.
KERNEL_H gs_resid(const double2* __restrict__ Ur, const double2* __restrict__ Pr, double s, unsigned n, double ka,
                  double kb, unsigned nh, int even, unsigned long long N, double* part, unsigned int* count,
                  double* out) {
    double v[2] = {0.0, 0.0};
    HALF_LOOP(i, r, j, N, nh) {
        const double kk = stiff(r, j, n, ka, kb);
        const double2 u = Ur[i], pr = Pr[i];
        const double2 uu = make_double2(u.x * s, u.y * s);
        double2 f = make_double2(kk * uu.x - pr.x * s, kk * uu.y - pr.y * s);
        if (i == 0) f = make_double2(0.0, 0.0);
        const double wgt = PWEIGHT(j, nh, even);
        v[0] += wgt * cdot(f, f);
        v[1] += wgt * kk * cdot(uu, uu);
    }
    grid_reduce<2>(v, 0u, part, count, out);
}

// ------------------------------------------------------------------------------------------------ hard wall
// Passes of the hard-wall minimiser (gapsweep/gfmd/_constrained.py) on any nx x ny grid (N = nx ny), one pass each
// with its reductions, rounded as the numba passes of _constrained_ops.py (no fma contraction); S = {p > 0}.
#define IN_S(i) (p[i] > 0.0)

// out = (|S|, sum_S (u - h)).
KERNEL pk_contact_sum(const double* __restrict__ u, const double* __restrict__ h, const double* __restrict__ p,
                      unsigned long long N, double* part, unsigned int* count, double* out) {
    double v[2] = {0.0, 0.0};
    GRID_LOOP(i, N) {
        if (IN_S(i)) { v[0] += 1.0; v[1] += __dsub_rn(u[i], h[i]); }
    }
    grid_reduce<2>(v, 0u, part, count, out);
}

// g = (u - h) - gbar, gs = g on S else 0; out = (sum_S g^2, -min over the free surface of g) (max of -g).
KERNEL pk_gap(const double* __restrict__ u, const double* __restrict__ h, double gbar, const double* __restrict__ p,
              double* g, double* gs, unsigned long long N, double* part, unsigned int* count, double* out) {
    double v[2] = {0.0, neg_inf()};
    GRID_LOOP(i, N) {
        const double x = __dsub_rn(__dsub_rn(u[i], h[i]), gbar);
        g[i] = x;
        if (IN_S(i)) { gs[i] = x; v[0] += __dmul_rn(x, x); }
        else { gs[i] = 0.0; v[1] = comb(v[1], -x, true); }
    }
    grid_reduce<2>(v, 2u, part, count, out);
}

// out = (sum_S z, sum gs z).
KERNEL pk_zstats(const double* __restrict__ z, const double* __restrict__ gs, const double* __restrict__ p,
                 unsigned long long N, double* part, unsigned int* count, double* out) {
    double v[2] = {0.0, 0.0};
    GRID_LOOP(i, N) {
        if (IN_S(i)) { v[0] += z[i]; v[1] += __dmul_rn(gs[i], z[i]); }
    }
    grid_reduce<2>(v, 0u, part, count, out);
}

// t = (z - zbar) + c t on S, 0 elsewhere. No reduction.
extern "C" __global__ void __launch_bounds__(NT) pk_direction(double* t, const double* __restrict__ z, double zbar,
                                                             double c, const double* __restrict__ p,
                                                             unsigned long long N) {
    GRID_LOOP(i, N) t[i] = IN_S(i) ? __dadd_rn(__dsub_rn(z[i], zbar), __dmul_rn(c, t[i])) : 0.0;
}

// out = (sum_S r, sum_S r t, sum_S t, sum gs t).
KERNEL pk_rstats(const double* __restrict__ r, const double* __restrict__ t, const double* __restrict__ gs,
                 const double* __restrict__ p, unsigned long long N, double* part, unsigned int* count, double* out) {
    double v[4] = {0.0, 0.0, 0.0, 0.0};
    GRID_LOOP(i, N) {
        const double tt = t[i];
        if (IN_S(i)) {
            const double rr = r[i];
            v[0] += rr;
            v[1] += __dmul_rn(rr, tt);
            v[2] += tt;
        }
        v[3] += __dmul_rn(gs[i], tt);
    }
    grid_reduce<4>(v, 0u, part, count, out);
}

// p = max(p - tau t, 0), then p = -tau_g g where p = 0 and g < 0 (tau_g: a stiffness); out = (#clipped,
// #overlap, sum p).
KERNEL pk_update(double* p, const double* __restrict__ t, const double* __restrict__ g, double tau,
                 double tau_g, unsigned long long N, double* part, unsigned int* count, double* out) {
    double v[3] = {0.0, 0.0, 0.0};
    GRID_LOOP(i, N) {
        double x = __dsub_rn(p[i], __dmul_rn(tau, t[i]));
        if (x < 0.0) { v[0] += 1.0; x = 0.0; }
        const double gg = g[i];
        if (x == 0.0 && gg < 0.0) { v[1] += 1.0; x = __dmul_rn(-tau_g, gg); }
        p[i] = x;
        v[2] += x;
    }
    grid_reduce<3>(v, 0u, part, count, out);
}

// p *= scale; follow: u = scale (u - tau r). No reduction.
extern "C" __global__ void __launch_bounds__(NT) pk_rescale(double* p, double* u, const double* __restrict__ r,
                                                           double scale, double tau, int follow,
                                                           unsigned long long N) {
    GRID_LOOP(i, N) {
        p[i] = __dmul_rn(p[i], scale);
        if (follow) u[i] = __dmul_rn(scale, __dsub_rn(u[i], __dmul_rn(tau, r[i])));
    }
}

// ------------------------------------------------------------------------------------------------- batches
// Kernels of gapsweep/gfmd/batched.py: a stack of B problems, problem b = blockIdx.y, its arrays at offset
// b * N (real n x n: N = n^2; half spectra n x nh: N = n nh; k is shared by all problems). Per-problem scalars
// come in device arrays; a problem whose active[b] is 0 is skipped (its block-row writes nothing and reduces
// identities). Each block writes its K partials to part[(b K + k) gridDim.x + blockIdx.x]; the host side sums
// (or maxes) them over blocks in a fixed order, so results are deterministic.
template <int K>
__device__ void batch_reduce(double* v, unsigned mx, double* part) {
    __shared__ double sh[K][NT / 32];
    block_reduce<K>(v, mx, sh);
    if (threadIdx.x == 0) {
#pragma unroll
        for (int k = 0; k < K; k++) part[((unsigned long long)blockIdx.y * K + k) * gridDim.x + blockIdx.x] = v[k];
    }
}

#define BATCH_LOOP(i, N) GRID_LOOP(i, N)

// Trial point of each active problem: Wt = W + c[b] d, e = exp(Wt - shift[b]);
// partials (max Wt, sum e, sum e d, sum e d^2).
KERNEL bt_point(const double* __restrict__ W, const double* __restrict__ d, const double* __restrict__ c,
                const double* __restrict__ shift, const int* __restrict__ active, double* Wt, double* e,
                unsigned long long N, double* part) {
    double v[4] = {neg_inf(), 0.0, 0.0, 0.0};
    const unsigned b = blockIdx.y;
    if (active[b]) {
        const double cb = c[b], sb = shift[b];
        const unsigned long long o = (unsigned long long)b * N;
        BATCH_LOOP(i, N) {
            const double dv = d[o + i];
            const double w = fma(cb, dv, W[o + i]);
            Wt[o + i] = w;
            const double ex = exp(w - sb);
            e[o + i] = ex;
            v[0] = comb(v[0], w, true);
            v[1] += ex;
            const double ed = ex * dv;
            v[2] += ed;
            v[3] += ed * dv;
        }
    }
    batch_reduce<4>(v, 1u, part);
}

// Partials (sum e d, sum e d^2) of every problem.
KERNEL bt_moments(const double* __restrict__ e, const double* __restrict__ d, unsigned long long N, double* part) {
    double v[2] = {0.0, 0.0};
    const unsigned long long o = (unsigned long long)blockIdx.y * N;
    BATCH_LOOP(i, N) {
        const double ed = e[o + i] * d[o + i];
        v[0] += ed;
        v[1] += ed * d[o + i];
    }
    batch_reduce<2>(v, 0u, part);
}

// CG dots of every problem: (<Z G>, <Z Gold>), Z = minv G (Parseval weights).
KERNEL_H bt_cgdots(const double* __restrict__ minv, const double2* __restrict__ G, const double2* __restrict__ Gold,
                   unsigned nh, int even, unsigned long long N, double* part) {
    double v[2] = {0.0, 0.0};
    const unsigned long long o = (unsigned long long)blockIdx.y * N;
    HALF_LOOP(i, r, j, N, nh) {
        const double z = PWEIGHT(j, nh, even) * minv[o + i];
        const double2 g = G[o + i];
        v[0] += z * cdot(g, g);
        v[1] += z * cdot(g, Gold[o + i]);
    }
    batch_reduce<2>(v, 0u, part);
}

// Active problems: D = beta[b] D - minv G; partials (<G D>, <kD X>, <kD D>).
KERNEL_H bt_cgupdate(double2* D, const double* __restrict__ beta, const double* __restrict__ minv,
                     const double2* __restrict__ G, const double* __restrict__ k, const double2* __restrict__ X,
                     const int* __restrict__ active, unsigned nh, int even, unsigned long long N, double* part) {
    double v[3] = {0.0, 0.0, 0.0};
    const unsigned b = blockIdx.y;
    if (active[b]) {
        const double bb = beta[b];
        const unsigned long long o = (unsigned long long)b * N;
        HALF_LOOP(i, r, j, N, nh) {
            const double2 g = G[o + i], d0 = D[o + i];
            const double mi = minv[o + i];
            const double2 d = make_double2(bb * d0.x - mi * g.x, bb * d0.y - mi * g.y);
            D[o + i] = d;
            const double wgt = PWEIGHT(j, nh, even);
            const double kw = wgt * k[i];
            v[0] += wgt * cdot(g, d);
            v[1] += kw * cdot(d, X[o + i]);
            v[2] += kw * cdot(d, d);
        }
    }
    batch_reduce<3>(v, 0u, part);
}

// Active problems accept their step: Gold = G, X += alpha[b] D, G = k X - c[b] E (0 at q = 0);
// partial <G G>.
KERNEL_H bt_accept(double2* X, const double2* __restrict__ D, const double* __restrict__ alpha,
                   const double2* __restrict__ E, const double* __restrict__ c, const double* __restrict__ k,
                   double2* G, double2* Gold, const int* __restrict__ active, unsigned nh, int even,
                   unsigned long long N, double* part) {
    double v[1] = {0.0};
    const unsigned b = blockIdx.y;
    if (active[b]) {
        const double ab = alpha[b], cb = c[b];
        const unsigned long long o = (unsigned long long)b * N;
        HALF_LOOP(i, r, j, N, nh) {
            const double2 g0 = G[o + i], dd = D[o + i], ee = E[o + i];
            Gold[o + i] = g0;
            double2 x = X[o + i];
            x.x = fma(ab, dd.x, x.x);
            x.y = fma(ab, dd.y, x.y);
            X[o + i] = x;
            double2 g = make_double2(k[i] * x.x - cb * ee.x, k[i] * x.y - cb * ee.y);
            if (i == 0) g = make_double2(0.0, 0.0);
            G[o + i] = g;
            v[0] += PWEIGHT(j, nh, even) * cdot(g, g);
        }
    }
    batch_reduce<1>(v, 0u, part);
}
