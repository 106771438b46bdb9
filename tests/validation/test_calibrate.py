"""`rodo calibrate`'s library: ML Qc from true SDE trajectories, the EM E-step (smoother) and loop, the config
writer (docs/calibration.md; the measurement noise: test_calibrate_sensor.py)."""

import dataclasses

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from rodo import scenarios
from rodo.estimator.config import MODELS, OdometryConfig
from rodo.estimator.errors import InputError
from rodo.estimator.lie import se3
from rodo.estimator.priors import ConstantAccelerationPrior
from rodo.sim.prior_sampling import sample_prior
from rodo.validation import calibrate as cal
from rodo.validation.calibrate_config import calibrate_with_truth, config_toml

QC = np.array([0.5, 0.1, 0.05, 0.005, 0.005, 0.05])  # CA: jerk PSD; also used as the CV acceleration PSD
VARPI0 = np.array([-10.0, 0, 0, 0, 0, 0])


def _rng(*key):
    return np.random.default_rng(np.random.SeedSequence([20261201, *key]))


def _scan_times(rng, n):
    """n intervals at 13 Hz with +-10 % jitter."""
    return np.r_[0.0, np.cumsum(1 / 13 * (1 + 0.1 * rng.uniform(-1, 1, n)))]


def draw_ca_tracks(qc, n_tracks, n_intervals, rng, substeps=8):
    """Trajectories of the CA SDE (rodo.sim.prior_sampling.sample_prior, one interval at a time) at scan times."""
    prior = ConstantAccelerationPrior(np.diag(qc))
    tracks = []
    for _ in range(n_tracks):
        t = _scan_times(rng, n_intervals)
        states = [(np.eye(4), VARPI0, np.zeros(6))]
        for dt in np.diff(t):
            draw = sample_prior(prior, *states[-1], np.zeros((18, 18)), dt, 1, rng, substeps)
            states.append(tuple(a[0] for a in draw))
        tracks.append(cal.StateTrack(t, *(np.array(a) for a in zip(*states))))
    return tracks


def draw_cv_tracks(qc, n_tracks, n_intervals, rng, substeps=8):
    """Trajectories of the CV SDE (white-noise acceleration): piecewise-constant acceleration a_j ~ N(0, Qc/h)
    over sub-steps h, each sub-step integrated exactly enough by the order-4 Magnus CA mean."""
    stepper = ConstantAccelerationPrior(np.eye(6), magnus_order=4)
    tracks = []
    for _ in range(n_tracks):
        t = _scan_times(rng, n_intervals)
        T, w = np.eye(4), VARPI0.copy()
        Ts, ws = [T], [w]
        for dt in np.diff(t):
            h = dt / substeps
            for a in rng.standard_normal((substeps, 6)) * np.sqrt(qc / h):
                T, w, _ = stepper.predict(T, w, a, h)
            Ts.append(T)
            ws.append(w)
        tracks.append(cal.StateTrack(t, np.array(Ts), np.array(ws), np.zeros((len(t), 6))))
    return tracks


@pytest.fixture(scope="module")
def ca_tracks():
    return draw_ca_tracks(QC, 20, 40, _rng(1))  # 800 intervals


# ------------------------------------------------------------------------------------------ ML with truth


@pytest.mark.parametrize("kind", ["ca", "cv"])
def test_residuals_equal_the_priors_residual(kind):
    track = (draw_ca_tracks if kind == "ca" else draw_cv_tracks)(QC, 1, 5, _rng(2))[0]
    prior = cal.make_prior(kind, QC)
    e = cal.prior_residuals(kind, track)
    for k in range(1, 6):
        args = (track.T_vehicle_world[k - 1], track.varpi[k - 1]) + ((track.varpi_dot[k - 1],) if kind == "ca" else ())
        args += (track.T_vehicle_world[k], track.varpi[k]) + ((track.varpi_dot[k],) if kind == "ca" else ())
        np.testing.assert_allclose(e[k - 1], prior.residual(*args, track.t[k] - track.t[k - 1])[0], atol=1e-12)


