"""The radar model: exact geometry (noise-free), radial velocity (sign, finite differences, moving targets),
noise statistics, field of view and range gates, occlusion."""

from dataclasses import replace

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy import stats

from rodo.estimator.lie import se3, so3
from rodo.sim import objects as ob
from rodo.sim import trajectory as tr
from rodo.sim.radar import DEG, Radar, RadarConfig
from rodo.sim.sequence import polar_to_cartesian
from rodo.sim.world import World
from tests.strategies import vehicle_motion

IDEAL = RadarConfig().noise_free()
IDEAL_AT_ORIGIN = replace(IDEAL, T_vehicle_sensor=np.eye(4))


def _world(points=None, patches=None, movers=()):
    pts = ob.Points.concat([] if points is None else [ob.Points(np.atleast_2d(points), np.ones(len(np.atleast_2d(
        points))), np.arange(len(np.atleast_2d(points))))])
    return World(ob.Patches.concat([] if patches is None else [patches]), pts, tuple(movers))


def _scene() -> World:
    """A facade box ahead-left, a parked car ahead-right, ground, and scattered points."""
    rng = np.random.default_rng(0)
    yaw = so3.exp(np.array([0, 0, 0.1]))
    patches = ob.Patches.concat([
        ob.box(se3.from_rotation_translation(yaw, np.array([40.0, 15.0, -1.0])), (30, 10, 15), 0),
        ob.box(se3.from_rotation_translation(np.eye(3), np.array([15.0, -4.0, -0.35])), (4.5, 1.8, 1.5), 1, 2.0),
        ob.rectangle([-10, -20, -0.35], [100, 0, 0], [0, 40, 0], 2, 0.15, opaque=False, max_size=5.0),
    ])
    pts = ob.Points(rng.uniform([5, -30, -0.3], [80, 30, 5], (200, 3)), np.full(200, 0.8), np.arange(200))
    return World(patches, pts)


def _pose(x, y, yaw):
    return se3.from_rotation_translation(so3.exp(np.array([0, 0, yaw])), np.array([x, y, 0.0]))


@settings(max_examples=20)
@given(vehicle_motion(), st.floats(-3, 3), st.floats(-3, 3), st.floats(-0.3, 0.3))
def test_noise_free_scan_reproduces_geometry_and_static_radial_velocity(motion, x, y, yaw):
    varpi, _ = motion
    T_world_vehicle = _pose(x, y, yaw)
    radar = Radar(IDEAL)
    det = radar.scan(_scene(), T_world_vehicle, varpi, np.random.default_rng(1))
    assert len(det) > 100
    assert np.all(det.label < 2)
    # polar coordinates map back to the true scatterer given the true pose
    T_world_sensor = T_world_vehicle @ IDEAL.T_vehicle_sensor
    p_back = se3.transform_points(T_world_sensor, polar_to_cartesian(det.range, det.azimuth, det.elevation))
    np.testing.assert_allclose(p_back, det.p_world, atol=1e-9)
    # static radial velocity from docs/conventions.md: dp_vehicle/dt = nu + omega x p_vehicle,
    # dp_sensor/dt = C_vehicle_sensor^T dp_vehicle/dt
    p_vehicle = se3.transform_points(se3.inverse(T_world_vehicle), det.p_world)
    C_vehicle_sensor = IDEAL.T_vehicle_sensor[:3, :3]
    dps = (varpi[:3] + np.cross(varpi[3:], p_vehicle)) @ C_vehicle_sensor
    u = polar_to_cartesian(1.0, det.azimuth, det.elevation)
    np.testing.assert_allclose(det.radial_velocity, np.einsum("ij,ij->i", u, dps), atol=1e-9)


def test_radial_velocity_is_the_time_derivative_of_range():
    """Finite differences of |p_s(t)| along an integrated CA trajectory equal the reported v_r."""
    profile = tr.Profile([tr.Segment(2.0, accel=1.0, pitch_acc=0.05, yaw_acc=0.3)], speed0=12.0)
    t, h = 1.0, 1e-4
    m = profile.sample(np.array([t - h, t, t + h]))
    world = _scene()
    det = Radar(IDEAL).scan(world, m.T_world_vehicle[1], m.varpi[1], np.random.default_rng(2))
    ranges = [np.linalg.norm(se3.transform_points(se3.inverse(T @ IDEAL.T_vehicle_sensor), det.p_world), axis=1)
              for T in m.T_world_vehicle[[0, 2]]]
    np.testing.assert_allclose(det.radial_velocity, (ranges[1] - ranges[0]) / (2 * h), atol=1e-6)


def test_radial_velocity_sign_driving_at_a_point_dead_ahead():
    det = Radar(IDEAL_AT_ORIGIN).scan(_world(points=[20.0, 0, 0]), np.eye(4), np.array([-10.0, 0, 0, 0, 0, 0]),
                                      np.random.default_rng(0))
    assert len(det) == 1
    assert det.radial_velocity[0] == pytest.approx(-10.0, abs=1e-12)
    assert det.range[0] == pytest.approx(20.0) and det.azimuth[0] == 0.0 and det.elevation[0] == 0.0


