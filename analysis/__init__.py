"""Post-hoc analysis of gapsweep stores (docs/analysis.md): aggregation over seeds, theory-vs-simulation
comparisons, the
paper's figures (docs/model.md M6), an xarray view, and the report (``gapsweep report STORE... --out DIR``).

Modules: :mod:`analysis.aggregate`, :mod:`analysis.compare`, :mod:`analysis.figures`, :mod:`analysis.dataset`,
:mod:`analysis.report`, :mod:`analysis.make_results` (docs/results/ from the full jobs). See docs/analysis.md.
"""

from analysis.aggregate import aggregate_histograms, aggregate_mean_gap, merge_histograms, status_counts
from analysis.compare import agreement_regions, histogram_distance, histogram_distances, theory_vs_gfmd

__all__ = [
    "aggregate_histograms",
    "aggregate_mean_gap",
    "agreement_regions",
    "histogram_distance",
    "histogram_distances",
    "merge_histograms",
    "status_counts",
    "theory_vs_gfmd",
]
