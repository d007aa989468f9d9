"""Where each predictor was validated, and the warning it gives outside (docs/theory.md, "Validity").

A predictor called outside the domain on which it was checked against GFMD still answers, but says so once per
call with :class:`PredictorDomainWarning` (a ``UserWarning``: shown once per call site by Python's default
filter, silenced with ``warnings.simplefilter("ignore", PredictorDomainWarning)``). The domains are those the
held-out sets measured (docs/theory.md, "Validity"); a status column in a store says the same per row.
"""

from __future__ import annotations

import logging
import warnings

__all__ = ["PredictorDomainWarning", "warn_outside"]

log = logging.getLogger("gapsweep.theory.domain")


class PredictorDomainWarning(UserWarning):
    """A predictor was called outside the domain where it was validated against GFMD (docs/theory.md,
    "Validity"); its answer may be far off (the paper's field theory: up to +209 % at ``rho/h_rms = 0.05``)."""


def warn_outside(predictor: str, why: str, *, stacklevel: int = 3) -> None:
    """Warn once for this call that ``predictor`` runs outside its validated domain, ``why`` naming the parameter,
    its value and the bound."""
    log.debug("%s outside its validated domain: %s", predictor, why)
    warnings.warn(f"{predictor}: outside its validated domain: {why}", PredictorDomainWarning, stacklevel=stacklevel)
