"""studies.predictors: regime split and error definitions on a hand-made table."""

from __future__ import annotations

import sys
from pathlib import Path

import pandas as pd
import pytest

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:  # studies/ is a folder of the checkout, not of the installed package
    sys.path.insert(0, str(ROOT))

from studies import predictors  # noqa: E402


def test_per_point_errors_and_regimes():
    df = pd.DataFrame(dict(job=["a", "a", "b", "b"], hurst=0.5, rho=1e-3, sigma0=[1e-3, 1e-3, 0.5, 0.5],
                           seed=[0, 1, 0, 1], h_rms=0.01, gfmd=[0.05, 0.07, 0.001, 0.003],
                           x=[0.063, 0.063, 0.004, 0.004]))
    agg = predictors.per_point(df, ["x"]).set_index("job")
    assert agg.loc["a", "regime"] == "|g0|>=h_rms"
    assert agg.loc["a", "err_x"] == pytest.approx(0.063 / 0.06 - 1)  # relative to the seed mean
    assert agg.loc["b", "regime"] == "|g0|<h_rms"
    assert agg.loc["b", "err_x"] == pytest.approx((0.004 - 0.002) / 0.01)  # absolute, in h_rms
    md = predictors.markdown(agg.reset_index()[["job", "err_x"]], ".2f")
    assert md.splitlines()[0] == "| job | err_x |" and "| a | 0.05 |" in md


def test_markdown_escapes_pipes():
    md = predictors.markdown(pd.DataFrame({"regime": ["|g0|<h_rms"]}))
    assert md.splitlines()[2] == "| \\|g0\\|<h_rms |"
