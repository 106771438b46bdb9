"""Simulated vs real radar data, side by side (`rodo realism PROFILE`): ground-truth-free statistics of a sensor
profile's simulation and of the recording it was calibrated on, each with a distance and the 20 % goal.

Statistics (pooled over all scans; the same code on both sides, on the recorded columns only):
- points per scan: the mean; distance |sim - real| / real;
- range, azimuth (and elevation for a 4D radar) distributions, and the RCS (`rcs` column) or, for a radar that
  reports SNR instead (`snr`), the SNR distribution: Kolmogorov-Smirnov distance sup |F_sim - F_real|;
- Doppler: per scan with at least MIN_POINTS detections the estimator's RANSAC ego-velocity fit
  (`estimator.ego_velocity.estimate_ego_velocity`, inlier gate DOPPLER_GATE); over the scans where the fitted
  sensor speed exceeds MOVING, the spread of the static (inlier) points' Doppler residual (1.4826 MAD) and the
  fraction of non-static (outlier) points; distance relative, as for the points per scan;
- ghost rate: the simulation's multipath ghosts per detection (truth label 4); the real data carry no ghost
  labels, so this one is reported, not compared.
Goal: every distance <= GOAL (0.2: "within 20 %" for the scalars, a KS distance of 0.2 for the distributions).
Both sides are cropped to the real data's range span where the recording was cropped (RaFlow: 78 m).

Checked by: tests/cli/test_realism_cli.py, tests/sim/test_profiles.py, tests/sim/test_traffic.py (the boulevard)
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Callable

import numpy as np

from rodo.estimator.ego_velocity import estimate_ego_velocity
from rodo.estimator.errors import InputError
from rodo.sim import profiles
from rodo.sim import trajectory as traj
from rodo.sim import world as w
from rodo.sim.objects import GHOST
from rodo.sim.simulate import simulate

GOAL = 0.2
DOPPLER_GATE = 0.3  # m/s: inlier gate of the ego-velocity fit (both sides)
MOVING = 0.3  # m/s: scans whose fitted sensor speed is above this enter the Doppler statistics
MIN_POINTS = 5
FIT_SEED = 0


@dataclass(frozen=True)
class Setup:
    """How one profile is compared: the real recording (folder in the real-data directory and its converter),
    the simulation (seeds -> list of (Sequence, truth)), the value column and the range crop."""

    profile: str
    folder: str
    real: Callable
    simulate: Callable
    column: str
    crop: float | None = None
    notes: str = ""


@dataclass
class Pooled:
    """One side's pooled per-detection and per-scan values."""

    counts: np.ndarray
    range: np.ndarray
    azimuth: np.ndarray
    elevation: np.ndarray
    value: np.ndarray
    residual: np.ndarray
    nonstatic: float  # NaN without a moving scan
    ghost_rate: float | None = None
    moving_scans: int = 0  # scans that enter the Doppler statistics (fitted sensor speed above MOVING)


@dataclass
class Row:
    """One statistic; sim or real NaN: not computable on that side (then distance None, as for a statistic that is
    reported, not compared)."""

    name: str
    sim: float | str
    real: float | str
    distance: float | None
    measure: str

    @property
    def ok(self) -> bool | None:
        return None if self.distance is None else bool(self.distance <= GOAL)


@dataclass
class Report:
    profile: str
    rows: list[Row]
    sim: Pooled
    real: Pooled
    notes: list[str] = field(default_factory=list)


# ----------------------------------------------------------------------------------------------- statistics

def ks_distance(a: np.ndarray, b: np.ndarray) -> float:
    """Kolmogorov-Smirnov distance sup_x |F_a(x) - F_b(x)| of two samples' empirical distributions."""
    a, b = np.sort(np.asarray(a, float)), np.sort(np.asarray(b, float))
    if a.size == 0 or b.size == 0:
        return float("nan")
    x = np.concatenate([a, b])
    return float(np.max(np.abs(np.searchsorted(a, x, "right") / a.size - np.searchsorted(b, x, "right") / b.size)))


