"""The experiments behind the paper's figures 1-4 and our Fig. 5: they sample the prior, simulate scenarios and
run the estimators, and return plain dicts of arrays. `viz.figures` only draws them; the commands (`rodo
figures`, `rodo demo`) call `figure_data` and hand the result to `viz.figures`.

Each `figN_data(...)` returns a plain dict of arrays; the tests check these numbers.
Conventions (docs/conventions.md): T = T_vehicle_world, varpi = [nu; omega] (driving forward: nu_x < 0;
yawing left: omega_z < 0), left perturbation, radial velocity negative when approaching.

Checked by: tests/validation/test_experiments.py
"""

from __future__ import annotations

import numpy as np

from rodo.estimator import measurements
from rodo.estimator.errors import InputError
from rodo.estimator.lie import se3

from .alignment import align_to_first
from .covariance import position_covariance_world
from .metrics import drift, path_distances


# ----------------------------------------------------------------------------------------------- Fig. 1
def fig1_data(n_samples: int = 400, n_times: int = 4, horizon: float = 2.0, seed: int = 1,
              substeps: int = 100) -> dict:
    """Monte Carlo of the CA prior under pure yaw acceleration (sim.prior_sampling.yaw_acceleration_case).

    For horizons t_i = i horizon / n_times (i = 1..n_times) the SDE is sampled from x0 (+) N(0, P0) and the prior's
    Gaussian is propagated (mean f(x0), P = F P0 F^T + Q). The vehicle's world position of a sample is
    r_w = -C^T r of its T_vehicle_world; the propagated world-position covariance is C^T P_rho C
    (`validation.covariance.position_covariance_world`).

    Returns:
        dict: t (n_times,); samples_pos (n_times, n, 3); samples_varpi, samples_varpi_dot (n_times, n, 6);
        mean_pos (n_times, 3); cov_pos (n_times, 3, 3); mean_varpi, mean_varpi_dot (n_times, 6);
        cov_varpi, cov_varpi_dot (n_times, 6, 6); mean_path (50, 3) the mean position over [0, horizon];
        case (the set-up dict).
    """
    from rodo.estimator.priors import ConstantAccelerationPrior
    from rodo.sim.prior_sampling import propagate_mean_cov, sample_prior, yaw_acceleration_case

    case = yaw_acceleration_case()
    prior = ConstantAccelerationPrior(case["Qc"])
    rngs = [np.random.default_rng(s) for s in np.random.SeedSequence(seed).spawn(n_times)]
    t = float(horizon) * np.arange(1, n_times + 1) / n_times
    out = {k: [] for k in ("samples_pos", "samples_varpi", "samples_varpi_dot", "mean_pos", "cov_pos", "mean_varpi",
                           "mean_varpi_dot", "cov_varpi", "cov_varpi_dot")}
    for ti, rng in zip(t, rngs):
        T, varpi, varpi_dot = sample_prior(prior, case["T0"], case["varpi0"], case["vd0"], case["P0"], ti,
                                           n_samples, rng, substeps=substeps)
        (Tm, varpi_m, varpi_dot_m), P = propagate_mean_cov(prior, case["T0"], case["varpi0"], case["vd0"],
                                                           case["P0"], ti)
        out["samples_pos"].append(se3.inverse(T)[:, :3, 3])
        out["samples_varpi"].append(varpi)
        out["samples_varpi_dot"].append(varpi_dot)
        out["mean_pos"].append(se3.inverse(Tm)[:3, 3])
        out["cov_pos"].append(position_covariance_world(Tm, P[:3, :3]))
        out["mean_varpi"].append(varpi_m)
        out["mean_varpi_dot"].append(varpi_dot_m)
        out["cov_varpi"].append(P[6:12, 6:12])
        out["cov_varpi_dot"].append(P[12:, 12:])
    data = {k: np.stack(v) for k, v in out.items()}
    ts = np.linspace(1e-3, float(horizon), 50)
    Tm = prior.predict(np.broadcast_to(case["T0"], (50, 4, 4)), case["varpi0"], case["vd0"], ts)[0]
    data["mean_path"] = np.r_[se3.inverse(case["T0"])[None, :3, 3], se3.inverse(Tm)[:, :3, 3]]
    data["t"] = t
    data["case"] = case
    return data


