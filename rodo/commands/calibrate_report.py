"""The reports of `rodo calibrate` (rodo/commands/calibrate.py): the config's header lines and CONFIG.md, from the
report the calibration returns (`validation.calibrate_config`)."""

from __future__ import annotations

import numpy as np

from rodo.validation.calibrate import COMPONENTS
from rodo.validation.calibrate_drift import DRIFT_SIGNIFICANCE
from rodo.validation.calibrate_relative import REST_FRACTION
from rodo.validation.error_growth import growth_lines
from rodo.validation.qc_information import bound_header, bound_lines
from rodo.validation.velocity_growth import growth_check_header, growth_check_lines

MAX_NAMED = 8  # gross failures named in the report by run and time (all of them in the .json)


def floor_words(floor) -> str:
    """The floor as the report says it: '1e-04' or 'x 1e-04, ..., yaw 1e-04'."""
    if np.ndim(floor) == 0:
        return f"{floor:g}"
    return ", ".join(f"{c} {v:g}" for c, v in zip(COMPONENTS, floor))


def header(report: dict, seq_dir: str, model: str) -> list[str]:
    lines = [f"rodo calibrate {seq_dir} --model {model}: {report['mode']}."]
    if report["mode"] == "ground truth":
        lines += [f"noise.qc_ca, noise.qc_cv: maximum likelihood of the true states' prior residuals "
                  f"({report['qc_ca']['intervals']} intervals); elements at the floor "
                  f"({floor_words(report['floor'])}) were not excited by the trajectory.",
                  "noise.sensor_sigma_scale: ML common factor on sensor.toml's sigmas from the static detections; "
                  "per-channel sigmas are in the .json/.md report.",
                  f"noise.doppler_common_sigma {report['measurement']['doppler_common']['sigma_c']:.3g} m/s: the "
                  "scans' common Doppler error (0 unless significant; docs/calibration.md)."]
        lines += _vehicle_lines(report.get("vehicle"))
        if "consistency" in report:
            c = report["consistency"]
            v = c["velocity_inflation"]
            rel = c["relative_inflation"]
            lines.append(f"uncertainty: measurement_inflation {c['measurement_inflation']:.3g}, inflation "
                         f"{_relative_words(rel)}, velocity_inflation "
                         f"{v['inflation']:.3g} + {v['per_speed']:.3g} s/m x speed + {v['per_doppler']:.3g} x "
                         "ln(1 + Doppler NIS)" + _rate_words(v)
                         + (" and per axis" if set(v.get("per_axis", [1.0])) != {1.0} else "") + _lag_words(v)
                         + ", drift_rate_sigma and "
                         f"velocity_correlation_time {c['velocity_correlation_time']:g} s"
                         + _correlation_words(c)
                         + _heading_words(c) + _jitter_words(c)
                         + _axis_words(c)
                         + (", stationary_variance and stationary_time" if c.get("stationary_error", {}).get("fitted")
                            else "") + " fitted so that the "
                         "estimator's NEES against the truth is consistent (docs/calibration.md).")
    else:
        it = report["iterations"]
        lines += [f"noise.{report['field']} ({', '.join(report['learned_components'])}): EM over the estimator's "
                  f"posteriors, {len(it)} iteration(s), last "
                  f"relative change {it[-1]['change']:.3g}, {_left(it[-1]['remaining'])} left to the fixed point the "
                  f"steps extrapolate to ({'converged' if report['converged'] else 'NOT converged'}"
                  f" at {report['tolerance']:g}).",
                  "noise.sensor_sigma_scales, noise.cartesian_sigma: learned first from the static detections of "
                  "consecutive scans (docs/calibration.md); everything else as in the base config."
                  if "measurement" in report else
                  "Everything else (including the measurement noise) as in the base config."]
        if report.get("runaway"):
            lines.append(f"RUNAWAY: EM's {', '.join(report['runaway'])} reached the fit's upper bound (no fixed point "
                         "on this drive: an estimate's jump or error booked as motion); the base config's value is "
                         "kept.")
        lines += growth_check_header(report.get("velocity_growth"), report["learned_components"])
        if isinstance(report.get("information"), dict):
            lines += bound_header(report["information"]["rows"])
    return lines + ["The learned values and likelihoods are in the .json and .md files beside this one.", ""]


def _left(remaining) -> str:
    """The distance EM had left; None (JSON has no infinity) where the last runs' steps grew: "inf"."""
    return "inf" if remaining is None else f"{remaining:.3g}"


