"""The driver: run the estimator over a sequence, time it, and write the results.

Three layers, as in kiss-icp: the algorithm (`estimator.odometry.RadarOdometry`), this driver (the dataset
loop, timing, results on disk), and the CLI (`rodo run`). Outputs of `write_run(out_dir, result)`:

- `estimate.txt`: TUM rows `t tx ty tz qx qy qz qw` of T_world_vehicle at every scan time;
- `states.npz`: `t` (N,), `T_vehicle_world` (N,4,4), `varpi` (N,6), `varpi_dot` (N,6; zeros for CV),
  `P` (N,d,d) posterior covariance of the newest state, `n_detections`, `n_static`, `n_associated`, `nis`,
  `ms_per_scan`;
- `summary.json`: model, scans, median_associations, median_ms_per_scan, p95_ms_per_scan, time split per stage,
  events, and the resolved config.

A run keeps its per-scan values as arrays (`ScanColumns`), and the `ScanEstimate` objects only when asked
(`keep_estimates`: the Rerun recording needs their detail); `run_scans` takes any iterable of scans, e.g. a
simulation streamed scan by scan (`validation.streamed`), so a long drive runs in bounded memory.
"""

from __future__ import annotations

import io
import json
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Iterable

import numpy as np
from threadpoolctl import threadpool_limits

from rodo.estimator.attitude_jitter import attitude_jitter_of
from rodo.estimator.stationary_error import stationary_error_of
from rodo.estimator.config import OdometryConfig
from rodo.estimator.errors import InputError
from rodo.estimator.lie import se3
from rodo.estimator.odometry import RadarOdometry
from rodo.estimator.scan import ScanEstimate
from rodo.estimator.heading_reversion import heading_of
from rodo.estimator.velocity_inflation import velocity_inflation_array
from rodo.sim.sequence import Sequence, Trajectory, atomic_write_bytes, write_tum


STAGES = ("predict", "associate", "solve", "map")
COUNTS = ("n_detections", "n_static", "n_associated")


class ScanColumns:
    """The per-scan values of a run in growing arrays (capacity doubles): what a run keeps of each
    `ScanEstimate` (the states.npz arrays, T_world_vehicle, the stage timings), about 3.5 kB per CA scan
    instead of the estimate object with its dicts and lists.

    Every value is copied as `ScanEstimate` holds it, so the arrays equal those stacked from the estimates.

    Checked by: tests/validation/test_stream.py::test_compact_run_keeps_the_same_arrays_as_a_full_run
    """

    def __init__(self, capacity: int = 256):
        self._data: dict[str, np.ndarray] = {}
        self._capacity = max(1, int(capacity))
        self.n = 0

    def append(self, est: ScanEstimate) -> None:
        row = {"t": est.t, "T_vehicle_world": est.T_vehicle_world, "T_world_vehicle": est.T_world_vehicle,
               "varpi": est.varpi, "varpi_dot": est.varpi_dot if est.varpi_dot is not None else np.zeros(6),
               "P": est.P, "n_detections": est.n_detections, "n_static": est.n_static,
               "n_associated": est.n_associated, "nis": float(est.nis),
               "P_relative": _or_filled(est.P_relative, np.nan), "P_revision": _or_filled(est.P_revision, 0.0),
               "P_pose_absolute": _or_filled(est.P_pose_absolute, np.nan), "map_reuse": est.map_reuse,
               "doppler_nis": est.doppler_nis, "pose_pull": est.pose_pull, "restarted": est.restarted,
               "velocity_lag": est.velocity_lag,
               **{f"s_{key}": est.timings.get(key, 0.0) for key in STAGES}}
        if self.n == self._capacity:
            self._capacity *= 2
            for key, arr in self._data.items():
                grown = np.empty((self._capacity,) + arr.shape[1:], arr.dtype)
                grown[:self.n] = arr[:self.n]
                self._data[key] = grown
        for key, value in row.items():
            value = np.asarray(value)
            if key not in self._data:  # counts as int64, everything else float64 (as np.array of the values)
                dtype = np.int64 if key in COUNTS else np.float64
                self._data[key] = np.empty((self._capacity,) + value.shape, dtype)
            self._data[key][self.n] = value
        self.n += 1

    def arrays(self) -> dict[str, np.ndarray]:
        """Views of the filled rows, (n, ...) per value."""
        return {key: arr[:self.n] for key, arr in self._data.items()}


