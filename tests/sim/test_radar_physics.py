"""sim.radar_physics: the radar equation, detection from SNR, noise from SNR, ambiguities, validation."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from rodo.estimator.errors import InputError
from rodo.sim import radar_physics as rp
from rodo.sim.radar import DEG

_finite = dict(allow_nan=False, allow_infinity=False)


@given(r=st.floats(0.5, 500.0, **_finite), rcs=st.floats(-40.0, 40.0, **_finite), k=st.floats(1.1, 10.0, **_finite),
       d_rcs=st.floats(-20.0, 20.0, **_finite))
def test_snr_falls_as_r4_and_rises_with_rcs(r, rcs, k, d_rcs):
    """SNR(k R) / SNR(R) = k^-4 and SNR(sigma + d dB) = SNR(sigma) + d dB (Richards eq. 2.17)."""
    base = rp.snr_db(90.0, np.array([rcs]), np.array([r]))[0]
    farther = rp.snr_db(90.0, np.array([rcs]), np.array([k * r]))[0]
    assert farther - base == pytest.approx(-40.0 * np.log10(k), abs=1e-9)
    lin = 10 ** (np.array([base, farther]) / 10)
    assert lin[1] / lin[0] == pytest.approx(k ** -4, rel=1e-9)
    assert rp.snr_db(90.0, np.array([rcs + d_rcs]), np.array([r]))[0] - base == pytest.approx(d_rcs, abs=1e-9)


@given(a=st.floats(0.0, 1e6, **_finite), b=st.floats(0.0, 1e6, **_finite), pfa=st.floats(1e-9, 0.5, **_finite))
def test_detection_probability_is_monotone_in_snr(a, b, pfa):
    lo, hi = sorted((a, b))
    p = rp.detection_probability(np.array([0.0, lo, hi]), pfa)
    assert p[0] == pytest.approx(pfa, rel=1e-12)  # no signal: the false-alarm probability
    assert pfa * (1 - 1e-12) <= p[0] <= p[1] <= p[2] <= 1.0


def test_detection_by_threshold_has_the_swerling1_probability():
    """The simulated detection x = (1 + SNR) E > -ln(pfa) happens with Pd = exp(-T / (1 + SNR)) (Monte Carlo, 4
    binomial sigmas)."""
    rng = np.random.default_rng(1)
    physics = rp.RadarPhysics(snr_1m_db=0.0, pfa=1e-3)
    n = 40_000
    for snr in (1.0, 10.0, 100.0):
        x = (1.0 + snr) * rng.standard_exponential(n)
        pd = rp.detection_probability(np.array([snr]), physics.pfa)[0]
        assert abs(np.mean(x > physics.threshold) - pd) < 4 * np.sqrt(pd * (1 - pd) / n) + 1e-4


def test_angle_noise_matches_the_formula():
    """Sample std of the simulated noise at fixed power and azimuth vs sqrt(floor^2 + (bw / cos az)^2 /
    (1.6^2 2 x)); the std of a sample std is sigma / sqrt(2 n), the tolerance 4 of those. The noise grows off
    boresight."""
    physics = rp.RadarPhysics(snr_1m_db=0.0, beamwidth=(4 * DEG, 8 * DEG), range_resolution=0.3,
                              velocity_resolution=0.2)
    floors = (0.05, 0.2 * DEG, 0.4 * DEG, 0.02)
    n, rng = 20_000, np.random.default_rng(2)
    stds = []
    for x, az in ((20.0, 0.0), (20.0, 50 * DEG), (500.0, 30 * DEG)):
        true = np.tile(np.array([[30.0], [az], [0.05], [-3.0]]), (1, n))
        t = rp.Targets(true, np.full(n, x), np.zeros(n, int), np.full(n, -1), np.full(n, -1), np.zeros((n, 3)))
        err = t.noisy(physics, floors, rng).meas - true
        want = np.sqrt(floors[1] ** 2 + (physics.beamwidth[0] / np.cos(az)) ** 2 / (rp.ANGLE_K ** 2 * 2 * x))
        assert np.std(err[1]) == pytest.approx(want, rel=4 / np.sqrt(2 * n))
        want_r = np.sqrt(floors[0] ** 2 + physics.range_resolution ** 2 / (2 * x))
        assert np.std(err[0]) == pytest.approx(want_r, rel=4 / np.sqrt(2 * n))
        stds.append(np.std(err[1]))
    assert stds[1] > 1.3 * stds[0] and stds[2] < stds[0]  # off boresight worse; high SNR better


@given(v=st.floats(-1e4, 1e4, **_finite), limit=st.floats(0.1, 100.0, **_finite))
def test_wrap_maps_into_the_interval_and_is_identity_inside(v, limit):
    out = rp.wrap(np.array([v]), limit)[0]
    assert -limit - 1e-9 * max(1.0, abs(v)) <= out < limit + 1e-9 * max(1.0, abs(v))
    k = (v - out) / (2 * limit)
    assert k == pytest.approx(round(k), abs=1e-6)
    inside = float(np.clip(v, -limit * 0.999, limit * 0.999))
    assert rp.wrap(np.array([inside]), limit)[0] == pytest.approx(inside, abs=1e-12)
    assert rp.wrap(np.array([v]), None)[0] == v


def test_range_folds_and_quantisation_rounds():
    assert np.allclose(rp.fold_range(np.array([5.0, 25.0, 41.0]), 20.0), [5.0, 5.0, 1.0])
    assert np.allclose(rp.quantise(np.array([0.06, -0.19, 0.3]), 0.125), [0.0, -0.25, 0.25])
    assert np.array_equal(rp.quantise(np.array([0.06]), 0.0), np.array([0.06]))


def test_reported_rcs_inverts_the_radar_equation():
    """Without noise power (x = SNR) and pattern, the reported RCS is the target's RCS."""
    physics = rp.RadarPhysics(snr_1m_db=80.0)
    rcs, r = np.array([-10.0, 0.0, 12.0]), np.array([5.0, 40.0, 120.0])
    x = 10 ** (rp.snr_db(80.0, rcs, r) / 10)
    assert np.allclose(rp.reported_rcs(physics, x, r, np.zeros(3), np.zeros(3)), rcs)


