// CUDA kernels of the gap SDE (docs/model.md M5) for NVIDIA GPUs, compiled by NVRTC through cupy with
// -use_fast_math (gapsweep/_sde_cuda.py). The same scheme and the same random numbers as the warp kernels of
// gapsweep/_sde_kernels.py (see its docstring): state y = g - g0(zeta), Strang split with the half steps of the
// noise merged (y += s[k] n_k, then the exact repulsion y -> rho logaddexp(y/rho, b[k])), normals from
// Philox-4x32-10 keyed by the 64-bit seed with counter (group, 0, index_lo, index_hi), four per call, by
// Box-Muller on 32-bit uniforms in (0, 1]. Realisation `index` gets the same numbers as on the CPU.
// Why a second implementation: warp 1.19 reached 1.42x a plain fast-math Euler-Maruyama kernel, this 1.08x
// (docs/benchmarks.md, issue 14); the extra cost in warp is code generation, not arithmetic.

__device__ __forceinline__ void philox(unsigned int c[4], unsigned int k0, unsigned int k1) {
#pragma unroll
    for (int r = 0; r < 10; ++r) {
        unsigned int hi0 = __umulhi(0xD2511F53u, c[0]), lo0 = 0xD2511F53u * c[0];
        unsigned int hi1 = __umulhi(0xCD9E8D57u, c[2]), lo1 = 0xCD9E8D57u * c[2];
        unsigned int n0 = hi1 ^ c[1] ^ k0, n2 = hi0 ^ c[3] ^ k1;
        c[0] = n0; c[1] = lo1; c[2] = n2; c[3] = lo0;
        k0 += 0x9E3779B9u; k1 += 0xBB67AE85u;
    }
}

template <typename T> __device__ __forceinline__ T unif(unsigned int x) {
    return ((T)x + (T)0.5) * (T)2.3283064365386963e-10;  // (0, 1]: never 0
}

__device__ __forceinline__ void box_muller(unsigned int a, unsigned int b, float &z0, float &z1) {
    float r = sqrtf(-2.0f * logf(unif<float>(a)));
    float s, c;
    sincosf(6.283185307179586f * unif<float>(b), &s, &c);
    z0 = r * c; z1 = r * s;
}

__device__ __forceinline__ void box_muller(unsigned int a, unsigned int b, double &z0, double &z1) {
    double r = sqrt(-2.0 * log(unif<double>(a)));
    double s, c;
    sincos(6.283185307179586 * unif<double>(b), &s, &c);
    z0 = r * c; z1 = r * s;
}

// log(1 + e) for 0 <= e <= 1. float: e P9(e), the degree-9 Chebyshev fit of gapsweep/_sde_kernels.py
// (relative error <= 1.5e-7, FMAs only); double: the library's log1p.
__device__ __forceinline__ float log1p01(float e) {
    float p = -0.0032141131814569235f;
    p = fmaf(p, e, 0.019649622961878777f);
    p = fmaf(p, e, -0.05643612518906593f);
    p = fmaf(p, e, 0.10533368587493896f);
    p = fmaf(p, e, -0.15251556038856506f);
    p = fmaf(p, e, 0.19651539623737335f);
    p = fmaf(p, e, -0.24947820603847504f);
    p = fmaf(p, e, 0.3332909941673279f);
    p = fmaf(p, e, -0.4999985098838806f);
    p = fmaf(p, e, 1.0f);
    return p * e;
}
__device__ __forceinline__ double log1p01(double e) { return log1p(e); }

template <typename T>
__device__ __forceinline__ T step(T y, int k, T n, int n_steps, const T *__restrict__ s, const T *__restrict__ b,
                                  const T *__restrict__ rb, T rho, T inv_rho, int repulse) {
    y += s[k] * n;  // A: noise over the merged half steps (D1 is carried by g0)
    if (repulse && k < n_steps) {  // B: exact repulsion without overflow or cancellation
        T d = b[k] - y * inv_rho;
        if (d > (T)-40) {  // else exp(-|d|) < e^-40: y would change by < 4e-18 rho
            T l = rho * log1p01(exp(-fabs(d)));
            y = (d <= (T)0) ? y + l : rb[k] + l;
        }
    }
    return y;
}