@dataclass
class RunResult:
    """A run: the config, the per-scan values (`columns`), wall time per scan, events; and the `ScanEstimate`
    objects themselves when the run kept them (`run_scans(keep_estimates=True)`: needed for their detail and
    events per scan, e.g. by the Rerun recording; empty otherwise)."""

    config: OdometryConfig
    estimates: list[ScanEstimate]
    wall_ms: np.ndarray  # (N,) per scan
    events: list[tuple[int, float, str]] = field(default_factory=list)
    columns: dict | None = None  # ScanColumns.arrays(); built from `estimates` when not given

    def __post_init__(self):
        if self.columns is None:
            cols = ScanColumns(max(1, len(self.estimates)))
            for e in self.estimates:
                cols.append(e)
            self.columns = cols.arrays()

    @property
    def n_scans(self) -> int:
        return len(self.wall_ms)

    @property
    def t(self) -> np.ndarray:
        return self.columns["t"] if self.n_scans else np.zeros(0)

    def state_arrays(self) -> dict:
        """The per-scan arrays of states.npz (docs: README "Reading the results", docs/consistency.md)."""
        c, u = self.columns, self.config.uncertainty
        d = c["P"].shape[-1]
        return dict(
            t=c["t"],
            T_vehicle_world=c["T_vehicle_world"],
            varpi=c["varpi"],
            varpi_dot=c["varpi_dot"],
            P=c["P"].reshape(self.n_scans, d, d),
            n_detections=c["n_detections"],
            n_static=c["n_static"],
            n_associated=c["n_associated"],
            nis=c["nis"].astype(float),
            ms_per_scan=np.asarray(self.wall_ms),
            P_relative=c["P_relative"],
            P_revision=c["P_revision"],
            P_pose_absolute=c["P_pose_absolute"],
            map_reuse=c["map_reuse"],
            doppler_nis=c["doppler_nis"],
            pose_pull=c["pose_pull"],
            restarted=c["restarted"].astype(bool),
            velocity_lag=c["velocity_lag"],
            velocity_correlation_time=np.float64(u.velocity_correlation_time),
            velocity_error_share=np.float64(u.velocity_error_share),
            velocity_error_share_per_speed=np.float64(u.velocity_error_share_per_speed),
            registration_correlation=np.float64(u.registration_correlation),
            registration_axis_correlation=np.asarray(u.registration_axis_correlation, dtype=float),
            drift_rate_sigma=np.asarray(u.drift_rate_sigma, dtype=float),
            velocity_inflation=velocity_inflation_array(
                u.velocity_inflation, u.velocity_inflation_per_speed, u.velocity_inflation_per_doppler,
                u.velocity_inflation_per_rate),
            velocity_axis_inflation=np.asarray(u.velocity_axis_inflation, dtype=float),
            heading_reversion=heading_of(u),
            attitude_jitter=attitude_jitter_of(u),
            stationary_error=stationary_error_of(u),
        )

    def trajectory(self) -> Trajectory:
        return Trajectory(self.t, self.columns["T_world_vehicle"])

    def summary(self) -> dict:
        c, n = self.columns, self.n_scans
        stages = {key: float(np.median(c[f"s_{key}"]) * 1e3) if n else 0.0 for key in STAGES}
        return {
            "model": self.config.model,
            "scans": n,
            "median_associations": float(np.median(c["n_associated"])) if n else 0.0,
            "median_detections": float(np.median(c["n_detections"])) if n else 0,
            "median_ms_per_scan": float(np.median(self.wall_ms)) if n else 0.0,
            "p95_ms_per_scan": float(np.percentile(self.wall_ms, 95)) if n else 0.0,
            "median_ms_per_stage": stages,
            "events": [{"scan": s, "t": t, "event": ev} for s, t, ev in self.events],
            "config": self.config.to_dict(),
        }


SAME_TIME = 1e-6  # s: groundtruth.txt keeps 9 decimals, so a pose within 1 us of a scan is at that scan


def scan_times(seq: Sequence) -> np.ndarray:
    """Times at which the estimator reports: every scan with rows, plus the empty scans known from groundtruth.txt
    (`empty_scan_times`: only where its times are the radar's own scan times; a radar.csv without rows has
    nothing else to go by, so then every pose is one).

    Checked by: tests/validation/test_input_defects_gt_times.py::test_shifted_or_faster_groundtruth_changes_nothing
    """
    t = np.array([s.t for s in seq.scans], dtype=float)
    if seq.groundtruth is None or not len(seq.groundtruth.t):
        return t
    g = np.asarray(seq.groundtruth.t, dtype=float)
    if not len(t):
        return np.unique(g)
    index = np.array([s.scan for s in seq.scans], dtype=np.int64)
    return np.union1d(t, empty_scan_times(t, index, g, seq.sensor.rate_hz))


