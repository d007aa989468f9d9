"""Result record of a GFMD run (docs/model.md M3, M5)."""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from gapsweep.gfmd._ops import _is_cupy

FIELDS = ("gap", "pressure", "displacement")


def final_status(status: str, fields_ok: bool, residual: float, load_error: float, tol: float) -> tuple[str, bool]:
    """The status a solver reports for its returned fields: "non_finite" when they (or the residual) are not
    finite, "stalled" when the iteration said "converged" but the fields miss ``tol`` (residual or load error);
    else the iteration's own. Returns ``(status, within)``, ``within``: the fields are finite and meet ``tol``
    (the solver's ``converged`` is ``status == "converged"``, or ``within`` where the hard wall judges its fields
    alone). One rule for every GFMD solver: a numerical failure is never stored as success."""
    if not fields_ok:
        status = "non_finite"
    within = fields_ok and residual <= tol and load_error <= tol
    if status == "converged" and not within:
        status = "stalled"
    return status, within


def fields_to_host(mover: Any, host: Any, gap: Any, pressure: Any, displacement: Any) -> tuple[Any, Any, Any]:
    """``(gap, pressure, displacement)`` with the fields ``host`` asks for (:func:`host_fields`) copied to the
    host by ``mover.to_host_many`` (a grid or FFT pair) in one transfer; the others returned as they are."""
    fields = dict(zip(FIELDS, (gap, pressure, displacement)))
    fields.update(mover.to_host_many({k: fields[k] for k in host_fields(host)}))
    return fields["gap"], fields["pressure"], fields["displacement"]


def host_fields(host: Any) -> tuple[str, ...]:
    """The result fields a caller wants on the host: ``True`` all of :data:`FIELDS`, ``False`` none (a cupy
    run keeps them on the GPU), or an iterable of names from :data:`FIELDS` (only those are copied; the others
    stay where they were computed)."""
    if host is True or host is False:
        return FIELDS if host else ()
    if isinstance(host, str) or not hasattr(host, "__iter__"):
        raise ValueError(f"host must be True, False or a list of field names from {FIELDS}, got {host!r}")
    names = tuple(host)
    bad = [k for k in names if k not in FIELDS]
    if bad:
        raise ValueError(f"host: unknown field(s) {bad}; allowed: {', '.join(FIELDS)}")
    return tuple(k for k in FIELDS if k in names)


def law_result(law: Any, t_start: float, **fields: Any) -> GFMDResult:
    """The :class:`GFMDResult` of a solve with interaction law ``law`` (every minimiser's): the law's name,
    parameters and contact criterion, the wall time since ``t_start`` (``time.perf_counter()``), and ``fields``,
    the others (a field named there overrides the law's, e.g. the capped hard wall's ``params``)."""
    own = {"interaction": law.name, "params": law.params(), "contact_criterion": law.contact_criterion}
    return GFMDResult(wall_time=time.perf_counter() - t_start, **{**own, **fields})


def _namespace(a: Any) -> Any:
    if _is_cupy(a):
        import cupy

        return cupy
    return np


def _host(a: Any) -> np.ndarray:
    return a.get() if _is_cupy(a) else np.asarray(a)