def markdown(report: dict) -> str:
    vec = lambda v: ", ".join(f"{x:.4g}" for x in v)  # noqa: E731
    lines = [f"# rodo calibrate: {report['mode']}", ""]
    if report["mode"] == "ground truth":
        for key in ("qc_ca", "qc_cv"):
            r = report[key]
            lines.append(f"- {key} = [{vec(r['qc'])}] (log-likelihood {r['loglik']:.6g}, {r['intervals']} intervals)")
        m = report["measurement"]
        lines += ["", "| channel | sigma | sensor.toml | mean | a + b r: a, b per m (stderr) | range dependent |",
                  "| --- | --- | --- | --- | --- | --- |"]
        for name, c in m["channels"].items():
            ln = c["line"]
            lines.append(f"| {name} | {c['sigma']:.4g} | {m['sensor_toml_sigmas'][name]:.4g} | {c['mean']:.2g} | "
                         f"{ln['a']:.4g}, {ln['b_per_m']:.2g} ({ln['b_stderr']:.2g}) | {c['range_dependent']} |")
        d = m["doppler_common"]
        lines += [""] + _vehicle_lines(report.get("vehicle"))
        lines += ["", f"sensor_sigma_scale = {m['sensor_sigma_scale']:.4g}",
                  "", f"common Doppler error per scan: sigma_c {d['sigma_c_estimate']:.3g} m/s "
                  f"({'significant' if d['significant'] else 'not significant: 0 written'}), independent radial "
                  f"velocity sigma {d['sigma_vr_independent']:.3g} m/s, lag-1 correlation "
                  f"{', '.join(f'{x:.2f}' for x in d['lag1'])} over {d['scans']} scans"]
        if "consistency" in report:
            lines += [""] + _consistency_markdown(report["consistency"])
            lines += growth_lines(report["consistency"].get("error_growth"), lambda v: "-" if v is None else f"{v:.3g}")
    else:
        lines += ["| iteration (estimator run) | Qc in | Qc out | EM steps in its stand-in | change | left (extrapolated) "
                  "| expected log-likelihood |", "| --- | --- | --- | --- | --- | --- | --- |"]
        for i, h in enumerate(report["iterations"], 1):
            lines.append(f"| {i} | {vec(h['qc_in'])} | {vec(h['qc_out'])} | {h.get('steps', '-')} | {h['change']:.3g} | "
                         f"{'-' if h['remaining'] is None else format(h['remaining'], '.3g')} | {h['loglik']:.6g} |")
        if "measurement" in report:
            lines += [""] + _sensor_noise_markdown(report["measurement"])
        lines += [""] + growth_check_lines(report.get("velocity_growth"), report["learned_components"])
        info = report.get("information")
        if info is not None:
            lines += [""] + (bound_lines(info["rows"], info["duration_s"]) if isinstance(info, dict) else [info])
    return "\n".join(lines) + "\n"


def _sensor_noise_markdown(m: dict) -> list[str]:
    """The measurement noise learned without ground truth: per channel learned, configured and sensor.toml."""
    lines = ["## Measurement noise without ground truth", "",
             f"{m['pairs']} pairs of static detections in consecutive scans, the radial velocity from "
             f"{m['doppler_detections']} static detections in {m['doppler_scans']} scans.", "",
             "| channel | learned sigma | the base config's | sensor.toml | learned |",
             "| --- | --- | --- | --- | --- |"]
    for (name, sigma), on in zip(m["sigmas"].items(), m["learned"]):
        lines.append(f"| {name} | {sigma:.4g} | {m['configured_sigmas'][name]:.4g} | "
                     f"{m['sensor_toml_sigmas'][name]:.4g} | {'yes' if on else 'no (planar data): kept'} |")
    cart = m["cartesian_sigma"]
    return lines + ["", f"cartesian_sigma = {cart:.4g} m" if cart is not None else
                    "cartesian_sigma: kept (planar data: the elevation's share is unknown)"]


def _failure_words(failures) -> str:
    """'; N scans left out as gross failures[: run r at t s, ...]' (validation.gross_failures), '' for none; failures:
    a count, or {"scans", "runs", "t"}."""
    n = failures if isinstance(failures, int) or not failures else failures["scans"]
    if not n:
        return ""
    words = (f"; {n} scan{'s' if n != 1 else ''} left out as gross failures (NEES above 100 per dof at the median "
             "scan's level)")
    if isinstance(failures, int):
        return words
    where = ", ".join(f"run {r} at {t:.2f} s" for r, t in zip(failures["runs"][:MAX_NAMED], failures["t"][:MAX_NAMED]))
    return f"{words}: {where}{f' and {n - MAX_NAMED} more' if n > MAX_NAMED else ''} (runs: the SEQ_DIRs from 0)"


