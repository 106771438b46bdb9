"""Consistency of the estimator: average NEES over a small seeded campaign against chi-square bounds, per block,
with the motion prior alone (no measurements) as the control.

NEES (validation/consistency.py): e = x_true (-) x_est (paper eq. 12, left perturbation), NEES = e^T P^-1 e with
P the posterior covariance of the newest state; for N consistent runs the average over runs at one scan, times
N, is chi-square(N d). Blocks: pose [rho; phi] (6), translation rho (3), rotation phi (3), velocity varpi (6),
acceleration varpi_dot (6, CA only); a block's NEES uses the matching sub-block of P (its marginal).

Measured (4 runs x 3 s of `yaw_accel`, seeds trial_seeds(7, 4), 2026-11-22; mean over scans of the average
over runs, "ratio" = that mean / d; bounds of the 4-run average per scan: d = 18 [12.6, 24.3], d = 12
[7.7, 17.3], d = 6 [3.1, 9.8], d = 3 [1.1, 5.8]):

    model         full (d)       pose (6)      trans (3)     rot (3)      velocity (6)   accel (6)
    ca-polar      130.2 (18) 7.2x  81.0  13.5x  51.7  17.2x   5.0  1.7x   20.6  3.4x     0.80  0.13x
    cv-cartesian   49.9 (12) 4.2x  47.0   7.8x  42.7  14.2x   4.9  1.6x    2.0  0.34x    -

Not run here (40 s), the same 4 x 3 s campaign of `city` (turns at low speed, more clutter) gave:

    ca-polar      353.6 (18) 19.6x 192.7  32.1x  39.3  13.1x  100.9 33.6x  16.6  2.8x     2.43  0.40x
    cv-cartesian  102.6 (12) 8.6x   75.7  12.6x  12.1   4.0x   44.9 15.0x   3.5  0.59x    -

So the estimator is over-confident, and the over-confidence is in the pose: its translation on the fast
`yaw_accel` drive (14-17x the dimension; rotation nearly consistent there, 1.6-1.7x), its rotation in `city`
(15-34x); then the CA velocity (2.8-3.4x). The CA acceleration and the CV velocity are under-confident (their
process noise is generous). The scenarios are noise-calibrated: the estimator uses the simulated sensor's own
noise sigmas (sensor.toml of the sequence, scale 1, floors below them). Cause (known): map points are reused
across scans, so their errors are counted as independent information many times, and the map's own
uncertainty is only partly carried (map_sigma). The motion prior alone is consistent (control below), so the
excess comes from the measurement side.

Tolerance asserted (documented, about 2x the measured values so the test catches a regression, not noise):
average NEES / d < 15 for the full state and < 30 for every block; and never below the lower chi-square bound
of the full state (a filter that is suddenly under-confident everywhere is also a regression).

Checked against: validation/consistency.py (nees, chi2_bounds, average_nees, nees_sequence).
"""

import numpy as np
import pytest

from rodo import scenarios
from rodo.estimator.config import OdometryConfig
from rodo.estimator.lie import se3
from rodo.estimator.motion import motion_prior
from rodo.sim import prior_sampling as ps
from rodo.validation.campaign import trial_seeds
from rodo.validation.consistency import average_nees, chi2_bounds, nees, nees_sequence, state_error
from rodo.validation.driver import run_sequence

SCENARIO, RUNS, DURATION, SEED = "yaw_accel", 4, 3.0, 7
FULL_TOLERANCE = 15.0  # average NEES / d, full state (measured 7.2 CA/P, 4.2 CV/C)
BLOCK_TOLERANCE = 30.0  # average NEES / d, any block (measured at most 17.2: CA/P translation)
BLOCKS = {"pose": slice(0, 6), "translation": slice(0, 3), "rotation": slice(3, 6), "velocity": slice(6, 12),
          "acceleration": slice(12, 18)}


def _states(result) -> dict:
    est = result.estimates
    d = est[0].P.shape[0]
    return {"t": result.t, "T_vehicle_world": np.stack([e.T_vehicle_world for e in est]),
            "varpi": np.stack([e.varpi for e in est]),
            "varpi_dot": np.stack([e.varpi_dot if e.varpi_dot is not None else np.zeros(6) for e in est]),
            "P": np.stack([e.P for e in est]).reshape(len(est), d, d)}


def block_nees(error: np.ndarray, P: np.ndarray) -> dict:
    """Per-scan NEES of the full state and of each block present, {name: (K,)}, with its dimension."""
    d = error.shape[-1]
    out = {"full": (nees(error, P), d)}
    for name, b in BLOCKS.items():
        if b.stop <= d:
            out[name] = (nees(error[:, b], P[:, b, b]), b.stop - b.start)
    return out


@pytest.fixture(scope="module")
def campaign():
    """{model: {block: (list of per-scan NEES arrays, one per run), dim}} of the small campaign."""
    runs: dict = {}
    for seed in trial_seeds(SEED, RUNS):
        seq, truth = scenarios.get(SCENARIO).simulate(seed, DURATION)
        for model in ("ca-polar", "cv-cartesian"):
            states = _states(run_sequence(seq, OdometryConfig.for_model(model)))
            ns = nees_sequence(states, truth)
            ia = np.searchsorted(states["t"], ns["t"])
            for name, (v, d) in block_nees(ns["error"], states["P"][ia]).items():
                runs.setdefault(model, {}).setdefault(name, ([], d))[0].append(v)
    return runs


def _time_average(per_run: list[np.ndarray]) -> tuple[float, np.ndarray, np.ndarray]:
    mean, count = average_nees(per_run)
    fin = np.isfinite(mean)
    return float(mean[fin].mean()), mean[fin], count[fin]