def empty_scan_times(t: np.ndarray, index: np.ndarray, g: np.ndarray, rate_hz: float) -> np.ndarray:
    """The ground-truth times `g` that are scans without rows, given the scans with rows (times `t`, scan indices
    `index`, both increasing) and the sensor's rate. The simulator and the converters write no rows for an empty
    scan but a pose at every scan time, with consecutive scan indices; ground truth at another rate or phase (or
    from another clock) must not add scans. So its times are taken as the radar's scan times only when
    - every scan with rows has a pose within SAME_TIME, and
    - between two consecutive scans with rows there are exactly as many other poses as their indices skip;
    then the other poses are empty scans: those between scans; those before the first scan with rows when they
    are as many as its index; those after the last when two or more scans have rows (the counts above were
    checked) or, with one, when each is a whole number of periods 1 / rate_hz after it (within SAME_TIME).
    Otherwise there are none: groundtruth.txt is then for evaluation only (docs/sequence_format.md).

    Checked by: tests/validation/test_input_defects_gt_times.py::test_simulated_empty_scans_are_still_run,
        ::test_empty_scan_rule_on_synthetic_times
    """
    none = np.zeros(0)
    if len(t) == 0:
        return np.unique(g)
    on_scan = _nearest_gap(t, g) <= SAME_TIME
    if not np.all(_nearest_gap(g, t) <= SAME_TIME):
        return none  # a scan without a pose: the poses are not at the scan times
    other = g[~on_scan]
    where = np.searchsorted(t, other)  # 0: before the first scan with rows, len(t): after the last
    counts = np.bincount(where, minlength=len(t) + 1)
    if not np.array_equal(counts[1:len(t)], np.diff(index) - 1):
        return none
    keep = (where > 0) & (where < len(t))
    if counts[0] == index[0]:
        keep |= where == 0
    after = where == len(t)
    if len(t) >= 2:
        keep |= after
    elif np.any(after):
        steps = (other[after] - t[-1]) * rate_hz
        on_grid = np.abs(other[after] - (t[-1] + np.round(steps) / rate_hz)) <= SAME_TIME
        keep |= after & bool(np.all(on_grid))
    return np.unique(other[keep])


