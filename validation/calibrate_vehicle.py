"""`rodo calibrate` with truth: the road-vehicle terms on the roll and pitch rates (`[vehicle] sigma_roll_rate`,
`sigma_pitch_rate`) from the true motion.

Each moving state's roll and pitch rates get a zero-mean Gaussian term (estimator/config.py, `VehicleConfig`;
docs/estimator.md, "Roll and pitch rates"). The true rate's RMS over the moving scans (speed above the config's
`standstill.speed`, where the term applies) is its spread; but every one of the window's `window` states carries the
term, and a road vehicle's rate holds for seconds, longer than the window spans, so their information adds up on
one rate: sigma = RMS x sqrt(window) gives that rate the variance RMS^2 (the RMS itself made hills, whose grade
changes hold the pitch rate for seconds, less accurate: docs/consistency.md, "The vehicle's rate terms learned").
Floored at RATE_FLOOR. A term the base config has off (0: a hand-held sensor, a drone, the prior's own motion) stays
off. The defaults, 0.01 and 0.015 rad/s, were chosen by hand on city and hills seeds 1-5 as a compromise between
city (whose rates are a tenth of them) and hills (whose grade changes reach 0.03 rad/s); learned, each scenario gets
its own. Only with `--vehicle-rates`: the reported covariance's learned terms do not follow it yet.

Checked by: tests/validation/test_calibrate_vehicle.py
"""

from __future__ import annotations

import dataclasses

import numpy as np

from rodo.estimator.config import OdometryConfig

from . import calibrate as cal

RATE_FLOOR = 1e-3  # rad/s: the least sigma learned (a drive whose truth never rolls would give 0, which is "off")
ROLL, PITCH = 3, 4  # varpi's rows of the roll and pitch rates


def fit_vehicle_rates(tracks: list[cal.StateTrack], config: OdometryConfig,
                      floor: float = RATE_FLOOR) -> tuple[OdometryConfig, dict]:
    """The config with `vehicle.sigma_roll_rate` and `sigma_pitch_rate` at sqrt(window) times the RMS of the true roll
    and pitch rates over the tracks' moving scans (pooled; at least `floor`), each where the base config has its term
    on; and the report: the RMS, the sigmas in and out, the moving scans."""
    varpi = np.concatenate([np.asarray(k.varpi, dtype=float) for k in tracks])
    moving = np.linalg.norm(varpi[:, :3], axis=1) > config.standstill.speed
    rms = np.sqrt(np.mean(varpi[moving][:, [ROLL, PITCH]] ** 2, axis=0)) if moving.any() else np.full(2, np.nan)
    v = config.vehicle
    before = (v.sigma_roll_rate, v.sigma_pitch_rate)
    scale = np.sqrt(config.window)
    after = tuple(float(max(r * scale, floor)) if s > 0 and np.isfinite(r) else float(s) for r, s in zip(rms, before))
    report = {"rms": rms.tolist(), "before": list(before), "sigma": list(after), "floor": floor,
              "moving_scans": int(moving.sum()), "fitted": True}
    vehicle = dataclasses.replace(v, sigma_roll_rate=after[0], sigma_pitch_rate=after[1])
    return config.replace(vehicle=vehicle), report