@dataclass
class GFMDResult:
    """Equilibrium of one GFMD run. Fields are numpy arrays on the host (``nx x ny``; cupy arrays for
    ``host=False`` GPU runs), lengths in units of ``length``, pressures in the units of ``sigma0``.

    ``iterations``: force evaluations (= rfft2/irfft2 pairs). ``status``: "converged", "max_iter",
    "non_finite" (a non-finite value appeared; the fields are those of the last finite state) or "stalled"
    (round-off floor: no descent direction left above ``tol``, or the residual recomputed from the returned
    fields is above ``tol``). ``residual``: the convergence measure of the law's minimiser evaluated on the
    returned fields (docs/gfmd.md, "Convergence"); ``converged`` iff it and ``load_error`` are ``<= tol``.

    Quantities (docs/gfmd.md, "Quantities"): ``contact_area`` (fraction of the nominal area, by the law's
    ``contact_criterion``), ``elastic_energy`` (stored elastic energy per nominal area,
    ``(E*/4) sum_q q |u~(q)|^2``, pressure x length), ``interaction`` (the law's name) with its ``params``,
    ``diagnostics`` (the minimiser's further convergence measures, e.g. complementarity for the hard wall).
    ``periodic``: False for a finite map solved with free boundaries (``solve(..., periodic=False)``).
    ``plastic_area`` and ``plastic_displacement``: a capped hard wall's plastic set (``solve(..., hardness=H)``,
    docs/gfmd.md "Plastic contact (pressure cap)"). ``substrate``: an elastic layer's parameters (``solve(...,
    thickness=t)``), empty for the half-space.
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
    length: float | tuple[float, float] = 1.0
    tol: float = math.nan
    history: list[float] = field(default_factory=list, repr=False)
    interaction: str = "exponential"
    params: dict[str, float] = field(default_factory=dict)
    contact_area: float = math.nan
    elastic_energy: float = math.nan
    contact_criterion: str = ""
    diagnostics: dict[str, float] = field(default_factory=dict)
    periodic: bool = True  # False: a finite map with free boundaries (docs/gfmd.md)
    # The hard wall with a pressure cap (solve(..., hardness=H); gfmd._plastic): fraction of the nominal area at
    # p = H, and the plastic displacement field (length; 0 off the plastic set). NaN / None without a cap.
    plastic_area: float = math.nan
    plastic_displacement: Any = field(default=None, repr=False)
    # The substrate: {} for the half-space; a layer's {"thickness", "poisson", "bottom", "mean_compression"}
    # (gfmd.substrates, docs/model.md "Elastic layer on a rigid base").
    substrate: dict[str, Any] = field(default_factory=dict)

    @property
    def n(self) -> int:
        """Grid points along x (axis 0); see :attr:`shape` for rectangular grids."""
        return int(self.gap.shape[0])

    @property
    def shape(self) -> tuple[int, int]:
        return (int(self.gap.shape[0]), int(self.gap.shape[1]))

    def contact_atom(self) -> float:
        """Fraction of the grid at exactly ``g = 0`` (hard-wall contact; 0 for smooth laws)."""
        xp = _namespace(self.gap)
        return float(xp.count_nonzero(self.gap == 0.0)) / self.gap.size

    def gap_histogram(self, bins: Any = 100, range: tuple[float, float] | None = None
                      ) -> tuple[np.ndarray, np.ndarray, float]:
        """``(edges, density, atom)`` of the gap (M5): ``atom`` is the fraction at exactly ``g = 0`` (the hard
        wall's contact), ``density`` the histogram of the other points, normalised to integrate to
        ``1 - atom`` over the bins (so atom + density together integrate to 1)."""
        return _atom_histogram(self.gap, bins, range)

    def pressure_histogram(self, bins: Any = 100, range: tuple[float, float] | None = None
                           ) -> tuple[np.ndarray, np.ndarray, float]:
        """``(edges, density, atom)`` of the local pressure: ``atom`` is the fraction at exactly ``p = 0`` (the
        hard wall's free surface), ``density`` the histogram of the other points normalised to ``1 - atom``."""
        return _atom_histogram(self.pressure, bins, range)

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


def _atom_histogram(a: Any, bins: Any, range: tuple[float, float] | None) -> tuple[np.ndarray, np.ndarray, float]:
    """``(edges, density, atom)`` of field ``a``: ``atom`` the fraction of points at exactly 0, ``density`` the
    histogram of the others over the whole grid's size (atom + density integrate to 1), binned where ``a``
    lives and returned on the host."""
    xp = _namespace(a)
    rest = a[a != 0.0]
    atom = 1.0 - rest.size / a.size
    if rest.size == 0:
        edges = np.linspace(0.0, 1.0, (bins if isinstance(bins, int) else 1) + 1)
        return edges, np.zeros(edges.size - 1), atom
    counts, edges = xp.histogram(rest, bins=bins, range=range)
    dens = counts / (a.size * xp.diff(edges))
    return _host(edges), _host(dens), atom