# ----------------------------------------------------------------------------------------------- Fig. 2
def fig2_data(seed: int = 0, cartesian_sigma: float | None = None, max_points: int = 40) -> dict:
    """3-sigma position uncertainty of one simulated scan under the polar and the Cartesian models.

    Polar: the sensor's polar noise diag(s_r^2, s_az^2, s_el^2) propagated to Cartesian sensor coordinates,
    J diag(.) J^T (`measurements.cartesian_position_covariance`; lateral 1-sigma = r s_az). Cartesian: the fixed
    c^2 I of the CV/C baseline (c = NoiseConfig.cartesian_sigma), the same at every range, so it is larger than
    the polar ellipse near the sensor and smaller (over-confident) beyond r* = c / s_az in azimuth.

    Args:
        seed: scenario seed (a "city" scan, 0.5 s into the run).
        cartesian_sigma: c in metres (default: the estimator's default).
        max_points: at most this many detections are kept, one per range bin of max_range / max_points.

    Returns:
        dict: polar (n, 4); points (n, 3) sensor frame; cov_polar (n, 3, 3); cov_cartesian (3, 3);
        sigmas (4,); crossover_range (m) c / s_az; ranges (k,), semi_polar (k, 2) 3-sigma [radial, lateral]
        and semi_cartesian (scalar) for the range sweep.
    """
    from rodo import scenarios
    from rodo.estimator.config import NoiseConfig

    c = NoiseConfig().cartesian_sigma if cartesian_sigma is None else float(cartesian_sigma)
    if not c > 0:
        raise InputError(f"cartesian_sigma: must be > 0, got {c}")
    seq, _ = scenarios.get("city").simulate(seed, duration=0.5)
    scan = max(seq.scans, key=len)
    polar = scan.polar
    # one detection per range bin (the first in radar.csv order), so every range is represented
    edges = np.linspace(0.0, seq.sensor.max_range, max_points + 1)
    _, first = np.unique(np.digitize(polar[:, 0], edges), return_index=True)
    polar = polar[np.sort(first)]
    sigmas = seq.sensor.noise.as_array()
    cov = measurements.cartesian_position_covariance(polar, sigmas)
    ranges = np.linspace(1.0, seq.sensor.max_range, 200)
    semi_polar = 3.0 * np.c_[np.full_like(ranges, sigmas[0]), ranges * sigmas[1]]
    return dict(polar=polar, points=measurements.polar_to_cartesian(polar), cov_polar=cov,
                cov_cartesian=c * c * np.eye(3), sigmas=sigmas, cartesian_sigma=c, crossover_range=c / sigmas[1],
                ranges=ranges, semi_polar=semi_polar, semi_cartesian=3.0 * c, max_range=seq.sensor.max_range)