def _consistency_markdown(c: dict) -> list[str]:
    """The uncertainty fit's table: per estimator run, kappa, tau and the median NEES ratios."""
    names = ("velocity", "relative_scan", "relative_span", "pose")
    lines = ["## Uncertainty (median NEES / median of chi2(6): 1 is consistent)", "",
             "| run | measurement_inflation | tau (s) | " + " | ".join(names) + " |",
             "| --- | --- | --- |" + " --- |" * len(names)]
    for i, s in enumerate(c["steps"], 1):
        ratios = " | ".join(f"{s['median_ratio'][n]:.3g}" for n in names)
        lines.append(f"| {i} | {s['kappa']:.3g} | {s['tau']:g} | {ratios} |")
    d, v, rel = c["drift_rate"], c["velocity_inflation"], c["relative_inflation"]
    vec = ", ".join(f"{x:.3g}" for x in d["sigma"])
    before, after = rel["mean_ratio"]
    lines += ["", "relative pose covariance factor (uncertainty.inflation, inflation_per_doppler, "
              f"inflation_per_pull, inflation_per_rate; velocity_error_share) {_relative_words(rel)} (mean "
              f"NEES/dof of the one-scan relative pose {before:.3g} -> {after:.3g}; "
              f"{rel['outcome']}{_failure_words(rel.get('gross_failures', 0))})",
              f"velocity variance factor {v['inflation']:.3g} + {v['per_speed']:.3g} s/m x speed + "
              f"{v['per_doppler']:.3g} x ln(1 + Doppler NIS){_rate_words(v)}, per axis vx, vy, vz, wx, wy, wz x "
              f"[{', '.join(f'{g:.3g}' for g in v.get('per_axis', [1.0] * 6))}]{_lag_words(v)} (maximum "
              f"likelihood over {v['scans']} scans: mean velocity NEES/dof {v['nees_per_dof'][0]:.3g} -> "
              f"{v['nees_per_dof'][1]:.3g}{_failure_words(v.get('gross_failures'))})",
              f"drift_rate_sigma = [{vec}] (x, y, z m/m; roll, pitch, yaw rad/m) over {d['distance']:.0f} m"
              + (f" (beta / its standard error over {d['block']:g} s blocks "
                 f"[{', '.join(f'{x:.2g}' for x in d['z'])}]: components below {DRIFT_SIGNIFICANCE:g} not carried)"
                 if "z" in d else ""),
              "tau grid (median ratio of the relative pose over the span / of the absolute pose): "
              + ", ".join(f"{t} s: {r['relative_span']:.3g} / {r['pose']:.3g}" for t, r in c["tau_grid"].items())]
    if c.get("registration_correlation", {}).get("grid"):
        lines.append("registration_correlation grid (alpha: its tau, the cost): " + ", ".join(
            f"{a}: {r['tau']:g} s, {r['cost']:.3g}" for a, r in c["registration_correlation"]["grid"].items()))
    if c.get("heading_reversion", {}).get("grid"):
        h = c["heading_reversion"]
        chosen = f"{h['time']:g} / {h['anchor_time']:g} s" if h["time"] > 0 else "off"
        lines.append("heading reversion grid (T_r / T_a s: the cost of the yaw's E[e^2 / sigma^2] over the spans "
                     "from the span on and over the drive, at the first tau): "
                     + ", ".join(f"{k}: {_heading_cost(r)}" for k, r in h["grid"].items()) + f"; chosen: {chosen}")
    j = c.get("attitude_jitter", {})
    if j.get("fitted"):
        lines.append(f"attitude jitter variance {j['variance']:.3g} rad^2 at T {j['time']:g} s ({j['outcome']}: mean "
                     f"roll and pitch NEES/dof of the relative pose over the span {j['mean_without']:.3g} -> "
                     f"{j['mean_with']:.3g})")
    a = c.get("registration_axis_correlation", {})
    if a.get("fitted"):
        lines.append("registration's correlation per axis (the share of what alpha leaves independent; the cost of its "
                     "growth over 0.5-20 s without -> with): " + ", ".join(
                         f"{k} {x['share']:g} ({x['cost_without']:.3g} -> {x['cost']:.3g})"
                         for k, x in a["axes"].items()))
    s = c.get("stationary_error", {})
    if s.get("fitted"):
        lines.append("stationary error per axis (share of the one-scan variance / T s / V; the cost of its growth "
                     "over 0.5-20 s without -> with): " + ", ".join(
                         f"{k} {a['share']:g} / {a['time']:g} s / {a['variance']:.3g} ({a['cost_without']:.3g} -> "
                         f"{a['cost']:.3g})" if a["share"] else f"{k} off" for k, a in s["axes"].items()))
    return lines