def test_beam_pattern_is_minus_3db_at_half_width_off_boresight():
    physics = rp.RadarPhysics(snr_1m_db=80.0, pattern=(40 * DEG, 10 * DEG))
    g = rp.pattern_db(physics, np.array([0.0, 20 * DEG, 0.0]), np.array([0.0, 0.0, 5 * DEG]))
    assert np.allclose(g, [0.0, -6.0, -6.0])  # two-way: -3 dB each way
    tilted = rp.RadarPhysics(snr_1m_db=80.0, pattern=(40 * DEG, 10 * DEG), pattern_tilt=-3 * DEG)
    assert np.allclose(rp.pattern_db(tilted, np.zeros(2), np.array([-3 * DEG, 2 * DEG])), [0.0, -6.0])


@pytest.mark.parametrize("kwargs, named", [
    (dict(pfa=0.0), "pfa"), (dict(pfa=1.5), "pfa"), (dict(range_resolution=0.0), "range_resolution"),
    (dict(velocity_resolution=-1.0), "velocity_resolution"), (dict(ghost_prob=2.0), "ghost_prob"),
    (dict(doppler_max=0.0), "doppler_max"), (dict(beamwidth=(0.0, 0.1)), "beamwidth"),
    (dict(rcs_dbsm={"ground": (0.0, 1.0)}), "rcs_dbsm"), (dict(snr_1m_db=float("nan")), "snr_1m_db"),
    (dict(doppler_step=-0.1), "doppler_step"), (dict(pattern=(0.1,)), "pattern"),
    (dict(elevation_missing=-0.1), "elevation_missing"), (dict(snr_1m_db="80"), "snr_1m_db")])
def test_bad_parameters_are_input_errors_naming_the_field(kwargs, named):
    kwargs = {"snr_1m_db": 80.0, **kwargs}
    with pytest.raises(InputError) as err:
        rp.RadarPhysics(**kwargs)
    assert named in str(err.value)


def test_radar_config_refuses_a_physics_of_the_wrong_type():
    from rodo.sim.radar import RadarConfig

    with pytest.raises(InputError, match="physics"):
        RadarConfig(physics={"snr_1m_db": 80.0})


def test_nearest_per_bin_keeps_the_nearest_of_each_cell_and_range_bin():
    """Brute force: group by (cell, floor(r / range_cell)), take the smallest r (ties: the first index)."""
    from rodo.sim.occlusion import nearest_per_bin

    rng = np.random.default_rng(4)
    cell = rng.integers(0, 30, 2000)
    r = np.round(rng.uniform(0.5, 40.0, 2000), 1)
    got = nearest_per_bin(cell, r, 2.0, 40.0)
    want = {}
    for i, (c, x) in enumerate(zip(cell, r)):
        k = (c, int(x // 2.0))
        if k not in want or x < r[want[k]]:
            want[k] = i
    assert sorted(got.tolist()) == sorted(want.values())


def test_range_cells_give_several_detections_per_angular_cell():
    """With range_cell the corner radar reports more detections than angular cells hold, at most one per
    (cell, range bin); without, at most one per angular cell."""
    from dataclasses import replace

    from rodo import scenarios
    from rodo.sim import profiles

    cfg = profiles.radar_config("corner2d")
    per_cell = replace(cfg, physics=replace(cfg.physics, range_cell=None), clutter_rate=0.0, surface_fill=5.0)
    per_bin = replace(cfg, physics=replace(cfg.physics, range_cell=1.0), clutter_rate=0.0, surface_fill=5.0)
    n = [np.mean([len(s) for s in scenarios.get("city").simulate(1, 1.0, radar=c)[0].scans]) for c in (per_cell,
                                                                                                        per_bin)]
    assert n[1] > 1.2 * n[0]
    assert n[0] <= per_cell.grid_shape[0] * per_cell.grid_shape[1]
