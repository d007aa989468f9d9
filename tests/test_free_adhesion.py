"""Free-boundary adhesion at tension (issue 36, item 4; docs/gfmd.md "Tensile loads", "Periodic or free
boundaries"): ``solve(..., periodic=False)`` at a tensile load follows the load from zero (the periodic
minimiser's continuation, stall test and pull-off bracket) and says "detached" only where no attached equilibrium
exists. Reference: an independent fine continuation by warm starts (each step a plain solve from the previous
equilibrium that converges without any continuation of its own). Also ``solve_path`` and a sweep on a measured
(free) map: ``last_attached_load`` is finite on the detached row and the figure marks the detached load."""

from __future__ import annotations

import math
import warnings

import numpy as np
import pytest

from gapsweep.gfmd import solve, solve_path
from gapsweep.surface import self_affine

WORK, RHO = 5e-4, 1.5 / 64
P_STAR = WORK / (math.e * RHO)  # the law's largest tension


def _map(seed: int, nx: int = 40, ny: int = 32) -> tuple[np.ndarray, tuple[float, float]]:
    h = self_affine(64, 0.8, lambda_l=0.5, lambda_s=4 / 64, seed=seed, rms_slope=1.0)[:nx, 3 : 3 + ny]
    return h, (nx / 64, ny / 64)


def _kw(length: tuple[float, float]) -> dict:
    return dict(interaction="adhesive", work=WORK, rho=RHO, periodic=False, length=length, tol=1e-8)


def _fine_continuation(h: np.ndarray, kw: dict, ds: float) -> tuple[float, dict[float, float]]:
    """Last load of a warm-started path in steps ``ds`` that converges step by step directly (no continuation
    inside ``solve``), and the mean gap at each load; the pull-off lies in ``(last - ds, last]``."""
    prev = solve(h, sigma0=0.0, **kw)
    assert prev.converged
    s, gaps = 0.0, {}
    while True:
        r = solve(h, sigma0=s - ds, initial=prev, **kw)
        direct = "continuation_from" not in r.diagnostics  # converged from the warm start itself
        if not (r.converged and direct) or abs(r.contact_area - prev.contact_area) > 0.1:
            return s, gaps
        s -= ds
        gaps[s] = r.mean_gap
        prev = r


@pytest.mark.validation
@pytest.mark.parametrize(("seed", "shape", "aspect"), [(7, (40, 32), 1.0), (12, (40, 32), 1.0), (5, (37, 29), 1.3)])
def test_free_tensile_loads_detach_only_beyond_pull_off(seed: int, shape: tuple[int, int], aspect: float) -> None:
    """From the default start, no load is reported detached where the fine warm-started continuation finds an
    attached equilibrium (before: 2 of 5 such loads on seed 7 "detached"), the attached answer is that
    continuation's (mean gap 1e-6 relative), and the pull-off bracket ``[last_attached_load - min_step,
    last_attached_load]`` overlaps the continuation's ``(last - ds, last]``. Every load of that continuation is
    checked; also an odd map with non-square pixels (``aspect``: dy/dx)."""
    h, length = _map(seed, *shape)
    kw = _kw((length[0], length[1] * aspect))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        ds = 0.02 * P_STAR
        last, gaps = _fine_continuation(h, kw, ds)
        assert last < -5 * ds  # the map holds a tension: the test is not vacuous
        for s0 in sorted(gaps):
            r = solve(h, sigma0=s0, **kw)
            assert r.status == "converged", (s0, r.status, r.diagnostics.get("last_attached_load"))
            assert r.mean_gap == pytest.approx(gaps[s0], rel=1e-6, abs=1e-9)
            assert r.diagnostics["last_attached_load"] == s0
        for s0 in (last - 1.5 * ds, last - 4 * ds):  # beyond pull-off: no attached equilibrium
            r = solve(h, sigma0=s0, **kw)
            assert r.status == "detached" and not r.converged
            la, step = r.diagnostics["last_attached_load"], r.diagnostics["min_step"]
            assert last - ds - step <= la <= last + step, (la, last, ds, step)


