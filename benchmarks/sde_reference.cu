// Hand-written CUDA kernels of the gap SDE for benchmarks/bench_sde_gpu.py (compiled by cupy/NVRTC with
// -use_fast_math). Not used by the library: they set the "kernel limit" that the warp kernels of
// gapsweep/_sde_kernels.py are measured against (issue 14).
//
// plain_em_curand: the plain Euler-Maruyama kernel of the issue: cuRAND Philox4_32_10, curand_normal4, one
//   thread per realisation, g += drift[k] + cdz[k] exp(-g/rho) + sd[k] n, histogram in shared memory.
// plain_em_philox: the same with the hand-written Philox + Box-Muller below (no cuRAND header needed).
#ifdef WITH_CURAND
#include <curand_kernel.h>
#endif

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

__device__ __forceinline__ float unif(unsigned int x) { return ((float)x + 0.5f) * 2.3283064365386963e-10f; }

__device__ __forceinline__ void box_muller(unsigned int a, unsigned int b, float &z0, float &z1) {
    float r = sqrtf(-2.0f * logf(unif(a)));
    float s, c;
    sincosf(6.283185307179586f * unif(b), &s, &c);
    z0 = r * c; z1 = r * s;
}

__device__ __forceinline__ void bin(float y, const float lo, const float inv_w, const float hi, int nb,
                                    unsigned int *sh) {
    int slot = nb + 2;
    if (isfinite(y)) {
        if (y < lo) slot = nb;
        else if (y >= hi) slot = nb + 1;
        else slot = min(max((int)floorf((y - lo) * inv_w), 0), nb - 1);
    }
    atomicAdd(&sh[slot], 1u);
}

__device__ __forceinline__ void flush(unsigned int *sh, int nslots, unsigned long long *counts) {
    __syncthreads();
    for (int i = threadIdx.x; i < nslots; i += blockDim.x)
        if (sh[i]) atomicAdd(&counts[i], (unsigned long long)sh[i]);
}

#define HIST_PROLOGUE                                                        \
    extern __shared__ unsigned int sh[];                                     \
    for (int i = threadIdx.x; i < nb + 3; i += blockDim.x) sh[i] = 0;       \
    __syncthreads();                                                         \
    long long tid = (long long)blockIdx.x * blockDim.x + threadIdx.x;

#ifdef WITH_CURAND
extern "C" __global__ void plain_em_curand(long long n, unsigned long long seed, int n_steps,
        const float *__restrict__ sd, const float *__restrict__ drift, const float *__restrict__ cdz,
        float inv_rho, float start, float shift, float lo, float inv_w, float hi, int nb,
        unsigned long long *counts) {
    HIST_PROLOGUE
    if (tid < n) {
        curandStatePhilox4_32_10_t st;
        curand_init(seed, tid, 0, &st);
        float g = start;
        for (int k = 0; k < n_steps; k += 4) {
            float4 z = curand_normal4(&st);
            float zz[4] = {z.x, z.y, z.z, z.w};
#pragma unroll
            for (int j = 0; j < 4; ++j)
                if (k + j < n_steps) g += drift[k + j] + cdz[k + j] * __expf(-g * inv_rho) + sd[k + j] * zz[j];
        }
        bin(g - shift, lo, inv_w, hi, nb, sh);
    }
    flush(sh, nb + 3, counts);
}
#endif

extern "C" __global__ void plain_em_philox(long long n, unsigned long long seed, int n_steps,
        const float *__restrict__ sd, const float *__restrict__ drift, const float *__restrict__ cdz,
        float inv_rho, float start, float shift, float lo, float inv_w, float hi, int nb,
        unsigned long long *counts) {
    HIST_PROLOGUE
    if (tid < n) {
        unsigned int k0 = (unsigned int)seed, k1 = (unsigned int)(seed >> 32);
        float g = start;
        for (int k = 0; k < n_steps; k += 4) {
            unsigned int c[4] = {(unsigned int)(k >> 2), 0u, (unsigned int)tid, (unsigned int)(tid >> 32)};
            philox(c, k0, k1);
            float zz[4];
            box_muller(c[0], c[1], zz[0], zz[1]);
            box_muller(c[2], c[3], zz[2], zz[3]);
#pragma unroll
            for (int j = 0; j < 4; ++j)
                if (k + j < n_steps) g += drift[k + j] + cdz[k + j] * __expf(-g * inv_rho) + sd[k + j] * zz[j];
        }
        bin(g - shift, lo, inv_w, hi, nb, sh);
    }
    flush(sh, nb + 3, counts);
}
