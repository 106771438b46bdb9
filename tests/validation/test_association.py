"""Time association: mutual nearest stamps within a tolerance (`associate`) and its per-stamp form (`match_index`)."""

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from rodo.estimator.errors import InputError
from rodo.validation.association import associate, match_index


def _rng(seed):
    return np.random.default_rng(np.random.SeedSequence(seed))


_keep = st.lists(st.integers(0, 79), min_size=60, max_size=60, unique=True).map(lambda v: np.sort(v))


@given(steps=arrays(np.float64, (80,), elements=st.floats(0.05, 0.1)), keep_a=_keep, keep_b=_keep,
       jitter=arrays(np.float64, (60,), elements=st.floats(-0.9e-3, 0.9e-3)))
def test_associate_recovers_true_pairs_under_jitter(steps, keep_a, keep_b, jitter):
    t = np.cumsum(steps)
    t_a = t[keep_a]
    t_b = t[keep_b] + jitter
    ia, ib = associate(t_a, t_b)
    common = np.intersect1d(keep_a, keep_b)
    np.testing.assert_array_equal(keep_a[ia], common)
    np.testing.assert_array_equal(keep_b[ib], common)
    assert np.all(np.abs(t_a[ia] - t_b[ib]) <= 1e-3)


def test_associate_uses_each_stamp_once():
    # two stamps of a within tolerance of one stamp of b: only the nearer is matched
    ia, ib = associate([0.0, 0.0004, 1.0, 2.0], [0.0003, 1.0, 2.0], min_fraction=0)
    np.testing.assert_array_equal(ia, [1, 2, 3])
    np.testing.assert_array_equal(ib, [0, 1, 2])


@pytest.mark.parametrize("t_a, t_b, match", [
    ([0.0, 2.0, 1.0], [0.0, 1.0, 2.0], "t_a: times must strictly increase"),
    ([0.0, 1.0, 2.0], [0.0, np.nan, 2.0], "t_b: time nan at index 1"),
    ([0.0, 1.0, 2.0], [0.5, 1.5, 2.5], "only 0 time stamps match"),
    (np.arange(10.0), np.arange(10.0) + 0.002, "same sequence"),
    ([[0.0, 1.0]], [0.0, 1.0], "t_a: expected a 1-D"),
    ([], [0.0], "empty"),
])
def test_associate_errors_name_the_problem(t_a, t_b, match):
    with pytest.raises(InputError, match=match):
        associate(t_a, t_b)


def test_match_index_nearest_within_tolerance():
    idx = match_index([0.0, 0.1, 0.25, 0.3 + 1e-9], [0.0, 0.1, 0.2, 0.3])
    assert idx.tolist() == [0, 1, -1, 3] and idx.dtype == np.int64
    assert match_index([5.0, 6.0], [0.0, 1.0]).tolist() == [-1, -1]  # nothing matches: gaps, not an error


@given(st.lists(st.floats(0.0, 100.0), min_size=1, max_size=30, unique=True),
       st.lists(st.floats(0.0, 100.0), min_size=1, max_size=30, unique=True), st.floats(0.0, 0.5))
def test_match_index_is_associate_per_stamp(t_a, t_b, tolerance):
    t_a, t_b = np.sort(t_a), np.sort(t_b)
    idx = match_index(t_a, t_b, tolerance)
    ia, ib = associate(t_a, t_b, tolerance, min_matches=0, min_fraction=0)
    assert np.flatnonzero(idx >= 0).tolist() == ia.tolist() and idx[ia].tolist() == ib.tolist()
    matched = idx >= 0
    assert np.all(np.abs(t_a[matched] - t_b[idx[matched]]) <= tolerance)
    # each matched pair is the nearest stamp of the other list
    for i in np.flatnonzero(matched):
        assert np.abs(t_b - t_a[i]).min() == np.abs(t_b[idx[i]] - t_a[i])
