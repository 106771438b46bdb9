"""`rodo calibrate`'s pipeline: learn the noise of a sequence and write an estimator config (docs/calibration.md).

- `calibrate_with_truth(seq, truth, config)`: ML Qc of both priors from the true states of truth.npz (of one
  sequence, or of several pooled)
  (`calibrate.fit_qc_to_truth`) and the measurement noise from the static detections
  (`calibrate_sensor`); the config gets both Qc, `noise.sensor_sigma_scales` (per channel), `noise.cartesian_sigma`
  and `noise.doppler_common_sigma`;
  then, unless told not to, the uncertainty parameters at that noise (`calibrate_consistency`: the pairs'
  effective count kappa, the drift rate, the velocity correlation time).
- `calibrate_without_truth(seq, config)`: EM (`calibrate.em_qc`) over the estimator's posteriors, for the
  Qc of the config's own prior; R as configured, or (`sensor_noise`) learned first from the static detections
  of consecutive scans and the estimated poses (`calibrate_sensor_em`). The estimator runs EM reads are at
  `solve_only(config)`: the window's own posteriors, not the reported covariances.
- `config_toml(config, header)`: the complete config as TOML that `OdometryConfig.from_toml` reads back.

Checked by: tests/validation/test_calibrate.py::test_config_toml_round_trips,
    tests/cli/test_calibrate_cli.py, tests/cli/test_calibrate_no_truth_cli.py
"""

from __future__ import annotations

import dataclasses

import numpy as np

from rodo.estimator.config import OdometryConfig, UncertaintyConfig
from rodo.estimator.errors import InputError
from rodo.sim.sequence import Sequence, Trajectory

from . import calibrate as cal
from . import calibrate_consistency as cc
from . import calibrate_sensor as cs
from . import calibrate_sensor_em as csem
from . import calibrate_vehicle as veh
from . import qc_information as qi
from . import velocity_growth as vg
from .driver import run_sequence


def truncate(seq: Sequence, duration: float | None) -> Sequence:
    """The first `duration` seconds of a sequence (all of it when None)."""
    if duration is None:
        return seq
    if not (np.isfinite(duration) and duration > 0):
        raise InputError(f"--duration: must be a positive number of seconds, got {duration}")
    times = [s.t for s in seq.scans] + ([] if seq.groundtruth is None else list(seq.groundtruth.t))
    end = min(times) + duration if times else 0.0
    gt = seq.groundtruth
    if gt is not None:
        keep = gt.t <= end
        gt = Trajectory(gt.t[keep], gt.T_world_vehicle[keep]) if keep.sum() else None
    return Sequence(sensor=seq.sensor, scans=[s for s in seq.scans if s.t <= end], groundtruth=gt)


def truth_track(truth: dict, end: float | None = None) -> cal.StateTrack:
    """The true states of truth.npz (scans at t <= end) as a StateTrack."""
    for key in ("t", "T_vehicle_world", "varpi", "varpi_dot"):
        if key not in truth:
            raise InputError(f"truth.npz: missing array {key!r} (needed for the motion prior's Qc)")
    t = np.asarray(truth["t"], dtype=float)
    n = len(t) if end is None else int(np.searchsorted(t, end, side="right"))
    return cal.StateTrack(t[:n], truth["T_vehicle_world"][:n], truth["varpi"][:n], truth["varpi_dot"][:n])


def _qc_report(fit: cal.QcFit) -> dict:
    return {"qc": fit.qc.tolist(), "loglik": fit.loglik, "intervals": fit.intervals, "at_floor": fit.at_floor}


