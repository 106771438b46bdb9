"""The imaging-radar sensor model: what a 4D radar (range, azimuth, elevation, radial velocity) reports for
one scan of a `sim.world.World`, computed from geometry only (no estimator code: the estimator's measurement
models are checked against this, and vice versa).

Measurement model (sensor frame x boresight, y left, z up; paper eq. 80 and docs/conventions.md):
    r = |p_sensor|, azimuth = atan2(y, x), elevation = asin(z / r),
    v_r = d r / dt = u . (C_sensor_world v_target - v_sensor),   u = p_sensor / r,
with v_sensor the velocity of the sensor origin in the sensor frame, from the vehicle twist
[v; w] = -varpi and the lever arm r_vehicle_sensor (translation of T_vehicle_sensor):
v_sensor = C_vehicle_sensor^T (v + w x r_vehicle_sensor). A static target gives v_r = -u . v_sensor
(negative when approaching). Then Gaussian noise in polar coordinates.

Per scan: cull patches -> sample surfaces (Poisson counts, density falling as 1/r^2, i.e. a fixed expected
number per resolution cell) -> add point scatterers and moving boxes -> field of view and range gates ->
occlusion (a depth buffer of opaque patches on the angular cell grid, then one detection per cell: the
nearest) -> detection probability -> noise -> Poisson false alarms. See docs/simulator.md.

Where the radar sits and the polar coordinates: sim/sensor_geometry.py.

Checked by: tests/sim/test_radar.py
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from rodo.estimator.errors import InputError
from rodo.estimator.lie import se3

from . import radar_kernels as kern
from . import radar_physics as rp
from .culling import Cull, PatchGeometry, PointIndex, transform
from .multipath import ghost_candidates, reflectors
from .objects import CLUTTER, GHOST, MOVING, STATIC_POINT, STATIC_SURFACE, Patches
from .occlusion import cell_directions, cross, depth_buffer, gate_cells, nearest_per_bin, nearest_visible
from .sensor_geometry import DEG, default_mount, polar, sensor_velocity


@dataclass(frozen=True, eq=False)
class RadarConfig:
    """Sensor parameters (SI units, radians). `noise_free()` gives sigmas 0, no clutter and detection prob 1.

    Attributes:
        sigmas: 1-sigma noise of (range, azimuth, elevation, radial_velocity).
        cell_azimuth, cell_elevation: angular resolution cell (occlusion and one detection per cell).
        pd_max, pd_range50, pd_width: detection probability pd(r) = pd_max / (1 + exp((r - r50) / width)),
            multiplied by a point scatterer's own probability.
        surface_fill: expected detections per resolution cell covered by a surface of reflectivity 1 seen
            head-on (the density of surface samples falls as cos(incidence) / r^2).
        min_density_range: below this range the surface density stops growing.
        clutter_rate: mean number of false alarms per scan (Poisson), uniform in the field of view and range,
            radial velocity uniform in +-clutter_speed.
        occlusion_tolerance: a target is hidden if an opaque surface of another object is this much closer.
        ideal_detection: every visible target is detected (pd 1, including point scatterers).
        physics: None (the default model above: pd(r), fixed sigmas) or a `sim.radar_physics.RadarPhysics`:
            RCS per scatterer class, SNR from the radar equation, detection and noise from SNR (the sigmas are
            then the accuracy floors), ambiguities, multipath ghosts, `rcs` and `snr` outputs (sensor profiles,
            `sim.profiles`).
    """

    rate_hz: float = 13.0
    T_vehicle_sensor: np.ndarray = field(default_factory=default_mount)
    sigmas: tuple = (0.02, 0.15 * DEG, 0.3 * DEG, 0.01)
    azimuth_fov: tuple = (-60 * DEG, 60 * DEG)
    elevation_fov: tuple = (-15 * DEG, 15 * DEG)
    min_range: float = 0.5
    max_range: float = 150.0
    cell_azimuth: float = 0.5 * DEG
    cell_elevation: float = 1.0 * DEG
    pd_max: float = 0.95
    pd_range50: float = 120.0
    pd_width: float = 10.0
    surface_fill: float = 0.2
    min_density_range: float = 2.0
    clutter_rate: float = 20.0
    clutter_speed: float = 20.0
    occlusion_tolerance: float = 0.3
    ideal_detection: bool = False
    physics: rp.RadarPhysics | None = None

    def __post_init__(self):
        if not (self.rate_hz > 0 and 0 <= self.min_range < self.max_range):
            raise InputError("RadarConfig: need rate_hz > 0 and 0 <= min_range < max_range")
        if len(self.sigmas) != 4 or any(not np.isfinite(s) or s < 0 for s in self.sigmas):
            raise InputError(f"RadarConfig.sigmas: need 4 finite values >= 0, got {self.sigmas}")
        for name in ("azimuth_fov", "elevation_fov"):
            lo, hi = getattr(self, name)
            if not lo < hi:
                raise InputError(f"RadarConfig.{name}: need min < max, got {(lo, hi)}")
        if self.cell_azimuth <= 0 or self.cell_elevation <= 0:
            raise InputError("RadarConfig.cell_azimuth/cell_elevation: must be > 0")
        if self.physics is not None and not isinstance(self.physics, rp.RadarPhysics):
            raise InputError(f"RadarConfig.physics: expected a RadarPhysics or None, got {type(self.physics).__name__}")

    def in_view(self, r: np.ndarray, az: np.ndarray, el: np.ndarray) -> np.ndarray:
        """Which targets at range r, azimuth az, elevation el lie within the range gates and the field of view."""
        return ((r >= self.min_range) & (r <= self.max_range) & (az >= self.azimuth_fov[0])
                & (az <= self.azimuth_fov[1]) & (el >= self.elevation_fov[0]) & (el <= self.elevation_fov[1]))

    def noise_free(self) -> "RadarConfig":
        return replace(self, sigmas=(0.0, 0.0, 0.0, 0.0), clutter_rate=0.0, ideal_detection=True)

    def pd(self, r: np.ndarray) -> np.ndarray:
        if self.ideal_detection:
            return np.ones_like(r)
        return self.pd_max / (1.0 + np.exp((r - self.pd_range50) / self.pd_width))

    def sensor_config(self):
        """The `sim.sequence.SensorConfig` written to sensor.toml. Zero sigmas (noise-free) are written as
        1e-6 because the file format requires positive sigmas."""
        from .sequence import NoiseSigmas, SensorConfig

        s = [max(x, 1e-6) for x in self.sigmas]
        return SensorConfig(self.rate_hz, np.array(self.T_vehicle_sensor), NoiseSigmas(*s), tuple(self.azimuth_fov),
                            tuple(self.elevation_fov), self.max_range, self.min_range)

    @property
    def grid_shape(self) -> tuple[int, int]:
        return (int(np.ceil((self.azimuth_fov[1] - self.azimuth_fov[0]) / self.cell_azimuth)),
                int(np.ceil((self.elevation_fov[1] - self.elevation_fov[0]) / self.cell_elevation)))


@dataclass(frozen=True)
class Detections:
    """One scan's output. Measured: range, azimuth, elevation, radial_velocity (n,). Truth: label (n,) (0 static
    surface, 1 static point, 2 moving, 3 clutter, 4 ghost), object_id (n,) (-1 if none), landmark_id (n,) (-1 if
    none), p_world (n, 3) the true scatterer (NaN for clutter and ghosts), true_polar (n, 4) noise-free measurement.
    With a physical radar (`RadarConfig.physics`) also the reported rcs (dBsm) and snr (dB), (n,); else None."""

    range: np.ndarray
    azimuth: np.ndarray
    elevation: np.ndarray
    radial_velocity: np.ndarray
    label: np.ndarray
    object_id: np.ndarray
    landmark_id: np.ndarray
    p_world: np.ndarray
    true_polar: np.ndarray
    rcs: np.ndarray | None = None
    snr: np.ndarray | None = None

    def __len__(self) -> int:
        return len(self.range)

    def extra(self) -> dict:
        """The optional measured columns of radar.csv (`rcs`, `snr`) that this scan has."""
        return {} if self.rcs is None else {"rcs": self.rcs, "snr": self.snr}


def empty_detections(config: RadarConfig | None = None) -> Detections:
    """A scan without detections (with empty rcs and snr for a physical radar)."""
    z = np.zeros(0)
    zi = np.zeros(0, int)
    optional = {} if config is None or config.physics is None else {"rcs": z, "snr": z}
    return Detections(z, z, z, z, zi, zi, zi, np.zeros((0, 3)), np.zeros((0, 4)), **optional)


class Radar:
    """A radar with a fixed configuration; `scan(...)` simulates one scan.

    Args:
        config: the sensor parameters.
    """

    def __init__(self, config: RadarConfig | None = None):
        self.config = RadarConfig() if config is None else config
        self._dirs = cell_directions(self.config)
        self._scene = (None, None, None)  # (world patches, world points, their _StaticScene)
        self._ghost_rng = None  # physical radars: spawned from the scan generator on the first scan

    def _static(self, world) -> "_StaticScene":
        """The culling geometry of the world's static patches and points, computed once per scene (kept for
        the last world scanned, recognised by its patches and points objects: a scene is not modified in place
        between scans)."""
        patches, points, scene = self._scene
        if patches is not world.patches or points is not world.points:
            scene = _StaticScene(PatchGeometry(world.patches, indexed=True), PointIndex(world.points.p))
            self._scene = (world.patches, world.points, scene)
        return scene

    def scan(self, world, T_world_vehicle: np.ndarray, varpi: np.ndarray, rng: np.random.Generator,
             movers: list | None = None) -> Detections:
        """Detections of one scan.

        Args:
            world: `sim.world.World` (static patches and points; its blackouts are handled by the caller).
            T_world_vehicle: (4, 4) true vehicle pose at the scan time.
            varpi: (6,) the state's body velocity [nu; omega] at the scan time (nu = -speed forward).
            rng: the random generator (consumed in a fixed order: same state -> same scan).
            movers: list of (MovingBox, T_world_object (4, 4), v_world (3,), w_world (3,)) present now.

        Returns:
            `Detections` in random order.

        Checked by: tests/sim/test_radar.py (exact geometry, radial velocity sign, noise statistics, field
        of view, range limits, occlusion, moving targets).
        """
        cfg = self.config
        T_sensor_world = se3.inverse(T_world_vehicle @ cfg.T_vehicle_sensor)
        v_sensor, _ = sensor_velocity(np.asarray(varpi, dtype=float), cfg.T_vehicle_sensor)
        if cfg.physics is not None:
            return self._physical_scan(world, T_sensor_world, v_sensor, rng, movers or ())
        cand, opaque, n_all, _ = _candidates(world, self._static(world), T_sensor_world, cfg, rng, movers or ())
        p_sensor = transform(cand.p_world, T_sensor_world[:3, :3], T_sensor_world[:3, 3], n_all)
        idx, r, az, el = self._visible(p_sensor, cand.object_id, opaque)
        pd = cfg.pd(r) * (1.0 if cfg.ideal_detection else cand.pd_own.take(idx))
        hit = rng.random(len(idx)) < pd
        idx, r, az, el = idx[hit], r[hit], az[hit], el[hit]
        u = p_sensor.take(idx, axis=0) / np.repeat(r, 3).reshape(-1, 3)  # = / r[:, None]
        v = cand.v_world.take(idx, axis=0) @ T_sensor_world[:3, :3].T
        for j in range(3):
            v[:, j] -= v_sensor[j]
        vr = np.einsum("ij,ij->i", u, v)
        return _noisy_with_clutter(np.stack([r, az, el, vr]), cand, idx, cfg, rng)

    def _physical_scan(self, world, T_sensor_world: np.ndarray, v_sensor: np.ndarray, rng: np.random.Generator,
                       movers) -> Detections:
        """A scan of a radar with `config.physics` (sim.radar_physics): the same candidates, gates and occlusion,
        then RCS and power per target, detection by threshold, noise from SNR, multipath ghosts (their own
        generator, spawned from `rng` once: switching ghosts on or off changes no other draw), false alarms,
        order, then ambiguities and quantisation of what is reported."""
        cfg, phy = self.config, self.config.physics
        if self._ghost_rng is None:
            self._ghost_rng = rng.spawn(1)[0]
        cand, opaque, n_all, static = _candidates(world, self._static(world), T_sensor_world, cfg, rng, movers)
        C = T_sensor_world[:3, :3]
        p_sensor = transform(cand.p_world, C, T_sensor_world[:3, 3], n_all)
        idx, r, az, el = self._visible(p_sensor, cand.object_id, opaque, phy.range_cell)
        cls = rp.scatterer_class(cand.label.take(idx), cand.reflectivity.take(idx))
        rcs, x = rp.target_power(phy, cls, cand.pd_own.take(idx), r, az, el, rng)
        hit = np.flatnonzero(x > phy.threshold) if not cfg.ideal_detection else np.arange(len(idx))
        idx, r, az, el, rcs, x = (a.take(hit) for a in (idx, r, az, el, rcs, x))
        p = p_sensor.take(idx, axis=0)
        v = cand.v_world.take(idx, axis=0) @ C.T
        vr = np.einsum("ij,ij->i", p / r[:, None], v - v_sensor)
        real = rp.Targets(np.stack([r, az, el, vr]), x, cand.label.take(idx), cand.object_id.take(idx),
                          cand.landmark_id.take(idx), cand.p_world.take(idx, axis=0))
        ghosts = self._ghosts(static, p, v, v_sensor, rcs)
        fa = _false_alarms(cfg, rng)
        n_fa = fa.shape[1]
        clutter = rp.Targets(fa, phy.threshold + rng.standard_exponential(n_fa), np.full(n_fa, CLUTTER),
                             np.full(n_fa, -1), np.full(n_fa, -1), np.full((n_fa, 3), np.nan))
        out = rp.Targets.concat([real, clutter]).noisy(phy, cfg.sigmas, rng).permuted(rng)
        ghosts = ghosts.noisy(phy, cfg.sigmas, self._ghost_rng)
        out = rp.Targets.concat([out, ghosts]).inserted(len(out), self._ghost_rng)
        return Detections(**out.reported(phy))

    def _ghosts(self, static: Cull, p: np.ndarray, v: np.ndarray, v_sensor: np.ndarray,
                rcs: np.ndarray) -> "rp.Targets":
        """Multipath ghosts of the detected targets (sensor frame p, v) via the static reflectors in view, with
        the source's RCS less the bounce loss, detected by the same threshold (the ghost generator only)."""
        phy, g = self.config.physics, self._ghost_rng
        if phy.ghost_prob > 0:
            src, p_g, vr_g = ghost_candidates(p, v, v_sensor, reflectors(static.sensor(), phy.ghost_min_area),
                                              phy.ghost_prob, g)
        else:
            src, p_g, vr_g = np.zeros(0, int), np.zeros((0, 3)), np.zeros(0)
        r, az, el = polar(p_g)
        cfg = self.config
        snr = 10.0 ** ((rp.snr_db(phy.snr_1m_db, rcs.take(src) - phy.ghost_loss_db, r) + rp.pattern_db(phy, az, el))
                       / 10.0)
        x = (1.0 + snr) * g.standard_exponential(len(src))
        keep = np.flatnonzero((x > phy.threshold) & cfg.in_view(r, az, el))
        m = len(keep)
        return rp.Targets(np.stack([r, az, el, vr_g])[:, keep], x.take(keep), np.full(m, GHOST), np.full(m, -1),
                          np.full(m, -1), np.full((m, 3), np.nan))

    def _visible(self, p_sensor: np.ndarray, object_id: np.ndarray, opaque: list[Patches],
                 range_cell: float | None = None):
        """Gates (range, field of view), occlusion by opaque surfaces of other objects in front, then the
        nearest candidate per cell (per cell and range bin of `range_cell` m if given: physical radars only):
        indices into the candidates and their range, azimuth, elevation."""
        cfg = self.config
        r, az, el = polar(p_sensor)
        idx, cell, r_hidden, limit = gate_cells(r, az, el, cfg)  # limit: per cell the farthest r_hidden
        depth, owner = depth_buffer(Patches.concat(opaque), cfg, self._dirs, limit)
        if range_cell is None:
            idx = nearest_visible(idx, cell, r_hidden, r, object_id, depth, owner)
        else:
            visible = ~((depth.take(cell) < r_hidden) & (owner.take(cell) != object_id.take(idx)))
            idx, cell = idx[visible], cell[visible]
            idx = idx[nearest_per_bin(cell, r.take(idx), range_cell, cfg.max_range)]
        return idx, r.take(idx), az.take(idx), el.take(idx)


