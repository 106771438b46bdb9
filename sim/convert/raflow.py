"""RaFlow demo data (Hasco LRR30-F 4D imaging radar, GNSS/INS poses) -> the sequence format, one per chain.

Input layout (the folder `raflow_lrr30_demo/demo_data`, see its README): `{train,val,test}/radar_seqs-<s>_
samples-<k>.json`, one file per frame pair at 10 Hz: `pc1` and `pc2` with `car_loc_x/y/z` (m, radar frame: x
forward, y left, z up), `car_vel_r` (raw radial velocity, negative when approaching: the sequence format's sign),
`rcs`, `power` and `pose` (4x4 radar pose in a local GNSS/INS frame), `interval` (s) and `trans` =
inv(pose1) pose2.

Scans. Sample k's pc1 is frame k and its pc2 frame k + 1. Where sample k + 1's pc1 is sample k's pc2 (the same
Doppler list, positions and pose) the two samples belong to one chain; elsewhere the sample numbers skip frames
that are not in the data, and a new chain starts. A pair whose pc2 repeats pc1's raw scan (identical Doppler and
RCS lists: the 10 Hz resampling of the ~12 Hz radar; positions moved by the motion compensation) adds no
measurement: the repeat is dropped, leaving a 0.2 s gap. A raw scan is kept once per chain. Scan j of a chain
starting at sample k0 is at the sum of the pairs' intervals since the chain's first frame.

Output per chain of at least `min_scans` scans, named `<split>_seq<s>_<k0>`: radar.csv (extra columns `rcs`,
`power`), sensor.toml (vehicle frame = radar frame, nominal sigmas of the LRR30-F, field of view from its data
sheet: azimuth +-60 deg, elevation +-10 deg), groundtruth.txt (the GNSS/INS radar poses relative to the chain's
first, so the world is the first radar frame, as the estimator's). The reference jitters by about 0.3 m per pose
(the data's README), which bounds what a chain of ~10 m can show.

Refused, naming the sample file and the key: an entry that is not a JSON number (a string such as "1.5", true,
null), a pose that is not a rigid transform (not finite, bottom row, |C C^T - I| > 1e-6, a reflection: det C < 0),
an interval outside [1 ms, 10 s) (no radar's scan rate), a chain without detections.

Checked by: tests/sim/test_convert_raflow.py, tests/validation/test_realdata_raflow.py,
    tests/sim/test_convert_review55.py::test_raflow_*
"""

from __future__ import annotations

import json
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from rodo.estimator.errors import InputError
from rodo.estimator.sensor_values import check_pose
from rodo.sim.sequence import NoiseSigmas, SensorConfig, Sequence, Trajectory

from ._common import SCAN_RATE_HZ, Conversion, ConversionReport, polar_from_xyz, require_detections, scans_from_rows

FILE_RE = re.compile(r"^radar_seqs-(\d+)_samples-(\d+)\.json$")
SPLITS = ("train", "val", "test")
FIELDS = ("car_loc_x", "car_loc_y", "car_loc_z", "car_vel_r", "rcs", "power", "pose")
# nominal 1-sigma (data sheet resolutions: 0.13 m/s Doppler; accuracies not published): override with --sigma
DEFAULT_SIGMAS = NoiseSigmas(range=0.15, azimuth=float(np.deg2rad(0.5)), elevation=float(np.deg2rad(1.0)),
                             radial_velocity=0.1)
AZIMUTH_FOV = float(np.deg2rad(60.0))
ELEVATION_FOV = float(np.deg2rad(10.0))
MAX_RANGE = 250.0  # m
MIN_SCANS = 5
INTERVAL_S = (1e-3, 10.0)  # s: a pair's interval outside [1 ms, 10 s) gives no radar's scan rate (0.1-1000 Hz)
REPEATED = "repeated raw scans (resampling duplicates)"


@dataclass
class Frame:
    """One raw scan as a sample file holds it: points (n, 3) radar frame, v_r, rcs, power (n,), pose (4, 4)."""

    points: np.ndarray
    vr: np.ndarray
    rcs: np.ndarray
    power: np.ndarray
    pose: np.ndarray

    def same_raw(self, other: "Frame") -> bool:
        """The same radar measurement (Doppler and RCS lists identical), wherever its points were moved to."""
        return np.array_equal(self.vr, other.vr) and np.array_equal(self.rcs, other.rcs)

    def same(self, other: "Frame") -> bool:
        """The same frame: the same measurement at the same positions and pose."""
        return self.same_raw(other) and np.array_equal(self.points, other.points) \
            and np.array_equal(self.pose, other.pose)


