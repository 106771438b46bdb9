"""`rodo calibrate`'s choice of the heading's reversion (rodo.validation.calibrate_consistency.fit_heading, by the
yaw's error growth): on runs whose pose errors follow the drift model with and without a reverting yaw, it turns
the reversion on only where the errors revert, whatever the other axes do, and the run's states replay it."""

import numpy as np
import pytest

from rodo.estimator.heading_reversion import heading_reversion_matrix
from rodo.estimator.lie import se3
from rodo.validation import calibrate_consistency as cc
from rodo.validation import replayed_states as rs
from tests.validation.synthetic_drives import stated_run, straight_drive

DT, N = 0.1, 800
SIGMA = np.array([3e-3, 3e-3, 3e-3, 2e-4, 2e-4, 1e-3])  # per scan: the yaw the largest rotation


def _run(seed: int, heading, scale=np.ones(6)):
    """(states, truth) of a drive whose absolute pose error follows the recursion with tau 0 and no drift rate,
    xi_k = Ad(R_k) M(heading) xi_{k-1} + delta_k, delta_k ~ N(0, diag((scale SIGMA)^2)) (M: the reversion,
    identity when heading is None), the states carrying diag(SIGMA^2) as P_relative."""
    rng = np.random.default_rng(np.random.SeedSequence([2026, 30, seed]))
    T_true = straight_drive(rng, N)
    x = np.zeros(19)
    errors = [x[:6].copy()]
    M = np.eye(19) if heading is None else heading_reversion_matrix(DT, heading)
    for k in range(1, N):
        x = M @ x
        x[:6] = se3.adjoint(T_true[k] @ se3.inverse(T_true[k - 1])) @ x[:6] + rng.normal(size=6) * SIGMA * scale
        errors.append(x[:6].copy())
    states, truth = stated_run(DT, T_true, errors, np.diag(SIGMA**2))
    return rs.replayed(states, 0.0, None, heading), truth


GRID = ((0.0, 0.0), (1.0, 50.0), (2.0, 50.0), (4.0, 50.0), (6.0, 50.0), (12.0, 50.0), (2.0, 20.0), (2.0, 200.0))


def _runs(seed: int, heading, scale=np.ones(6)):
    """Four runs pooled, as `rodo calibrate` pools several sequences: one drive's absolute pose error is one
    slowly varying path, and its median NEES ratio alone strays far from 1 (0.26 at the true model, off, on
    one of these drives)."""
    runs = [_run(4 * seed + i, heading, scale) for i in range(4)]
    return [s for s, _ in runs], [t for _, t in runs]


@pytest.mark.parametrize("seed", [1, 2])
def test_the_reversion_is_chosen_where_the_errors_revert(seed):
    """Errors with a yaw reverting at T_r 2 s to an anchor of 50 s: the fit turns the reversion on, with T_r
    within a factor 2, and the chosen point is the cheapest of the grid it reports (the yaw's E[e^2 / sigma^2]
    over the spans from 1 s on, 1, 2, 5, 10 and 20 s, and over the drive); errors without it: off."""
    states, truth = _runs(seed, (2.0, 50.0))
    heading, grid = cc.fit_heading(states, truth, 1.0, 0.0, headings=GRID)
    assert set(grid) == set(GRID) - {(12.0, 50.0)}  # T_r 12 s is more than a tenth of the 80 s drives
    assert all(len(r) == 6 for r in grid.values())
    assert 1.0 <= heading[0] <= 4.0, (heading, grid)
    assert cc.tau_cost(grid[heading]) == min(cc.tau_cost(r) for r in grid.values())
    # the reversion takes yaw variance away: the absolute yaw's ratio rises as T_r falls (at one anchor time)
    drive = [grid[(r, 50.0)][-1] for r in (1.0, 2.0, 4.0, 6.0)]
    assert drive == sorted(drive, reverse=True)

    states, truth = _runs(seed, None)
    heading, grid = cc.fit_heading(states, truth, 1.0, 0.0, headings=GRID)
    assert heading == (0.0, 0.0), (heading, grid)


def test_the_other_axes_do_not_move_the_choice():
    """The same reverting runs with the position errors three times what their covariance says, and without
    the reversion with the roll and pitch errors three times theirs: the 6-dof relative and absolute pose are far
    over-confident in both, but the choice, on the yaw alone, is as without them (on, T_r within a factor 2; off)."""
    heading, grid = cc.fit_heading(*_runs(1, (2.0, 50.0), np.array([3.0, 3.0, 3.0, 1.0, 1.0, 1.0])), 1.0, 0.0,
                                   headings=GRID)
    assert 1.0 <= heading[0] <= 4.0, (heading, grid)
    heading, grid = cc.fit_heading(*_runs(1, None, np.array([1.0, 1.0, 1.0, 3.0, 3.0, 1.0])), 1.0, 0.0,
                                   headings=GRID)
    assert heading == (0.0, 0.0), (heading, grid)


def test_the_default_grid_holds_off_and_a_range_of_reversions():
    """HEADINGS: off first, T_r from 1 to 12 s, every anchor slower than its reversion."""
    assert cc.HEADINGS[0] == (0.0, 0.0)
    assert {r for r, _ in cc.HEADINGS[1:]} == {1.0, 2.0, 3.0, 4.0, 6.0, 8.0, 12.0}
    assert all(a > r for r, a in cc.HEADINGS[1:])


def test_replayed_states_carry_the_reversion_to_the_span_measures():
    """`replayed` records the reversion it composed with, and the span measure (`odometry_nees`) uses the run's
    own when not told otherwise: the same as given explicitly, not the same as off."""
    from rodo.validation.odometry_consistency import odometry_nees

    states, truth = _run(3, (2.0, 50.0))
    np.testing.assert_array_equal(states["heading_reversion"], [2.0, 50.0])
    own = odometry_nees(states, truth, tau=0.0)["relative_span"]
    given = odometry_nees(states, truth, tau=0.0, heading=(2.0, 50.0))["relative_span"]
    off = odometry_nees(states, truth, tau=0.0, heading=(0.0, 0.0))["relative_span"]
    np.testing.assert_array_equal(own, given)
    assert not np.allclose(own[20:], off[20:])