def calibrate_with_truth(seq: Sequence | list, truth: dict | list, config: OdometryConfig,
                         duration: float | None = None, floor: float = cal.DEFAULT_FLOOR, consistency: bool = True,
                         progress=None, velocity_axes: bool = True, heading_reversion: bool = False,
                         attitude_jitter: bool = True, velocity_lag: bool | None = None,
                         stationary_error: bool = False, axis_correlation: bool = True,
                         vehicle_rates: bool = False) -> tuple[OdometryConfig, dict]:
    """Learn qc_ca, qc_cv, the per-channel sensor sigma factors, the Cartesian sigma and the scans' common Doppler
    error (`calibrate_sensor.common_doppler_error`; 0 unless significant) from ground truth, with
    `vehicle_rates` the road-vehicle terms on the roll and pitch rates (`calibrate_vehicle`), then
    (`consistency`) the uncertainty section at that noise (the velocity's per-axis factors with `velocity_axes`,
    its lag behind a manoeuvre with `velocity_lag`, None: by the motion prior,
    the heading's reversion with `heading_reversion`, the roll and pitch jitter unless `attitude_jitter` is False,
    the stationary error per axis with `stationary_error`, the registration's correlation per axis unless
    `axis_correlation` is False);
    returns (config, report). `progress` gets each
    `calibrate_consistency.ConsistencyStep`. `seq` and `truth` may be lists of several sequences (of one sensor):
    every fit pools them (their prior intervals, detections and scans), `duration` cuts each."""
    seqs, truths = ([seq], [truth]) if isinstance(truth, dict) else (list(seq), list(truth))
    if not seqs or len(seqs) != len(truths):
        raise InputError(f"calibrate: {len(seqs)} sequences for {len(truths)} truths")
    other = next((i for i, q in enumerate(seqs) if q.sensor != seqs[0].sensor), None)
    if other is not None:
        raise InputError(f"calibrate: sequence {other + 1} has another sensor (sensor.toml) than sequence 1; "
                         "calibrate the sequences of one sensor together")
    seqs = [truncate(s, duration) for s in seqs]
    tracks = [truth_track(t, max(s.t for s in q.scans) if q.scans else None) for q, t in zip(seqs, truths)]
    fits = {kind: cal.fit_qc_to_truth(kind, tracks, floor) for kind in ("ca", "cv")}
    residuals = [cs.detection_residuals(q, t, scans=len(k.t)) for q, t, k in zip(seqs, truths, tracks)]
    res, r = (np.concatenate(x) for x in zip(*residuals))
    sensor = seqs[0].sensor.noise.as_array()
    scale = cs.sigma_scale(res, sensor)
    channels = cs.channel_noise(res, r)
    scales = tuple(float(channels[c]["sigma"] / s) for c, s in zip(cs.CHANNELS, sensor))
    cart = cs.cartesian_sigma(res, r)
    common = cs.common_doppler_error(seqs, truths, scans=[len(k.t) for k in tracks])
    if common["significant"]:  # the radial velocity's own sigma without the scans' common error
        scales = scales[:3] + (common["sigma_vr_independent"] / sensor[3],)
    noise = dataclasses.replace(config.noise, qc_ca=tuple(fits["ca"].qc), qc_cv=tuple(fits["cv"].qc),
                                sensor_sigma_scale=1.0, sensor_sigma_scales=scales, cartesian_sigma=cart,
                                doppler_common_sigma=common["sigma_c"])
    report = {
        "mode": "ground truth", "sequences": len(seqs), "scans": sum(len(k.t) for k in tracks), "floor": floor,
        "qc_ca": _qc_report(fits["ca"]), "qc_cv": _qc_report(fits["cv"]),
        "measurement": {"channels": channels,
                        "sensor_toml_sigmas": dict(zip(cs.CHANNELS, sensor.tolist())),
                        "sensor_sigma_scale": scale, "sensor_sigma_scales": list(scales),
                        "cartesian_sigma": cart, "doppler_common": common},
    }
    config = config.replace(noise=noise)
    if vehicle_rates:
        config, report["vehicle"] = veh.fit_vehicle_rates(tracks, config)
    if consistency:
        config, report["consistency"] = cc.fit_consistency(seqs, truths, config, progress=progress,
                                                           velocity_axes=velocity_axes, velocity_lag=velocity_lag,
                                                           heading_reversion=heading_reversion,
                                                           attitude_jitter=attitude_jitter,
                                                           stationary_error=stationary_error,
                                                           axis_correlation=axis_correlation)
    return config, report


