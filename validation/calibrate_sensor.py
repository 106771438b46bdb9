"""Learning the radar's measurement noise R from a simulated sequence with ground truth (`rodo calibrate`,
docs/calibration.md).

Residuals measured minus noise-free polar (truth.npz `det_true_polar`, azimuth wrapped) of the static
detections (`det_label` 0 static surface, 1 static point scatterer) give per channel the maximum-likelihood
zero-mean sigma sqrt(mean(res^2)), the mean (a bias), per-range-bin sigmas and a straight-line fit
sigma(r) = a + b r to |res| sqrt(pi / 2) (E|res| = sigma sqrt(2 / pi) for a Gaussian), with b's standard error,
to tell whether the spread depends on range. `sigma_scale` is the single factor s on the sensor.toml sigmas
that maximises the likelihood of all channels together (what `noise.sensor_sigma_scale` can express).

Checked by: tests/validation/test_calibrate_sensor.py::test_measurement_noise_recovered_on_city
"""

from __future__ import annotations

import numpy as np

from rodo.estimator.ego_velocity import PLANAR_ELEVATION
from rodo.estimator.errors import InputError
from rodo.estimator.radar_geometry import polar_to_cartesian, wrap_angle

CHANNELS = ("range", "azimuth", "elevation", "radial_velocity")
STATIC_LABELS = (0, 1)  # truth.npz det_label: 0 static surface, 1 static point scatterer, 2 mover, 3 clutter
RANGE_BINS = 6  # channel_noise's range bins, two detections each at least
WITH_TRUTH = f"static detections with truth (truth.npz det_label {' or '.join(map(str, STATIC_LABELS))})"


def check_residuals(res: np.ndarray, r: np.ndarray | None = None, minimum: int = 2 * RANGE_BINS,
                    what: str = WITH_TRUTH) -> np.ndarray:
    """res as an (M, 4) float array, M matching r; InputError (before any mean of an empty array) unless
    M >= minimum: a sequence without static detections (all dropped, all clutter) has no noise to learn.

    Checked by:
        tests/cli/test_command_defects_realism_calibrate.py::test_the_noise_fits_refuse_empty_residuals_before_any_mean
    """
    res = np.asarray(res, dtype=float)
    if res.ndim != 2 or res.shape[1] != 4 or (r is not None and res.shape[0] != np.shape(r)[0]):
        ranges = "" if r is None else f" and {np.shape(r)} ranges"
        raise InputError(f"measurement noise: expected (M, 4) residuals and M ranges, got {res.shape}{ranges}")
    if res.shape[0] < minimum:
        raise InputError(f"measurement noise: need >= {minimum} {what}, got {res.shape[0]}")
    return res


def detection_residuals(seq, truth: dict, scans: int | None = None,
                        labels=STATIC_LABELS) -> tuple[np.ndarray, np.ndarray]:
    """(res (M, 4), true range (M,)) of the detections with the given labels in the first `scans` scans of the
    truth (all when None; `seq` holds exactly those scans); res = measured - true polar, azimuth wrapped.

    Raises:
        InputError: radar.csv and truth.npz do not hold the same detections (counts per scan differ).
    """
    for key in ("det_true_polar", "det_label", "scan_offsets"):
        if key not in truth:
            raise InputError(f"truth.npz: missing array {key!r} (needed for the measurement noise)")
    offsets = np.asarray(truth["scan_offsets"])
    measured = np.concatenate([s.polar for s in seq.scans]) if seq.scans else np.zeros((0, 4))
    true = np.asarray(truth["det_true_polar"], dtype=float)
    if len(offsets) == 0 or offsets[-1] != len(true) or true.ndim != 2 or true.shape[1] != 4:
        raise InputError("truth.npz: scan_offsets and det_true_polar disagree")
    n = len(true) if scans is None else int(offsets[min(scans, len(offsets) - 1)])
    if len(measured) != n:
        raise InputError(f"truth.npz: det_true_polar has {n} detections in these scans, radar.csv {len(measured)}: "
                         "not the same sequence")
    keep = np.isin(np.asarray(truth["det_label"])[:n], labels)
    res = measured[:n][keep] - true[:n][keep]
    res[:, 1] = wrap_angle(res[:, 1])
    return res, true[:n][keep, 0]


