"""Monte Carlo ensembles of the gap SDE of docs/model.md M5 with NVIDIA warp (one kernel for the GPU and the CPU).

The gap of one realisation obeys (Ito, magnification ``zeta`` as time, M5)::

    dg = [D1(zeta) + C2 (gamma0/rho) exp(-g/rho)] dzeta + sqrt(2 D2(zeta)) dW,   g(1) = rho ln(gamma0/(rho sigma0)),

with ``D1``, ``D2`` from :mod:`gapsweep.theory` (``D1 = dg0/dzeta``, ``D2 = C1 (...)``). Lengths are in the
model's absolute units (M1); the repulsion drift is the paper's ``C2 f_rep`` (a pressure used as a gap rate,
i.e. in units with ``E* = 1`` as in M5).

Numerics (see :mod:`gapsweep._sde_kernels`): the state is ``y = g - g0(zeta)`` (float32 keeps its precision
because ``|y| ~ h_rms`` while ``g0`` can be many ``h_rms``); the drift ``D1`` and the noise are integrated exactly
over each step (variances ``2 int D2`` by Gauss-Legendre quadrature of ``theory.diffusion``); the repulsion is
integrated exactly (``g -> rho ln(exp(g/rho) + c dzeta/rho)``) in a Strang split, so the stiff case of M7
(``rho = 5e-4``, ``C2 = 1``, ``dzeta = 0.1``) stays finite and accurate. Steps in ``zeta`` are uniform (the
paper's ``dzeta``) or geometric (``steps="log"``: ``zeta_{k+1}/zeta_k = 1 + dzeta``, since ``D1, D2 ~
zeta^(-2H-1)``). Normals are counter-based (Philox keyed by seed and realisation index): the same seed gives the
same samples for any batch split, launch shape or device.

Engines: warp kernels (CPU, and CUDA without cupy) and, for the split scheme on CUDA, the equivalent CUDA kernels
of :mod:`gapsweep._sde_cuda` (same scheme, same Philox stream; 1.08x a plain Euler-Maruyama kernel against
warp's 1.42x, docs/benchmarks.md). ``GAPSWEEP_SDE_ENGINE=warp`` keeps warp on CUDA too.
"""

from __future__ import annotations

import logging
import math
import os
import sys
import time
from collections.abc import Sequence
from contextlib import contextmanager
from dataclasses import dataclass, field

import numpy as np

from gapsweep import theory
from gapsweep.core import checks as chk
from gapsweep.core.extras import require

log = logging.getLogger(__name__)

__all__ = [
    "HistogramResult",
    "StepPlan",
    "gap_histogram",
    "gap_histogram_counts",
    "gap_samples",
    "plan_steps",
    "zeta_grid",
]

STEP_KINDS = ("uniform", "log")
SCHEMES = ("split", "euler")
_GL_X, _GL_W = np.polynomial.legendre.leggauss(8)
_MAX_STEPS = 50_000_000


# ----------------------------------------------------------------------------------------------- validation
def _dtype(dtype: str | type | np.dtype) -> str:
    try:
        name = np.dtype(dtype).name
    except TypeError:
        raise ValueError(f"dtype must be 'float32' or 'float64', got {dtype!r}") from None
    if name not in ("float32", "float64"):
        raise ValueError(f"dtype must be 'float32' or 'float64', got {dtype!r}")
    return name


def _devices(device: str | Sequence[str], scheme: str = "split") -> list[str]:
    """Validate device names ("cpu", "cuda", "cuda:N"; or a list of them) as "cpu" / "cuda:N". CUDA devices
    that the CUDA engine runs (gapsweep._sde_cuda) are checked with cupy, so warp is needed only where a warp
    kernel runs (the CPU, or ``GAPSWEEP_SDE_ENGINE=warp``, or another scheme)."""
    from gapsweep.gapdist import _sde_cuda

    names = [device] if isinstance(device, str) else list(device)
    if not names:
        raise ValueError("device must be a warp device name or a non-empty list of them")
    for d in names:
        if not isinstance(d, str) or not (d == "cpu" or d == "cuda" or d.startswith("cuda:")):
            raise ValueError(f"unknown device {d!r}: use 'cpu', 'cuda' or 'cuda:N'")
    if all(_sde_cuda.enabled(d, scheme) for d in names):
        return [_sde_cuda.device_name(d) for d in names]
    wp = _warp()
    out = []
    for d in names:
        try:
            out.append(str(wp.get_device(d)))
        except Exception as exc:  # warp raises RuntimeError/ValueError for absent devices
            raise ValueError(f"device {d!r} is not available ({exc})") from None
    return out