def solve_only(config: OdometryConfig) -> OdometryConfig:
    """`config` with the `[uncertainty]` terms that change only what is reported at their defaults, and those in
    the solve (measurement_inflation, prior_memory) kept: a run at it has the same estimate and reports the
    window's own covariances. EM's stand-in needs those (`em_surrogate`): it takes a scan's information as
    P_k^-1 - (F_k P_{k-1} F_k^T + Q_k)^-1, which a velocity covariance inflated after the solve (the learned
    velocity factor, the lag) turns to nothing, so that every scan looks uninformative and Qc runs away (from a
    config `rodo calibrate` learned with truth: 200 x the truth in x, 4e4 in z, 5e9 in y on 30 s drives where the
    window's own posteriors give 0.66-1.5 x; docs/calibration.md, "EM reads the window's own posteriors"). A new
    `[uncertainty]` term that the solve reads must be kept here too.

    Checked by: tests/validation/test_em_surrogate.py::test_em_reads_the_windows_own_posteriors
    """
    u = config.uncertainty
    return config.replace(uncertainty=UncertaintyConfig(measurement_inflation=u.measurement_inflation,
                                                        prior_memory=u.prior_memory))


def estimator_track(seq: Sequence, config: OdometryConfig) -> cal.StateTrack:
    """Run the estimator; its per-scan posteriors as a StateTrack, intervals ending in an (re-)initialisation
    marked invalid."""
    result = run_sequence(seq, config)
    est = result.estimates
    if len(est) < 2:
        raise InputError("sequence: EM needs at least 2 scans")
    reinit = np.array([any("initialised" in ev for ev in e.events) for e in est[1:]])
    return cal.StateTrack(result.t, np.stack([e.T_vehicle_world for e in est]), np.stack([e.varpi for e in est]),
                          np.stack([e.varpi_dot if e.varpi_dot is not None else np.zeros(6) for e in est]),
                          np.stack([e.P for e in est]), ~reinit)


def with_learned_sensor_noise(seq: Sequence, config: OdometryConfig) -> tuple[OdometryConfig, dict]:
    """The measurement noise learned without ground truth (`calibrate_sensor_em.measurement_noise`, from one
    estimator run at `config`) written into the config's per-channel factors on sensor.toml's sigmas and its
    Cartesian sigma; returns (config, report). What the data cannot show (the elevation of a planar radar, and
    with it the Cartesian sigma) keeps the config's value."""
    noise = config.noise
    sensor = seq.sensor.noise.as_array()
    effective = np.asarray(noise.sensor_sigma_scales, dtype=float) * noise.sensor_sigma_scale  # on sensor.toml's
    result = run_sequence(seq, config, record_detail=True)
    fit = csem.measurement_noise(result.estimates, seq.sensor.T_vehicle_sensor, sensor * effective)
    learned = np.array([fit["sigmas"][c] for c in cs.CHANNELS])
    scales = np.where(fit["learned"], learned / sensor, effective)
    cart = noise.cartesian_sigma if fit["cartesian_sigma"] is None else fit["cartesian_sigma"]
    config = config.replace(noise=dataclasses.replace(noise, sensor_sigma_scale=1.0,
                                                      sensor_sigma_scales=tuple(float(x) for x in scales),
                                                      cartesian_sigma=cart))
    report = dict(fit, sensor_toml_sigmas=dict(zip(cs.CHANNELS, sensor.tolist())),
                  configured_sigmas=dict(zip(cs.CHANNELS, (sensor * effective).tolist())),
                  sensor_sigma_scales=scales.tolist())
    return config, report