def cartesian_sigma(res: np.ndarray, r: np.ndarray) -> float:
    """ML isotropic Cartesian sigma c of the detections' position errors (the CV/C baseline's fixed R):
    c^2 = mean over detections and axes of the squared Cartesian error, to first order the polar residuals
    seen through d(x, y, z)/d(r, az, el) at the true range (azimuth and elevation near boresight are enough for
    the trace: |dp|^2 = dr^2 + r^2 (cos^2(el) daz^2 + del^2), with cos(el) ~ 1 for a radar's elevations).

    Checked by: tests/validation/test_calibrate_sensor.py::test_cartesian_sigma_is_the_ml_isotropic_sigma
    """
    res = check_residuals(res, r, minimum=1, what="static detection")
    sq = res[:, 0] ** 2 + np.asarray(r, dtype=float) ** 2 * (res[:, 1] ** 2 + res[:, 2] ** 2)
    return float(np.sqrt(np.mean(sq) / 3.0))


def _range_fit(abs_res: np.ndarray, r: np.ndarray) -> dict:
    """Least squares |res| sqrt(pi/2) = a + b r, with b's standard error."""
    y = abs_res * np.sqrt(np.pi / 2)
    X = np.stack([np.ones_like(r), r], axis=1)
    coef, *_ = np.linalg.lstsq(X, y, rcond=None)
    resid = y - X @ coef
    dof = max(len(y) - 2, 1)
    cov = np.linalg.inv(X.T @ X) * float(resid @ resid) / dof
    return {"a": float(coef[0]), "b_per_m": float(coef[1]), "b_stderr": float(np.sqrt(cov[1, 1]))}


def channel_noise(res: np.ndarray, r: np.ndarray, bins: int = RANGE_BINS) -> dict:
    """Per channel: sigma (ML, zero mean), mean, count, sigma per range bin (equal counts), the line
    sigma(r) = a + b r and `range_dependent` (|b| above 4 standard errors and b (r_max - r_min) above 5 % of
    sigma).

    Checked by: tests/validation/test_calibrate_sensor.py::test_range_dependence_is_detected
    """
    res, r = check_residuals(res, r, 2 * bins), np.asarray(r, dtype=float)
    edges = np.quantile(r, np.linspace(0, 1, bins + 1))
    which = np.clip(np.searchsorted(edges, r, side="right") - 1, 0, bins - 1)
    out = {}
    for c, name in enumerate(CHANNELS):
        x = res[:, c]
        sigma = float(np.sqrt(np.mean(x**2)))
        fit = _range_fit(np.abs(x), r)
        span = float(r.max() - r.min())
        out[name] = {
            "sigma": sigma, "mean": float(np.mean(x)), "count": int(len(x)),
            "bins": [{"range_m": [float(edges[j]), float(edges[j + 1])],
                      "sigma": float(np.sqrt(np.mean(x[which == j]**2)))} for j in range(bins)],
            "line": fit,
            "range_dependent": bool(abs(fit["b_per_m"]) > 4 * fit["b_stderr"]
                                    and abs(fit["b_per_m"]) * span > 0.05 * sigma),
        }
    return out


def sigma_scale(res: np.ndarray, sensor_sigmas) -> float:
    """ML single scale s of the sensor sigmas over all channels: s^2 = mean((res / sigma_sensor)^2).

    Checked by: tests/validation/test_calibrate_sensor.py::test_measurement_noise_recovered_on_city
    """
    sig = np.asarray(sensor_sigmas, dtype=float)
    if sig.shape != (4,) or not np.all(sig > 0):
        raise InputError(f"sensor sigmas: expected 4 positive numbers, got {sensor_sigmas!r}")
    return float(np.sqrt(np.mean((check_residuals(res) / sig) ** 2)))


