"""Post-hoc analysis of gapsweep stores (docs/analysis.md): aggregation over seeds, theory-vs-simulation
comparisons, the paper's figures (docs/model.md M6), an xarray view, and the report (``gapsweep report STORE...
--out DIR``). A consumer of stores on the sweep's side: physics and the sweep never import it
(docs/architecture.md).

Modules: :mod:`gapsweep.analysis.aggregate`, :mod:`gapsweep.analysis.compare`, :mod:`gapsweep.analysis.figures`,
:mod:`gapsweep.analysis.contact`, :mod:`gapsweep.analysis.dataset`, :mod:`gapsweep.analysis.report`. The research
scripts that built docs/results/ (``studies/`` of the checkout, e.g. ``python -m studies.make_results``) are not
part of the package.
"""

from gapsweep.analysis.aggregate import aggregate_histograms, aggregate_mean_gap, merge_histograms, status_counts
from gapsweep.analysis.compare import agreement_regions, histogram_distance, histogram_distances, theory_vs_gfmd

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