def _nearest_gap(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """For each of `b`, the distance to the nearest of `a` (sorted, non-empty)."""
    i = np.searchsorted(a, b)
    lo, hi = a[np.clip(i - 1, 0, len(a) - 1)], a[np.clip(i, 0, len(a) - 1)]
    return np.minimum(np.abs(b - lo), np.abs(b - hi))


def run_sequence(seq: Sequence, config: OdometryConfig, progress=None, record_detail: bool = False,
                 on_scan=None, keep_estimates: bool = True) -> RunResult:
    """Run the estimator over every scan of `seq`; `progress` is an optional object with update(), `on_scan` an
    optional callable (k, t, scan or None, estimate) called after each scan (the live Rerun stream uses it).
    `keep_estimates=False` keeps only the per-scan arrays (`RunResult.columns`), not the estimate objects.

    BLAS is limited to one thread for the run: the estimator's matrices are tiny (at most a few hundred rows),
    where threading costs far more than it gains (measured: a 72x72 Cholesky solve took 7.8 ms with two busy
    threads, 77 us with one).
    """
    if not (hasattr(seq, "scans") and hasattr(seq, "sensor")):
        raise InputError(f"seq: expected a sim.sequence.Sequence (read_sequence(DIR), or the first of a scenario's "
                         f"simulate(seed)), got {type(seq).__name__}")
    ts = np.array([s.t for s in seq.scans], dtype=float)
    bad = ~np.isfinite(ts) | np.r_[False, ~(np.diff(ts) > 0)]  # a Sequence built in memory: not read and checked
    if bad.any():
        k = int(np.argmax(bad))
        raise InputError(f"sequence: scan times must be finite and increase strictly (scan {k}: t = {ts[k]}"
                         + (f" after {ts[k - 1]})" if k else ")"))
    times = scan_times(seq)
    if len(times) == 0:
        raise InputError("sequence: no scans (radar.csv has no rows and there is no groundtruth.txt)")
    by_t = {s.t: s for s in seq.scans}
    return run_scans(seq.sensor, ((t, by_t.get(t)) for t in times), config, progress, record_detail, on_scan,
                     keep_estimates)


def run_scans(sensor, scans: Iterable, config: OdometryConfig, progress=None, record_detail: bool = False,
              on_scan=None, keep_estimates: bool = False) -> RunResult:
    """The per-scan loop of `run_sequence` over any iterable of (t, RadarScan or None) in time order, e.g. a
    streamed simulation (`sim.stream`) that never holds the whole sequence: with `keep_estimates=False` the
    run's memory is the estimator's window and map plus `ScanColumns` (about 3.5 kB per scan).

    Same scans -> the same estimates, bit for bit, whatever the source and `keep_estimates`.

    Checked by: tests/validation/test_stream.py::test_streamed_compact_run_gives_the_same_poses
    """
    with threadpool_limits(limits=1, user_api="blas"):
        return _run(sensor, scans, config, progress, record_detail, on_scan, keep_estimates)


def run_rig(rig, config: OdometryConfig, progress=None, record_detail: bool = False, on_scan=None,
            keep_estimates: bool = True) -> RunResult:
    """Run one estimator over every radar of a rig (`sim.rig`): each scan, in time order, with its own radar
    (`RadarOdometry.add_sensor`), into one window and one map. Checked by: tests/validation/test_rig_run.py"""
    scans = [(t, scan, i) for t, i, scan in rig.scans()]
    if not scans:
        raise InputError("rig: no scans (no radar.csv of the rig has rows)")
    with threadpool_limits(limits=1, user_api="blas"):
        return _run([s.sensor for s in rig.sequences], scans, config, progress, record_detail, on_scan,
                    keep_estimates)


def _odometry(sensors, config: OdometryConfig, record_detail: bool) -> RadarOdometry:
    """The estimator for one SensorConfig, or a list of them (a rig: the first, then `add_sensor`)."""
    sensors = sensors if isinstance(sensors, (list, tuple)) else [sensors]
    odo = None
    for s in sensors:
        args = (s.T_vehicle_sensor, s.noise.as_array(), s.max_range)
        fov = (s.azimuth_fov, s.elevation_fov)
        if odo is None:
            odo = RadarOdometry(config, *args, record_detail=record_detail, fov=fov)
        else:
            odo.add_sensor(*args, fov=fov)
    return odo


def _run(sensor, scans: Iterable, config: OdometryConfig, progress, record_detail: bool, on_scan,
         keep_estimates: bool) -> RunResult:
    odo = _odometry(sensor, config, record_detail)
    columns, estimates, wall, events = ScanColumns(), [], [], []
    empty = np.zeros((0, 4))
    for k, (t, scan, *radar) in enumerate(scans):
        tic = time.perf_counter()
        try:
            est = odo.process(t, scan.polar if scan is not None else empty, radar[0] if radar else 0)
        except InputError as exc:  # a Sequence built in memory is not checked as a file is: name the scan
            raise InputError(f"scan {k} (t = {t} s): {exc}") from None
        wall.append((time.perf_counter() - tic) * 1e3)
        columns.append(est)
        if keep_estimates:
            estimates.append(est)
        events.extend((k, float(t), ev) for ev in est.events)
        if on_scan is not None:
            on_scan(k, float(t), scan, est)
        if progress is not None:
            progress.update()
    if not wall:
        raise InputError("sequence: no scans to run")
    return RunResult(config, estimates, np.asarray(wall), events, columns.arrays())


def write_run(out_dir: str | Path, result: RunResult) -> None:
    """Write estimate.txt, states.npz and summary.json (each atomically: a crash never leaves half a file)."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    write_tum(out / "estimate.txt", result.trajectory())
    buf = io.BytesIO()
    np.savez_compressed(buf, **result.state_arrays())
    atomic_write_bytes(out / "states.npz", buf.getvalue())  # unique temporary names, removed on failure
    atomic_write_bytes(out / "summary.json", (json.dumps(result.summary(), indent=2) + "\n").encode())


def _or_filled(P: np.ndarray | None, fill: float) -> np.ndarray:
    return np.full((6, 6), fill) if P is None else P


def relative_pose_errors(gt: Trajectory, est: Trajectory) -> tuple[np.ndarray, np.ndarray]:
    """Per-frame relative errors (translation m, rotation rad) between consecutive poses; a quick check."""
    Tg, Te = gt.T_world_vehicle, est.T_world_vehicle
    dg = se3.inverse(Tg[:-1]) @ Tg[1:]
    de = se3.inverse(Te[:-1]) @ Te[1:]
    E = se3.inverse(de) @ dg
    return np.linalg.norm(E[:, :3, 3], axis=1), np.linalg.norm(se3.log(E)[:, 3:], axis=1)
