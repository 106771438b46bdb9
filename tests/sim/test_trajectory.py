"""Trajectories: exact integration (Magnus vs DOP853), segments' varpi_dot honoured, profile properties."""

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st
from scipy.integrate import solve_ivp

from rodo.estimator.errors import InputError
from rodo.estimator.lie import se3
from rodo.sim import trajectory as tr
from tests.strategies import hypothesis_rngs


def _rate(limit: float):
    """Floats in [-limit, limit], 0 or at least 1e-9 in magnitude: with a motion of 1e-156 alone (yaw_acc, from
    rest) DOP853's error norm in the reference (`_dop853`) underflows to 0 / 0 in scipy's step control."""
    return st.one_of(st.just(0.0), st.floats(1e-9, limit), st.floats(-limit, -1e-9))


seg_strategy = st.builds(tr.Segment, duration=st.floats(0.3, 2.0), accel=_rate(3.0), roll_acc=_rate(0.2),
                         pitch_acc=_rate(0.2), yaw_acc=_rate(0.5))


def _dop853(profile: tr.Profile, times: np.ndarray) -> np.ndarray:
    """Reference: integrate the 16 entries of T with DOP853 (rtol 1e-13), restarting at segment boundaries."""
    out = np.empty((len(times), 4, 4))
    T = profile.T0.copy()
    for i in range(len(profile.segments)):
        t0, t1 = profile.t_start[i], profile.t_start[i + 1]
        w0, wd = profile.varpi_seg[i], profile.varpi_dot_seg[i]
        sel = np.flatnonzero((times >= t0) & (times < t1))
        sol = solve_ivp(lambda t, y: (se3.hat(w0 + (t - t0) * wd) @ y.reshape(4, 4)).ravel(), (t0, t1), T.ravel(),
                        method="DOP853", rtol=1e-13, atol=1e-13, t_eval=np.r_[times[sel], t1])
        out[sel] = sol.y.T[:-1].reshape(-1, 4, 4)
        T = sol.y.T[-1].reshape(4, 4)
    return out


def test_magnus_matches_dop853():
    profile = tr.Profile([tr.Segment(2.0, 1.5, 0.02, -0.05, 0.3), tr.Segment(3.0, -1.0, 0.0, 0.05, -0.2),
                          tr.Segment(2.5, 0.5, -0.04, 0.0, 0.1)], speed0=20.0)
    times = np.arange(0, profile.duration, 1 / 13)
    ours = profile.sample(times).T_vehicle_world
    ref = _dop853(profile, times)
    scale = 1.0 + np.abs(ref[:, :3, 3]).max()  # positions reach ~150 m
    assert np.abs(ours - ref).max() / scale < 1e-12
    assert np.abs(se3.log(ours @ se3.inverse(ref))).max() < 1e-10


@given(st.lists(seg_strategy, min_size=1, max_size=4), st.floats(0.0, 30.0), st.data())
def test_a_pose_depends_on_its_time_alone(segments, speed0, data):
    """Sampled alone, in any subset or after other samples: the same pose, bit for bit (a mover is sampled only
    where it is present), and within 2.5e-12 (relative to the positions' scale) of DOP853's integration of the
    whole profile. The sampler's truncation error sits below DOP853's own (up to 9e-13 in 900 random profiles
    of this strategy; halving the step again leaves it unchanged). At the former 0.005 s step it was not:
    hypothesis found 2.9e-12 after a 2 rad/s turn from rest, 4.8e-12 at 0.005 s, 2.9e-13 at 0.0025 s."""
    profile = tr.Profile(segments, speed0=speed0)
    times = np.unique(data.draw(st.lists(st.floats(0.0, profile.duration), min_size=2, max_size=12)))
    every = profile.sample(times).T_vehicle_world
    k = data.draw(st.integers(0, len(times) - 1))
    fresh = tr.Profile(segments, speed0=speed0)  # its grid integrated anew
    np.testing.assert_array_equal(fresh.sample(times[k:k + 1]).T_vehicle_world[0], every[k])
    np.testing.assert_array_equal(profile.sample(times[k:]).T_vehicle_world, every[k:])
    inside = times < profile.duration  # the reference integrates each segment up to its end, exclusive
    if inside.any():
        ref = _dop853(profile, times[inside])
        assert np.abs(every[inside] - ref).max() / (1.0 + np.abs(ref[:, :3, 3]).max()) < 2.5e-12