def common_doppler_error(seq, truth: dict, scans: int | None = None, labels=STATIC_LABELS,
                         significance: float = 4.0) -> dict:
    """The scans' common Doppler error (`noise.doppler_common_sigma`) from the static detections' radial-velocity
    residuals (measured - true): per scan k, b_k = least-squares fit of the residuals e on the true directions u
    (e = -u . b_k + independent noise); the independent sigma_vr from what the fits leave; sigma_c^2 = mean over
    scans and axes of b_k^2 minus the fit's own noise sigma_vr^2 (U^T U)^-1, set to 0 unless it exceeds
    `significance` standard errors of that mean (a clean simulation then gets exactly 0). `seq` and `truth` may
    be lists (several sequences, their scans pooled; `scans` then one limit for each or a list). Returns sigma_c,
    sigma_vr (independent), the lag-1 correlation of the b_k, the scans used and whether it was significant.

    Checked by: tests/validation/test_calibrate_sensor.py::test_common_doppler_error_recovered_from_truth
    """
    if isinstance(truth, dict):
        seq, truth, scans = [seq], [truth], [scans]
    b, excess_noise, rss, dof_sum = [], [], 0.0, 0
    for seq, truth, limit in zip(seq, truth, scans if isinstance(scans, (list, tuple)) else [scans] * len(truth)):
        offsets = np.asarray(truth["scan_offsets"])
        true = np.asarray(truth["det_true_polar"], dtype=float)
        label = np.asarray(truth["det_label"])
        n_scans = len(offsets) - 1 if limit is None else min(limit, len(offsets) - 1)
        measured = [s.polar for s in seq.scans[:n_scans]]
        for k in range(n_scans):
            rows = slice(offsets[k], offsets[k + 1])
            keep = np.isin(label[rows], labels)
            if len(measured[k]) != offsets[k + 1] - offsets[k]:
                raise InputError(f"truth.npz: scan {k} has {offsets[k + 1] - offsets[k]} detections, radar.csv "
                                 f"{len(measured[k])}: not the same sequence")
            t, m = true[rows][keep], measured[k][keep]
            dof = 2 if np.all(np.abs(t[:, 2]) < PLANAR_ELEVATION) else 3
            if len(t) < dof + 5:
                continue
            U = polar_to_cartesian(np.c_[np.ones(len(t)), t[:, 1], t[:, 2]])[:, :dof]
            e = m[:, 3] - t[:, 3]
            info = U.T @ U
            b_k = -np.linalg.solve(info, U.T @ e)
            r = e + U @ b_k
            rss, dof_sum = rss + float(r @ r), dof_sum + len(e) - dof
            b.append(b_k)
            excess_noise.append(np.diag(np.linalg.inv(info)))
    if len(b) < 10:
        raise InputError(f"common Doppler error: need >= 10 scans with static detections, got {len(b)}")
    sigma_vr2 = rss / dof_sum
    # unbiased for sigma_c^2 per scan and axis; a scan whose detections all lie in the sensor plane fits 2 axes
    samples = np.concatenate([b_k**2 - sigma_vr2 * d for b_k, d in zip(b, excess_noise)])
    est, se = float(samples.mean()), float(samples.std(ddof=1) / np.sqrt(samples.size))
    significant = bool(est > significance * se)
    axes = [np.array([b_k[i] for b_k in b if len(b_k) > i]) for i in range(max(len(b_k) for b_k in b))]
    lag1 = [float(np.corrcoef(x[1:], x[:-1])[0, 1]) if len(x) > 2 else float("nan") for x in axes]
    return {"sigma_c": float(np.sqrt(est)) if significant else 0.0,
            "sigma_c_estimate": float(np.sqrt(max(est, 0.0))), "standard_error_of_sigma_c2": se,
            "significant": significant, "sigma_vr_independent": float(np.sqrt(sigma_vr2)), "lag1": lag1,
            "scans": len(b)}