@pytest.mark.slow
@pytest.mark.parametrize("model", ["ca-polar", "cv-cartesian"])
def test_estimator_average_nees_within_documented_tolerance(campaign, model):
    report = {}
    for name, (per_run, d) in campaign[model].items():
        avg, mean, count = _time_average(per_run)
        bounds = chi2_bounds(count, d)
        within = float(np.mean((mean >= bounds[:, 0]) & (mean <= bounds[:, 1])))
        report[name] = (avg, avg / d, within)
        assert len(mean) >= 30, f"{model} {name}: only {len(mean)} scans with a finite NEES"
    print(f"\n{model}: " + ", ".join(f"{k} {a:.2f} ({r:.2f}x d, {100 * w:.0f} % scans in bounds)"
                                     for k, (a, r, w) in report.items()))
    full_avg, full_ratio, _ = report["full"]
    d = campaign[model]["full"][1]
    assert full_ratio < FULL_TOLERANCE, report
    assert full_avg > chi2_bounds(RUNS, d)[0], report
    for name, (_, ratio, _) in report.items():
        assert ratio < BLOCK_TOLERANCE, (name, report)


def _sample_cv(Qc, T0, varpi0, P0, dt, n, rng, substeps):
    """The CV prior's SDE (white acceleration noise): dT/dt = varpi^ T, d varpi/dt = w, w ~ GP(0, Qc delta),
    by sub-steps of piecewise-constant w; pose step = Magnus to third order of the linear-in-time varpi."""
    root = np.linalg.cholesky(P0)
    g0 = rng.standard_normal((n, 12)) @ root.T
    T = se3.exp(g0[:, :6]) @ T0
    varpi = varpi0 + g0[:, 6:]
    h = dt / substeps
    w_root = np.linalg.cholesky(Qc / h)
    for _ in range(substeps):
        w = rng.standard_normal((n, 6)) @ w_root.T
        sigma = h * varpi + h**2 / 2 * w + h**3 / 12 * ps._ad(w, varpi)
        T = se3.exp(sigma) @ T
        varpi = varpi + h * w
    return T, varpi


@pytest.mark.parametrize("kind", ["ca", "cv"])
def test_prior_alone_is_consistent_control(kind):
    """Control: the estimator's own motion prior (`motion_prior` with the default Qc, the estimator's initial
    covariance), chained over one window (4 scans at 13 Hz) with P <- F P F^T + Q and no measurement, against
    samples of the continuous SDE (10 m/s, turning and accelerating). The average NEES of 1000 samples must lie in
    its 99 % chi-square bounds, for the full state and for the pose and velocity blocks.

    Measured (seed 2026, 1000 samples): CA full 18.16 (d = 18, bounds [17.52, 18.49]), CV full 12.04 (d = 12,
    bounds [11.60, 12.40]); pose and velocity blocks 5.92-5.99 (d = 6).
    Over 13 scans (1 s) from the same wide initial covariance the CA full-state NEES grows to 19.0 (2000
    samples, above the 99 % bound 18.35) while every block stays at its dimension: the linearised
    propagation misses the curvature of a 0.2 rad/s-uncertain turn over a second (cross-block correlations),
    not a discretisation error; the estimator never predicts that far without measurements.
    """
    cfg = OdometryConfig.for_model("ca-polar" if kind == "ca" else "cv-cartesian")
    qc = cfg.noise.qc_ca if kind == "ca" else cfg.noise.qc_cv
    motion = motion_prior(kind, qc)
    s = cfg.solver
    sig = [1e-4] * 6 + [s.init_velocity_sigma] * 3 + list(s.init_rate_sigma)
    if kind == "ca":
        sig += list(s.init_accel_sigma) + list(s.init_angular_accel_sigma)
    P0 = np.diag(np.square(sig))
    varpi0 = np.array([-10.0, 0, 0, 0, 0, -0.3])  # 10 m/s forward, turning left at 0.3 rad/s
    vd0 = np.array([-1.0, 0, 0, 0, 0, -0.5])
    x = motion.initial_state(0.0, np.eye(4), varpi0)
    if kind == "ca":
        x.varpi_dot[:] = vd0
    P, dt, steps = P0.copy(), 1 / 13, cfg.window
    for k in range(steps):
        F, Q = motion.transition_and_noise(x, dt)
        x = motion.predict(x, (k + 1) * dt)
        P = F @ P @ F.T + Q
    P = 0.5 * (P + P.T)
    rng = np.random.default_rng(np.random.SeedSequence(2026))
    n = 1000
    if kind == "ca":
        T, w, vd = ps.sample_prior(motion.prior, np.eye(4), varpi0, vd0, P0, steps * dt, n, rng, substeps=20 * steps)
        e = state_error(T, w, x.T_vehicle_world, x.varpi, vd, x.varpi_dot)
    else:
        T, w = _sample_cv(np.diag(qc), np.eye(4), varpi0, P0, steps * dt, n, rng, substeps=20 * steps)
        e = state_error(T, w, x.T_vehicle_world, x.varpi)
    blocks = block_nees(e, np.broadcast_to(P, (n,) + P.shape))
    for name in ("full", "pose", "velocity"):
        v, d = blocks[name]
        lo, hi = chi2_bounds(n, d, alpha=0.01)
        print(f"{kind} prior {name}: mean NEES {v.mean():.2f} (d = {d}, 99 % bounds [{lo:.2f}, {hi:.2f}])")
        assert lo <= v.mean() <= hi, (name, v.mean(), (lo, hi))