def calibrate_without_truth(seq: Sequence, config: OdometryConfig, iterations: int = 30, tolerance: float = 0.05,
                            duration: float | None = None, floor: float = cal.DEFAULT_FLOOR,
                            progress=None, learn=None, sensor_noise: bool = False) -> tuple[OdometryConfig, dict]:
    """EM for the Qc of the config's prior, over estimator runs at `solve_only(config)`; returns (config, report),
    the config with its own `[uncertainty]` terms. `progress(EmIteration)` is called after each iteration; `learn`
    (6,) bool: the components to learn (default all; `calibrate.em_qc`). With `sensor_noise` the measurement noise
    is learned first (`with_learned_sensor_noise`) and EM runs at it. A component that ran away (EM's value at the
    fit's upper bound: no fixed point on this drive, e.g. a jump of the estimate booked as motion) keeps the base
    config's value; the report names it ("runaway")."""
    seq = truncate(seq, duration)
    field = f"qc_{config.prior}"
    measurement = None
    if sensor_noise:
        config, measurement = with_learned_sensor_noise(seq, config)

    tracks = []  # the last run's track, which EM's check reads (no run of its own)
    solve = solve_only(config)  # the window's own posteriors, not the reported covariances

    def run(qc):
        tracks[:] = [estimator_track(seq, solve.replace(noise=dataclasses.replace(solve.noise,
                                                                                  **{field: tuple(qc)})))]
        return tracks[0]

    history = cal.em_qc(run, config.prior, getattr(config.noise, field), iterations, tolerance, floor,
                        on_iteration=progress, learn=learn)
    qc = history[-1].qc_out
    learned = [c for c, on in zip(cal.COMPONENTS, np.ones(6, bool) if learn is None else learn) if on]
    away = (qc >= cal.QC_MAX) & np.isin(cal.COMPONENTS, learned)  # no fixed point: the base config's value is kept
    qc = np.where(away, np.asarray(getattr(config.noise, field), dtype=float), qc)
    report = {"mode": "EM without ground truth", "prior": config.prior, "field": field, "floor": floor,
              "learned_components": learned, "runaway": [c for c, a in zip(cal.COMPONENTS, away) if a],
              "converged": history[-1].remaining < tolerance, "tolerance": tolerance,
              "iterations": [{"qc_in": h.qc_in.tolist(), "qc_out": h.qc_out.tolist(), "loglik": h.loglik,
                              "change": h.change, "remaining": h.remaining if np.isfinite(h.remaining) else None,
                              "intervals": h.intervals,
                              "steps": h.steps}
                             for h in history]}
    if measurement is not None:
        report["measurement"] = measurement
    report["velocity_growth"] = _growth_check(tracks[0], config.prior, qc)
    report["information"] = _bound(tracks[0], config.prior, qc, history[-1].qc_in, learn)
    return config.replace(noise=dataclasses.replace(config.noise, **{field: tuple(qc)})), report


def _growth_check(track: cal.StateTrack, prior: str, qc) -> list[dict] | str:
    """EM's Qc against the one the estimated velocity's growth over seconds gives (`velocity_growth`), on EM's
    last run (at the Qc its last iteration started from: the growth hardly depends on it); or why it is not
    checked."""
    try:
        return vg.growth_check(qc, vg.velocity_growth(track, prior))
    except InputError as e:
        return f"not checked: {e}"


def _bound(track: cal.StateTrack, prior: str, qc, qc_run, learn) -> dict | str:
    """The Cramer-Rao bound of EM's Qc on this drive (`qc_information.qc_bound`, from EM's last run, at the Qc it
    started from), or why it was not computed."""
    try:
        rows = qi.qc_bound(prior, track, qc, qc_run, learn)
    except (np.linalg.LinAlgError, InputError) as e:
        return f"not computed: {e}"
    return {"duration_s": float(track.t[-1] - track.t[0]), "samples": qi.SAMPLES, "rows": rows}


def _toml_value(v) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(_toml_value(x) for x in v) + "]"
    if isinstance(v, int):
        return str(v)
    if isinstance(v, float):
        return repr(float(v))
    if isinstance(v, str):
        return '"' + v.replace("\\", "\\\\").replace('"', '\\"') + '"'
    raise InputError(f"config: cannot write {v!r} as TOML")


def config_toml(config: OdometryConfig, header: list[str] = ()) -> str:
    """The complete config as TOML (every field; floats as repr, so `from_toml` gives the same config back),
    after `header` lines written as comments.

    Checked by: tests/validation/test_calibrate.py::test_config_toml_round_trips
    """
    lines = [f"# {h}" if h else "#" for h in header]
    data = config.to_dict()
    tables = {k: v for k, v in data.items() if isinstance(v, dict)}
    lines += [f"{k} = {_toml_value(v)}" for k, v in data.items() if k not in tables]
    for name, table in tables.items():
        lines += ["", f"[{name}]"] + [f"{k} = {_toml_value(v)}" for k, v in table.items()]
    return "\n".join(lines) + "\n"
