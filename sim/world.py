"""Structured scenes around a route: buildings with gaps, poles, trees, parked cars, guard rails, road-side
clutter, ground that follows the road's height, and moving vehicles (lead, oncoming, overtaking).

Everything static is placed relative to the route polyline (`sim.trajectory.Route`) and rejected if it would
come closer than `clearance` to the driven path. The ground is `GROUND_BELOW` metres under the vehicle frame
origin (the rear-axle centre), so on hills it follows the road's height. `landmark_world` is the other kind of
scene: persistent point scatterers only (the exact measurement model of the `prior_*_points` scenarios).

Checked by: tests/sim/test_world.py
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.spatial import cKDTree

from rodo.estimator.lie import se3, so3

from .objects import MovingBox, Patches, Points, box, empty_patches
from .traffic import collision_free, footprints
from .trajectory import Profile, Route

GROUND_BELOW = 0.35  # m, ground under the vehicle frame origin
CAR_SIZE = (4.5, 1.8, 1.5)
TRUCK_SIZE = (8.0, 2.5, 3.6)


@dataclass(frozen=True)
class SceneParams:
    """What to put along the route (ranges are (low, high) of uniform draws; spacings in metres)."""

    building_offset: tuple = (9.0, 16.0)     # facade distance from the route, m (None-like: 0 buildings)
    building_length: tuple = (12.0, 40.0)
    building_gap: tuple = (3.0, 15.0)
    building_height: tuple = (6.0, 20.0)
    building_prob: float = 0.85              # a slot holds a building (else an open gap)
    pole_spacing: float = 25.0
    pole_offset: tuple = (4.5, 7.0)
    tree_spacing: float = 30.0
    tree_offset: tuple = (5.0, 9.0)
    parked_car_spacing: float = 20.0         # 0: none
    parked_car_offset: tuple = (3.6, 4.4)    # centre distance from the route
    guard_rail_offset: float = 0.0           # 0: no guard rails
    clutter_per_100m: float = 20.0
    ground_half_width: float = 20.0
    ground_reflectivity: float = 0.15
    clearance: float = 2.5
    left: "SceneParams | None" = None        # the left side's, where not the same (beyond lanes of traffic)

    def side(self, side: float) -> "SceneParams":
        """The params of the route's left (side > 0) or right side (the placement steps' per-side draws)."""
        return self.left if side > 0 and self.left is not None else self


CITY = SceneParams()
# CITY with traffic in the lane to the left (oncoming, 3.5 m): the parked cars on the left stand beyond it, clear
# of a truck's width; on the right at the kerb
CITY_ONCOMING = SceneParams(left=SceneParams(parked_car_offset=(6.2, 6.8)))
# ... and in the lane to the right too (overtaking, 3.5 m): the parked cars stand beyond both
CITY_TWO_LANES = SceneParams(parked_car_offset=(6.2, 6.8))
HIGHWAY = SceneParams(building_offset=(25.0, 45.0), building_prob=0.25, building_height=(5.0, 10.0),
                      pole_spacing=50.0, pole_offset=(9.0, 12.0), tree_spacing=40.0, tree_offset=(12.0, 25.0),
                      parked_car_spacing=0.0, guard_rail_offset=7.5, clutter_per_100m=10.0,
                      ground_half_width=25.0, clearance=5.0)
RURAL = SceneParams(building_offset=(12.0, 30.0), building_prob=0.3, building_height=(4.0, 9.0),
                    pole_spacing=40.0, tree_spacing=12.0, tree_offset=(5.0, 15.0), parked_car_spacing=0.0,
                    clutter_per_100m=30.0)


@dataclass(frozen=True)
class World:
    """A scene: static surface patches, persistent point scatterers, moving boxes, and blackout intervals
    (t0, t1) in which the radar is totally blocked (e.g. spray on the radome): those scans are empty."""

    patches: Patches
    points: Points
    movers: tuple = ()
    blackouts: tuple = ()
    solids: np.ndarray = field(default_factory=lambda: np.zeros((0, 4, 2)))  # (K, 4, 2) parked cars' footprints

    def blacked_out(self, t: float) -> bool:
        return any(t0 <= t <= t1 for t0, t1 in self.blackouts)

    def with_movers(self, movers) -> "World":
        return World(self.patches, self.points, tuple(self.movers) + tuple(movers), self.blackouts, self.solids)

    def with_traffic(self, movers) -> "World":
        """`with_movers` for traffic placed by rule: each mover whose footprint would overlap one already in
        the world, an earlier one of `movers` or a parked car while both are present is left out
        (`traffic.collision_free`)."""
        kept, _ = collision_free(tuple(self.movers) + tuple(movers), self.solids)
        return World(self.patches, self.points, tuple(kept), self.blackouts, self.solids)

    def with_blackouts(self, blackouts) -> "World":
        return World(self.patches, self.points, self.movers, tuple(self.blackouts) + tuple(blackouts), self.solids)


class _Ids:
    def __init__(self):
        self.object = 0
        self.landmark = 0

    def next_object(self) -> int:
        self.object += 1
        return self.object - 1

    def landmarks(self, n: int) -> np.ndarray:
        self.landmark += n
        return np.arange(self.landmark - n, self.landmark)


def _frame(route: Route, s: np.ndarray):
    """Route position (ground level), forward and left unit vectors at arc lengths s (clipped to the route)."""
    i = np.clip(np.round(np.asarray(s) / max(route.s[1] - route.s[0], 1e-9)).astype(int) if route.s.size > 1
                else np.zeros(np.shape(s), int), 0, len(route.s) - 1)
    ground = route.p_world[i] - np.array([0.0, 0.0, GROUND_BELOW])
    return ground, route.forward()[i], route.left()[i], i


def _positions(rng, length: float, spacing: float) -> np.ndarray:
    """Arc lengths roughly `spacing` apart (jittered), covering [0, length + 60] (a little past the end)."""
    if spacing <= 0:
        return np.zeros(0)
    n = int((length + 60.0) / spacing) + 1
    return np.cumsum(rng.uniform(0.5, 1.5, n) * spacing) - rng.uniform(0, spacing)


class _Scene:
    """What the placement steps share: the route, its kd-tree (clearance tests), the id counters, and the
    patches and points placed so far."""

    def __init__(self, route: Route, params: SceneParams):
        self.route = route
        self.params = params
        self.ids = _Ids()
        self.tree = cKDTree(route.p_world[:, :2])
        self.patches: list[Patches] = []
        self.points: list[Points] = []
        self.solids: list[np.ndarray] = []  # (4, 2) footprints of the parked cars

    def clear(self, pts) -> bool:
        """All points at least `clearance` from the driven path."""
        d, _ = self.tree.query(np.atleast_2d(pts)[:, :2])
        return bool(np.all(d >= self.params.clearance))

    def far(self, pts: np.ndarray, margin: float = 0.0) -> np.ndarray:
        """(n,) mask of the points at least `clearance + margin` from the driven path."""
        return self.tree.query(pts[:, :2])[0] >= self.params.clearance + margin


def build_world(rng: np.random.Generator, route: Route, params: SceneParams = CITY) -> World:
    """A static scene around `route`. Random draws only from `rng` (same rng state -> same world), in the
    order of the steps below."""
    scene = _Scene(route, params)
    _add_buildings(scene, rng)
    _add_poles(scene, rng)
    _add_trees(scene, rng)
    _add_parked_cars(scene, rng)
    if params.guard_rail_offset > 0:
        _add_guard_rails(scene)
    _add_roadside_clutter(scene, rng)
    scene.patches.append(_ground(route, params, scene.ids.next_object()))
    return World(Patches.concat(scene.patches), Points.concat(scene.points),
                 solids=np.array(scene.solids).reshape(-1, 4, 2))


def landmark_world(rng: np.random.Generator, route: Route, per_100m: float = 400.0, lateral: tuple = (3.0, 40.0),
                   height: tuple = (0.2, 6.0), pd: tuple = (0.6, 0.95)) -> World:
    """A scene of persistent point scatterers only: no surfaces, no ground. `per_100m` points per 100 m of route
    (Poisson, uniform along it from its start to its end), `lateral` metres to either side of it, `height` metres
    above the road, each with its own detection probability drawn from `pd`. Every return but clutter is then one
    of a fixed set of points seen again scan after scan, so the estimator's point-to-point pairs are an exact
    measurement model (resampled surfaces are not: docs/consistency.md). Random draws only from `rng`."""
    n = int(rng.poisson(per_100m * route.length / 100.0))
    g, _, left, _ = _frame(route, rng.uniform(0.0, route.length, n))
    side = rng.choice([-1.0, 1.0], n) * rng.uniform(*lateral, n)
    p = g + side[:, None] * left + np.array([0.0, 0.0, 1.0]) * rng.uniform(*height, (n, 1))
    keep = _Scene(route, SceneParams()).far(p)
    points = Points(p[keep], rng.uniform(*pd, n)[keep], np.arange(int(keep.sum())))
    return World(empty_patches(), points)


def _add_buildings(scene: _Scene, rng: np.random.Generator) -> None:
    """Buildings: boxes whose road-facing side is the facade; corners are strong point scatterers."""
    route = scene.route
    for side in (-1.0, 1.0):
        params = scene.params.side(side)
        s = rng.uniform(-20.0, 0.0)
        while s < route.length + 40.0:
            length = rng.uniform(*params.building_length)
            if rng.uniform() < params.building_prob:
                off, depth, height = rng.uniform(*params.building_offset), rng.uniform(8, 15), \
                    rng.uniform(*params.building_height)
                _add_building(scene, rng, side, s, length, off, depth, height)
            s += length + rng.uniform(*params.building_gap)


def _add_building(scene: _Scene, rng: np.random.Generator, side: float, s: float, length: float, off: float,
                  depth: float, height: float) -> None:
    """One building from arc length s to s + length, its facade `off` metres to the side (if the road is
    straight enough there and the building keeps clear of the path)."""
    (g0, g1), (f0, f1), (l0, l1), _ = _frame(scene.route, np.array([s, s + length]))
    if not np.dot(f0, f1) > np.cos(0.15):  # not straight enough
        return
    a = g0 + side * off * l0
    b = g1 + side * off * l1
    u = b - a
    u[2] = 0.0
    yaw = np.arctan2(u[1], u[0])
    centre = 0.5 * (a + b) + side * 0.5 * depth * l0
    centre[2] = min(a[2], b[2]) - 1.0
    size = (np.linalg.norm(u), depth, height + 1.0)
    T_world_building = se3.from_rotation_translation(so3.exp(np.array([0, 0, yaw])), centre)
    corners = se3.transform_points(T_world_building, np.array([[sx * size[0] / 2, sy * depth / 2, 1.5]
                                                               for sx in (-1, 1) for sy in (-1, 1)]))
    if scene.clear(corners) and size[0] > 1.0:
        scene.patches.append(box(T_world_building, size, scene.ids.next_object(), 1.0, opaque=True))
        scene.points.append(Points(corners, rng.uniform(0.5, 0.9, 4), scene.ids.landmarks(4)))


def _add_poles(scene: _Scene, rng: np.random.Generator) -> None:
    """Poles (3 scatterers up the pole) and signs."""
    route = scene.route
    for side in (-1.0, 1.0):
        params = scene.params.side(side)
        s = _positions(rng, route.length, params.pole_spacing)
        g, _, left, _ = _frame(route, s)
        base = g + side * rng.uniform(*params.pole_offset, (len(s), 1)) * left
        base = base[scene.far(base)]
        heights = np.array([0.5, 2.5, 4.5])
        p = (base[:, None, :] + heights[None, :, None] * np.array([0, 0, 1.0])).reshape(-1, 3)
        scene.points.append(Points(p, rng.uniform(0.6, 0.95, len(p)), scene.ids.landmarks(len(p))))


def _add_trees(scene: _Scene, rng: np.random.Generator) -> None:
    """Trees: a trunk scatterer and a few weak canopy scatterers."""
    route = scene.route
    for side in (-1.0, 1.0):
        params = scene.params.side(side)
        s = _positions(rng, route.length, params.tree_spacing)
        g, _, left, _ = _frame(route, s)
        base = g + side * rng.uniform(*params.tree_offset, (len(s), 1)) * left
        base = base[scene.far(base, 1.0)]
        canopy = base[:, None, :] + np.array([0, 0, 4.0]) + rng.normal(0, [1.2, 1.2, 0.8], (len(base), 5, 3))
        trunk = base + np.array([0, 0, 1.0])
        canopy = canopy.reshape(-1, 3)
        canopy = canopy[scene.far(canopy)]
        p = np.concatenate([trunk, canopy])
        pd = np.concatenate([np.full(len(trunk), 0.6), np.full(len(canopy), 0.3)])
        scene.points.append(Points(p, pd, scene.ids.landmarks(len(p))))


def _add_parked_cars(scene: _Scene, rng: np.random.Generator) -> None:
    """Parked cars: opaque boxes + bumper-corner scatterers."""
    route = scene.route
    for side in (-1.0, 1.0):
        params = scene.params.side(side)
        if not params.parked_car_spacing > 0:
            continue
        s = _positions(rng, route.length, params.parked_car_spacing)
        s = s[rng.uniform(size=len(s)) < 0.6]
        g, f, left, _ = _frame(route, s)
        for k in range(len(s)):
            c = g[k] + side * rng.uniform(*params.parked_car_offset) * left[k]
            yaw = np.arctan2(f[k, 1], f[k, 0]) + rng.normal(0, 0.03)
            T_world_car = se3.from_rotation_translation(so3.exp(np.array([0, 0, yaw])), c)
            L, W, _ = CAR_SIZE
            corners = se3.transform_points(T_world_car, np.array([[sx * L / 2, sy * W / 2, 0.5]
                                                                  for sx in (-1, 1) for sy in (-1, 1)]))
            if scene.clear(corners):
                scene.patches.append(box(T_world_car, CAR_SIZE, scene.ids.next_object(), 2.0, opaque=True,
                                         max_size=2.5))
                scene.points.append(Points(corners, np.full(4, 0.7), scene.ids.landmarks(4)))
                scene.solids.append(footprints(T_world_car, CAR_SIZE)[0])


def _add_guard_rails(scene: _Scene) -> None:
    """Guard rails: two-sided metal strips 0.4-0.75 m above ground, posts every 4 m (no random draws)."""
    route, params = scene.route, scene.params
    step = 4
    for side in (-1.0, 1.0):
        g, _, left, _ = _frame(route, route.s[::step])
        base = g + side * params.guard_rail_offset * left
        oid = scene.ids.next_object()
        u = np.diff(base, axis=0)
        n = len(u)
        o = base[:-1] + np.array([0, 0, 0.4])
        scene.patches.append(Patches(o, u, np.tile([0, 0, 0.35], (n, 1)), np.full(n, oid), np.full(n, 2.0),
                                     np.zeros(n, bool), np.ones(n, bool)))
        posts = base + np.array([0, 0, 0.5])
        scene.points.append(Points(posts, np.full(len(posts), 0.5), scene.ids.landmarks(len(posts))))


def _add_roadside_clutter(scene: _Scene, rng: np.random.Generator) -> None:
    """Road-side clutter: weak scatterers (bushes, debris, small signs) 3-40 m off the route."""
    route, params = scene.route, scene.params
    n = rng.poisson(params.clutter_per_100m * (route.length + 60.0) / 100.0)
    if n:
        g, _, left, _ = _frame(route, rng.uniform(-20.0, route.length + 40.0, n))
        lateral = rng.choice([-1.0, 1.0], n) * rng.uniform(3.0, 40.0, n)
        p = g + lateral[:, None] * left + np.array([0, 0, 1.0]) * rng.uniform(0.0, 3.0, (n, 1))
        p = p[scene.far(p)]
        scene.points.append(Points(p, rng.uniform(0.2, 0.6, len(p)), scene.ids.landmarks(len(p))))


def _ground(route: Route, params: SceneParams, object_id: int, step: float = 5.0, width: float = 5.0) -> Patches:
    """Ground strips following the road's height: tiles `step` long (along the road) and `width` wide."""
    k = max(int(round(step / max(route.s[1] - route.s[0], 1e-9))), 1) if route.s.size > 1 else 1
    idx = np.arange(0, len(route.s), k)
    ground = route.p_world[idx] - np.array([0, 0, GROUND_BELOW])
    left = route.left()[idx]
    # extend the first and last strips so the ground reaches behind the start and past the end
    fwd = route.forward()[idx]
    ground = np.concatenate([ground[:1] - 30 * fwd[:1], ground, ground[-1:] + 60 * fwd[-1:]])
    left = np.concatenate([left[:1], left, left[-1:]])
    along = np.diff(ground, axis=0)
    m = int(np.ceil(2 * params.ground_half_width / width))
    lat = -params.ground_half_width + width * np.arange(m)
    o = (ground[:-1, None, :] + lat[None, :, None] * left[:-1, None, :]).reshape(-1, 3)
    u = np.repeat(along, m, axis=0)
    v = np.repeat(left[:-1] * width, m, axis=0)
    n = len(o)
    return Patches(o, u, v, np.full(n, object_id), np.full(n, params.ground_reflectivity), np.zeros(n, bool),
                   np.zeros(n, bool))