def test_moving_target_reports_its_own_radial_velocity():
    """A car driving towards a standing radar at 5 m/s along -x: v_r = -5 u_x on its body; with the radar
    driving at 10 m/s towards it, v_r = -15 u_x."""
    T_world_carrier = _pose(16.0, 0.0, np.pi)  # carrier facing -x
    carrier = tr.Profile([tr.Segment(5.0)], 5.0, se3.inverse(T_world_carrier))
    car = ob.MovingBox(7, (4.5, 1.8, 1.5), carrier, 0.0, 1.0, 0.0, 5.0,
                       se3.from_rotation_translation(np.eye(3), np.array([1.0, 0.0, -0.5])))
    state = car.states(np.array([1.0]))
    assert state.present[0]
    np.testing.assert_allclose(state.v_world[0], [-5.0, 0, 0], atol=1e-12)
    radar = Radar(IDEAL_AT_ORIGIN)
    world = _world(movers=(car,))
    movers = [(car, state.T_world_object[0], state.v_world[0], state.w_world[0])]
    for speed in (0.0, 10.0):
        det = radar.scan(world, np.eye(4), np.array([-speed, 0, 0, 0, 0, 0]), np.random.default_rng(0), movers)
        assert len(det) > 20 and np.all(det.label == ob.MOVING) and np.all(det.object_id == 7)
        u = polar_to_cartesian(1.0, det.azimuth, det.elevation)
        np.testing.assert_allclose(det.radial_velocity, -(5.0 + speed) * u[:, 0], atol=1e-9)


def test_noise_matches_configured_sigmas():
    cfg = replace(RadarConfig(), clutter_rate=0.0)
    radar = Radar(cfg)
    rng = np.random.default_rng(4)
    world = _scene()
    res = []
    for k in range(20):
        det = radar.scan(world, _pose(0.1 * k, 0, 0), np.array([-8.0, 0, 0, 0, 0, 0.1]), rng)
        res.append(np.stack([det.range, det.azimuth, det.elevation, det.radial_velocity], 1) - det.true_polar)
    res = np.concatenate(res)
    assert len(res) > 3000
    z = res / np.asarray(cfg.sigmas)
    for j in range(4):
        chi2 = float(np.sum(z[:, j] ** 2))
        p = stats.chi2.sf(chi2, len(z))
        assert 1e-3 < p < 1 - 1e-3, (j, chi2 / len(z))
        assert abs(z[:, j].mean()) < 4 / np.sqrt(len(z))
    assert abs(np.corrcoef(z.T)[0, 1]) < 0.1


def test_field_of_view_and_range_gates():
    cfg = replace(IDEAL_AT_ORIGIN, min_range=1.0, max_range=50.0)
    az = np.deg2rad([0, 59, 61, -59, -61, 0, 0, 0, 0, 10])
    el = np.deg2rad([0, 0, 0, 0, 0, 14, 16, -14, -16, 5])
    r = np.array([10, 10, 10, 10, 10, 10, 10, 10, 10, 10.0])
    r_extra = np.array([0.9, 1.1, 49.9, 50.1])
    az_extra = np.array([0.2, 0.3, 0.4, 0.5])
    pts = np.concatenate([polar_to_cartesian(r, az, el), polar_to_cartesian(r_extra, az_extra, 0.0)])
    det = Radar(cfg).scan(_world(points=pts), np.eye(4), np.zeros(6), np.random.default_rng(0))
    seen = set(det.landmark_id.tolist())
    assert seen == {0, 1, 3, 5, 7, 9, 11, 12}
    # and on a full scene every detection respects the gates
    det = Radar(IDEAL).scan(_scene(), np.eye(4), np.zeros(6), np.random.default_rng(0))
    assert np.all((det.range >= IDEAL.min_range) & (det.range <= IDEAL.max_range))
    assert np.all(np.abs(det.azimuth) <= 60 * DEG) and np.all(np.abs(det.elevation) <= 15 * DEG)


def test_occlusion_by_surfaces_and_nearest_per_cell():
    wall = ob.rectangle([10.0, 3.0, -2.0], [0, -6.0, 0], [0, 0, 4.0], 0, opaque=True)  # normal -x: faces us
    pts = np.array([[20.0, 0.0, 0.0],    # behind the wall: hidden
                    [5.0, 0.5, 0.3],     # in front: seen
                    [20.0, 10.0, 0.0],   # beside the wall: seen
                    [30.0, 15.0, 0.0],   # same angular cell as the previous one, farther: hidden
                    [20.0, 2.5, 1.5]])   # behind the wall's corner region: hidden
    cfg = replace(IDEAL_AT_ORIGIN, surface_fill=0.0)  # the wall returns nothing but still blocks
    det = Radar(cfg).scan(_world(points=pts, patches=wall), np.eye(4), np.zeros(6), np.random.default_rng(0))
    assert set(det.landmark_id.tolist()) == {1, 2}
    # with returns from the wall: no detection lies behind it, all wall hits are on its plane
    det = Radar(IDEAL_AT_ORIGIN).scan(_world(points=pts, patches=wall), np.eye(4), np.zeros(6),
                                      np.random.default_rng(0))
    on_wall = det.label == ob.STATIC_SURFACE
    assert on_wall.sum() > 50
    np.testing.assert_allclose(det.p_world[on_wall, 0], 10.0, atol=1e-9)
    cells = np.stack([np.floor(det.azimuth / cfg.cell_azimuth), np.floor(det.elevation / cfg.cell_elevation)], 1)
    assert len(np.unique(cells, axis=0)) == len(det)  # one detection per resolution cell


