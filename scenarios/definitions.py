"""The scenario definitions (each registered explicitly at import; see docs/simulator.md for what they test).

`prior_ca` / `prior_cv` draw the motion from the estimator's own prior SDE (sim/sde_trajectory.py) with a `qc`
parameter: `scenarios.get("prior_ca").simulate(seed, qc=[...])`; `prior_ca_points` / `prior_cv_points` drive the
same motion through a world of persistent point scatterers only (`sim.world.landmark_world`), where the
estimator's point-to-point measurement model is exact too.

Mover ids start at MOVER_ID (well above any static object id) so truth ids never collide.
"""

from __future__ import annotations

import numpy as np

from rodo.sim import sde_trajectory as sde
from rodo.sim import trajectory as traj
from rodo.sim import world as w
from rodo.sim.radar import RadarConfig

from .registry import Scenario, register, seal

MOVER_ID = 1_000_000
CA_POLAR = {"model": "ca-polar"}
CV_POLAR = {"model": "cv-polar"}


def _route(profile):
    return traj.route_of(profile)


def _oncoming(rng, profile, duration, every: float, lane: float, first: float = 6.0, size=w.CAR_SIZE,
              start_id: int = 0):
    """Oncoming vehicles meeting the ego roughly every `every` seconds."""
    movers, t, k = [], first, start_id
    while t < duration:
        movers.append(w.oncoming_vehicle(profile, MOVER_ID + k, t, lane=lane,
                                         speed_ratio=rng.uniform(0.8, 1.2), size=size))
        k += 1
        t += rng.uniform(0.5, 1.5) * every
    return movers


def _city_world(rng, profile, duration):
    world = w.build_world(rng, _route(profile), w.CITY_TWO_LANES)
    movers = _oncoming(rng, profile, duration, 12.0, 3.5)
    n = len(movers)
    # passing in the lane to the right (a street with two lanes the ego's way): the lane to the left is the
    # oncoming traffic's, where an overtaking car met it head on (version 2)
    movers += [w.overtaking_vehicle(profile, MOVER_ID + n + i, t, lane=-3.5, speed_ratio=1.4)
               for i, t in enumerate(np.arange(20.0, duration, 45.0))]
    return world.with_traffic(movers)


def _highway_world(rng, profile, duration):
    world = w.build_world(rng, _route(profile), w.HIGHWAY)
    movers = [w.lead_vehicle(profile, MOVER_ID, 2.0, 0.0, duration, size=w.TRUCK_SIZE)]
    movers += [w.overtaking_vehicle(profile, MOVER_ID + 1 + i, t, lane=3.7, speed_ratio=rng.uniform(1.15, 1.3))
               for i, t in enumerate(np.arange(8.0, duration, 15.0))]
    return world.with_traffic(movers)


def _hills_world(rng, profile, duration):
    world = w.build_world(rng, _route(profile), w.RURAL)
    return world.with_traffic(_oncoming(rng, profile, duration, 20.0, 3.5))


def _stop_and_go_world(rng, profile, duration):
    world = w.build_world(rng, _route(profile), w.CITY_ONCOMING)
    return world.with_traffic(_oncoming(rng, profile, duration, 15.0, 3.5))


BLOCKAGE_DELTA = 3.3  # s: the truck's rear axle is where the ego's will be 3.3 s later
BLOCKAGE_SLOW = (13.0, 21.0)  # s: crawling at 1.6 m/s, the truck 0.8 m from the sensor, +-54 deg wide
BLOCKAGE_BLACKOUT = (5.0, 7.0)  # s: total blockage (empty scans)


def _blockage_profile(rng, duration):
    """Crawl at 2.5-3.5 m/s, slow to 1.6 m/s over 3 s for BLOCKAGE_SLOW, speed up, crawl on. The gap to the
    truck is the distance driven in BLOCKAGE_DELTA: sensor-to-truck 0.8 m at 1.6 m/s, 7 m at 3.5 m/s."""
    b = traj.ProfileBuilder(rng.uniform(2.5, 3.5))
    b.add(5.0, speed=rng.uniform(2.5, 3.5)).add(5.0, speed=rng.uniform(2.5, 3.5))
    b.add(BLOCKAGE_SLOW[0] - 10.0, speed=1.6).add(BLOCKAGE_SLOW[1] - BLOCKAGE_SLOW[0])
    b.add(3.0, speed=3.0)
    while b.duration < duration:
        b.add(rng.uniform(2.0, 5.0), speed=rng.uniform(2.5, 3.5))
        if rng.uniform() < 0.2:
            b.turn(rng.uniform(-0.3, 0.3), rng.uniform(30.0, 60.0))
    return b.build()