def _heading_cost(r: dict) -> str:
    """A heading grid point's cost (reports before session 46: its 6-dof span / pose ratios)."""
    return f"{r['cost']:.3g}" if "cost" in r else f"{r['relative_span']:.3g} / {r['pose']:.3g}"


def _heading_words(c: dict) -> str:
    """', heading_reversion_time T_r s and heading_anchor_time T_a s' of a consistency report, '' when off."""
    h = c.get("heading_reversion", {"time": 0.0})
    return (f", heading_reversion_time {h['time']:g} s and heading_anchor_time {h['anchor_time']:g} s"
            if h["time"] > 0 else "")


def _lag_words(v: dict) -> str:
    """' with its lag behind a manoeuvre [...] per forward and [...] per yaw acceleration' of a velocity factor
    with a lag (`estimator.velocity_lag`), '' otherwise."""
    a, y = v.get("lag_per_acceleration", [0.0] * 6), v.get("lag_per_yaw_acceleration", [0.0] * 6)
    if not (any(a) or any(y)):
        return ""
    a, y = (", ".join(f"{e:.3g}" for e in x) for x in (a, y))
    return f" with its lag behind a manoeuvre (velocity_lag) [{a}] s per forward and [{y}] per yaw acceleration"


def _rate_words(v: dict) -> str:
    """' + [r_x, r_y, r_z] s/rad x |body rates|' of a velocity or relative pose factor with rate terms, ''
    otherwise."""
    r = v.get("per_rate", [0.0] * 3)
    return f" + [{', '.join(f'{x:.3g}' for x in r)}] s/rad x |body rates|" if any(r) else ""


def _relative_words(rel: dict) -> str:
    """'f + d x ln(1 + Doppler NIS) + p x pull + [r_x, r_y, r_z] s/rad x |body rates| with velocity_error_share g
    + g_v s/m x speed' of the relative pose factor (the terms that are not 0, the share where it is not 1)."""
    d, p = rel.get("per_doppler", 0.0), rel.get("per_pull", 0.0)
    g, g_v = rel.get("velocity_error_share", 1.0), rel.get("velocity_error_share_per_speed", 0.0)
    return (f"{rel['inflation']:.3g}" + (f" + {d:.3g} x ln(1 + Doppler NIS)" if d else "")
            + (f" + {p:.3g} x pull" if p else "") + _rate_words(rel)
            + (f" with velocity_error_share {g:.3g}" if g != 1.0 or g_v else "")
            + (f" + {g_v:.3g} s/m x speed" if g_v else "")
            + (" (no speed term: the drive does not stop)" if "rest_fraction" in rel and not g_v
               and rel["rest_fraction"] < REST_FRACTION else ""))


def _correlation_words(c: dict) -> str:
    """' with registration_correlation alpha' of a consistency report (none in reports before it)."""
    alpha = c.get("registration_correlation", {}).get("value")
    return "" if alpha is None else f" with registration_correlation {alpha:g}"


def _vehicle_lines(v: dict | None) -> list[str]:
    """The road-vehicle terms learned (`calibrate_vehicle`): one line, none where they were not."""
    if not v or not v.get("fitted"):
        return []
    return [f"vehicle.sigma_roll_rate {v['sigma'][0]:.3g}, sigma_pitch_rate {v['sigma'][1]:.3g} rad/s: sqrt(window) x "
            f"the true roll and pitch rates' RMS over {v['moving_scans']} moving scans ({v['rms'][0]:.3g}, "
            f"{v['rms'][1]:.3g}; at least {v['floor']:g}; a term the base config has off stays off; it had "
            f"{v['before'][0]:g}, {v['before'][1]:g})."]


def _axis_words(c: dict) -> str:
    """', registration_axis_correlation (x 0.25, pitch 1)' where the fit took a share on some axis, else ''."""
    a = c.get("registration_axis_correlation", {})
    taken = [f"{k} {x['share']:g}" for k, x in a.get("axes", {}).items() if x["share"]] if a.get("fitted") else []
    return f", registration_axis_correlation ({', '.join(taken)})" if taken else ""


def _jitter_words(c: dict) -> str:
    """', attitude_jitter_variance V rad^2' of a consistency report whose jitter was fitted, '' otherwise."""
    j = c.get("attitude_jitter", {})
    return f", attitude_jitter_variance {j['variance']:.3g} rad^2" if j.get("fitted") else ""