def relative(sim: float, real: float) -> float:
    return float(abs(sim - real) / abs(real)) if real != 0 else float("inf")


def _doppler(scan, rng) -> tuple[np.ndarray, np.ndarray] | None:
    """Static-point residuals and the inlier mask of one scan's ego-velocity fit (None: not a moving scan)."""
    if len(scan) < MIN_POINTS:
        return None
    fit = estimate_ego_velocity(scan.azimuth, scan.elevation, scan.radial_velocity, rng, threshold=DOPPLER_GATE)
    if not fit.ok or np.linalg.norm(fit.v_sensor) <= MOVING:
        return None
    ce = np.cos(scan.elevation)
    u = np.stack([ce * np.cos(scan.azimuth), ce * np.sin(scan.azimuth), np.sin(scan.elevation)], axis=1)
    res = scan.radial_velocity + u @ fit.v_sensor
    return res[fit.inliers], fit.inliers


def pooled(scans, column: str, crop: float | None, ghosts: np.ndarray | None = None) -> Pooled:
    """Pool the scans' statistics (detections beyond `crop` m dropped first). `ghosts`: per scan the truth's
    ghost flags (simulation only), for the ghost rate."""
    rng = np.random.default_rng(FIT_SEED)
    counts, cols, residuals, n_out, n_moving, n_ghost = [], {k: [] for k in ("r", "az", "el", "v")}, [], 0, 0, 0
    for k, scan in enumerate(scans):
        keep = np.ones(len(scan), bool) if crop is None else scan.range <= crop
        scan = scan if keep.all() else _subset(scan, keep)
        counts.append(len(scan))
        for key, values in zip(cols, (scan.range, scan.azimuth, scan.elevation, scan.extra.get(column))):
            if values is not None:
                cols[key].append(values)
        if ghosts is not None:
            n_ghost += int(np.sum(ghosts[k][keep]))
        fit = _doppler(scan, rng)
        if fit is not None:
            residuals.append(fit[0])
            n_out += int(np.sum(~fit[1]))
            n_moving += len(scan)
    cat = {k: np.concatenate(v) if v else np.zeros(0) for k, v in cols.items()}
    return Pooled(np.array(counts), cat["r"], cat["az"], cat["el"], cat["v"],
                  np.concatenate(residuals) if residuals else np.zeros(0),
                  n_out / n_moving if n_moving else float("nan"),
                  None if ghosts is None else n_ghost / max(len(cat["r"]), 1), len(residuals))


def _subset(scan, keep: np.ndarray):
    from rodo.sim.sequence import RadarScan

    return RadarScan(scan.scan, scan.t, scan.range[keep], scan.azimuth[keep], scan.elevation[keep],
                     scan.radial_velocity[keep], extra={k: v[keep] for k, v in scan.extra.items()})


def spread(residual: np.ndarray) -> float:
    """Robust standard deviation: 1.4826 MAD."""
    return float(1.4826 * np.median(np.abs(residual - np.median(residual)))) if residual.size else float("nan")


def _median(x: np.ndarray, scale: float = 1.0) -> float:
    """The median (times scale), NaN for no values (not computable; no warning)."""
    return float(np.median(x) * scale) if np.size(x) else float("nan")


def _row(name: str, sim: float, real: float, distance: float, measure: str) -> Row:
    """A compared statistic; its distance None where either side is not computable (NaN)."""
    computable = np.isfinite(sim) and np.isfinite(real)
    return Row(name, float(sim), float(real), float(distance) if computable else None, measure)