def _blockage_world(rng, profile, duration):
    world = w.build_world(rng, _route(profile), w.CITY_ONCOMING)
    truck = w.lead_vehicle(profile, MOVER_ID, BLOCKAGE_DELTA, 0.0, duration, size=(8.0, 2.6, 3.8))
    movers = [truck] + _oncoming(rng, profile, duration, 10.0, 3.5, size=w.TRUCK_SIZE, start_id=1)
    return world.with_traffic(movers).with_blackouts([BLOCKAGE_BLACKOUT])


def _yaw_world(rng, profile, duration):
    return w.build_world(rng, _route(profile), w.RURAL)


def _prior_profile(kind: str):
    """The profile builder of prior_<kind>: the motion drawn from the prior's SDE with diagonal Qc `qc`
    (default `sim.sde_trajectory.DEFAULT_QC[kind]`), on a grid aligned with the scan times."""
    def profile(rng, duration, qc=None):
        qc = sde.DEFAULT_QC[kind] if qc is None else qc
        return sde.draw(kind, qc, duration, rng, rate_hz=RadarConfig().rate_hz)

    profile.__name__ = f"prior_{kind}"
    return profile


def _prior_world(rng, profile, duration):
    return w.build_world(rng, _route(profile), w.CITY)


def _landmark_world(rng, profile, duration):
    return w.landmark_world(rng, _route(profile))


def _prior_truth(profile) -> dict:
    return profile.truth_arrays()


CITY = register(Scenario(
    "city", 3, "urban driving 0-50 km/h: buildings, parked cars, poles, turns, stops, oncoming and passing traffic",
    traj.city, _city_world, estimator_defaults=dict(CA_POLAR), length=950.0))
HIGHWAY = register(Scenario(
    "highway", 2, "80-130 km/h, gentle curves, lane changes, guard rails, a lead truck, overtaking cars",
    traj.highway, _highway_world, estimator_defaults=dict(CA_POLAR), length=1200.0))
HILLS = register(Scenario(
    "hills", 2, "rural road 40-70 km/h with 3-8 % grades (tens of metres of height change)",
    traj.hills, _hills_world, estimator_defaults=dict(CA_POLAR), length=950.0))
STOP_AND_GO = register(Scenario(
    "stop_and_go", 3, "stop-and-go city traffic down to standstill, 10-35 km/h",
    traj.stop_and_go, _stop_and_go_world, estimator_defaults=dict(CA_POLAR), length=950.0))
BLOCKAGE = register(Scenario(
    "blockage", 3, "crawling behind a truck; 8 s at 1.6 m/s with it 0.8 m ahead (+-54 deg), 2 s total blockage",
    _blockage_profile, _blockage_world, estimator_defaults=dict(CA_POLAR), duration=40.0))
YAW_ACCEL = register(Scenario(
    "yaw_accel", 2, "the paper's Fig. 1 manoeuvre: 10 m/s with constant yaw acceleration 0.05 rad/s^2",
    traj.yaw_accel, _yaw_world, estimator_defaults=dict(CA_POLAR), duration=10.0))
PRIOR_CA = register(Scenario(
    "prior_ca", 1, "motion drawn from the CA prior's SDE (white jerk, Qc = diag(qc)), city scene, no movers",
    _prior_profile("ca"), _prior_world, estimator_defaults=dict(CA_POLAR), duration=60.0, params=("qc",),
    extra_truth=_prior_truth))
PRIOR_CV = register(Scenario(
    "prior_cv", 1, "motion drawn from the CV prior's SDE (white acceleration, Qc = diag(qc)), city scene",
    _prior_profile("cv"), _prior_world, estimator_defaults=dict(CV_POLAR), duration=60.0, params=("qc",),
    extra_truth=_prior_truth))
PRIOR_CA_POINTS = register(Scenario(
    "prior_ca_points", 1, "prior_ca's motion in a world of persistent point scatterers only (an exact measurement "
    "model)", _prior_profile("ca"), _landmark_world, estimator_defaults=dict(CA_POLAR), duration=60.0,
    params=("qc",), extra_truth=_prior_truth))
PRIOR_CV_POINTS = register(Scenario(
    "prior_cv_points", 1, "prior_cv's motion in a world of persistent point scatterers only (an exact measurement "
    "model)", _prior_profile("cv"), _landmark_world, estimator_defaults=dict(CV_POLAR), duration=60.0,
    params=("qc",), extra_truth=_prior_truth))

seal()  # the definitions above are built in: versioned, never replaced (Registry.seal)