def test_surfaces_resampled_points_persist():
    radar = Radar(IDEAL)
    world = _scene()
    a = radar.scan(world, np.eye(4), np.zeros(6), np.random.default_rng(1))
    b = radar.scan(world, np.eye(4), np.zeros(6), np.random.default_rng(2))
    surf_a = a.p_world[a.label == ob.STATIC_SURFACE]
    surf_b = b.p_world[b.label == ob.STATIC_SURFACE]
    d = np.linalg.norm(surf_a[:, None] - surf_b[None], axis=-1).min(axis=1)
    assert np.median(d) > 1e-3  # different places on the surfaces
    pa = set(a.landmark_id[a.label == ob.STATIC_POINT].tolist())
    pb = set(b.landmark_id[b.label == ob.STATIC_POINT].tolist())
    assert len(pa & pb) > 0.8 * len(pa)  # the same scatterers, at fixed positions (ideal detection)


def test_density_falls_with_range_and_clutter_is_labelled():
    wall_near = ob.rectangle([10.0, 3.0, -2.0], [0, -6.0, 0], [0, 0, 4.0], 0)
    wall_far = ob.rectangle([40.0, 3.0, -2.0], [0, -6.0, 0], [0, 0, 4.0], 1)
    cfg = replace(RadarConfig(), T_vehicle_sensor=np.eye(4), clutter_rate=50.0)
    radar = Radar(cfg)
    near = far = clutter = 0
    rng = np.random.default_rng(3)
    for _ in range(20):
        det = radar.scan(_world(patches=ob.Patches.concat([wall_near, wall_far.transformed(_pose(0, 20, 0))])),
                         np.eye(4), np.zeros(6), rng)
        near += np.sum(det.object_id == 0)
        far += np.sum(det.object_id == 1)
        clutter += np.sum(det.label == ob.CLUTTER)
        assert np.all(np.isnan(det.p_world[det.label == ob.CLUTTER]))
    assert near > 5 * far > 0
    assert abs(clutter / 20 - 50) < 4 * np.sqrt(50 / 20)


def test_boxes_are_seen_from_outside_only():
    """A box ahead at sensor height: only its rear face (x = 18) faces the sensor; sides and top do not."""
    car = ob.box(_pose(20.0, 0.0, 0.0) @ se3.from_rotation_translation(np.eye(3), np.array([0, 0, -0.35])),
                 (4.0, 2.0, 1.5), 0)
    det = Radar(IDEAL_AT_ORIGIN).scan(_world(patches=car), np.eye(4), np.zeros(6), np.random.default_rng(0))
    assert len(det) > 5
    np.testing.assert_allclose(det.p_world[:, 0], 18.0, atol=1e-9)


def test_occlusion_agrees_with_brute_force_ray_casting():
    """In a generated city, almost no detection has an opaque surface of another object on its line of
    sight (brute force over all patches). The depth buffer tests cell-centre rays, so a target may peek
    past an edge within one cell: allow 1 %."""
    from rodo.sim import world as w

    profile = tr.city(np.random.default_rng(0), 30.0)
    world = w.build_world(np.random.default_rng(1), tr.route_of(profile), w.CITY)
    radar = Radar(IDEAL)
    m = profile.sample(np.array([5.0, 12.0, 20.0]))
    opq = world.patches.subset(world.patches.opaque)
    n = np.cross(opq.u, opq.v)
    total = leaks = 0
    for k in range(3):
        det = radar.scan(world, m.T_world_vehicle[k], m.varpi[k], np.random.default_rng(k))
        o = (m.T_world_vehicle[k] @ IDEAL.T_vehicle_sensor)[:3, 3]
        d = det.p_world - o
        r = np.linalg.norm(d, axis=1)
        d /= r[:, None]
        with np.errstate(divide="ignore", invalid="ignore"):
            s = np.einsum("pj,pj->p", n, opq.origin - o)[None] / (d @ n.T)
            q = s[..., None] * d[:, None] - (opq.origin - o)[None]
            a = np.einsum("npj,pj->np", q, opq.u) / np.einsum("pj,pj->p", opq.u, opq.u)
            b = np.einsum("npj,pj->np", q, opq.v) / np.einsum("pj,pj->p", opq.v, opq.v)
        blocked = ((s > 0) & (s < r[:, None] - IDEAL.occlusion_tolerance) & (a >= 0) & (a <= 1) & (b >= 0)
                   & (b <= 1) & (opq.object_id[None] != det.object_id[:, None]))
        total += len(det)
        leaks += blocked.any(axis=1).sum()
    assert total > 1500
    assert leaks < 0.01 * total
