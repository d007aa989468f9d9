"""The shared argument validators (gapsweep/core/checks.py): types, ranges and the wording tests elsewhere match."""

import math

import numpy as np
import pytest

from gapsweep.core import checks as chk


@pytest.mark.parametrize("bad", [True, np.bool_(False), "1e-3", 1j, None, [1.0]])
def test_scalar_wrong_type_is_type_error(bad):
    for check in (chk.positive, chk.nonnegative, chk.hurst):
        with pytest.raises(TypeError, match="rho must be a real number"):
            check(bad, "rho")


def test_scalar_ranges():
    assert chk.positive(np.float32(2.5), "x") == 2.5 and type(chk.positive(3, "x")) is float
    assert chk.positive(np.array(0.5), "x") == 0.5  # 0-d arrays count as numbers
    assert chk.nonnegative(0, "x") == 0.0
    assert chk.hurst(0.3) == 0.3
    for v in (0.0, -1.0, math.nan, math.inf):
        with pytest.raises(ValueError, match="x must be finite and > 0"):
            chk.positive(v, "x")
    for v in (-1e-300, math.nan, math.inf):
        with pytest.raises(ValueError, match="x must be finite and >= 0"):
            chk.nonnegative(v, "x")
    for v in (0.0, 1.0, math.nan):
        with pytest.raises(ValueError, match=r"hurst must lie in \(0, 1\)"):
            chk.hurst(v)


def test_count():
    assert chk.count(np.int64(3), "n") == 3 and chk.count(4.0, "n") == 4
    assert chk.count(0, "first", minimum=0) == 0
    for bad in (2.5, True, "3", None):
        with pytest.raises(TypeError, match="n must be an integer"):
            chk.count(bad, "n")
    with pytest.raises(ValueError, match="n must be >= 2, got 1"):
        chk.count(1, "n", minimum=2)


def test_arrays():
    a = chk.positive_array([1, 2], "sigma0")
    assert a.dtype == np.float64 and a.tolist() == [1.0, 2.0]
    with pytest.raises(ValueError, match="sigma0 must be finite and > 0"):
        chk.positive_array([1.0, 0.0], "sigma0")
    with pytest.raises(ValueError, match=r"g must be finite \(no NaN or inf\)"):
        chk.finite_array([0.0, np.inf], "g")
    for bad in (np.zeros(3, complex), ["1", "2"], np.array([True]), [[1.0], [1.0, 2.0]]):
        with pytest.raises(TypeError, match=r"^g must be (a )?real"):
            chk.finite_array(bad, "g")


def test_square_heights():
    assert chk.square_heights(np.zeros((4, 4))).shape == (4, 4)
    for bad in (np.zeros((4, 5)), np.zeros((1, 1)), np.zeros(4)):
        with pytest.raises(ValueError, match="heights must be a square 2-D array"):
            chk.square_heights(bad)
    with pytest.raises(ValueError, match="NaN or inf"):
        chk.square_heights(np.full((4, 4), np.nan))