def _cuda_driver_present() -> bool:
    """Whether the NVIDIA driver library can be loaded (warp looks for the same names)."""
    import ctypes

    names = ("nvcuda.dll",) if sys.platform == "win32" else ("libcuda.so", "libcuda.so.1")
    for name in names:
        try:
            ctypes.CDLL(name)
        except OSError:
            continue
        return True
    return sys.platform == "darwin"  # no CUDA there; warp says nothing


@contextmanager
def _quiet_stderr():
    """Silence file descriptor 2 (native code's fprintf) for the duration of the block."""
    sys.stderr.flush()
    saved = os.dup(2)
    try:
        with open(os.devnull, "w") as null:
            os.dup2(null.fileno(), 2)
            yield
    finally:
        os.dup2(saved, 2)
        os.close(saved)


def _warp():
    """Import and initialise warp. Without an NVIDIA driver, warp's native "could not load the CUDA driver"
    warning (printed on every CPU-only run) is silenced and logged at debug level instead."""
    wp = require("warp", "the SDE ensembles (gapsweep.sde)")
    wp.config.log_level = max(wp.config.log_level, 30)  # no init banner (logging.WARNING)
    if _cuda_driver_present():
        wp.init()
    else:
        with _quiet_stderr():
            wp.init()
        log.debug("no NVIDIA driver found: warp runs on the CPU only")
    return wp


# ----------------------------------------------------------------------------------------------- step plan
def zeta_grid(zeta_end: float, dzeta: float = 0.01, steps: str = "uniform", n_steps: int | None = None
              ) -> np.ndarray:
    """Nodes ``1 = zeta_0 < ... < zeta_K = zeta_end`` of the integration in magnification (M5).

    ``steps="uniform"``: spacing ``dzeta`` (the last step is shortened to end on ``zeta_end``), as in the paper.
    ``steps="log"``: geometric, ``zeta_{k+1}/zeta_k = 1 + dzeta`` (rounded so that the last node is ``zeta_end``).
    ``n_steps`` overrides the count (``K``) of either sequence.
    """
    zeta_end = chk.positive(zeta_end, "zeta_end")
    if zeta_end < 1.0:
        raise ValueError(f"zeta_end must be >= 1 (magnification), got {zeta_end!r}")
    dzeta = chk.positive(dzeta, "dzeta")
    if steps not in STEP_KINDS:
        raise ValueError(f"steps must be one of {STEP_KINDS}, got {steps!r}")
    if zeta_end == 1.0:
        return np.ones(1)
    if n_steps is not None:
        k = chk.count(n_steps, "n_steps")
    elif steps == "uniform":
        k = math.ceil((zeta_end - 1.0) / dzeta - 1e-9)
    else:
        k = math.ceil(math.log(zeta_end) / math.log1p(dzeta) - 1e-9)
    if k > _MAX_STEPS:
        raise ValueError(f"dzeta={dzeta!r} gives {k} steps (> {_MAX_STEPS}); use a larger dzeta")
    if steps == "uniform":
        if n_steps is not None:
            z = np.linspace(1.0, zeta_end, k + 1)
        else:
            z = np.minimum(1.0 + dzeta * np.arange(k + 1), zeta_end)
            z[-1] = zeta_end
    else:
        z = np.exp(np.linspace(0.0, math.log(zeta_end), k + 1))
        z[0], z[-1] = 1.0, zeta_end
    return z