def compare(sim: Pooled, real: Pooled, column: str, planar: bool) -> list[Row]:
    """The statistics table (see the module docstring); a statistic one side has no data for (no detections, no
    moving scan) is NaN on that side, with no distance."""
    mean_sim, mean_real = (float(p.counts.mean()) if p.counts.size else float("nan") for p in (sim, real))
    deg = 180.0 / np.pi
    rows = [_row("points per scan (mean)", mean_sim, mean_real, relative(mean_sim, mean_real), "relative"),
            _row("range (m)", _median(sim.range), _median(real.range), ks_distance(sim.range, real.range), "KS"),
            _row("azimuth (deg)", _median(sim.azimuth, deg), _median(real.azimuth, deg),
                 ks_distance(sim.azimuth, real.azimuth), "KS")]
    if not planar:
        rows.append(_row("elevation (deg)", _median(sim.elevation, deg), _median(real.elevation, deg),
                         ks_distance(sim.elevation, real.elevation), "KS"))
    unit = "dBsm" if column == "rcs" else "dB"
    spreads = spread(sim.residual), spread(real.residual)
    rows += [_row(f"{column} ({unit})", _median(sim.value), _median(real.value), ks_distance(sim.value, real.value),
                  "KS"),
             _row("static Doppler residual spread (m/s)", *spreads, relative(*spreads), "relative"),
             _row("non-static fraction", sim.nonstatic, real.nonstatic, relative(sim.nonstatic, real.nonstatic),
                  "relative"),
             Row("ghost rate (per detection)", float(sim.ghost_rate or 0.0), "n/a (no labels)", None, "reported")]
    return rows


def not_computable(sim: Pooled, real: Pooled) -> list[str]:
    """Notes on the statistics a side could not give: no moving scan for the Doppler ones.

    Checked by:
        tests/cli/test_command_defects_realism_calibrate.py::test_a_side_without_moving_scans_has_no_doppler_statistics
    """
    notes = []
    for side, p in (("simulation", sim), ("real recording", real)):
        if not p.moving_scans:
            notes.append(f"static Doppler residual spread, non-static fraction: not computable for the {side} "
                         f"(n/a): no scan with >= {MIN_POINTS} detections moved faster than {MOVING:g} m/s"
                         + (" (a longer --duration reaches the motion)" if side == "simulation" else ""))
    return notes


# ------------------------------------------------------------------------------------------------- set-ups

def _real_raflow(folder: Path) -> list:
    from rodo.sim.convert import raflow

    return [c.sequence for c in raflow.convert(folder / "demo_data", min_scans=2)]


def _real_ti(folder: Path) -> list:
    from rodo.sim.convert import ti_mmwave

    return [ti_mmwave.convert(folder).sequence]


_KERB = w.SceneParams(building_offset=(14.0, 30.0), building_gap=(5.0, 20.0), building_height=(10.0, 30.0),
                      pole_spacing=15.0, pole_offset=(6.0, 12.0), tree_spacing=10.0, tree_offset=(5.0, 12.0),
                      parked_car_spacing=12.0, parked_car_offset=(6.0, 9.0), clutter_per_100m=40.0,
                      ground_half_width=30.0)
BOULEVARD = replace(_KERB, left=replace(_KERB, pole_offset=(13.0, 15.0), tree_offset=(13.0, 15.0),
                                        parked_car_offset=(13.4, 13.8), building_offset=(15.5, 30.0)))
"""The LRR30-F comparison's scene: a wide urban boulevard (Shanghai). On the right buildings 14-30 m away, trees
and poles, cars parked at the kerb 6-9 m off the lane; on the left, beyond the two oncoming lanes (7 and 10.5 m),
trees and poles 13-15 m, parked cars 13.4-13.8 m, buildings 15.5-30 m."""
TRAFFIC_ID = 1_000_000


