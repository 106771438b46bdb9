"""Alignment by the first pose, in both pose conventions (T_world_vehicle and the state's T_vehicle_world)."""

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from rodo.estimator.errors import InputError
from rodo.estimator.lie import se3
from rodo.validation.alignment import align_to_first, truth_in_estimator_frame
from tests.strategies import twists


def _trajectory(xis):
    """T_world_vehicle poses: a chain of the given steps from an arbitrary first pose."""
    out = [se3.exp(xis[0])]
    for xi in xis[1:]:
        out.append(out[-1] @ se3.exp(xi))
    return np.stack(out)


@given(st.lists(twists("any", 20.0), min_size=2, max_size=6), twists("any", 50.0))
def test_align_to_first_starts_together_and_keeps_relative_poses(xis, target):
    T_a = _trajectory(xis)
    T_b0 = se3.exp(target)
    aligned = align_to_first(T_a, T_b0)
    np.testing.assert_allclose(aligned[0], T_b0, atol=1e-9)
    # one rigid change of world frame: relative poses T_v0_vk are unchanged
    rel_a = se3.inverse(T_a[0]) @ T_a
    rel_b = se3.inverse(aligned[0]) @ aligned
    np.testing.assert_allclose(rel_b, rel_a, atol=1e-8)


def test_align_to_first_rejects_non_finite_poses():
    T = np.stack([np.eye(4)] * 3)
    T[1, 0, 3] = np.nan
    with pytest.raises(InputError, match="T_a_vehicle"):
        align_to_first(T, np.eye(4))


@given(st.lists(twists("any", 20.0), min_size=2, max_size=6))
def test_truth_in_estimator_frame_is_align_to_first_of_state_poses(xis):
    T_vehicle_world = se3.inverse(_trajectory(xis))
    rel = truth_in_estimator_frame(T_vehicle_world)
    np.testing.assert_allclose(rel[0], np.eye(4), atol=1e-12)
    expected = se3.inverse(align_to_first(se3.inverse(T_vehicle_world), np.eye(4)))
    np.testing.assert_allclose(rel, expected, atol=1e-8)
