"""The Python API's bad input, as a researcher meets it (a review of session 54): every case below was a hang, a
deep traceback or a silently wrong result, and is now an InputError naming the argument."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from rodo import scenarios
from rodo.estimator.config import OdometryConfig
from rodo.estimator.errors import InputError
from rodo.estimator.odometry import RadarOdometry
from rodo.scenarios import Scenario
from rodo.sim import trajectory as traj
from rodo.sim import world as w
from rodo.sim.sequence import Sequence
from rodo.validation.driver import run_sequence
from rodo.validation.metrics import evaluate


@pytest.fixture(scope="module")
def city():
    """(sequence, truth, run) of 2 s of city seed 1 at the default CA/P."""
    seq, truth = scenarios.get("city").simulate(1, duration=2.0)
    return seq, truth, run_sequence(seq, OdometryConfig.for_model("ca-polar"))


def _fixed_100_m(rng, duration):
    return traj.ProfileBuilder(5.0).add(20.0).build()  # 100 m, whatever duration is asked


def _world(rng, profile, duration):
    return w.build_world(rng, traj.route_of(profile), w.CITY)


def test_a_length_the_trajectory_never_reaches_is_an_error_not_a_hang():
    s = Scenario("fixed_100_m", 1, "a profile of fixed length", _fixed_100_m, _world, length=950.0)
    with pytest.raises(InputError, match="'fixed_100_m': its trajectory covers 100 m of its 950 m length"):
        s.default_duration(1)


@pytest.mark.parametrize("kw, needle", [({}, "give one of length"), ({"length": 5.0, "duration": 2.0}, "give one of"),
                                        ({"length": -1.0}, "length must be a positive number"),
                                        ({"duration": "2"}, "duration must be a positive number")])
def test_a_scenario_needs_one_length_or_duration(kw, needle):
    with pytest.raises(InputError, match=needle):
        Scenario("bad", 1, "x", _fixed_100_m, _world, **kw)


@pytest.mark.parametrize("call, needle", [(lambda s: s.simulate(1, duration="2"), "duration: must be a positive"),
                                          (lambda s: s.simulate(1, duration=1.0, faults="clutter=5"),
                                           "faults: expected a sim.faults.Faults")])
def test_simulate_arguments_of_the_wrong_type(call, needle):
    with pytest.raises(InputError, match=needle):
        call(scenarios.get("city"))


def test_scan_times_must_be_finite_numbers(city):
    seq = city[0]
    scan = seq.scans[0]
    polar = np.c_[scan.range, scan.azimuth, scan.elevation, scan.radial_velocity]
    sensor = (seq.sensor.T_vehicle_sensor, seq.sensor.noise.as_array())
    for t, needle in ((float("nan"), "t: must be finite"), (float("inf"), "t: must be finite"),
                      (None, "t: expected a time in seconds")):
        odo = RadarOdometry(OdometryConfig.for_model("ca-polar"), *sensor)
        with pytest.raises(InputError, match=needle):
            odo.process(t, polar)
    with pytest.raises(InputError, match=r"polar: expected shape \(N, 4\), got \(5, 4, 4\)"):
        odo.process(0.0, np.stack([polar[:4]] * 5))
    with pytest.raises(InputError, match="config: expected an OdometryConfig"):
        RadarOdometry("ca-polar", *sensor)


def test_an_in_memory_sequence_with_a_repeated_scan_time_is_refused(city):
    """With ground truth the repeated scan was dropped without a word (one estimate per time)."""
    seq = city[0]
    scans = list(seq.scans)
    scans.insert(4, dataclasses.replace(scans[5], t=scans[4].t))
    with pytest.raises(InputError, match=r"scan times must be finite and increase strictly \(scan 5: t = "):
        run_sequence(Sequence(seq.sensor, scans, seq.groundtruth), OdometryConfig.for_model("ca-polar"))
    with pytest.raises(InputError, match="seq: expected a sim.sequence.Sequence"):
        run_sequence((seq, city[1]), OdometryConfig.for_model("ca-polar"))


def test_evaluate_checks_its_arguments_as_rodo_evaluate_checks_files(city):
    seq, truth, run = city
    gt, est, states = seq.groundtruth, run.trajectory(), run.state_arrays()
    assert np.isfinite(evaluate(gt, est, states=states, truth=truth)["nees"]["mean"])  # the right ones pass
    _, other = scenarios.get("city").simulate(2, duration=2.0)
    with pytest.raises(InputError, match="truth and gt: the truth's poses are not the ground truth's"):
        evaluate(gt, est, states=states, truth=other)  # gave a NEES of 6e5 without a word
    with pytest.raises(InputError, match="truth: missing array"):
        evaluate(gt, est, states=states, truth={"t": truth["t"], "T_vehicle_world": truth["T_vehicle_world"]})
    for lengths in ([-5.0], [], "100 m"):
        with pytest.raises(InputError, match="lengths: need positive finite"):
            evaluate(gt, est, lengths=lengths)
    with pytest.raises(InputError, match="est: expected a trajectory with t and T_world_vehicle"):
        evaluate(gt, run)
    moved = dict(states, T_vehicle_world=states["T_vehicle_world"].copy())  # another run's poses
    moved["T_vehicle_world"][3:, 0, 3] += 0.5
    with pytest.raises(InputError, match="states and est: the states' poses are not the estimate's"):
        evaluate(gt, est, states=moved, truth=truth)


def test_bad_values_in_an_in_memory_scan_name_the_scan(city):
    seq = city[0]
    scans = list(seq.scans)
    r = scans[5].range.copy()
    r[3] = np.nan
    scans[5] = dataclasses.replace(scans[5], range=r)
    with pytest.raises(InputError, match=rf"^scan 5 \(t = {scans[5].t} s\): polar: contains NaN or infinity$"):
        run_sequence(Sequence(seq.sensor, scans, seq.groundtruth), OdometryConfig.for_model("ca-polar"))


def test_an_in_memory_scan_in_degrees_is_refused_naming_the_scan(city):
    """The file readers refuse angles in degrees; an in-memory Sequence gave a silently wrong estimate (ATE 2.5 m
    against 5 mm) before the estimator checked them too (session 55)."""
    seq = city[0]
    scans = list(seq.scans)
    scans[2] = dataclasses.replace(scans[2], azimuth=np.rad2deg(scans[2].azimuth))
    with pytest.raises(InputError, match=rf"^scan 2 \(t = {scans[2].t} s\): polar\[\d+, 1\] \(azimuth\): value .*"
                                         "looks like degrees"):
        run_sequence(Sequence(seq.sensor, scans, seq.groundtruth), OdometryConfig.for_model("ca-polar"))