def _frame(path: Path, name: str, pc) -> Frame:
    if not isinstance(pc, dict):
        raise InputError(f"{path}: field '{name}' must be an object with {', '.join(FIELDS)}")
    missing = [f for f in FIELDS if f not in pc]
    if missing:
        raise InputError(f"{path}: field '{name}' lacks {', '.join(missing)}")
    cols = {f: _numbers(path, f"{name}.{f}", pc[f]) for f in FIELDS}
    n = len(cols["car_loc_x"])
    for f in FIELDS[:-1]:
        if cols[f].shape != (n,):
            raise InputError(f"{path}: field '{name}.{f}': expected {n} numbers (as car_loc_x), "
                             f"got shape {cols[f].shape}")
    where = f"{path}: field '{name}.pose' (a 4x4 rigid transform)"
    if cols["pose"].shape != (4, 4):
        raise InputError(f"{where}: got shape {cols['pose'].shape}")
    pose = check_pose(where, cols["pose"])
    return Frame(np.c_[cols["car_loc_x"], cols["car_loc_y"], cols["car_loc_z"]], cols["car_vel_r"],
                 cols["rcs"], cols["power"], pose)


def _numbers(path: Path, key: str, value) -> np.ndarray:
    """A JSON list (of lists) of numbers as a float array; InputError naming the file and key for anything else
    (numpy would read the string "1.5" and true as numbers, null as NaN)."""
    try:
        entries = np.asarray(value, dtype=object)
        if entries.ndim == 0 or not all(type(v) in (int, float) for v in entries.flat):
            raise TypeError
        return entries.astype(float)
    except (TypeError, ValueError, OverflowError):
        raise InputError(f"{path}: field '{key}': every entry must be a number") from None


def read_sample(path) -> tuple[Frame, Frame, float]:
    """(pc1, pc2, interval s) of one sample file; InputError naming the file and field."""
    path = Path(path)
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except OSError as exc:
        raise InputError(f"{path}: cannot read ({exc.strerror or exc})") from None
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise InputError(f"{path}: not valid JSON ({exc})") from None
    if not isinstance(data, dict) or not {"pc1", "pc2", "interval"} <= data.keys():
        raise InputError(f"{path}: expected an object with fields pc1, pc2 and interval")
    interval = data["interval"]
    lo, hi = INTERVAL_S
    if isinstance(interval, bool) or not isinstance(interval, (int, float)) or not lo <= interval < hi:
        raise InputError(f"{path}: field 'interval': expected seconds in [{lo:g}, {hi:g}), got {interval!r}")
    return _frame(path, "pc1", data["pc1"]), _frame(path, "pc2", data["pc2"]), float(interval)


def _samples(source: Path) -> dict[tuple[str, int], dict[int, Path]]:
    """(split, sequence) -> {sample number: file}."""
    out: dict[tuple[str, int], dict[int, Path]] = {}
    for split in SPLITS:
        for path in sorted((source / split).glob("*.json")):
            m = FILE_RE.match(path.name)
            if m:
                out.setdefault((split, int(m.group(1))), {})[int(m.group(2))] = path
    if not out:
        raise InputError(f"SOURCE: no radar_seqs-<s>_samples-<k>.json files in {source}/{{{','.join(SPLITS)}}}")
    return out


def chains(samples: dict[int, Path], report: ConversionReport) -> list[tuple[int, list[tuple[float, Frame]]]]:
    """The chains of one sequence: [(first sample, [(time s, Frame), ...])], repeats dropped. Times from the
    chain's first frame, each pair adding its own `interval` (0.099-0.1 s in the data)."""
    out, current, start, prev = [], [], None, None
    for k in sorted(samples):
        pc1, pc2, interval = read_sample(samples[k])
        if prev is None or prev[0] != k - 1 or not prev[1].same(pc1):
            if current:
                out.append((start, current))
            current, start, t = [(0.0, pc1)], k, 0.0
        else:
            t = prev[2]
        if any(pc2.same_raw(g) for _, g in current[-3:]):
            report.dropped[REPEATED] = report.dropped.get(REPEATED, 0) + 1
        else:
            current.append((t + interval, pc2))
        prev = (k, pc2, t + interval)
    if current:
        out.append((start, current))
    return out


