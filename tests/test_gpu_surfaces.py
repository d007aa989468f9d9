"""A GPU GFMD task's synthetic surface made on its GPU (gapsweep.sweep.context, issue 38), on the CPU through
the numpy stand-in for cupy (tests/cupy_shim.py): the heights equal the host surface's to FFT round-off, the rms
values the host's to round-off, no host surface is made (nothing for the host threads to prefetch), the cache
keeps as many surfaces as the host cache; tasks that keep fields, file surfaces, CPU backends and
``GAPSWEEP_GPU_SURFACES=0`` keep the host path."""

from __future__ import annotations

import math

import numpy as np
import pytest

from gapsweep.sweep import context as C
from gapsweep.sweep import spec as specmod
from gapsweep.sweep import tasks as T

JOB = """
[job]
name = "gpu-surfaces"
[grid]
hurst = [0.45]
rho = [4e-2]
sigma0 = [1e-2]
seeds = [0, 1, 2, 3, 4, 5]
[surface]
lambda_l = 0.5
lambda_s = 0.05
rms_slope = 0.7
length = 2.0
[material]
gamma0 = 1e-3
[histogram]
bins = 16
[methods.gfmd]
n = 96
backend = "{backend}"
{extra}
"""


@pytest.fixture
def shim(monkeypatch):
    from tests import cupy_shim

    return cupy_shim.install_fresh(monkeypatch)


def _tasks(tmp_path, backend="cupy", extra=""):
    p = tmp_path / f"{backend}.toml"
    p.write_text(JOB.format(backend=backend, extra=extra))
    return [t for t in T.expand(specmod.load(p)) if t.method == "gfmd"]


def test_surface_made_on_the_gpu_equals_the_host_surface(shim, tmp_path):
    ts = _tasks(tmp_path)
    ctx = C.Context(gpu=0)
    t = ts[0]
    assert ctx.makes_on_gpu(t)
    h = ctx.surface_on_gpu(t, t.n)
    assert type(h).__module__ == "cupy" and h.shape == (96, 96)
    ref = C._make_surface(t, t.n, t.surface_params())
    assert np.max(np.abs(np.asarray(h) - ref)) <= 1e-13 * np.max(np.abs(ref))
    assert not ctx._surfaces  # no host surface made
    h_rms, g_rms = ctx.surface_rms(t, t.n)
    want = C._rms(ref, t.surface_params())
    assert math.isclose(h_rms, want[0], rel_tol=1e-12) and math.isclose(g_rms, want[1], rel_tol=1e-12)
    assert math.isclose(g_rms, 0.7, rel_tol=1e-9)  # the spec's rms slope (M2: the modes are normalised to it)
    assert not ctx._surfaces
    assert all(math.isnan(x) for x in ctx.surface_spectrum_rms(t, t.n)) and not ctx._surfaces
    assert ctx.surface_on_gpu(t, t.n) is h  # cached: a chain makes its surface once


def test_gpu_cache_keeps_as_many_as_the_host_cache_and_nothing_is_prefetched(shim, tmp_path):
    ts = _tasks(tmp_path)
    ctx = C.Context(gpu=0, max_surfaces=3)
    ctx.ahead(1)
    try:
        for t in ts:
            ctx.prefetch(t, t.n)
            ctx.surface_on_gpu(t, t.n)
            ctx.surface_rms(t, t.n)
        assert not ctx._ahead and not ctx._surfaces
        assert [k[1] for k in ctx._made_on_gpu] == [3, 4, 5]  # seeds: the last three
        assert {k[1] for k in ctx._rms} == {3, 4, 5}
    finally:
        ctx.close()


def test_host_path_where_the_gpu_does_not_make_the_surface(shim, tmp_path, monkeypatch):
    keep = _tasks(tmp_path, extra='keep_fields = { fields = ["gap"] }')[0]
    cpu = _tasks(tmp_path, backend="numpy")[0]
    ctx = C.Context(gpu=0)
    assert not ctx.makes_on_gpu(keep) and not ctx.makes_on_gpu(cpu)
    h = ctx.surface_on_gpu(keep, keep.n)  # the host surface, copied
    assert np.array_equal(np.asarray(h), ctx.surface(keep, keep.n)) and len(ctx._surfaces) == 1
    monkeypatch.setenv("GAPSWEEP_GPU_SURFACES", "0")
    t = _tasks(tmp_path)[0]
    assert not C.Context(gpu=0).makes_on_gpu(t)


