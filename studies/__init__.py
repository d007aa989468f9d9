"""Research scripts that made ``docs/results/`` (not part of the installed package; run from a checkout, e.g.
``python -m studies.predictors_heldout --set heldout --out docs/results``). They use the public API of gapsweep
and :mod:`gapsweep.analysis`; their outputs and the exact command lines are listed in docs/results/README.md."""
