"""The experiments behind the paper's figures 1-4 and our Fig. 5 (validation.experiments): the numbers the figures
draw (viz.figures only draws them: tests/viz/test_figures.py)."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from rodo.estimator import measurements
from rodo.estimator.errors import InputError
from rodo.estimator.lie import se3
from rodo.validation import experiments


# ------------------------------------------------------------------------------------------------ Fig. 1
@pytest.fixture(scope="module")
def fig1():
    return experiments.fig1_data(n_samples=300, n_times=2, horizon=1.0, substeps=40)


def test_fig1_samples_agree_with_the_propagated_prior(fig1):
    """Monte Carlo of the SDE vs the prior's mean and covariance (world position and velocity)."""
    n = fig1["samples_pos"].shape[1]
    for i in range(len(fig1["t"])):
        for samples, mean, cov in ((fig1["samples_pos"][i], fig1["mean_pos"][i], fig1["cov_pos"][i]),
                                   (fig1["samples_varpi"][i], fig1["mean_varpi"][i], fig1["cov_varpi"][i])):
            L = np.linalg.cholesky(cov)
            z = np.linalg.solve(L, (samples - mean).T).T   # whitened: ~ N(0, I) if the prior is right
            assert np.all(np.abs(z.mean(axis=0)) < 5 / np.sqrt(n))
            assert np.abs(np.cov(z.T) - np.eye(len(mean))).max() < 0.35
    assert np.allclose(fig1["mean_path"][-1], fig1["mean_pos"][-1], atol=1e-9)
    # pure yaw acceleration to the left: the mean turns left (y > 0) while yawing faster
    assert fig1["mean_pos"][-1, 1] > 0 and -fig1["mean_varpi"][-1, 5] > -fig1["mean_varpi"][0, 5] > 0




# ------------------------------------------------------------------------------------------------ Fig. 2
@pytest.fixture(scope="module")
def fig2():
    return experiments.fig2_data()


def test_fig2_cartesian_is_too_large_near_and_too_small_far(fig2):
    r = fig2["polar"][:, 0]
    c2 = fig2["cartesian_sigma"] ** 2
    r_star = fig2["crossover_range"]
    assert r_star == pytest.approx(fig2["cartesian_sigma"] / fig2["sigmas"][1])
    near, far = r < 0.5 * r_star, r > 1.05 * r_star
    assert near.sum() >= 5 and far.sum() >= 1
    # near: c^2 I - Sigma_polar positive definite (the Cartesian ellipse contains the polar one)
    assert np.all(np.linalg.eigvalsh(fig2["cov_cartesian"] - fig2["cov_polar"][near]) > 0)
    # far: the polar lateral variance exceeds c^2 (the Cartesian model is over-confident across the beam)
    assert np.all(np.linalg.eigvalsh(fig2["cov_polar"][far, :2, :2])[:, -1] > c2)
    sweep = fig2["semi_polar"][:, 1] > fig2["semi_cartesian"]
    assert np.array_equal(sweep, fig2["ranges"] > r_star)


def test_fig2_polar_covariance_matches_monte_carlo(fig2):
    """The plotted polar ellipse of the farthest detection against sampled polar noise."""
    i = int(np.argmax(fig2["polar"][:, 0]))
    rng = np.random.default_rng(np.random.SeedSequence(2))
    noisy = fig2["polar"][i, :3] + rng.standard_normal((20000, 3)) * fig2["sigmas"][:3]
    S_mc = np.cov(measurements.polar_to_cartesian(noisy).T)
    L = np.linalg.cholesky(fig2["cov_polar"][i])
    W = np.linalg.solve(L, np.linalg.solve(L, S_mc).T)
    assert np.abs(W - np.eye(3)).max() < 0.05




# ------------------------------------------------------------------------------------------------ Fig. 3
@given(yaw_accel=st.floats(0.2, 2.0), azimuth_deg=st.floats(-50.0, 50.0), target_range=st.floats(20.0, 120.0))
def test_fig3_bias_is_the_linearised_effect_of_the_ignored_acceleration(yaw_accel, azimuth_deg, target_range):
    """b = g(x') - g(x) = G dx to first order (eq. 90-91), dx = [ln(T' T^-1); varpi' - varpi] with
    varpi' - varpi = -dt varpi_dot exactly and the yaw part of the pose difference = yaw_accel dt^2 / 2."""
    d = experiments.fig3_data(yaw_accel=yaw_accel, target_azimuth=np.radians(azimuth_deg), target_range=target_range)
    dt = d["dt"]
    (T_k, varpi_k, _), (T_n, varpi_n) = d["x_k"], d["x_noacc"]
    dx = np.r_[se3.log(T_n @ se3.inverse(T_k)), varpi_n - varpi_k]
    assert np.allclose(dx[6:], -dt * d["varpi_dot0"], atol=1e-12)
    assert dx[5] == pytest.approx(yaw_accel * dt**2 / 2, rel=1e-6)
    pred = measurements.predict("polar", T_k, varpi_k, d["p_world"][None], d["T_vehicle_sensor"])
    expected = np.concatenate([pred.J_z_xi[0], pred.J_z_varpi[0]], axis=1) @ dx
    # azimuth and radial velocity carry the effect; the rest is second order in the acceleration (the
    # product of the pose and rate errors on the lever arm: about 1e-3 m/s at 1 rad/s^2)
    for j, second_order in ((1, 1e-6), (3, 2e-3)):
        assert abs(d["bias"][j] - expected[j]) <= 0.03 * abs(expected[j]) + second_order * yaw_accel**2
    # physics: the yaw-rate error dw = dt yaw_accel acting on the sensor's lever arm r_x gives
    # dv_r = dw r_x sin(azimuth); the pose error (yaw_accel dt^2 / 2) adds at most about speed yaw_accel dt^2
    lever = dt * yaw_accel * d["T_vehicle_sensor"][0, 3] * np.sin(np.radians(azimuth_deg))
    speed = -d["varpi0"][0]
    assert abs(d["bias"][3] - lever) <= 0.1 * abs(lever) + speed * yaw_accel * dt**2 + 1e-3