def _sequence(frames: list[tuple[float, Frame]], report: ConversionReport, where: str) -> Sequence:
    n = np.array([len(f.vr) for _, f in frames])
    scan = np.repeat(np.arange(len(frames)), n)
    t_scan = np.array([t for t, _ in frames])
    pts = np.concatenate([f.points for _, f in frames])
    vr = np.concatenate([f.vr for _, f in frames])
    extra = {"rcs": np.concatenate([f.rcs for _, f in frames]), "power": np.concatenate([f.power for _, f in frames])}
    keep = report.drop("detections with NaN or infinity", ~(np.all(np.isfinite(pts), axis=1) & np.isfinite(vr)))
    rng, az, el = polar_from_xyz(np.where(keep[:, None], pts, 1.0))
    keep &= report.drop("detections at zero range", keep & ~(rng > 1e-6))
    scans = scans_from_rows(report, scan[keep], t_scan, rng[keep], az[keep], el[keep], vr[keep],
                            {k: v[keep] for k, v in extra.items()})
    require_detections(report, where)
    first = np.linalg.inv(frames[0][1].pose)
    gt = Trajectory(t_scan, np.stack([first @ f.pose for _, f in frames]))
    rate, (lo, hi) = float((len(t_scan) - 1) / (t_scan[-1] - t_scan[0])), SCAN_RATE_HZ
    if not lo <= rate <= hi:  # intervals of up to 10 s with repeats dropped between them: below 0.1 Hz
        raise InputError(f"{where}: field 'interval': the chain's {len(t_scan)} scans span {t_scan[-1]:.6g} s, "
                         f"{rate:.3g} Hz, no radar's scan rate (expected {lo:g}-{hi:g} Hz)")
    sensor = SensorConfig(rate_hz=rate, T_vehicle_sensor=np.eye(4), noise=DEFAULT_SIGMAS,
                          azimuth_fov=(-AZIMUTH_FOV, AZIMUTH_FOV), elevation_fov=(-ELEVATION_FOV, ELEVATION_FOV),
                          max_range=MAX_RANGE)
    return Sequence(sensor=sensor, scans=scans, groundtruth=gt)


def convert(source, min_scans: int = MIN_SCANS) -> list[Conversion]:
    """Convert the RaFlow demo data (see module docstring): one Conversion per chain of >= min_scans scans.

    Checked by: tests/sim/test_convert_raflow.py
    """
    source = Path(source)
    if not source.is_dir():
        raise InputError(f"SOURCE: {source} is not a directory (expected RaFlow demo_data with train/val/test)")
    if isinstance(min_scans, bool) or not isinstance(min_scans, (int, np.integer)) or min_scans < 2:
        raise InputError(f"--min-scans: must be an integer >= 2, got {min_scans!r}")
    out = []
    for (split, seq), samples in sorted(_samples(source).items()):
        report_seq = ConversionReport("raflow", str(source))
        found = chains(samples, report_seq)
        for start, frames in found:
            name = f"{split}_seq{seq}_{start}"
            if len(frames) < min_scans:
                continue
            report = ConversionReport("raflow", str(source), dropped=dict(report_seq.dropped))
            sequence = _sequence(frames, report, f"{samples[start]} (the first sample of chain {name})")
            report.info.update({"split": split, "sequence": seq, "first_sample": start,
                                "scan_times_s": [round(t, 6) for t, _ in frames], "chains_in_sequence": len(found)})
            report.notes += ["vehicle frame = radar frame; nominal sigmas unless --sigma",
                             "ground truth: GNSS/INS radar poses relative to the chain's first (jitter ~0.3 m)",
                             "dropped counts are per source sequence (all its chains)"]
            out.append(Conversion(name, sequence, report))
    if not out:
        raise InputError(f"SOURCE: no chain of at least {min_scans} consecutive scans in {source}")
    return out