# ----------------------------------------------------------------------------------------------- Fig. 3
def fig3_data(yaw_accel: float = 1.0, speed: float = 10.0, yaw_rate: float = 0.2, dt: float = 1.0 / 13.0,
              target_range: float = 40.0, target_azimuth: float = np.radians(25.0)) -> dict:
    """Association with and without acceleration in the state (paper eq. 86-92, Fig. 3).

    From x_{k-1} = {I, varpi, varpi_dot} (driving forward at `speed`, yawing left at `yaw_rate` and accelerating
    the yaw at `yaw_accel`), the CA prior predicts x_k = {T_k, varpi_k, varpi_dot} and P_k = F P0 F^T + Q.
    Ignoring the acceleration (x = {T, varpi, 0}, as a CV prior does) predicts x'_k = {exp(dt varpi^), varpi, 0}.
    A static map point seen at (target_range, target_azimuth) from the true x_k is predicted from both:

        z = g(x_k, p),  z' = g(x'_k, p),  b = z' - z  (the bias of the acceleration-free prediction),
        S = G P G^T + R  (eq. 87),        S~ = S + b b^T  (eq. 92: E[e_bar e_bar^T] = b b^T).

    Two detections are placed: the correct target at z (noise-free) and a distractor at z' + 0.5 sigma
    (per component of S); d2 of each under (z, S) and (z', S~) shows which one each model associates.

    Returns:
        dict: z, z_noacc, bias (4,); S, S_tilde (4, 4); detections (2, 4) [correct, distractor];
        d2_full, d2_noacc (2,); p_world (3,); T_vehicle_sensor (4, 4); x_k (T, varpi, varpi_dot); x_noacc (T, varpi);
        dt, yaw_accel, varpi0, varpi_dot0.
    """
    from rodo.estimator.config import NoiseConfig
    from rodo.estimator.priors import ConstantAccelerationPrior
    from rodo.sim.radar import RadarConfig

    radar = RadarConfig()
    T_vehicle_sensor = np.asarray(radar.T_vehicle_sensor, dtype=float)
    sigmas = np.asarray(radar.sigmas, dtype=float)
    noise = NoiseConfig()
    varpi0 = np.array([-speed, 0.0, 0.0, 0.0, 0.0, -yaw_rate])
    varpi_dot0 = np.array([0.0, 0.0, 0.0, 0.0, 0.0, -yaw_accel])
    prior = ConstantAccelerationPrior(np.diag(noise.qc_ca))
    T_k, varpi_k, varpi_dot_k = prior.predict(np.eye(4), varpi0, varpi_dot0, dt)
    F, Q = prior.transition_and_noise(varpi0, varpi_dot0, dt)
    std0 = np.r_[[0.02] * 3, [0.002] * 3, [0.05] * 3, [0.005] * 3, [0.2] * 3, [0.05] * 3]
    P = F @ np.diag(std0**2) @ F.T + Q
    T_nacc, varpi_nacc = se3.exp(dt * varpi0) @ np.eye(4), varpi0.copy()

    # the map point: at (range, azimuth, elevation 0) from the sensor of the true state x_k
    p_sensor = target_range * np.array([np.cos(target_azimuth), np.sin(target_azimuth), 0.0])
    p_world = se3.transform_points(se3.inverse(T_k) @ T_vehicle_sensor, p_sensor[None])[0]
    pred = measurements.predict("polar", T_k, varpi_k, p_world[None], T_vehicle_sensor)
    pred_n = measurements.predict("polar", T_nacc, varpi_nacc, p_world[None], T_vehicle_sensor)
    R = measurements.noise_covariance("polar", np.zeros((1, 4)) + [1, 0, 0, 0], sigmas, noise.cartesian_sigma)[0]
    S = measurements_S(pred, P[:12, :12], R)
    S_n = measurements_S(pred_n, P[:12, :12], R)
    z, z_n = pred.z[0], pred_n.z[0]
    bias = measurements.residual("polar", z_n, z)
    S_tilde = S_n + np.outer(bias, bias)
    distractor = z_n + 0.5 * np.sqrt(np.diag(S))
    dets = np.stack([z, distractor])

    def d2(centre, cov):
        e = measurements.residual("polar", dets, centre)
        return np.einsum("ni,ij,nj->n", e, np.linalg.inv(cov), e)

    return dict(z=z, z_noacc=z_n, bias=bias, S=S, S_tilde=S_tilde, detections=dets, d2_full=d2(z, S),
                d2_noacc=d2(z_n, S_tilde), p_world=p_world, T_vehicle_sensor=T_vehicle_sensor,
                x_k=(T_k, varpi_k, varpi_dot_k), x_noacc=(T_nacc, varpi_nacc), dt=dt, yaw_accel=yaw_accel,
                varpi0=varpi0, varpi_dot0=varpi_dot0)


def measurements_S(pred, P12: np.ndarray, R: np.ndarray) -> np.ndarray:
    """S = G P G^T + R (eq. 87) of a single predicted measurement, G = [J_z_xi, J_z_varpi]."""
    G = np.concatenate([pred.J_z_xi[0], pred.J_z_varpi[0]], axis=1)
    S = G @ P12 @ G.T + R
    return 0.5 * (S + S.T)


