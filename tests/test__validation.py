"""The boundary checks shared by the library (mmsnap_graph/_validation.py)."""

import numpy as np
import pytest
from scipy.stats import chi2

from mmsnap_graph._validation import check_count, check_probability, chi2_gate
from mmsnap_graph.errors import ConfigurationError, ValidationError


@pytest.mark.parametrize("value", [1, 7, np.int32(3), np.int64(2**40)])
def test_check_count_accepts_integers(value):
    out = check_count(value, "n")
    assert out == value and type(out) is int


@pytest.mark.parametrize("value, match", [
    (True, "n=True must be an integer, got bool"), (np.bool_(True), "integer"),
    (2.0, "n=2.0 must be an integer, got float"), ("3", "got str"), (None, "integer"),
    (0, r"n=0 must be an integer >= 1"), (np.int64(-1), ">= 1"),
])
def test_check_count_rejects_non_integers_and_small_values(value, match):
    with pytest.raises(ValidationError, match=match):
        check_count(value, "n")


def test_check_count_bounds_and_error_class():
    assert check_count(0, "n", 0) == 0
    assert check_count(6, "order", 1, 6) == 6
    with pytest.raises(ValidationError, match=r"order=7 must be an integer in \[1, 6\]"):
        check_count(7, "order", 1, 6)
    with pytest.raises(ConfigurationError, match="max_misses"):
        check_count(0, "max_misses", error=ConfigurationError)


@pytest.mark.parametrize("value", [1e-9, 0.5, 0.999, np.float32(0.25), np.float64(0.9)])
def test_check_probability_accepts_open_interval(value):
    assert check_probability(value, "p") == pytest.approx(float(value))


@pytest.mark.parametrize("value", [0, 1, 0.0, 1.0, -0.1, 1.5, np.nan, np.inf, True, "0.5", None])
def test_check_probability_rejects_outside_open_interval(value):
    with pytest.raises(ValidationError, match="p must be"):
        check_probability(value, "p")


def test_chi2_gate_is_the_keep_quantile():
    assert chi2_gate(0.999, 2) == pytest.approx(-2 * np.log(1 - 0.999))
    assert chi2_gate(0.95, 3) == pytest.approx(chi2.ppf(0.95, 3))
    assert isinstance(chi2_gate(0.9, 4), float)
    rows = chi2_gate(0.99, np.array([1, 3, 5]))
    np.testing.assert_allclose(rows, chi2.ppf(0.99, [1, 3, 5]))
    # A larger keep probability is a wider gate.
    assert chi2_gate(0.9999, 3) > chi2_gate(0.999, 3)


@pytest.mark.parametrize("p, dof, match", [
    (1e-3 - 1, 3, r"gate_probability must be in \(0, 1\), got -0.999"), (1.0, 3, "gate_probability"),
    (0.99, 0, "dof must be > 0"), (0.99, [], "dof"), (0.99, np.nan, "dof"),
])
def test_chi2_gate_rejects_bad_input(p, dof, match):
    with pytest.raises(ValidationError, match=match):
        chi2_gate(p, dof)


def test_frame_steps_are_exact_across_the_ends_of_int64():
    from mmsnap_graph._validation import frame_steps

    big = np.iinfo(np.int64)
    f = np.array([big.min, big.min + 3, -1, 5, big.max, 0], dtype=np.int64)
    assert frame_steps(f).tolist() == [3, 2 ** 63 - 4, 6, big.max - 5, -big.max]
    assert frame_steps([big.min, big.max]).tolist() == [big.max]  # 2^64 - 1, saturated
    assert frame_steps([7]).size == 0
    np.testing.assert_array_equal(frame_steps(np.arange(5) * 3), np.diff(np.arange(5) * 3))


def test_frame_steps_fast_path_matches_the_exact_steps():
    """Frames less than 2^63 apart take np.diff; the result equals the
    saturated exact steps, up to the span where a step could wrap."""
    from mmsnap_graph._validation import frame_steps

    big = np.iinfo(np.int64)
    rng = np.random.default_rng(0)
    f = rng.integers(-2**40, 2**40, size=200)
    np.testing.assert_array_equal(frame_steps(f), np.diff(f))
    assert frame_steps(f).dtype == np.int64
    edge = np.array([-1, big.max], dtype=np.int64)  # 2^63 apart: the exact path
    assert frame_steps(edge).tolist() == [big.max]
    assert frame_steps(np.array([0, big.max])).tolist() == [big.max]  # the widest fast one
    assert frame_steps(np.array([], dtype=np.int64)).size == 0


@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf])
def test_check_finite_names_the_first_non_finite_entry(bad):
    from mmsnap_graph._validation import check_finite

    arr = np.zeros((4, 2))
    arr[2, 1] = bad
    with pytest.raises(ValidationError, match=r"x must be finite, got .* at index \(2, 1\)"):
        check_finite(arr, "x")
    arr[0, 0] = np.inf if bad != np.inf else -np.inf  # sum nan: inf - inf
    with pytest.raises(ValidationError, match=r"at index \(0, 0\)"):
        check_finite(arr, "x")


def test_check_finite_returns_its_input_and_warns_of_nothing():
    import warnings

    from mmsnap_graph._validation import check_finite

    arr = np.full(4, np.finfo(float).max)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert check_finite(arr, "x") is arr
        ints = np.array([2**62, 2**62, 2**62])
        assert check_finite(ints, "x") is ints
        with pytest.raises(ValidationError):
            check_finite(np.array([np.inf, -np.inf]), "x")