def test_noise_basis_sums_to_the_priors_q(ca_tracks):
    track = ca_tracks[0]
    _, B = cal.transitions_and_basis("ca", track, QC)
    Q = cal.make_prior("ca", QC).process_noise_batch(track.varpi[:-1], track.varpi_dot[:-1], np.diff(track.t))
    np.testing.assert_allclose(np.einsum("i,kiab->kab", QC, B), Q, rtol=1e-9, atol=1e-9 * np.abs(Q).max())


def test_likelihood_gradient_matches_finite_differences():
    rng = _rng(3)
    G = rng.standard_normal((10, 6, 5, 2))
    B = G @ np.swapaxes(G, -1, -2)
    e = rng.standard_normal((10, 5))
    S = e[:, :, None] * e[:, None, :]
    q = rng.uniform(0.5, 2.0, 6)
    value, grad = cal.expected_log_likelihood(q, B, S)
    h = 1e-6
    fd = [(cal.expected_log_likelihood(q + h * np.eye(6)[i], B, S)[0]
           - cal.expected_log_likelihood(q - h * np.eye(6)[i], B, S)[0]) / (2 * h) for i in range(6)]
    np.testing.assert_allclose(grad, fd, rtol=1e-5)
    Q = np.einsum("i,kiab->kab", q, B)
    direct = sum(-0.5 * (np.linalg.slogdet(Qk)[1] + ek @ np.linalg.solve(Qk, ek) + 5 * np.log(2 * np.pi))
                 for Qk, ek in zip(Q, e))
    assert value == pytest.approx(direct, rel=1e-10)


@pytest.mark.slow
def test_ml_recovers_qc_of_ca_sde_trajectories(ca_tracks):
    fit = cal.fit_qc_to_truth("ca", ca_tracks)
    assert fit.intervals == 800
    np.testing.assert_allclose(fit.qc, QC, rtol=0.10)  # measured: 0.94-1.02 of the truth per component
    assert not any(fit.at_floor)
    worse = cal.expected_log_likelihood(1.2 * fit.qc, *_moments(ca_tracks))[0]
    assert fit.loglik > worse


def _moments(tracks):
    B = np.concatenate([cal.transitions_and_basis("ca", tr, QC)[1] for tr in tracks])
    e = np.concatenate([cal.prior_residuals("ca", tr) for tr in tracks])
    return B, e[:, :, None] * e[:, None, :]


@pytest.mark.slow
def test_ml_recovers_qc_of_cv_sde_trajectories():
    tracks = draw_cv_tracks(QC, 20, 40, _rng(4))
    fit = cal.fit_qc_to_truth("cv", tracks)
    np.testing.assert_allclose(fit.qc, QC, rtol=0.10)  # measured: 0.92-1.01


def test_unexcited_component_goes_to_the_floor():
    tracks = draw_ca_tracks(np.array([0.5, 0.1, 0.05, 1e-14, 0.005, 0.05]), 2, 20, _rng(5))
    fit = cal.fit_qc_to_truth("ca", tracks, floor=1e-9)
    assert fit.at_floor[3] and fit.qc[3] == pytest.approx(1e-9)


def test_each_component_can_have_its_own_floor():
    """A floor per component holds the unexcited roll at its own floor and, where the data excite a component
    well above its floor, leaves the fit as one floor for all does."""
    qc = np.array([0.5, 0.1, 0.05, 1e-14, 0.005, 0.05])
    tracks = draw_ca_tracks(qc, 2, 20, _rng(5))
    one = cal.fit_qc_to_truth("ca", tracks, floor=1e-9)
    own = cal.fit_qc_to_truth("ca", tracks, floor=[1e-9, 1e-9, 1e-9, 1e-6, 1e-9, 1e-9])
    assert own.at_floor == [False, False, False, True, False, False] and own.qc[3] == pytest.approx(1e-6)
    np.testing.assert_allclose(own.qc[[0, 1, 2, 4, 5]], one.qc[[0, 1, 2, 4, 5]], rtol=0.05)
    raised = cal.fit_qc_to_truth("ca", tracks, floor=[1e-9, 1e-9, 1e-9, 1e-9, 1.0, 1e-9])  # above pitch's fit
    assert raised.at_floor[4] and raised.qc[4] == pytest.approx(1.0) and one.qc[4] < 0.1