# ----------------------------------------------------------------------------------------------- Fig. 4
def fig4_data(scenario: str = "hills", seed: int = 0, duration: float = 12.0, progress=None) -> dict:
    """Ground truth, CV/C and CA/P trajectories of a simulated sequence (both run through
    `validation.driver.run_sequence`), every trajectory aligned to the truth's first pose.

    Returns:
        dict: t (N,); truth, cv, ca (N, 3) world positions (truth frame); distance (N,) truth path length;
        final_error (dict model -> m); path_length (m); scenario, seed, duration.
    """
    from rodo import scenarios
    from rodo.estimator.config import OdometryConfig

    from .driver import run_sequence

    seq, _ = scenarios.get(scenario).simulate(seed, duration=duration)
    gt = seq.groundtruth
    out = dict(scenario=scenario, seed=seed, duration=duration, final_error={})
    for key, model in (("cv", "cv-cartesian"), ("ca", "ca-polar")):
        result = run_sequence(seq, OdometryConfig.for_model(model), progress=progress)
        est = result.trajectory()
        if not np.allclose(est.t, gt.t):
            raise InputError(f"scenario {scenario!r}: estimate and ground-truth times differ")
        # truth frame: T_g_v(est) = T_g_v(0) T_e_v(0)^-1 T_e_v, i.e. the estimate aligned to the first truth pose
        aligned = align_to_first(est.T_world_vehicle, gt.T_world_vehicle[0])
        out[key] = aligned[:, :3, 3]
        out["final_error"][model] = float(np.linalg.norm(out[key][-1] - gt.T_world_vehicle[-1, :3, 3]))
    p = gt.T_world_vehicle[:, :3, 3]
    out["t"] = np.asarray(gt.t)
    out["truth"] = p
    out["distance"] = path_distances(gt.T_world_vehicle)
    out["path_length"] = float(out["distance"][-1])
    return out


# ----------------------------------------------------------------------------------------------- Fig. 5 (ours)
VEHICLE_OFF = {"vehicle": {"sigma_roll_rate": 0.0, "sigma_pitch_rate": 0.0}}


def fig5_data(scenario: str = "city", seed: int = 2, duration: float = 30.0, progress=None) -> dict:
    """Out-of-plane drift (not in the paper): z, roll and pitch errors over the distance travelled of CV/C and
    CA/P, each with the road-vehicle roll and pitch rate terms (the default) and without them
    (docs/estimator.md, "Roll and pitch rates"); `validation.metrics.drift`, both trajectories relative to
    their first pose.

    Returns:
        dict: distance (N,) truth path length; runs {label: (N, 6) drift series [x, y, z m, roll, pitch, yaw
        deg]}; final {label: {z, roll, pitch}}; path_length (m); scenario, seed, duration.
    """
    from rodo import scenarios
    from rodo.estimator.config import OdometryConfig

    from .driver import run_sequence

    seq, _ = scenarios.get(scenario).simulate(seed, duration=duration)
    gt = seq.groundtruth.T_world_vehicle
    out = dict(scenario=scenario, seed=seed, duration=duration, runs={}, final={})
    for name, model in (("CV/C", "cv-cartesian"), ("CA/P", "ca-polar")):
        for suffix, extra in (("", {}), (", no roll/pitch rate terms", VEHICLE_OFF)):
            result = run_sequence(seq, OdometryConfig.from_dict({"model": model} | extra), progress=progress)
            d = drift(gt, result.trajectory().T_world_vehicle)
            out["runs"][name + suffix] = d["series"]
            out["final"][name + suffix] = {axis: d["final"][axis] for axis in ("z", "roll", "pitch")}
    out["distance"] = path_distances(gt)
    out["path_length"] = float(out["distance"][-1])
    return out


# ----------------------------------------------------------------------------------------------- all figures
def figure_data(number: int, quick: bool = False, progress=None) -> dict:
    """The data of figure `number` (1-5) at the size `rodo figures` uses: quick (about a minute for all five:
    200 prior samples, 12 s of hills for Fig. 4, 30 s of city for Fig. 5) or full (600 samples, 60 s, 90 s).

    Checked by: tests/viz/test_figures.py::test_rodo_figures_writes_five_pngs
    """
    experiments = {1: lambda: fig1_data(n_samples=200 if quick else 600),
                   2: lambda: fig2_data(),
                   3: lambda: fig3_data(),
                   4: lambda: fig4_data(duration=12.0 if quick else 60.0, progress=progress),
                   5: lambda: fig5_data(duration=30.0 if quick else 90.0, progress=progress)}
    if number not in experiments:
        raise InputError(f"number: no figure {number!r} (figures 1-5)")
    return experiments[number]()
