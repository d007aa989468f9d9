"""Warp kernels of the gap SDE (docs/model.md M5); the host side is :mod:`gapsweep.sde`.

Scheme (one thread per realisation, state ``y = g - g0(zeta)``, the deviation from the field-theory mean gap):

* Strang splitting of ``dg = [D1 + c exp(-g/rho)] dzeta + sqrt(2 D2) dW`` into
  A (drift ``D1`` + noise, exact: ``y += N(0, 2 int D2)``; ``D1`` is absorbed into ``g0``) and
  B (repulsion ``dg/dzeta = c exp(-g/rho)``, exact: ``g -> rho ln(exp(g/rho) + c dzeta/rho)``).
  The half steps of A of neighbouring steps are merged, so a step costs one normal and one B:
  ``y += s[k] n_k``, then ``y -> rho logaddexp(y/rho, b[k])`` with ``b[k] = ln(c dzeta_k/rho) - g0(mid_k)/rho``
  precomputed on the host in float64. The last half step of A is ``s[K]``.
* Counter-based normals: Philox-4x32-10 keyed by the 64-bit seed, counter (group, 0, index_lo, index_hi), so
  realisation ``index`` sees the same numbers whatever the launch shape, batch split or device. One Philox call
  gives four normals (two Box-Muller pairs from 32-bit uniforms in (0, 1]).

* ``log1p`` of the repulsion step, float32 (``VARIANTS``): "poly" (default) evaluates ``e P9(e)``, a degree-9
  Chebyshev fit of ``log1p(e)/e`` on [0, 1] (max relative error 1.5e-7, about one float32 ulp) with FMAs only;
  "div" is Goldberg's ``log(1+e) e/((1+e)-1)`` (a log and a division: two special-function unit operations
  more per step, the issue-14 bottleneck); "log" is plain ``log(1+e)`` (fast-math log, absolute error 2^-21).
  float64 always uses "div" (exact to rounding). The Philox stream, hence reproducibility from
  ``(seed, realisation)``, is the same in every variant.

Kernels are built per float type and variant by :func:`kernels` (warp kernels must be defined in a file).
"""

import functools
from typing import Any

import warp as wp

PHILOX_M0 = wp.constant(wp.uint64(0xD2511F53))
PHILOX_M1 = wp.constant(wp.uint64(0xCD9E8D57))
PHILOX_W0 = wp.constant(wp.uint32(0x9E3779B9))
PHILOX_W1 = wp.constant(wp.uint32(0xBB67AE85))
SHIFT32 = wp.constant(wp.uint64(32))
MASK32 = wp.constant(wp.uint64(0xFFFFFFFF))

# fast_math: approximate exp/log/sin/cos intrinsics on the GPU (float32); no adjoints needed.
_OPTIONS = {"fast_math": True, "enable_backward": False}

# log1p variant of the float32 repulsion step (module docstring); benchmarks/bench_sde_gpu.py times them all.
VARIANTS = ("poly", "div", "log")
VARIANT = "poly"
# log1p(e)/e ~ sum LOG1P_POLY[i] e^i on [0, 1]: least-squares Chebyshev fit, degree 9, rounded to float32.
LOG1P_POLY = (1.0, -0.4999985098838806, 0.3332909941673279, -0.24947820603847504, 0.19651539623737335,
              -0.15251556038856506, 0.10533368587493896, -0.05643612518906593, 0.019649622961878777,
              -0.0032141131814569235)

from gapsweep.gapdist._sde_cuda import N_EXTRA  # noqa: E402, F401  histogram slots after the bins (below, above, non-finite)


@wp.func
def philox4x32(c0: wp.uint32, c1: wp.uint32, c2: wp.uint32, c3: wp.uint32, k0: wp.uint32, k1: wp.uint32):
    """Philox-4x32-10 (Salmon et al., SC'11): the 4-word block for counter (c0..c3) under key (k0, k1)."""
    for _ in range(10):
        p0 = PHILOX_M0 * wp.uint64(c0)
        p1 = PHILOX_M1 * wp.uint64(c2)
        hi0 = wp.uint32(p0 >> SHIFT32)
        lo0 = wp.uint32(p0 & MASK32)
        hi1 = wp.uint32(p1 >> SHIFT32)
        lo1 = wp.uint32(p1 & MASK32)
        n0 = hi1 ^ c1 ^ k0
        n2 = hi0 ^ c3 ^ k1
        c0 = n0
        c1 = lo1
        c2 = n2
        c3 = lo0
        k0 = k0 + PHILOX_W0
        k1 = k1 + PHILOX_W1
    return c0, c1, c2, c3