def test_fig3_ignoring_acceleration_picks_the_distractor():
    d = experiments.fig3_data()
    assert d["d2_full"][0] == pytest.approx(0.0, abs=1e-12)
    assert np.argmin(d["d2_full"]) == 0      # the full model associates the correct target
    assert np.argmin(d["d2_noacc"]) == 1     # ignoring acceleration associates the distractor
    # S~ is inflated by exactly the outer product of the bias (eq. 92) and is larger than S along b
    b = d["bias"]
    assert b @ np.linalg.solve(d["S_tilde"], b) < b @ np.linalg.solve(d["S"], b)




# ------------------------------------------------------------------------------------------------ Fig. 4
@pytest.fixture(scope="module")
def fig4():
    return experiments.fig4_data(duration=2.0)


def test_fig4_trajectories_start_together_and_stay_close(fig4):
    from rodo.sim.simulate import path_length
    from rodo import scenarios

    assert np.allclose(fig4["ca"][0], fig4["truth"][0]) and np.allclose(fig4["cv"][0], fig4["truth"][0])
    assert np.all(np.diff(fig4["distance"]) >= 0)
    seq, _ = scenarios.get("hills").simulate(0, duration=2.0)
    assert np.allclose(fig4["truth"], seq.groundtruth.T_world_vehicle[:, :3, 3])
    assert fig4["path_length"] == pytest.approx(path_length(seq.groundtruth.T_world_vehicle))
    for model, err in fig4["final_error"].items():
        assert err < 0.05 * fig4["path_length"], (model, err)




# ------------------------------------------------------------------------------------------------ Fig. 5
@pytest.fixture(scope="module")
def fig5():
    return experiments.fig5_data(duration=30.0)  # as `rodo figures --quick`


def test_fig5_the_rate_terms_hold_roll_and_pitch(fig5):
    """30 s of city seed 2 (240 m): the drift series start at zero and cover every scan, and with the roll and
    pitch rate terms both models' roll and pitch errors over the drive (RMS of both) stay below 0.7 of what they
    reach without them (measured, RMS |roll|, |pitch|: CA/P 0.60, 0.23 deg vs 1.20, 0.31 deg; CV/C 0.53, 0.73 vs
    1.27, 0.89 deg; ratios 0.52 and 0.58. At city's version 2 the maxima were 0.61, 0.43 vs 3.74, 1.70 deg for
    CA/P)."""
    n = len(fig5["distance"])
    assert set(fig5["runs"]) == {"CV/C", "CA/P", "CV/C, no roll/pitch rate terms", "CA/P, no roll/pitch rate terms"}
    for series in fig5["runs"].values():
        assert series.shape == (n, 6) and np.all(series[0] == 0.0) and np.all(np.isfinite(series))
    for name in ("CV/C", "CA/P"):
        on, off = fig5["runs"][name], fig5["runs"][name + ", no roll/pitch rate terms"]
        rms_on, rms_off = np.sqrt(np.mean(on[:, 3:5] ** 2)), np.sqrt(np.mean(off[:, 3:5] ** 2))
        assert rms_on < 0.7 * rms_off, (name, rms_on, rms_off)


def test_figure_data_sizes_and_unknown_figure(monkeypatch):
    """figure_data dispatches to figN_data with the sizes of `rodo figures` (quick and full)."""
    calls = []
    for n in range(1, 6):
        monkeypatch.setattr(experiments, f"fig{n}_data", lambda n=n, **kw: calls.append((n, kw)) or {"n": n})
    for quick in (True, False):
        assert [experiments.figure_data(n, quick=quick)["n"] for n in range(1, 6)] == [1, 2, 3, 4, 5]
    sizes = {(n, quick): kw for (n, kw), quick in zip(calls, [True] * 5 + [False] * 5)}
    assert sizes[1, True]["n_samples"] == 200 and sizes[1, False]["n_samples"] == 600
    assert sizes[4, True]["duration"] == 12.0 and sizes[5, False]["duration"] == 90.0
    with pytest.raises(InputError, match="number"):
        experiments.figure_data(6)