@dataclass(frozen=True)
class _Candidates:
    """Scatterers that may be detected in one scan (before gates and occlusion), (n,) or (n, 3) each."""

    p_world: np.ndarray
    v_world: np.ndarray
    label: np.ndarray
    object_id: np.ndarray
    landmark_id: np.ndarray
    pd_own: np.ndarray
    reflectivity: np.ndarray | None = None  # physical radars only (the RCS class of surface samples)

    def __len__(self) -> int:
        return len(self.p_world)


@dataclass(frozen=True)
class _StaticScene:
    """A world's static patches and points, indexed for culling (`sim.culling`)."""

    patches: PatchGeometry
    points: PointIndex


def _candidates(world, scene: _StaticScene, T_sensor_world: np.ndarray, cfg: RadarConfig,
                rng: np.random.Generator, movers) -> tuple[_Candidates, list[Patches], int, Cull]:
    """Static surface samples, the point scatterers near enough to be in range and the movers' surface samples
    (drawn in that order), with the opaque patches (sensor frame) that may hide them, the number of
    candidates had every point scatterer been included (see `sim.culling.transform`) and the static culling.
    With `cfg.physics` the candidates also carry their surfaces' reflectivity (no further draws)."""
    static = Cull(scene.patches, T_sensor_world, cfg)
    pts, k = static.sample(cfg, rng)
    opaque = [static.sensor(opaque_only=True)]
    P = world.points
    near = scene.points.near(T_sensor_world, cfg)
    p, pd, landmark_id = (P.p, P.pd, P.landmark_id) if near is None else (P.p.take(near, axis=0), P.pd.take(near),
                                                                          P.landmark_id.take(near))
    p_world, v_moving, n_moving = [pts, p], [], []
    refl = None if cfg.physics is None else [world.patches.reflectivity.take(static.idx.take(k))]
    if movers:  # culled together (one set of calls), sampled one by one (the draws in the movers' order)
        bodies = [mover.body_patches.transformed(T_world_object) for mover, T_world_object, _, _ in movers]
        cull = Cull(PatchGeometry(Patches.concat(bodies), indexed=False), T_sensor_world, cfg)
        groups = np.searchsorted(cull.idx, np.cumsum([0] + [len(b) for b in bodies]))
        for g, (mover, T_world_object, v_object, w_object) in enumerate(movers):
            pts_g, _ = cull.sample(cfg, rng, slice(groups[g], groups[g + 1]))
            p_world.append(pts_g)
            v_moving.append(v_object + cross(w_object, pts_g - T_world_object[:3, 3]))
            n_moving.append(len(pts_g))
            if refl is not None:
                refl.append(np.full(len(pts_g), 2.0))
        opaque.append(cull.sensor(groups=groups))
    n_s, n_p, n_m = len(pts), len(p), sum(n_moving)
    mover_ids = np.array([mover.object_id for mover, *_ in movers], dtype=int)
    cand = _Candidates(
        p_world=np.concatenate(p_world), v_world=np.concatenate([np.zeros((n_s + n_p, 3))] + v_moving),
        label=np.repeat([STATIC_SURFACE, STATIC_POINT, MOVING], [n_s, n_p, n_m]),
        object_id=np.concatenate([static.object_id.take(k), np.full(n_p, -1), np.repeat(mover_ids, n_moving)]),
        landmark_id=np.concatenate([np.full(n_s, -1), landmark_id, np.full(n_m, -1)]),
        pd_own=np.concatenate([np.ones(n_s), pd, np.ones(n_m)]),
        reflectivity=None if refl is None else np.concatenate([refl[0], np.ones(n_p)] + refl[1:]))
    return cand, opaque, len(cand) + len(P) - n_p, static