def kernels(dtype_name: str, variant: str | None = None) -> dict[str, Any]:
    """Kernels for ``dtype_name`` in {"float32", "float64"}: ``{"real": type, "split"|"euler": {"samples",
    "histogram"}}`` (built once per variant, cached). ``variant`` (float32 only): one of :data:`VARIANTS`,
    default :data:`VARIANT`."""
    if dtype_name not in ("float32", "float64"):
        raise ValueError(f"dtype must be 'float32' or 'float64', got {dtype_name!r}")
    variant = VARIANT if variant is None else variant
    if variant not in VARIANTS:
        raise ValueError(f"variant must be one of {VARIANTS}, got {variant!r}")
    return _kernels(dtype_name, "div" if dtype_name == "float64" else variant)


@functools.cache
def _kernels(dtype_name: str, variant: str) -> dict[str, Any]:
    real = wp.float32 if dtype_name == "float32" else wp.float64
    c0, c1, c2, c3, c4, c5, c6, c7, c8, c9 = (real(c) for c in LOG1P_POLY)
    # Skip the repulsion step when exp(-|d|) < e^-40: it would change y by < 4e-18 rho.
    skip = real(-40.0)

    @wp.func
    def uniform(x: wp.uint32):
        # (x + 1/2) 2^-32 in (0, 1]: never 0, so log() stays finite (tails up to ~6.8 sigma)
        return (real(x) + real(0.5)) * real(2.3283064365386963e-10)

    @wp.func
    def box_muller(a: wp.uint32, b: wp.uint32):
        r = wp.sqrt(real(-2.0) * wp.log(uniform(a)))
        t = real(6.283185307179586) * uniform(b)
        return r * wp.cos(t), r * wp.sin(t)

    @wp.func
    def log1p_div(e: Any):
        # log(1 + e) for 0 <= e <= 1, accurate for tiny e (Goldberg's trick; warp has no log1p)
        u = real(1.0) + e
        d = u - real(1.0)
        r = e
        if d != real(0.0):
            r = wp.log(u) * (e / d)
        return r

    @wp.func
    def log1p_poly(e: Any):
        # e P9(e), Horner: FMAs only (no special-function unit), relative error <= 1.5e-7 on [0, 1]
        p = c9
        p = p * e + c8
        p = p * e + c7
        p = p * e + c6
        p = p * e + c5
        p = p * e + c4
        p = p * e + c3
        p = p * e + c2
        p = p * e + c1
        p = p * e + c0
        return p * e

    @wp.func
    def log1p_log(e: Any):
        return wp.log(real(1.0) + e)

    log1p_small = {"div": log1p_div, "poly": log1p_poly, "log": log1p_log}[variant]

    @wp.func
    def step(y: Any, k: int, n: Any, n_steps: int, s: wp.array(dtype=real), b: wp.array(dtype=real),
             rb: wp.array(dtype=real), rho: Any, inv_rho: Any, repulse: int):
        # A: noise over the merged half steps (D1 is carried by g0)
        y = y + s[k] * n
        # B: exact repulsion, y -> rho logaddexp(y/rho, b[k]) without overflow or cancellation
        if repulse != 0 and k < n_steps:
            d = b[k] - y * inv_rho
            if d > skip:
                l = rho * log1p_small(wp.exp(-wp.abs(d)))
                if d <= real(0.0):
                    y = y + l
                else:
                    y = rb[k] + l
        return y

    @wp.func
    def evolve(index: wp.uint64, k0: wp.uint32, k1: wp.uint32, n_steps: int, s: wp.array(dtype=real),
               b: wp.array(dtype=real), rb: wp.array(dtype=real), rho: Any, inv_rho: Any, repulse: int):
        ilo = wp.uint32(index & MASK32)
        ihi = wp.uint32(index >> SHIFT32)
        y = real(0.0)
        n_groups = (n_steps + 1 + 3) // 4  # n_steps + 1 normals, four per Philox block
        for grp in range(n_groups):
            r0, r1, r2, r3 = philox4x32(wp.uint32(grp), wp.uint32(0), ilo, ihi, k0, k1)
            g0, g1 = box_muller(r0, r1)
            g2, g3 = box_muller(r2, r3)
            k = grp * 4
            y = step(y, k, g0, n_steps, s, b, rb, rho, inv_rho, repulse)
            if k + 1 <= n_steps:
                y = step(y, k + 1, g1, n_steps, s, b, rb, rho, inv_rho, repulse)
            if k + 2 <= n_steps:
                y = step(y, k + 2, g2, n_steps, s, b, rb, rho, inv_rho, repulse)
            if k + 3 <= n_steps:
                y = step(y, k + 3, g3, n_steps, s, b, rb, rho, inv_rho, repulse)
        return y

    @wp.func
    def evolve_euler(index: wp.uint64, k0: wp.uint32, k1: wp.uint32, n_steps: int, s: wp.array(dtype=real),
                     b: wp.array(dtype=real), rb: wp.array(dtype=real), inv_rho: Any, start: Any, shift: Any):
        # The paper's Euler-Maruyama on g itself (baseline for benchmarks): per step k
        # g += D1(z_k) dz + c dz exp(-g/rho) + sqrt(2 D2(z_k) dz) n, with b = D1 dz, rb = c dz, s = sd.
        # Overflows (inf/nan) on the stiff case of M7: that is what it is kept for. A step that breaks the
        # explicit-Euler stability bound of the repulsion, lambda dz = c dz exp(-g/rho)/rho > 2 (linearised
        # amplification |1 - lambda dz| > 1), marks the realisation failed: it returns NaN instead of a finite
        # but meaningless gap (docs/model.md M5, M7).
        ilo = wp.uint32(index & MASK32)
        ihi = wp.uint32(index >> SHIFT32)
        g = start
        failed = int(0)  # noqa: UP018 (warp: a dynamic variable, not a constant)
        n_groups = (n_steps + 3) // 4
        for grp in range(n_groups):
            r0, r1, r2, r3 = philox4x32(wp.uint32(grp), wp.uint32(0), ilo, ihi, k0, k1)
            g0, g1 = box_muller(r0, r1)
            g2, g3 = box_muller(r2, r3)
            k = grp * 4
            for j in range(4):
                if k + j < n_steps:
                    n = g0
                    if j == 1:
                        n = g1
                    elif j == 2:
                        n = g2
                    elif j == 3:
                        n = g3
                    push = rb[k + j] * wp.exp(-g * inv_rho)
                    if push * inv_rho > real(2.0) or not wp.isfinite(push):
                        failed = 1
                    g = g + b[k + j] + push + s[k + j] * n
        if failed != 0:
            g = real(wp.nan)
        return g - shift

    @wp.func
    def evolve_split(index: wp.uint64, k0: wp.uint32, k1: wp.uint32, n_steps: int, s: wp.array(dtype=real),
                     b: wp.array(dtype=real), rb: wp.array(dtype=real), rho: Any, inv_rho: Any, repulse: int,
                     start: Any, shift: Any):
        return evolve(index, k0, k1, n_steps, s, b, rb, rho, inv_rho, repulse)

    @wp.func
    def evolve_em(index: wp.uint64, k0: wp.uint32, k1: wp.uint32, n_steps: int, s: wp.array(dtype=real),
                  b: wp.array(dtype=real), rb: wp.array(dtype=real), rho: Any, inv_rho: Any, repulse: int,
                  start: Any, shift: Any):
        return evolve_euler(index, k0, k1, n_steps, s, b, rb, inv_rho, start, shift)

    out = {"real": real}
    # One kernel pair per scheme, so the production (split) kernel carries no code or registers of the other.
    for name, final_y in (("split", evolve_split), ("euler", evolve_em)):
        out[name] = _make_pair(real, final_y)
    return out