def _interval_integrals(fun, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``int_a^b fun(z) dz`` per interval, 8-point Gauss-Legendre in ``ln z`` (integrand smooth in ln z)."""
    la, lb = np.log(a), np.log(b)
    half = 0.5 * (lb - la)
    u = (0.5 * (la + lb))[:, None] + half[:, None] * _GL_X[None, :]
    z = np.exp(u)
    return half * np.sum(_GL_W[None, :] * fun(z) * z, axis=1)


@dataclass(frozen=True)
class StepPlan:
    """Per-step coefficients of the split scheme (float64), for ``K`` steps over ``zeta`` nodes.

    ``noise_sd[k]`` (K+1 values): standard deviation of the Gaussian added before repulsion step ``k`` (merged
    Strang half steps; the last one closes the final half step). ``wall[k]`` (K): ``ln(c dzeta_k/rho) -
    g0(zeta_mid_k)/rho`` with ``c = C2 gamma0/rho`` (``-inf`` when ``C2 = 0``). ``g0`` (K+1): field-theory mean
    gap at the nodes (M4, paper form, = flat gap + ``int D1``). ``variance``: ``2 int_1^zeta_end D2``, the exact
    variance of the gap when ``C2 = 0``.
    """

    zeta: np.ndarray
    noise_sd: np.ndarray
    wall: np.ndarray
    g0: np.ndarray
    variance: float
    rho: float
    c2: float
    params: dict = field(default_factory=dict)
    euler: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None

    @property
    def n_steps(self) -> int:
        return len(self.zeta) - 1

    @property
    def g0_end(self) -> float:
        return float(self.g0[-1])


def _check_common(sigma0, hurst, h_rms, rho, gamma0, lambda_l, lambda_s, e_star, zeta_end, c1, c2):
    sigma0 = chk.positive(sigma0, "sigma0")
    hurst = chk.hurst(hurst)
    h_rms = chk.nonnegative(h_rms, "h_rms")
    rho = chk.positive(rho, "rho")
    gamma0 = chk.positive(gamma0, "gamma0")
    lambda_l = chk.positive(lambda_l, "lambda_l")
    lambda_s = chk.positive(lambda_s, "lambda_s")
    if lambda_s > lambda_l:
        raise ValueError(f"lambda_s must be <= lambda_l, got lambda_s={lambda_s!r}, lambda_l={lambda_l!r}")
    e_star = chk.positive(e_star, "e_star")
    zeta_end = lambda_l / lambda_s if zeta_end is None else chk.positive(zeta_end, "zeta_end")
    if zeta_end < 1.0:
        raise ValueError(f"zeta_end must be >= 1 (magnification), got {zeta_end!r}")
    c1 = None if c1 is None else chk.nonnegative(c1, "c1")
    c2 = chk.nonnegative(c2, "c2")
    return dict(sigma0=sigma0, hurst=hurst, h_rms=h_rms, rho=rho, gamma0=gamma0, lambda_l=lambda_l,
                lambda_s=lambda_s, e_star=e_star, zeta_end=zeta_end, c1=c1, c2=c2)


def plan_steps(sigma0: float, *, hurst: float, h_rms: float, rho: float, gamma0: float, lambda_l: float,
               lambda_s: float, e_star: float = 1.0, zeta_end: float | None = None, c1: float | None = None,
               c2: float = 0.0, dzeta: float = 0.01, steps: str = "uniform", n_steps: int | None = None
               ) -> StepPlan:
    """Precompute the split-step coefficients of the M5 SDE on the nodes of :func:`zeta_grid` (float64).

    ``D1`` and ``D2`` come from :func:`gapsweep.theory.drift` / :func:`gapsweep.theory.diffusion`, integrated
    over each half step by Gauss-Legendre quadrature, so long (log) steps lose no accuracy in drift or variance.
    """
    p = _check_common(sigma0, hurst, h_rms, rho, gamma0, lambda_l, lambda_s, e_star, zeta_end, c1, c2)
    z = zeta_grid(p["zeta_end"], dzeta, steps, n_steps)
    k = len(z) - 1
    coef = dict(hurst=p["hurst"], h_rms=p["h_rms"], rho=p["rho"], lambda_l=p["lambda_l"], e_star=p["e_star"])
    flat = float(theory.flat_gap(p["sigma0"], rho=p["rho"], gamma0=p["gamma0"]))
    if k == 0:
        return StepPlan(z, np.zeros(1), np.full(0, -np.inf), np.array([flat]), 0.0, p["rho"], p["c2"], p)
    mid = 0.5 * (z[:-1] + z[1:])
    w = np.empty(2 * k + 1)  # z0, m0, z1, m1, ..., zK
    w[0::2], w[1::2] = z, mid

    def d1(x):
        return np.asarray(theory.drift(x, p["sigma0"], **coef))

    def d2(x):
        return np.asarray(theory.diffusion(x, p["sigma0"], c1=p["c1"], **coef))

    i1 = _interval_integrals(d1, w[:-1], w[1:])  # 2K half-step integrals of D1
    i2 = _interval_integrals(d2, w[:-1], w[1:])
    g0w = flat + np.concatenate(([0.0], np.cumsum(i1)))
    var = np.empty(k + 1)  # merged Strang half steps of the noise
    var[0] = i2[0]
    var[1:k] = i2[1:-1:2] + i2[2:-1:2]
    var[k] = i2[-1]
    noise_sd = np.sqrt(2.0 * var)
    if p["c2"] > 0.0:
        c = p["c2"] * p["gamma0"] / p["rho"]
        wall = np.log(c * np.diff(z) / p["rho"]) - g0w[1::2] / p["rho"]
    else:
        wall = np.full(k, -np.inf)
    dz = np.diff(z)
    c = p["c2"] * p["gamma0"] / p["rho"]
    euler = (d1(z[:-1]) * dz, np.sqrt(2.0 * d2(z[:-1]) * dz), c * dz)
    return StepPlan(z, noise_sd, wall, g0w[0::2], float(2.0 * np.sum(i2)), p["rho"], p["c2"], p, euler)


# ----------------------------------------------------------------------------------------------- launches
def _default_batch(device: str) -> int:
    return 1 << 24 if device.startswith("cuda") else 1 << 16


def _batches(n: int, batch: int, first: int = 0):
    start = 0
    while start < n:
        m = min(batch, n - start)
        yield first + start, start, m
        start += m


@dataclass(frozen=True)
class _Job:
    """Validated arguments shared by :func:`gap_samples` and :func:`gap_histogram_counts`."""

    plan: StepPlan
    n: int
    first: int
    k0: int
    k1: int
    devices: list[str]
    dtype: str
    scheme: str
    batch: int

    def launches(self):
        """``(device, global index, start, size)`` of each batch; batches go round-robin over the devices."""
        for i, (gidx, start, m) in enumerate(_batches(self.n, self.batch, self.first)):
            yield self.devices[i % len(self.devices)], gidx, start, m

    def kernels(self):
        """``(warp, real type, kernels of the scheme)`` for the job's arithmetic."""
        wp = _warp()
        from gapsweep.gapdist._sde_kernels import kernels

        allk = kernels(self.dtype)
        return wp, allk["real"], allk[self.scheme]


def _job(sigma0: float, *, n: int, seed: int, device: str | Sequence[str], dtype: str, first: int,
         batch: int | None, scheme: str, plan_kw: dict) -> _Job:
    """Validate the common arguments of the public samplers (same order and messages in both) and plan the steps."""
    n = chk.count(n, "n")
    scheme = _scheme(scheme)
    first = chk.count(first, "first", minimum=0)
    dtype = _dtype(dtype)
    k0, k1 = _seed_key(seed)
    devices = _devices(device, scheme)
    plan = plan_steps(sigma0, **plan_kw)
    batch = chk.count(batch, "batch") if batch is not None else _default_batch(devices[0])
    return _Job(plan, n, first, k0, k1, devices, dtype, scheme, batch)


def _seed_key(seed: int) -> tuple[int, int]:
    seed = chk.count(seed, "seed", minimum=0)
    if seed >= 1 << 64:
        raise ValueError(f"seed must be < 2**64, got {seed}")
    return seed & 0xFFFFFFFF, seed >> 32


def _coefficients(plan: StepPlan, scheme: str) -> tuple[np.ndarray, np.ndarray, np.ndarray, int]:
    """Per-step coefficient arrays (float64) of the kernels: split ``(s, b, rb, repulse)``, euler
    ``(sd, drift, cdz, 1)`` (see :mod:`gapsweep._sde_kernels`)."""
    k = plan.n_steps
    if scheme == "euler":
        if k == 0:
            drift, sd, cdz = np.zeros(1), np.zeros(1), np.zeros(1)
        else:
            drift, sd, cdz = plan.euler
        return np.asarray(sd), np.asarray(drift), np.asarray(cdz), 1
    if plan.c2 > 0.0 and k > 0:
        b_np = plan.wall
        rb_np = plan.rho * plan.wall
    else:
        b_np = rb_np = np.zeros(max(k, 1))
    return np.asarray(plan.noise_sd), np.asarray(b_np), np.asarray(rb_np), int(plan.c2 > 0.0 and k > 0)


def _coefficient_arrays(wp, plan: StepPlan, real, dtype: str, device: str, scheme: str):
    *arrs, repulse = _coefficients(plan, scheme)
    return (*[wp.array(np.asarray(a, dtype=dtype), dtype=real, device=device) for a in arrs], repulse)


def _common_inputs(plan: StepPlan, real, arrays) -> list:
    s, b, rb, repulse = arrays
    start = plan.g0[0]  # used by scheme="euler" only (it evolves g itself)
    return [plan.n_steps, s, b, rb, real(plan.rho), real(1.0 / plan.rho), repulse, real(start),
            real(plan.g0_end)]


def _scheme(scheme: str) -> str:
    if scheme not in SCHEMES:
        raise ValueError(f"scheme must be one of {SCHEMES}, got {scheme!r}")
    return scheme


def gap_samples(sigma0: float, *, hurst: float, h_rms: float, rho: float, gamma0: float, lambda_l: float,
                lambda_s: float, e_star: float = 1.0, zeta_end: float | None = None, c1: float | None = None,
                c2: float = 0.0, dzeta: float = 0.01, n: int = 10**6, seed: int = 0,
                device: str | Sequence[str] = "cpu", dtype: str = "float32", steps: str = "uniform",
                n_steps: int | None = None, first: int = 0, batch: int | None = None, scheme: str = "split"
                ) -> np.ndarray:
    """Final gaps ``g(zeta_end)`` [length] of ``n`` realisations of the M5 SDE (float64 array, length ``n``).

    ``zeta_end=None`` means ``zeta_s = lambda_l/lambda_s``; ``c1=None`` means ``C1 = H h_rms^2``. ``dtype`` is
    the arithmetic of the kernel (float32 default). ``first`` is the global index of the first realisation:
    realisations ``first .. first+n-1`` of a seed are the same numbers however they are split into calls or
    batches. ``device``: "cpu", "cuda", "cuda:N" or a list (batches go round-robin). ``scheme="split"`` (default,
    exact repulsion) or ``"euler"`` (the paper's Euler-Maruyama, a baseline that blows up on stiff cases).
    Raises ``FloatingPointError`` if a realisation failed (only the Euler baseline does that: a step broke its
    stability bound ``c dzeta exp(-g/rho)/rho <= 2`` or the gap became non-finite).
    """
    job = _job(sigma0, n=n, seed=seed, device=device, dtype=dtype, first=first, batch=batch, scheme=scheme,
               plan_kw=dict(hurst=hurst, h_rms=h_rms, rho=rho, gamma0=gamma0, lambda_l=lambda_l, lambda_s=lambda_s,
                            e_star=e_star, zeta_end=zeta_end, c1=c1, c2=c2, dzeta=dzeta, steps=steps,
                            n_steps=n_steps))
    out = _run_samples(job).astype(np.float64) + job.plan.g0_end
    bad = int(np.count_nonzero(~np.isfinite(out)))
    if bad:
        raise FloatingPointError(f"{bad} of {job.n} realisations failed (non-finite, or a scheme='euler' step broke "
                                 "its stability bound c dzeta exp(-g/rho)/rho <= 2: use scheme='split' or a "
                                 "smaller dzeta)")
    return out


def _cuda_engine(job: _Job, device: str):
    """The CUDA engine (:mod:`gapsweep._sde_cuda`) for ``device`` when it runs this job, else None."""
    from gapsweep.gapdist import _sde_cuda

    if not _sde_cuda.enabled(device, job.scheme):
        return None
    s, b, rb, repulse = _coefficients(job.plan, job.scheme)
    return _sde_cuda.Engine(device, job.dtype, s, b, rb, job.plan.rho, repulse, job.plan.n_steps)


def _run_samples(job: _Job) -> np.ndarray:
    plan = job.plan
    out = np.empty(job.n, dtype=job.dtype)
    engines = {d: _cuda_engine(job, d) for d in job.devices}
    warp_devs = [d for d, e in engines.items() if e is None]
    if warp_devs:
        wp, real, ks = job.kernels()
        per_dev = {d: _coefficient_arrays(wp, plan, real, job.dtype, d, job.scheme) for d in warp_devs}
    pending = []
    for d, gidx, start, m in job.launches():
        eng = engines[d]
        if eng is not None:
            pending.append((start, m, eng.samples(gidx, job.k0, job.k1, m), eng))
            continue
        buf = wp.empty(m, dtype=real, device=d)
        wp.launch(ks["samples"], dim=m, device=d,
                  inputs=[gidx, job.k0, job.k1, *_common_inputs(plan, real, per_dev[d]), buf])
        pending.append((start, m, buf, None))
    for start, m, buf, eng in pending:
        out[start:start + m] = buf.numpy() if eng is None else eng.to_host(buf)
    return out


@dataclass
class HistogramResult:
    """Gap histogram binned on the device.

    ``edges`` [length] (n_bins+1), ``counts`` per bin, ``below``/``above``: finite samples outside the edges,
    ``nonfinite``: realisations that failed (non-finite, or a ``scheme="euler"`` step broke the stability bound
    ``c dzeta exp(-g/rho)/rho <= 2``; never with the default split scheme), ``n``: realisations run,
    ``wall_time`` [s] (kernel launches + the final copy of the counts), ``plan``: the step coefficients.
    """

    edges: np.ndarray
    counts: np.ndarray
    below: int
    above: int
    nonfinite: int
    n: int
    wall_time: float
    plan: StepPlan

    @property
    def n_finite(self) -> int:
        return self.n - self.nonfinite

    @property
    def density(self) -> np.ndarray:
        """Density normalised to integrate to 1 over the bins (``counts / (sum(counts) * width)``)."""
        total = max(int(self.counts.sum()), 1)
        return self.counts / (total * np.diff(self.edges))


def _default_edges(plan: StepPlan, bins: int) -> np.ndarray:
    """Default range for ``bins`` equal bins: ``g0 -/+ 6 sd`` widened upwards by the repulsion's push."""
    sd = math.sqrt(max(plan.variance, 0.0))
    lo, hi = plan.g0_end - 6.0 * sd, plan.g0_end + 6.0 * sd
    if plan.c2 > 0.0 and plan.n_steps > 0:
        # deterministic floor of the repulsion after the whole run, g >= rho ln(c (zeta-1)/rho), reflected
        c = plan.c2 * plan.params["gamma0"] / plan.rho
        wall = plan.rho * math.log(c * (plan.zeta[-1] - 1.0) / plan.rho)
        lo = max(lo, wall - 30.0 * plan.rho)
        hi = max(hi, 2.0 * wall - (plan.g0_end - 6.0 * sd), wall + 6.0 * sd)
    if not hi > lo:
        hi = lo + max(abs(lo), 1.0) * 1e-6
    return np.linspace(lo, hi, bins + 1)


def gap_histogram_counts(sigma0: float, *, hurst: float, h_rms: float, rho: float, gamma0: float,
                         lambda_l: float, lambda_s: float, bins: int | np.ndarray = 200, e_star: float = 1.0,
                         zeta_end: float | None = None, c1: float | None = None, c2: float = 0.0,
                         dzeta: float = 0.01, n: int = 10**6, seed: int = 0,
                         device: str | Sequence[str] = "cpu", dtype: str = "float32", steps: str = "uniform",
                         n_steps: int | None = None, first: int = 0, batch: int | None = None,
                         scheme: str = "split") -> HistogramResult:
    """Histogram of ``g(zeta_end)`` over ``n`` realisations of the M5 SDE, binned on the device.

    Only the counts cross to the host, so ``n = 10^8`` needs no sample memory. ``bins``: number of equal bins
    over a default range (``g0 -/+ 6 sd``, widened for the repulsion) or increasing edges [length]. Other
    arguments as in :func:`gap_samples`.
    """
    job = _job(sigma0, n=n, seed=seed, device=device, dtype=dtype, first=first, batch=batch, scheme=scheme,
               plan_kw=dict(hurst=hurst, h_rms=h_rms, rho=rho, gamma0=gamma0, lambda_l=lambda_l, lambda_s=lambda_s,
                            e_star=e_star, zeta_end=zeta_end, c1=c1, c2=c2, dzeta=dzeta, steps=steps,
                            n_steps=n_steps))
    plan, dtype = job.plan, job.dtype
    if np.ndim(bins) == 0:
        edges = _default_edges(plan, chk.count(bins, "bins"))
    else:
        edges = np.asarray(bins, dtype=np.float64)
        if edges.ndim != 1 or edges.size < 2 or not np.all(np.isfinite(edges)) or np.any(np.diff(edges) <= 0):
            raise ValueError("bins must be a positive count or a 1-D array of >= 2 finite increasing edges")
    from gapsweep.gapdist._sde_cuda import N_EXTRA

    nb = edges.size - 1
    # bin in the y = g - g0 frame: the shift is exact in float64 on the host
    y_edges = (edges - plan.g0_end).astype(dtype)
    widths = np.diff(edges)
    is_uniform = int(np.allclose(widths, widths[0], rtol=1e-9, atol=0.0))
    lo, inv_w = float(y_edges[0]), nb / float(y_edges[-1] - y_edges[0])
    t0 = time.perf_counter()
    engines = {d: _cuda_engine(job, d) for d in job.devices}
    state = {}
    for d, eng in engines.items():
        if eng is not None:
            state[d] = (None, *eng.histogram_state(y_edges))
            continue
        wp, real, ks = job.kernels()
        state[d] = (_coefficient_arrays(wp, plan, real, dtype, d, job.scheme),
                    wp.array(y_edges, dtype=real, device=d),
                    wp.zeros(nb + N_EXTRA, dtype=wp.int64, device=d))
    for d, gidx, _start, m in job.launches():
        arrays, e_arr, counts = state[d]
        if engines[d] is not None:
            engines[d].histogram(gidx, job.k0, job.k1, m, e_arr, lo, inv_w, is_uniform, counts)
            continue
        wp.launch(ks["histogram"], dim=m, device=d,
                  inputs=[gidx, job.k0, job.k1, *_common_inputs(plan, real, arrays), e_arr,
                          real(lo), real(inv_w), is_uniform, counts])
    total = np.zeros(nb + N_EXTRA, dtype=np.int64)
    for d in job.devices:
        c = state[d][2]
        total += c.numpy() if engines[d] is None else engines[d].to_host(c).astype(np.int64)
    wall = time.perf_counter() - t0
    return HistogramResult(edges=edges, counts=total[:nb], below=int(total[nb]), above=int(total[nb + 1]),
                           nonfinite=int(total[nb + 2]), n=job.n, wall_time=wall, plan=plan)


def gap_histogram(sigma0: float, *, hurst: float, h_rms: float, rho: float, gamma0: float, lambda_l: float,
                  lambda_s: float, bins: int | np.ndarray = 200, **kwargs) -> tuple[np.ndarray, np.ndarray, int]:
    """``(edges, density, n_finite)`` of the final gaps (M5), binned on the device.

    ``density`` integrates to 1 over the bins (samples outside the edges are left out: widen ``bins`` or use
    :func:`gap_histogram_counts`, which also reports them). Keyword arguments as in :func:`gap_samples`.
    """
    r = gap_histogram_counts(sigma0, hurst=hurst, h_rms=h_rms, rho=rho, gamma0=gamma0, lambda_l=lambda_l,
                             lambda_s=lambda_s, bins=bins, **kwargs)
    return r.edges, r.density, r.n_finite