def _traffic(rng: np.random.Generator, profile: traj.Profile, duration: float) -> list:
    """Dense traffic: oncoming cars (and every fourth a truck) about every 2.5 s in the lanes 7 and 10.5 m to
    the left, and overtaking cars in the lane to the right every 10 s."""
    movers, t, k = [], 1.0, 0
    while t < duration:
        size = w.TRUCK_SIZE if k % 4 == 3 else w.CAR_SIZE
        movers.append(w.oncoming_vehicle(profile, TRAFFIC_ID + k, t, lane=(7.0, 10.5)[k % 2],
                                         speed_ratio=rng.uniform(0.8, 1.2), size=size))
        k, t = k + 1, t + rng.uniform(1.5, 3.5)
    movers += [w.overtaking_vehicle(profile, TRAFFIC_ID + k + i, t0, lane=-3.5, speed_ratio=1.3)
               for i, t0 in enumerate(np.arange(3.0, duration, 10.0))]
    return movers


def boulevard(seed: int, duration: float, motion=traj.city) -> tuple:
    """(profile, world, the radar's rng) of drive `seed`: `motion` (the `city` scenario's: 0-50 km/h, turns, stops;
    or another) on BOULEVARD in dense traffic, clear of itself and of the parked cars (`World.with_traffic`)."""
    s_traj, s_world, s_radar = np.random.SeedSequence(seed).spawn(3)
    rng_world = np.random.default_rng(s_world)
    prof = motion(np.random.default_rng(s_traj), duration + 5.0)
    world = w.build_world(rng_world, traj.route_of(prof), BOULEVARD)
    return prof, world.with_traffic(_traffic(rng_world, prof, duration)), np.random.default_rng(s_radar)


def _sim_boulevard(profile: str, seeds, duration: float, motion=traj.city) -> list:
    out = []
    for seed in seeds:
        prof, world, rng_radar = boulevard(seed, duration, motion)
        out.append(simulate(world, prof, profiles.radar_config(profile), rng_radar, duration))
    return out


YARD = w.SceneParams(building_offset=(6.0, 12.0), building_length=(6.0, 15.0), building_gap=(1.0, 4.0),
                     building_height=(3.0, 6.0), building_prob=0.68, pole_spacing=10.0, pole_offset=(2.0, 6.0),
                     tree_spacing=15.0, tree_offset=(4.0, 10.0), parked_car_spacing=0.0, clutter_per_100m=390.0,
                     ground_half_width=10.0, clearance=1.0)
"""The TI comparison's scene: a yard or narrow lane (walls 6-12 m away, posts 2-6 m, trees, dense clutter: shrubs,
furniture), like the handheld rio demo's surroundings (ranges 0.5-19 m, median 4.5 m)."""


def walk_profile(rng: np.random.Generator, duration: float) -> traj.Profile:
    """The rio demo's motion: 13.7 s standing, walking ~1.3 m/s with gentle turns for 19.6 s, standing."""
    b = traj.ProfileBuilder(0.0).add(13.7).add(1.0, speed=1.3)
    while b.duration < 33.3:
        b.add(rng.uniform(1.0, 3.0), speed=rng.uniform(1.0, 1.6), yaw_rate=rng.uniform(-0.01, 0.01))
    b.add(1.0, speed=0.0, yaw_rate=0.0)
    return b.add(max(duration - b.duration, 1.0)).build()


def _sim_walk(profile: str, seeds, duration: float) -> list:
    out = []
    for seed in seeds:
        s_traj, s_world, s_radar = np.random.SeedSequence(seed).spawn(3)
        prof = walk_profile(np.random.default_rng(s_traj), duration + 1.0)
        world = w.build_world(np.random.default_rng(s_world), traj.route_of(prof), YARD)
        out.append(simulate(world, prof, profiles.radar_config(profile), np.random.default_rng(s_radar), duration))
    return out


def _real_radarscenes(folder: Path) -> list:
    from rodo.sim.convert import radarscenes

    return [radarscenes.convert_radar(folder, 3).sequence]