template <typename T>
__device__ T evolve(unsigned long long index, unsigned int k0, unsigned int k1, int n_steps,
                    const T *__restrict__ s, const T *__restrict__ b, const T *__restrict__ rb, T rho, T inv_rho,
                    int repulse) {
    T y = (T)0;
    int n_groups = (n_steps + 1 + 3) / 4;  // n_steps + 1 normals, four per Philox block
    for (int grp = 0; grp < n_groups; ++grp) {
        unsigned int c[4] = {(unsigned int)grp, 0u, (unsigned int)index, (unsigned int)(index >> 32)};
        philox(c, k0, k1);
        T z[4];
        box_muller(c[0], c[1], z[0], z[1]);
        box_muller(c[2], c[3], z[2], z[3]);
        int k = grp * 4;
#pragma unroll
        for (int j = 0; j < 4; ++j)
            if (k + j <= n_steps) y = step<T>(y, k + j, z[j], n_steps, s, b, rb, rho, inv_rho, repulse);
    }
    return y;
}

template <typename T>
__device__ void samples(long long n, unsigned long long first, unsigned int k0, unsigned int k1, int n_steps,
                        const T *s, const T *b, const T *rb, T rho, T inv_rho, int repulse, T *out) {
    long long tid = (long long)blockIdx.x * blockDim.x + threadIdx.x;
    if (tid < n) out[tid] = evolve<T>(first + (unsigned long long)tid, k0, k1, n_steps, s, b, rb, rho, inv_rho,
                                      repulse);
}

// Histogram of the final y: bins [edges[i], edges[i+1]), then slots nb (below), nb+1 (above), nb+2 (non-finite).
// Per-block counts in shared memory when `shared` (nb + 3 slots fit), added to the global counts at the end.
template <typename T>
__device__ void histogram(long long n, unsigned long long first, unsigned int k0, unsigned int k1, int n_steps,
                          const T *s, const T *b, const T *rb, T rho, T inv_rho, int repulse,
                          const T *__restrict__ edges, int nb, T uniform_lo, T uniform_inv_w, int is_uniform,
                          int shared, unsigned long long *counts) {
    extern __shared__ unsigned int sh[];
    if (shared) {
        for (int i = threadIdx.x; i < nb + 3; i += blockDim.x) sh[i] = 0u;
        __syncthreads();
    }
    long long tid = (long long)blockIdx.x * blockDim.x + threadIdx.x;
    if (tid < n) {
        T y = evolve<T>(first + (unsigned long long)tid, k0, k1, n_steps, s, b, rb, rho, inv_rho, repulse);
        int slot = nb + 2;
        if (isfinite(y)) {
            if (y < edges[0]) slot = nb;
            else if (y >= edges[nb]) slot = nb + 1;
            else if (is_uniform) slot = min(max((int)floor((y - uniform_lo) * uniform_inv_w), 0), nb - 1);
            else {
                int lo = 0, hi = nb;  // edges[lo] <= y < edges[hi]
                while (hi - lo > 1) {
                    int mid = (lo + hi) / 2;
                    if (y >= edges[mid]) lo = mid; else hi = mid;
                }
                slot = lo;
            }
        }
        if (shared) atomicAdd(&sh[slot], 1u);
        else atomicAdd(&counts[slot], 1ull);
    }
    if (shared) {
        __syncthreads();
        for (int i = threadIdx.x; i < nb + 3; i += blockDim.x)
            if (sh[i]) atomicAdd(&counts[i], (unsigned long long)sh[i]);
    }
}

#define SDE_KERNELS(SUFFIX, T)                                                                                  \
    extern "C" __global__ void sde_samples_##SUFFIX(long long n, unsigned long long first, unsigned int k0,     \
            unsigned int k1, int n_steps, const T *s, const T *b, const T *rb, T rho, T inv_rho, int repulse,    \
            T *out) {                                                                                           \
        samples<T>(n, first, k0, k1, n_steps, s, b, rb, rho, inv_rho, repulse, out);                            \
    }                                                                                                           \
    extern "C" __global__ void sde_histogram_##SUFFIX(long long n, unsigned long long first, unsigned int k0,   \
            unsigned int k1, int n_steps, const T *s, const T *b, const T *rb, T rho, T inv_rho, int repulse,    \
            const T *edges, int nb, T uniform_lo, T uniform_inv_w, int is_uniform, int shared,                  \
            unsigned long long *counts) {                                                                       \
        histogram<T>(n, first, k0, k1, n_steps, s, b, rb, rho, inv_rho, repulse, edges, nb, uniform_lo,         \
                     uniform_inv_w, is_uniform, shared, counts);                                                \
    }

SDE_KERNELS(f32, float)
SDE_KERNELS(f64, double)