@given(st.lists(seg_strategy, min_size=1, max_size=4), st.floats(0.0, 30.0))
def test_segments_varpi_dot_honoured(segments, speed0):
    """varpi is piecewise linear with the segments' slopes, and the integrated poses move with that varpi:
    the finite-difference derivative of T matches varpi (1st) and varpi_dot (2nd)."""
    profile = tr.Profile(segments, speed0=speed0)
    starts = profile.t_start[:-1]
    for i, seg in enumerate(segments):
        t = starts[i] + np.array([0.2, 0.5, 0.8]) * seg.duration
        varpi, varpi_dot = profile.twist(t)
        np.testing.assert_allclose(varpi_dot, np.tile(seg.varpi_dot, (3, 1)), atol=0)
        np.testing.assert_allclose(varpi[2] - varpi[0], 0.6 * seg.duration * seg.varpi_dot, atol=1e-12)
        assert np.all(varpi[:, 1:3] == 0.0)  # no lateral slip
        h = 1e-3
        m = profile.sample(np.array([t[1] - h, t[1], t[1] + h]))
        xi_f = se3.log(m.T_vehicle_world[2] @ se3.inverse(m.T_vehicle_world[1]))
        xi_b = se3.log(m.T_vehicle_world[1] @ se3.inverse(m.T_vehicle_world[0]))
        np.testing.assert_allclose((xi_f + xi_b) / (2 * h), varpi[1], atol=1e-5 * (1 + abs(speed0)))
        np.testing.assert_allclose((xi_f - xi_b) / h**2, varpi_dot[1], atol=2e-2 * (1 + abs(speed0)))


def test_builder_turn_reaches_heading_and_stops_yawing():
    b = tr.ProfileBuilder(10.0)
    b.turn(np.pi / 2, 12.0)
    b.add(1.0)
    profile = b.build()
    m = profile.sample(np.array([profile.duration]))
    fwd = m.T_world_vehicle[0][:3, 0]
    assert np.arctan2(fwd[1], fwd[0]) == pytest.approx(np.pi / 2, abs=1e-9)
    assert np.abs(m.varpi[0, 3:]).max() < 1e-12


@pytest.mark.parametrize("name", ["city", "highway", "hills", "stop_and_go", "crawl", "yaw_accel"])
@given(rng=hypothesis_rngs())
def test_profiles_never_reverse_and_stay_vehicle_like(name, rng):
    """Any draws (hypothesis-controlled, so a failure shrinks to the smallest draws) give a valid profile."""
    profile = getattr(tr, name)(rng, 120.0)
    lo, hi = profile.speed_range()
    assert lo >= 0.0
    assert profile.duration >= 120.0
    limits = {"city": 50, "highway": 130, "hills": 70, "stop_and_go": 35, "crawl": 15, "yaw_accel": 40}
    assert hi <= limits[name] / 3.6 + 1e-9
    if name == "highway":
        assert lo >= 80 / 3.6 - 1e-9
    assert np.all(profile.varpi_seg[:, 1:3] == 0)


def test_hills_change_height_by_metres():
    profile = tr.hills(np.random.default_rng(0), 60.0)
    route = tr.route_of(profile)
    assert np.ptp(route.p_world[:, 2]) > 5.0


def test_stop_and_go_reaches_standstill():
    profile = tr.stop_and_go(np.random.default_rng(1), 60.0)
    t = np.arange(0, 60.0, 1 / 13)
    m = profile.sample(t)
    still = m.speed == 0.0
    assert still.sum() > 13  # more than a second standing still in total
    assert still[1:].any() and (~still).any()
    # standing still means not moving: consecutive standstill poses are identical
    p = m.T_world_vehicle[:, :3, 3]
    both = still[1:] & still[:-1]
    assert np.abs(p[1:][both] - p[:-1][both]).max() < 1e-12


def test_yaw_accel_is_pure_yaw_acceleration():
    profile = tr.yaw_accel(np.random.default_rng(0), 10.0)
    varpi, varpi_dot = profile.twist(np.linspace(0, 10, 7))
    np.testing.assert_array_equal(varpi_dot, np.tile([0, 0, 0, 0, 0, -0.05], (7, 1)) + 0.0)
    np.testing.assert_allclose(varpi[:, 0], -10.0)


def test_route_length_matches_integrated_speed():
    profile = tr.city(np.random.default_rng(5), 60.0)
    route = tr.route_of(profile)
    assert route.length == pytest.approx(profile.path_length(), abs=1.5)
    np.testing.assert_allclose(np.linalg.norm(route.left(), axis=1), 1.0)


def test_bad_inputs_raise_input_error():
    with pytest.raises(InputError, match="duration"):
        tr.Profile([tr.Segment(0.0)])
    with pytest.raises(InputError, match="speed0"):
        tr.Profile([tr.Segment(1.0)], speed0=-1.0)
    with pytest.raises(InputError, match="times"):
        tr.Profile([tr.Segment(1.0)]).sample(np.array([0.0, 2.0]))