def _make_pair(real, final_y):
    @wp.kernel(module="unique", module_options=_OPTIONS)
    def samples_kernel(first: wp.uint64, k0: wp.uint32, k1: wp.uint32, n_steps: int, s: wp.array(dtype=real),
                       b: wp.array(dtype=real), rb: wp.array(dtype=real), rho: real, inv_rho: real,
                       repulse: int, start: real, shift: real, out: wp.array(dtype=real)):
        tid = wp.tid()
        out[tid] = final_y(first + wp.uint64(tid), k0, k1, n_steps, s, b, rb, rho, inv_rho, repulse, start, shift)

    @wp.kernel(module="unique", module_options=_OPTIONS)
    def histogram_kernel(first: wp.uint64, k0: wp.uint32, k1: wp.uint32, n_steps: int, s: wp.array(dtype=real),
                         b: wp.array(dtype=real), rb: wp.array(dtype=real), rho: real, inv_rho: real,
                         repulse: int, start: real, shift: real, edges: wp.array(dtype=real),
                         uniform_lo: real, uniform_inv_w: real, is_uniform: int,
                         counts: wp.array(dtype=wp.int64)):
        tid = wp.tid()
        y = final_y(first + wp.uint64(tid), k0, k1, n_steps, s, b, rb, rho, inv_rho, repulse, start, shift)
        nb = edges.shape[0] - 1
        slot = nb + 2  # non-finite
        if wp.isfinite(y):
            if y < edges[0]:
                slot = nb
            elif y >= edges[nb]:
                slot = nb + 1
            elif is_uniform != 0:
                slot = wp.clamp(int(wp.floor((y - uniform_lo) * uniform_inv_w)), 0, nb - 1)
            else:
                lo = int(0)  # noqa: UP018 (warp: a dynamic loop variable, not a constant)
                hi = nb
                while hi - lo > 1:  # edges[lo] <= y < edges[hi]
                    mid = (lo + hi) // 2
                    if y >= edges[mid]:
                        lo = mid
                    else:
                        hi = mid
                slot = lo
        wp.atomic_add(counts, slot, wp.int64(1))

    return {"samples": samples_kernel, "histogram": histogram_kernel}