def test_gfmd_task_on_a_gpu_made_surface(shim, tmp_path, monkeypatch):
    """A whole GFMD row (exponential law, cupy branch through the shim) on the surface made on the GPU: done, no
    host surface made, its mean gap within the solver's tolerance (1e-6) of the row on the host-made surface."""
    from gapsweep.sweep.methods.gfmd import run_gfmd

    t = _tasks(tmp_path)[0]
    rows = {}
    for flag in ("1", "0"):
        monkeypatch.setenv("GAPSWEEP_GPU_SURFACES", flag)
        ctx = C.Context(gpu=0)
        rows[flag], _ = run_gfmd(t, ctx, None)
        assert rows[flag].status == "done" and len(ctx._surfaces) == (0 if flag == "1" else 1)
    a, b = rows["1"].values, rows["0"].values
    assert abs(a["mean_gap"] - b["mean_gap"]) <= 1e-6 * abs(b["mean_gap"])
    assert math.isclose(a["g_rms"], b["g_rms"], rel_tol=1e-12) and math.isclose(a["h_rms"], b["h_rms"], rel_tol=1e-12)


def test_units_held_ahead_only_where_the_host_prepares_something(tmp_path, monkeypatch):
    """A worker holds units ahead only to make their surfaces on host threads: GPU units whose surfaces the GPU
    makes are not held ahead (they would be committed early, against the largest-first order)."""
    from types import SimpleNamespace

    from gapsweep.sweep import runner
    from gapsweep.sweep.schema import Unit

    gpu_made, keep = _tasks(tmp_path)[0], _tasks(tmp_path, extra='keep_fields = { fields = ["gap"] }')[0]
    r = SimpleNamespace(tasks=[gpu_made, keep], units=[Unit((0,), 1.0, True), Unit((1,), 1.0, True),
                                                       Unit((0,), 1.0, False), Unit((0,), 1.0, True, "batch")],
                        ctx=C.Context(gpu=0))
    assert runner._Run.ahead_ok(r) == [False, True, False, True]  # a batch stacks host surfaces
    monkeypatch.setenv("GAPSWEEP_GPU_SURFACES", "0")
    r.ctx = C.Context(gpu=0)
    assert runner._Run.ahead_ok(r) == [True, True, False, True]


@pytest.mark.gpu
def test_gpu_made_surface_on_a_gpu(tmp_path):
    """The same on a GPU (cupy, cuFFT; skipped without one): heights and rms values to round-off, a GFMD row
    within the solver's tolerance of the host-surface row."""
    from tests.gpu.cuda_skip import cupy_or_skip

    cupy = cupy_or_skip()
    from gapsweep.sweep.methods.gfmd import run_gfmd

    t = _tasks(tmp_path)[0]
    ctx = C.Context(gpu=0)
    h = ctx.surface_on_gpu(t, t.n)
    ref = C._make_surface(t, t.n, t.surface_params())
    assert isinstance(h, cupy.ndarray) and np.max(np.abs(cupy.asnumpy(h) - ref)) <= 1e-13 * np.max(np.abs(ref))
    got, want = ctx.surface_rms(t, t.n), C._rms(ref, t.surface_params())
    assert all(math.isclose(a, b, rel_tol=1e-12) for a, b in zip(got, want)) and not ctx._surfaces
    row, _ = run_gfmd(t, C.Context(gpu=0), None)
    host = C.Context(gpu=0)
    host.gpu_surfaces = False
    row_host, _ = run_gfmd(t, host, None)
    assert row.status == row_host.status == "done"
    assert abs(row.values["mean_gap"] - row_host.values["mean_gap"]) <= 1e-6 * abs(row_host.values["mean_gap"])