SETUPS = {
    "lrr30f": Setup("lrr30f", "raflow_lrr30_demo", _real_raflow, lambda seeds, d: _sim_boulevard("lrr30f", seeds, d),
                    "rcs", crop=78.0, notes="real: RaFlow demo data, all chains of >= 2 scans (104 scans); sim: "
                    "city motion on a wide boulevard in dense traffic (realism.BOULEVARD); both cropped at 78 m (the "
                    "demo data's largest range)"),
    "iwr6843aop": Setup("iwr6843aop", "rio_ti_mmwave_demo", _real_ti,
                        lambda seeds, d: _sim_walk("iwr6843aop", seeds, d), "snr",
                        notes="real: rio demo (412 scans, handheld, standing 2/3 of the time); sim: the same "
                        "stand-walk-stand timeline in a yard scene (realism.YARD); the radar reports SNR, not RCS"),
    "corner2d": Setup("corner2d", "radarscenes_seq105_2d", _real_radarscenes,
                      lambda seeds, d: _sim_boulevard("corner2d", seeds, d, traj.hills), "rcs",
                      notes="real: RadarScenes sequence 105, radar 3 (front left), 122 s at 13-25 m/s; sim: the "
                      "hills motion (40-70 km/h) on the boulevard in dense traffic; 2D (no elevation row)"),
}
DEFAULT_SEEDS = (0, 1, 2)
DEFAULT_DURATION = {"lrr30f": 20.0, "iwr6843aop": 40.0, "corner2d": 20.0}


def realism(profile: str, realdata: Path, seeds=DEFAULT_SEEDS, duration: float | None = None) -> Report:
    """Compare profile `profile`'s simulation with its real recording in `realdata` (../shared/realdata).

    Raises InputError for a profile without a comparison or a missing recording."""
    profiles.get(profile)
    if profile not in SETUPS:
        raise InputError(f"PROFILE: no real data to compare {profile!r} with; profiles with a comparison: "
                         f"{', '.join(SETUPS)}")
    setup = SETUPS[profile]
    folder = Path(realdata) / setup.folder
    if not folder.is_dir():
        raise InputError(f"--realdata: {folder} not found (the real recordings, docs/realdata.md)")
    duration = DEFAULT_DURATION[profile] if duration is None else float(duration)
    real_scans = [s for seq in setup.real(folder) for s in seq.scans]
    sims = setup.simulate(tuple(seeds), duration)
    sim_scans, ghosts = [], []
    for seq, truth in sims:
        off = truth["scan_offsets"]
        for scan in seq.scans:
            sim_scans.append(scan)
            ghosts.append(truth["det_label"][off[scan.scan]:off[scan.scan + 1]] == GHOST)
    planar = not profiles.radar_config(profile).physics.report_elevation
    sim = pooled(sim_scans, setup.column, setup.crop, ghosts)
    real = pooled(real_scans, setup.column, setup.crop)
    notes = [setup.notes, f"sim: seeds {', '.join(map(str, seeds))}, {duration:g} s each, {len(sim_scans)} scans; "
             f"real: {len(real_scans)} scans"] + not_computable(sim, real)
    return Report(profile, compare(sim, real, setup.column, planar), sim, real, notes)


def format_table(report: Report) -> str:
    """The report's table as Markdown."""
    lines = [f"| statistic ({report.profile}) | sim | real | distance | within {GOAL:.0%} |",
             "| --- | --- | --- | --- | --- |"]
    for row in report.rows:
        fmt = (lambda v: v if isinstance(v, str) else f"{v:.4g}" if np.isfinite(v) else "n/a")
        dist = "-" if row.distance is None else f"{row.distance:.3f} ({row.measure})"
        ok = "-" if row.ok is None else ("yes" if row.ok else "NO")
        lines.append(f"| {row.name} | {fmt(row.sim)} | {fmt(row.real)} | {dist} | {ok} |")
    return "\n".join(lines)


__all__ = ["BOULEVARD", "DEFAULT_SEEDS", "GOAL", "Pooled", "Report", "Row", "SETUPS", "Setup", "boulevard", "compare",
           "format_table", "ks_distance", "pooled", "realism", "relative", "spread", "walk_profile"]
