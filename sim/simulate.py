"""Trajectory + world + radar -> a radar `Sequence` and its truth (the richer ground truth of truth.npz).

Scan k is taken at t_k = k / rate_hz (k = 0 .. floor(duration * rate_hz)); every scan, even an empty one
(total blockage), has a row in groundtruth.txt and in truth.npz. The truth.npz layout is documented in
docs/simulator.md.

Checked by: tests/sim/test_simulate.py
"""

from __future__ import annotations

import io
import zipfile
from pathlib import Path

import numpy as np

from rodo.estimator.errors import InputError

from .faults import Faults
from .faults import apply as apply_faults
from .radar import Radar, RadarConfig, empty_detections
from .sequence import RadarScan, Sequence, Trajectory, atomic_write_bytes, write_sequence
from .sequence_types import check_pose
from .trajectory import Profile
from .world import World

TRUTH_NPZ = "truth.npz"


def scan_times(duration: float, rate_hz: float) -> np.ndarray:
    """t_k = k / rate_hz for k = 0 .. floor(duration * rate_hz (+1e-9))."""
    n = int(np.floor(duration * rate_hz + 1e-9)) + 1
    return np.arange(n) / rate_hz


def simulate(world: World, profile: Profile, config: RadarConfig, rng: np.random.Generator,
             duration: float | None = None, progress=None, faults: Faults | None = None,
             fault_seed: np.random.SeedSequence | None = None, t_offset: float = 0.0) -> tuple[Sequence, dict]:
    """Simulate a radar sequence.

    Args:
        world: the scene (static parts, moving boxes, blackout intervals).
        profile: the ego trajectory (CA segments).
        config: the radar.
        rng: random generator for all measurement randomness (consumed scan by scan).
        duration: seconds to simulate (default: the whole profile); must not exceed the profile.
        progress: optional object with update() called once per scan (e.g. rodo.progress.Progress).
        faults: optional `sim.faults.Faults` (ghosts, dropped scans, jitter, outages; clutter is the caller's
            radar config, `Faults.radar`), drawn from `fault_seed` (required with faults). Off: no change.
        t_offset: the first scan's time (s, in [0, duration)): the scans are t_offset + k / rate_hz up to
            the duration, so radars of a rig scan at their own instants (`scenarios.simulate_rig_to`).

    Returns:
        (sequence, truth): the `sim.sequence.Sequence` (all scans, empty ones included, ground truth
        T_world_vehicle at every scan time) and the truth dict of `truth_arrays`.
    """
    duration = profile.duration if duration is None else float(duration)
    if not (0 < duration <= profile.duration + 1e-9):
        raise InputError(f"duration: must be in (0, {profile.duration:.3f}] s, got {duration}")
    t = scan_times(min(duration, profile.duration), config.rate_hz)
    if t_offset:
        if not (np.isfinite(t_offset) and 0 < t_offset < duration):
            raise InputError(f"t_offset: must be in [0, {duration:g}) s, got {t_offset}")
        t = t_offset + scan_times(min(duration, profile.duration) - t_offset, config.rate_hz)
    motion = profile.sample(t)
    T_world_vehicle = motion.T_world_vehicle
    radar = Radar(config)
    mover_states = [(m, m.states(t)) for m in world.movers]
    dets = []
    for k, tk in enumerate(t):
        if world.blacked_out(tk):
            det = empty_detections(config)
        else:
            movers = [(m, s.T_world_object[k], s.v_world[k], s.w_world[k]) for m, s in mover_states
                      if s.present[k]]
            det = radar.scan(world, T_world_vehicle[k], motion.varpi[k], rng, movers)
        dets.append(det)
        if progress is not None:
            progress.update()
    scans, trajectory, extra = _recorded(dets, t, T_world_vehicle, profile, config, faults, fault_seed)
    seq = Sequence(config.sensor_config(), scans, trajectory)
    truth = truth_arrays(motion, extra.pop("dets"), config, mover_states)
    truth.update(extra)
    return seq, truth


def _recorded(dets, t, T_world_vehicle, profile, config, faults, fault_seed):
    """What is recorded: the scans (faults applied), the ground-truth trajectory, and for the truth the
    per-scan detections plus, with faults, `fault_t_recorded` and `fault_dropped` (docs/simulator.md)."""
    if faults is None or not faults.changes_scans:
        scans = [RadarScan(k, float(tk), d.range, d.azimuth, d.elevation, d.radial_velocity, extra=d.extra())
                 for k, (tk, d) in enumerate(zip(t, dets))]
        return scans, Trajectory(t, T_world_vehicle), {"dets": dets}
    faults.check_rate(config.rate_hz)
    if fault_seed is None:
        raise InputError("simulate: faults need a fault_seed (a SeedSequence)")
    faulted = apply_faults(faults, dets, t, config, fault_seed)
    dets = [empty_detections(config) if gone else d for d, gone in zip(faulted.dets, faulted.dropped)]
    t_rec = np.clip(faulted.t_recorded, 0.0, profile.duration)
    scans = [RadarScan(k, float(t_rec[k]), d.range, d.azimuth, d.elevation, d.radial_velocity, extra=d.extra())
             for k, d in enumerate(dets) if not faulted.dropped[k]]
    if faults.jitter > 0:  # groundtruth.txt: the true poses at the recorded times (the true times: truth.npz)
        trajectory = Trajectory(t_rec, profile.sample(t_rec).T_world_vehicle)
    else:
        trajectory = Trajectory(t, T_world_vehicle)
    return scans, trajectory, {"dets": dets, "fault_t_recorded": t_rec, "fault_dropped": faulted.dropped}


