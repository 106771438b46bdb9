"""TI mmWave (ti_mmwave_rospkg, RIO demo CSV export) 4D radar -> the sequence format.

Input folder (`rio_ti_mmwave_demo`, see its README): `radar_scans.csv` (`scan_idx,t_trigger_ns,...`),
`radar_detections.csv` (`scan_idx,x_m,y_m,z_m,intensity,v_radial_mps,...`, sensor frame x forward, y left,
z up) and `calib_ti_mmwave_rospkg_dataset.yaml` (radar -> IMU body extrinsics, radar_frame_ms).

- Scan time: trigger time + radar_frame_ms / 2 (the upstream ekf_rio convention: mid-exposure), in seconds
  from the first scan's trigger (its absolute time in ns is kept in conversion.json, `t0_ns`).
- Vehicle frame = the IMU body frame (`base_link`). The yaml's q_b_r/l_b_r refer to RIO's radar frame
  (x_r = -y_ti, y_r = x_ti, z_r = z_ti), so T_vehicle_sensor = [C_b_r C_r_ti, l_b_r].
- Polar coordinates are recomputed in float64 from x, y, z; `intensity` is kept as the extra column `snr`.
- Doppler quantisation is measured (step and share of values on the grid) and reported; sigma_vr is the
  quantisation noise (measured step) / sqrt(12) (the sensor noise below it is not observable here).
- No ground truth: no groundtruth.txt.
- Refused, naming the file and field: trigger times whose median step is no scan rate (0.1-1000 Hz: times in
  ms?), more than 1 % of the detections beyond MAX_RANGE_M (millimetres?; fewer are dropped and counted), no
  detections.

Checked by: tests/sim/test_convert.py::test_ti_*, tests/validation/test_realdata.py::test_ti_*,
    tests/sim/test_convert_review55.py::test_ti_*
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from rodo.estimator.errors import InputError
from rodo.estimator.lie import so3
from rodo.sim.sequence import NoiseSigmas, SensorConfig, Sequence

from ._common import (Conversion, ConversionReport, check_scan_step, drop_few, field_of_view, polar_from_xyz,
                      read_csv, read_flat_yaml, require_detections, scans_from_rows)

SCANS_CSV = "radar_scans.csv"
DETECTIONS_CSV = "radar_detections.csv"
CALIB_YAML = "calib_ti_mmwave_rospkg_dataset.yaml"
CALIB_KEYS = ("l_b_r_x", "l_b_r_y", "l_b_r_z", "q_b_r_x", "q_b_r_y", "q_b_r_z", "q_b_r_w", "radar_frame_ms")
C_RIO_TI = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])  # p_rio = C_RIO_TI @ p_ti
MAX_RANGE_M = 2000.0  # m: farther detections are dropped, refused when more than 1 % (millimetres; the IWR6843
# sees tens of metres); also keeps a range that overflows (1e308 m) out
MAX_SPAN_NS = 10**18  # trigger times spread over more than 30 years are refused
DOPPLER_STEP = 0.125  # m/s, nominal quantisation (the measured step is used and reported)
# nominal sigmas (IWR6843AOP, 3 Tx / 4 Rx: coarse angles); not observable without ground truth
RANGE_SIGMA = 0.05
AZIMUTH_SIGMA = np.deg2rad(3.0)
ELEVATION_SIGMA = np.deg2rad(5.0)


def read_calibration(path) -> tuple[np.ndarray, float]:
    """(4, 4) T_vehicle_sensor (vehicle = IMU body) and radar_frame_ms from the RIO calibration yaml."""
    values = read_flat_yaml(path)
    missing = [k for k in CALIB_KEYS if k not in values]
    if missing:
        raise InputError(f"{path}: missing key(s) {', '.join(missing)}")
    v = {k: values[k][0] for k in CALIB_KEYS}
    q = np.array([v["q_b_r_x"], v["q_b_r_y"], v["q_b_r_z"], v["q_b_r_w"]])
    # components checked before the norm: 1e154 would overflow it (found by the fuzzer)
    norm = float(np.linalg.norm(q)) if np.all(np.abs(q) <= 2.0) else float("nan")
    if not abs(norm - 1.0) <= 1e-3:
        raise InputError(f"{path}, line {values['q_b_r_x'][1]}, field 'q_b_r': not a unit quaternion "
                         f"(x, y, z, w = {', '.join(f'{c:.6g}' for c in q)})")
    if not 0 <= v["radar_frame_ms"] < np.inf:
        raise InputError(f"{path}, line {values['radar_frame_ms'][1]}, field 'radar_frame_ms': must be a finite "
                         f"number >= 0, got {v['radar_frame_ms']}")
    bad = [k for k in ("l_b_r_x", "l_b_r_y", "l_b_r_z") if not np.isfinite(v[k])]
    if bad:
        raise InputError(f"{path}, line {values[bad[0]][1]}, field '{bad[0]}': must be a finite number")
    T = np.eye(4)
    T[:3, :3] = so3.from_quaternion(q / norm) @ C_RIO_TI
    T[:3, 3] = v["l_b_r_x"], v["l_b_r_y"], v["l_b_r_z"]
    return T, v["radar_frame_ms"]


def doppler_quantisation(radial_velocity) -> dict:
    """Measure the Doppler quantisation: step = median spacing of the distinct values; share of values within
    1e-3 steps of the grid k * step; number of distinct values. (The demo: step 0.12492 m/s, nominal 0.125.)"""
    vr = np.asarray(radial_velocity, dtype=float)
    u = np.unique(vr)
    if len(u) < 2:
        return {"step_mps": None, "fraction_on_grid": 1.0, "distinct_values": int(len(u))}
    step = float(np.median(np.diff(u)))
    on_grid = np.abs(vr / step - np.round(vr / step)) < 1e-3
    return {"step_mps": step, "fraction_on_grid": float(on_grid.mean()), "distinct_values": int(len(u))}


def convert(source) -> Conversion:
    """Convert the TI mmWave demo folder (see module docstring) into one Conversion named 'ti_mmwave'.

    Checked by: tests/sim/test_convert.py::test_ti_times_extrinsics_and_quantisation,
        ::test_ti_real_demo_converts, ::test_ti_bad_calibration_and_missing_files
    """
    source = Path(source)
    if not source.is_dir():
        raise InputError(f"SOURCE: {source} is not a directory (expected the TI mmWave CSV export)")
    T_vehicle_sensor, frame_ms = read_calibration(source / CALIB_YAML)
    sc = read_csv(source / SCANS_CSV, ("scan_idx", "t_trigger_ns"), int_columns=("scan_idx", "t_trigger_ns"))
    det = read_csv(source / DETECTIONS_CSV, ("scan_idx", "x_m", "y_m", "z_m", "intensity", "v_radial_mps"),
                   int_columns=("scan_idx",))
    report = ConversionReport("ti-mmwave", str(source))
    idx, t_scan, t0_ns = _scan_times(source, sc, frame_ms, report)
    k, keep, rng, az, el = _kept_detections(det, idx, report, source / DETECTIONS_CSV)
    vr = det["v_radial_mps"]
    scans = scans_from_rows(report, k[keep], t_scan, rng[keep], az[keep], el[keep], vr[keep],
                            {"snr": det["intensity"][keep]})
    require_detections(report, source / DETECTIONS_CSV)
    quant = doppler_quantisation(vr[keep])
    step = quant["step_mps"] if quant["step_mps"] is not None else DOPPLER_STEP
    sigma_vr = step / np.sqrt(12.0)
    noise = NoiseSigmas(range=RANGE_SIGMA, azimuth=float(AZIMUTH_SIGMA), elevation=float(ELEVATION_SIGMA),
                        radial_velocity=float(sigma_vr))
    rate = float(1.0 / np.median(np.diff(t_scan))) if len(t_scan) > 1 else 10.0
    try:  # the calibration's mount and the data's Doppler step go into it
        sensor = SensorConfig(rate_hz=rate, T_vehicle_sensor=T_vehicle_sensor, noise=noise,
                              azimuth_fov=field_of_view(az[keep], np.pi / 2, np.pi),
                              elevation_fov=field_of_view(el[keep], np.pi / 4, np.pi / 2),
                              max_range=float(np.ceil(rng[keep].max())) if keep.any() else 20.0)
    except InputError as exc:
        raise InputError(f"{source}: {exc} (from {CALIB_YAML} and {DETECTIONS_CSV})") from None
    report.info.update({"t0_ns": t0_ns, "time": "trigger + radar_frame_ms / 2, seconds from t0_ns",
                        "radar_frame_ms": frame_ms, "rate_hz": rate, "doppler_quantisation": quant,
                        "sigma_radial_velocity_mps": float(sigma_vr)})
    _add_notes(report, step, quant)
    return Conversion("ti_mmwave", Sequence(sensor=sensor, scans=scans, groundtruth=None), report)


def _scan_times(source: Path, sc: dict, frame_ms: float, report: ConversionReport):
    """Scan indices in time order (scans whose trigger time does not increase dropped), their times in
    seconds from the first trigger (trigger + radar_frame_ms / 2), and the first trigger in ns."""
    idx, trig = sc["scan_idx"], sc["t_trigger_ns"]
    if len(idx) == 0:
        raise InputError(f"{source / SCANS_CSV}: no scans")
    if np.any(idx < 0) or len(np.unique(idx)) != len(idx):
        raise InputError(f"{source / SCANS_CSV}, field 'scan_idx': must be unique and >= 0")
    if int(trig.max()) - int(trig.min()) > MAX_SPAN_NS:  # (also keeps trig - t0 inside int64)
        raise InputError(f"{source / SCANS_CSV}, field 't_trigger_ns': trigger times span more than "
                         f"{MAX_SPAN_NS:g} ns")
    order = np.argsort(idx)
    idx, trig = idx[order], trig[order]
    t0_ns = int(trig[0])
    t_scan = (trig - t0_ns).astype(np.float64) * 1e-9 + 0.5e-3 * frame_ms  # (S,) s
    # each kept time above all earlier ones, in float64 (1 ns steps late in a long recording round to equal
    # times; comparing with the previous row only let 0, 10, 5, 7 through; both found by the fuzzer)
    good = np.r_[True, t_scan[1:] > np.maximum.accumulate(t_scan)[:-1]]
    if not good.all():
        report.dropped["scans whose trigger time does not increase"] = int((~good).sum())
    check_scan_step(trig[good], 1e-9, "ns", f"{source / SCANS_CSV}, field 't_trigger_ns'")
    return idx[good], t_scan[good], t0_ns


def _kept_detections(det: dict, idx: np.ndarray, report: ConversionReport, path: Path):
    """Each detection's position in the scan table (-1: none), the mask of usable detections (dropped ones
    counted in the report), and range, azimuth, elevation of all rows (float64, from x, y, z). More than 1 %
    of the detections beyond MAX_RANGE_M: InputError naming `path`, the first one's line and coordinate."""
    s = det["scan_idx"]
    j = np.clip(np.searchsorted(idx, s), 0, len(idx) - 1)  # idx is sorted: no table as long as the largest index
    k = np.where(idx[j] == s, j, -1)
    keep = report.drop("detections whose scan has no (valid) trigger time", k < 0)
    vals = np.stack([det[c] for c in ("x_m", "y_m", "z_m", "intensity", "v_radial_mps")])
    keep &= report.drop("detections with NaN or infinity", keep & ~np.all(np.isfinite(vals), axis=0))
    big = np.any(np.abs(vals[:3]) > MAX_RANGE_M, axis=0)  # before the norm: 1e308 m overflowed it (fuzzer)
    rng, az, el = polar_from_xyz(np.where((keep & ~big)[:, None], vals[:3].T, 1.0))
    names = ("x_m", "y_m", "z_m")

    def explain(k: int) -> str:
        c = int(np.argmax(np.abs(vals[:3, k])))
        return (f"{path}, line {k + 2}, field '{names[c]}': {vals[c, k]:.6g} puts a detection farther than "
                f"{MAX_RANGE_M:g} m: millimetres? (x_m, y_m, z_m must be metres)")

    keep = drop_few(report, keep, big | (rng > MAX_RANGE_M), f"detections farther than {MAX_RANGE_M:g} m", explain)
    keep &= report.drop("detections at zero range", keep & ~(rng > 1e-6))
    return k, keep, rng, az, el


def _add_notes(report: ConversionReport, step: float, quant: dict) -> None:
    report.notes.append(f"Doppler step measured {step:.6g} m/s (nominal {DOPPLER_STEP}); on that grid: "
                        f"{100 * quant['fraction_on_grid']:.2f} % of "
                        f"detections, {quant['distinct_values']} distinct values")
    report.notes.append("vehicle frame = IMU body frame; no ground truth (no groundtruth.txt)")
    report.notes.append("range/azimuth/elevation sigmas are nominal; sigma_vr = Doppler step / sqrt(12)")