def test_free_solve_path_keeps_contact_to_pull_off() -> None:
    """Coarse steps of solve_path (warm starts) on a free map: every load before the fine continuation's pull-off
    converges; the path stops "detached" beyond it, with the bracket on the detached result."""
    h, length = _map(7)
    kw = _kw(length)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        last, _ = _fine_continuation(h, kw, 0.05 * P_STAR)
        loads = np.linspace(0.0, 1.6 * last, 9)
        path = solve_path(h, loads, **kw)
    before = [r for r in path.results if r.sigma0 >= last]
    assert all(r.converged for r in before)
    assert path.stopped == "detached" and path.results[-1].sigma0 < last - 0.05 * P_STAR
    assert path.results[-1].diagnostics["last_attached_load"] <= last + 1e-12


@pytest.mark.timeout(300)
def test_sweep_on_free_map_gives_bracket_and_marks_detachment(tmp_path) -> None:
    """A sweep on a measured-style (non-periodic) map with the adhesive law: the detached row carries a finite
    ``last_attached_load`` (before: NaN, free solves had no continuation) and the contact figure marks the
    detached load and the bracket."""
    from gapsweep import runner, store
    from gapsweep.analysis import contact

    h, (lx, ly) = _map(7, 32, 24)
    np.save(tmp_path / "map.npy", h)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        last, _ = _fine_continuation(h, _kw((lx, ly)), 0.05 * P_STAR)
    loads = [0.0, round(0.5 * last, 8), round(1.5 * last, 8)]
    (tmp_path / "job.toml").write_text(f"""
[job]
name = "free-adhesion"
description = "adhesion on a non-periodic map into tension"

[grid]
rho = [{RHO!r}]
sigma0 = {loads!r}

[surface]
kind = "file"
path = "map.npy"
unit = "m"
pixel_size = {1 / 64!r}
periodic = false

[interaction]
kind = "adhesive"
work = {WORK!r}

[material]
e_star = 1.0

[histogram]
bins = 16

[methods.gfmd]
tol = 1e-8
backend = "numpy"
order = "decreasing"
""")
    path = tmp_path / "s.h5"
    runner.run(tmp_path / "job.toml", path, progress="none", mpi="off")
    df = store.read(path).sort_values("sigma0")
    det = df[df["sigma0"] == loads[2]].iloc[0]
    att = df[df["sigma0"] == loads[1]].iloc[0]
    assert att["status"] == "done" and det["status"] == "not_converged" and "detached" in det["message"]
    assert math.isfinite(det["last_attached_load"])
    assert loads[2] < det["last_attached_load"] <= last + 0.05 * P_STAR
    points, persson = contact.tables(df.assign(interaction="adhesive", job="free-adhesion"))
    fig = contact.fig_contact(points, persson, job="free-adhesion", info={"units": {}, "file": True})
    labels = [ln.get_label() for ln in fig.axes[0].get_lines()]
    assert "detached (beyond pull-off)" in labels and "last attached load (pull-off bracket)" in labels
    xs = {ln.get_label(): ln.get_xdata()[0] for ln in fig.axes[0].get_lines() if ln.get_label().startswith(("det",
                                                                                                            "last"))}
    assert xs["detached (beyond pull-off)"] == pytest.approx(loads[2])
    assert xs["last attached load (pull-off bracket)"] == pytest.approx(det["last_attached_load"])


def test_free_tensile_answers_are_unit_invariant() -> None:
    """Lengths x 1e-6 and pressures x 1e9 (um and GPa-like scales) or x 1e3 / 1e-3: the same dimensionless mean
    gaps, statuses and pull-off bracket as in model units."""
    h, (lx, ly) = _map(12)
    ref = None
    for lf, pf in ((1.0, 1.0), (1e-6, 1e9), (1e3, 1e-3)):
        kw = dict(interaction="adhesive", work=WORK * lf * pf, rho=RHO * lf, periodic=False, length=(lx * lf, ly * lf),
                  tol=1e-8, e_star=pf)
        out = []
        for s in (-0.1, -0.35, -1.2):
            r = solve(h * lf, sigma0=s * P_STAR * pf, **kw)
            la = r.diagnostics["last_attached_load"] / (P_STAR * pf)
            out.append((r.status, r.mean_gap / lf if r.converged else math.nan, la))
        if ref is None:
            ref = out
            assert [o[0] for o in out] == ["converged", "converged", "detached"]
            continue
        for a, b in zip(out, ref):
            assert a[0] == b[0]
            assert a[1] == pytest.approx(b[1], rel=1e-7, nan_ok=True)
            assert a[2] == pytest.approx(b[2], rel=1e-6)