# ------------------------------------------------------------------------------------------- moving traffic

def _offset(x: float, y: float, yaw: float = 0.0) -> np.ndarray:
    """Carrier -> box transform: box bottom centre at (x, y) in the carrier frame, on the ground."""
    return se3.from_rotation_translation(so3.exp(np.array([0, 0, yaw])), np.array([x, y, -GROUND_BELOW]))


def lead_vehicle(ego: Profile, object_id: int, delta: float, t_on: float, t_off: float,
                 size=CAR_SIZE) -> MovingBox:
    """A vehicle on the ego's own path, `delta` seconds ahead (its rear axle where the ego will be at
    t + delta). Only safe when the ego keeps moving (the gap is the distance driven in delta seconds)."""
    t_off = min(t_off, ego.duration - delta)
    return MovingBox(object_id, tuple(size), ego, t_on + delta, 1.0, t_on, t_off,
                     _offset(size[0] / 2 - 1.0, 0.0))


def oncoming_vehicle(ego: Profile, object_id: int, t_meet: float, window: float = 12.0, lane: float = 3.5,
                     speed_ratio: float = 1.0, size=CAR_SIZE) -> MovingBox:
    """Oncoming traffic in the lane `lane` metres to the left, meeting the ego at t_meet: it drives the ego's
    path backwards, tau(t) = t_meet - speed_ratio (t - t_meet), turned by a half turn."""
    t_on = t_meet - window
    t_off = t_meet + window
    # keep tau inside the carrier's time span
    t_on = max(t_on, t_meet - (ego.duration - t_meet) / speed_ratio)
    t_off = min(t_off, t_meet + t_meet / speed_ratio)
    tau0 = t_meet - speed_ratio * (t_on - t_meet)
    return MovingBox(object_id, tuple(size), ego, tau0, -speed_ratio, t_on, t_off,
                     _offset(size[0] / 2 - 1.0, lane, np.pi))


def overtaking_vehicle(ego: Profile, object_id: int, t_pass: float, window: float = 15.0, lane: float = 3.5,
                       speed_ratio: float = 1.3, size=CAR_SIZE) -> MovingBox:
    """A faster vehicle in the lane to the left, level with the ego at t_pass (same path, time map rate > 1)."""
    t_on = max(t_pass - window, t_pass - t_pass / speed_ratio)
    t_off = min(t_pass + window, t_pass + (ego.duration - t_pass) / speed_ratio)
    tau0 = t_pass + speed_ratio * (t_on - t_pass)
    return MovingBox(object_id, tuple(size), ego, tau0, speed_ratio, t_on, t_off, _offset(size[0] / 2 - 1.0, lane))