def _false_alarms(cfg: RadarConfig, rng: np.random.Generator) -> np.ndarray:
    """Poisson(clutter_rate) false alarms, uniform in range, field of view and +-clutter_speed: (4, n_fa)."""
    n_fa = rng.poisson(cfg.clutter_rate) if cfg.clutter_rate > 0 else 0
    return np.stack([rng.uniform(cfg.min_range, cfg.max_range, n_fa), rng.uniform(*cfg.azimuth_fov, n_fa),
                     rng.uniform(*cfg.elevation_fov, n_fa), rng.uniform(-cfg.clutter_speed, cfg.clutter_speed, n_fa)])


def _noisy_with_clutter(true: np.ndarray, cand: _Candidates, idx: np.ndarray, cfg: RadarConfig,
                        rng: np.random.Generator) -> Detections:
    """Polar noise on the detected targets' true measurements (4, n) (range, azimuth, elevation, radial
    velocity), Poisson false alarms, a random order."""
    n = true.shape[1]
    z = rng.standard_normal((n, 4))  # the draws: (n, 4) row-major, then the false alarms, then the order
    fa = _false_alarms(cfg, rng)
    perm = rng.permutation(n + fa.shape[1])
    cols = kern.noisy_in_order(np.ascontiguousarray(true), z, np.asarray(cfg.sigmas, dtype=float), fa, perm, idx,
                               cand.label, cand.object_id, cand.landmark_id, np.ascontiguousarray(cand.p_world),
                               CLUTTER)
    return Detections(*cols)