def truth_arrays(motion, dets, config: RadarConfig, mover_states) -> dict:
    """The truth.npz arrays (docs/simulator.md): per scan and per detection (detections of scan k are rows
    scan_offsets[k]:scan_offsets[k+1], in radar.csv order)."""
    counts = np.array([len(d) for d in dets], dtype=np.int64)
    cat = lambda name: np.concatenate([getattr(d, name) for d in dets]) if dets else None  # noqa: E731
    K = len(motion.t)
    ids = np.array([m.object_id for m, _ in mover_states], dtype=np.int64)
    T_mov = np.full((K, len(ids), 4, 4), np.nan)
    for j, (_, s) in enumerate(mover_states):
        T_mov[s.present, j] = s.T_world_object[s.present]
    return {
        "t": motion.t,
        "T_vehicle_world": motion.T_vehicle_world,
        "varpi": motion.varpi,
        "varpi_dot": motion.varpi_dot,
        "T_vehicle_sensor": np.array(config.T_vehicle_sensor),
        "scan_offsets": np.concatenate([[0], np.cumsum(counts)]).astype(np.int64),
        "det_scan": np.repeat(np.arange(K), counts).astype(np.int64),
        "det_label": cat("label").astype(np.int8),
        "det_object_id": cat("object_id").astype(np.int64),
        "det_landmark_id": cat("landmark_id").astype(np.int64),
        "det_p_world": cat("p_world"),
        "det_true_polar": cat("true_polar"),
        "mover_ids": ids,
        "mover_T_world_object": T_mov,
    }


def save_npz(path, arrays: dict) -> None:
    """np.savez without timestamps: same arrays -> same bytes (zip entries dated 1980-01-01, sorted keys)."""
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w", compression=zipfile.ZIP_DEFLATED, compresslevel=1) as zf:
        for key in sorted(arrays):
            info = zipfile.ZipInfo(key + ".npy", date_time=(1980, 1, 1, 0, 0, 0))
            info.compress_type = zipfile.ZIP_DEFLATED
            data = io.BytesIO()
            np.lib.format.write_array(data, np.ascontiguousarray(arrays[key]), allow_pickle=False)
            zf.writestr(info, data.getvalue(), compresslevel=1)
    atomic_write_bytes(path, buf.getvalue())  # a crash never leaves a truncated truth.npz


def read_npz(path, name: str, expected: str) -> dict:
    """Every array of the .npz archive at `path` (an existing file; no pickles), or an InputError `NAME: ...`
    saying what it is not; `expected` names the file it should be. truth.npz, and a run's states.npz for
    `rodo evaluate` and `rodo export`, are read with it."""
    if not zipfile.is_zipfile(path):  # np.load would take it for a pickle and suggest loading it unsafely
        raise InputError(f"{name}: not a readable .npz archive (expected {expected})")
    try:
        with open(path, "rb") as f, np.load(f, allow_pickle=False) as z:  # ours to close when the load fails
            return {k: z[k] for k in z.files}
    except (OSError, ValueError, EOFError, TypeError, zipfile.BadZipFile) as exc:  # TypeError: a bare .npy
        raise InputError(f"{name}: not a readable .npz file ({exc})") from None


def write_simulation(out_dir, seq: Sequence, truth: dict) -> Path:
    """Write the sequence (radar.csv, sensor.toml, groundtruth.txt) and truth.npz into out_dir."""
    out = Path(out_dir)
    write_sequence(out, seq)
    save_npz(out / TRUTH_NPZ, truth)
    return out


def load_truth(path) -> dict:
    """Read truth.npz (a sequence directory or the file itself) into a dict of arrays."""
    path = Path(path)
    if path.is_dir():
        path = path / TRUTH_NPZ
    if not path.is_file():
        raise InputError(f"{path}: truth file not found")
    truth = read_npz(path, str(path), "the truth.npz `rodo simulate` writes")
    for key in ("t", "T_vehicle_world", "varpi", "varpi_dot"):  # the states' arrays: finite numbers
        a = truth.get(key)
        if a is not None and not (np.issubdtype(a.dtype, np.number) and np.isfinite(a).all()):
            raise InputError(f"{path}: array {key} holds NaN, infinity or non-numbers")
    if "T_vehicle_world" in truth and len(truth["T_vehicle_world"]):  # poses, not any 4 x 4 matrices
        check_pose(f"{path}: array T_vehicle_world", truth["T_vehicle_world"])
    return truth


def path_length(T_world_vehicle: np.ndarray) -> float:
    """Length of the polyline through the vehicle positions, metres."""
    p = T_world_vehicle[:, :3, 3]
    return float(np.sum(np.linalg.norm(np.diff(p, axis=0), axis=1)))


__all__ = ["TRUTH_NPZ", "load_truth", "path_length", "read_npz", "save_npz", "scan_times", "simulate",
           "truth_arrays", "write_simulation"]
