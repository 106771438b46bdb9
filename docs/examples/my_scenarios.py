"""A scenario and a sensor profile of your own, registered when this module is imported (docs/simulator.md,
"Custom scenarios and sensor profiles"). From the repository's root:

    PYTHONPATH=docs/examples rodo --plugin my_scenarios scenarios
    PYTHONPATH=docs/examples rodo --plugin my_scenarios simulate campus --seed 1 --duration 10 --out runs/campus

Checked by: tests/cli/test_plugins.py
"""

import numpy as np

from rodo import scenarios
from rodo.sim import CITY, ProfileBuilder, RadarConfig, build_world, mount, oncoming_vehicle, profiles, route_of

DEG = np.pi / 180.0


def campus_drive(rng, duration):
    """The ego's trajectory: 10-20 km/h with gentle turns, drawn from `rng` until `duration` s are covered
    (a longer duration extends the same draw)."""
    b = ProfileBuilder(speed0=3.0)
    while b.duration < duration:
        b.add(rng.uniform(3.0, 6.0), speed=rng.uniform(3.0, 5.5))
        b.turn(rng.uniform(-0.6, 0.6), radius=rng.uniform(20.0, 40.0))
    return b.build()


def campus_world(rng, profile, duration):
    """The city scene along the route (buildings, poles, trees, parked cars) and an oncoming car every 20 s."""
    world = build_world(rng, route_of(profile), CITY)
    cars = [oncoming_vehicle(profile, scenarios.MOVER_ID + i, t)
            for i, t in enumerate(np.arange(10.0, duration, 20.0))]
    return world.with_traffic(cars)


def short_range_radar():
    """A short-range radar: 20 Hz, +-75 deg by +-15 deg, 60 m, on the front bumper."""
    return RadarConfig(rate_hz=20.0, T_vehicle_sensor=mount(3.6, 0.0, 0.5), sigmas=(0.05, 0.5 * DEG, 1.0 * DEG, 0.02),
                       azimuth_fov=(-75 * DEG, 75 * DEG), max_range=60.0, cell_azimuth=1.0 * DEG)


SHORT_RANGE = profiles.register(profiles.SensorProfile(
    "short_range", 1, "a short-range radar: 20 Hz, +-75 deg, 60 m", "assumed (an example)", short_range_radar))

CAMPUS = scenarios.register(scenarios.Scenario(
    "campus", 1, "a slow drive through a campus, 10-20 km/h, gentle turns, an oncoming car every 20 s",
    campus_drive, campus_world, estimator_defaults={"model": "ca-polar"}, duration=60.0,
    sensor_profile="short_range"))