@pytest.mark.parametrize("floor", [[1e-4, 1e-3], [1e-4] * 5 + [float("nan")], [0.0] * 6, 1e9])
def test_a_floor_out_of_its_range_is_refused(floor):
    with pytest.raises(InputError, match="floor"):
        cal.floors(floor)


# ------------------------------------------------------------------------------------------ EM without truth

def test_aitken_step_reaches_a_geometric_limit():
    step, previous = np.array([0.5, -0.2, 0.1, 0.3]), np.array([1.0, -0.4, -0.1, 0.3])
    out = cal.aitken_step(step, previous)
    np.testing.assert_allclose(out[:2], step[:2] / (1 - 0.5))  # 0.5 + 0.25 + ... still to go
    assert out[2] == step[2]  # opposite signs: plain EM step
    assert out[3] == step[3] * 5.0  # r = 1: capped
    np.testing.assert_array_equal(cal.aitken_step(step, None), step)




# ------------------------------------------------------------------------------------------ config writer

@given(model=st.sampled_from(MODELS), qc=st.lists(st.floats(1e-12, 1e6), min_size=6, max_size=6),
       scale=st.floats(1e-3, 1e3), fuse=st.booleans())
def test_config_toml_round_trips(tmp_path_factory, model, qc, scale, fuse):
    config = OdometryConfig.for_model(model)
    config = config.replace(noise=dataclasses.replace(config.noise, qc_ca=tuple(qc), sensor_sigma_scale=scale),
                            map=dataclasses.replace(config.map, fuse=fuse))
    path = tmp_path_factory.mktemp("toml") / "c.toml"
    path.write_text(config_toml(config, ["learned from a test", ""]))
    assert OdometryConfig.from_toml(path) == config


@pytest.mark.slow
def test_calibrate_with_truth_recovers_the_simulators_qc_and_r():
    """A radar sequence driven along the CA prior's own SDE (`prior_ca`, 40 s, 520 intervals) with a known Qc,
    and the simulator's sensor sigmas: `calibrate_with_truth` returns each Qc component and each channel's sigma
    within 10 % (measured: 0.95-1.03 and 0.998-1.001)."""
    qc = np.array([1e-2, 1e-4, 1e-4, 1e-7, 1e-7, 1e-5])
    seq, truth = scenarios.get("prior_ca").simulate(3, 40.0, qc=qc.tolist())
    config, report = calibrate_with_truth(seq, truth, OdometryConfig.for_model("ca-polar"), consistency=False)
    np.testing.assert_allclose(np.array(report["qc_ca"]["qc"]) / qc, 1.0, rtol=0.10)
    np.testing.assert_allclose(config.noise.sensor_sigma_scales, 1.0, rtol=0.10)
    assert "consistency" not in report


@given(start=st.floats(-3.0, 3.0), rate=st.floats(0.05, 0.98), n=st.integers(1, 8))
def test_remaining_distance_of_a_geometric_sequence(start, rate, n):
    """log q_n = log q* + c r^n: from two consecutive steps the distance left to q* is exact (relative, as
    exp(|log q_n - log q*|) - 1); a step that grows has none (inf), the first step counts as it is."""
    c = np.array([start, 0.5 * start, 0.0, -start, 0.1, 0.0])
    x = [c * rate**k for k in (n - 1, n, n + 1)]  # log q - log q* at three iterations
    previous, step = x[1] - x[0], x[2] - x[1]
    left = cal.remaining_distance(step, previous)
    assert left == pytest.approx(float(np.max(np.expm1(np.abs(x[2])))), rel=1e-6, abs=1e-12)
    assert cal.remaining_distance(2 * previous, previous) == (np.inf if np.any(previous) else 0.0)
    assert cal.remaining_distance(step, None) == pytest.approx(float(np.max(np.expm1(np.abs(step)))))
