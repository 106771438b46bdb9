"""sim.multipath: mirror ghosts across a flat reflector: position, Doppler, validity, and a profile's ghosts in a
simulation (flagged in the truth only, drawn from their own generator)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from rodo.sim import multipath as mp
from rodo.sim.objects import GHOST, Patches, rectangle

_finite = dict(allow_nan=False, allow_infinity=False)


def _wall(y: float = 6.0):
    """A 60 m x 10 m vertical wall at y = `y` (sensor frame), facing the sensor (normal -y for y > 0)."""
    return rectangle([-20.0, y, -2.0], [60.0, 0.0, 0.0], [0.0, 0.0, 10.0], 7, max_size=1e3)


@given(x=st.floats(5.0, 30.0, **_finite), y=st.floats(-4.0, 4.0, **_finite), z=st.floats(-1.0, 1.0, **_finite),
       v=st.tuples(*[st.floats(-10.0, 10.0, **_finite)] * 3), vs=st.tuples(*[st.floats(-15.0, 15.0, **_finite)] * 3))
def test_ghost_is_the_mirror_image_with_the_mirrored_doppler(x, y, z, v, vs):
    """p' = p reflected across the wall plane (y = 6: (x, 12 - y, z)); v_r' = d|p'|/dt for the target moving with
    v and the sensor with vs, by a central finite difference of the mirrored geometry."""
    wall = _wall(6.0)
    p, v, vs = np.array([[x, y, z]]), np.array([v]), np.array(vs)
    p_g, vr, valid = mp.mirror(p, v, vs, wall, np.array([0]))
    assert np.allclose(p_g[0], [x, 12.0 - y, z], atol=1e-9)
    h = 1e-6
    image = lambda t: np.array([x + v[0, 0] * t, 12.0 - (y + v[0, 1] * t), z + v[0, 2] * t]) - vs * t  # noqa: E731
    fd = (np.linalg.norm(image(h)) - np.linalg.norm(image(-h))) / (2 * h)
    assert vr[0] == pytest.approx(fd, abs=1e-5)
    assert valid[0]  # the bounce point lies on the 60 m wall


def test_no_ghost_behind_the_plane_or_past_the_reflector():
    wall = _wall(6.0)
    p = np.array([[10.0, 8.0, 0.0],     # behind the wall (other side from the sensor)
                  [80.0, 2.0, 0.0],     # bounce point (x = 48) beyond the wall's end (x = 40)
                  [10.0, 2.0, 0.0]])    # a real ghost
    _, _, valid = mp.mirror(p, np.zeros((3, 3)), np.zeros(3), wall, np.zeros(3, int))
    assert valid.tolist() == [False, False, True]


def test_valid_pairs_agree_with_mirror():
    """The matrix form of the validity test gives `mirror`'s answer for every (target, reflector) pair."""
    rng = np.random.default_rng(5)
    refl = Patches.concat([_wall(6.0), _wall(-6.0), rectangle([15.0, -5, -1], [0, 10.0, 0], [0, 0, 4.0], 9)])
    p = np.column_stack([rng.uniform(-10, 40, 300), rng.uniform(-10, 10, 300), rng.uniform(-2, 3, 300)])
    valid = mp.valid_pairs(p, refl)
    i, j = np.divmod(np.arange(valid.size), len(refl))
    assert np.array_equal(valid.ravel(), mp.mirror(p[i], np.zeros((len(i), 3)), np.zeros(3), refl, j)[2])
    assert 0 < valid.mean() < 1


def test_ghost_candidates_pick_a_valid_reflector_and_respect_the_probability():
    rng = np.random.default_rng(3)
    walls = _wall(6.0)
    p = np.column_stack([rng.uniform(5, 30, 2000), rng.uniform(-4, 4, 2000), np.zeros(2000)])
    src, p_g, vr = mp.ghost_candidates(p, np.zeros_like(p), np.array([10.0, 0, 0]), walls, 0.25, rng)
    assert abs(len(src) / 2000 - 0.25) < 4 * np.sqrt(0.25 * 0.75 / 2000)
    assert np.allclose(p_g[:, 1], 12.0 - p[src, 1])
    assert mp.ghost_candidates(p, p, np.zeros(3), walls, 0.0, rng)[0].size == 0


def test_profile_ghosts_are_flagged_in_the_truth_and_change_no_other_draw():
    """With the lrr30f profile the truth labels ghosts (label 4) while radar.csv has no truth column; with
    ghosts off (ghost_prob 0) every other detection is the same (the ghosts draw from their own generator)."""
    from rodo import scenarios
    from rodo.sim import profiles

    cfg = profiles.radar_config("lrr30f")
    off = replace(cfg, physics=replace(cfg.physics, ghost_prob=0.0))
    sc = scenarios.get("city")
    seq_on, truth_on = sc.simulate(3, 1.5, radar=cfg)
    seq_off, truth_off = sc.simulate(3, 1.5, radar=off)
    ghost = truth_on["det_label"] == GHOST
    assert ghost.sum() > 0 and not np.any(truth_off["det_label"] == GHOST)
    assert list(seq_on.scans[0].extra) == ["rcs", "snr"]

    def rows(seq, keep):
        cols = np.concatenate([np.column_stack([s.range, s.azimuth, s.elevation, s.radial_velocity, s.extra["rcs"]])
                               for s in seq.scans])[keep]
        return cols[np.lexsort(cols.T)]

    assert np.array_equal(rows(seq_on, ~ghost), rows(seq_off, np.ones(len(ghost) - ghost.sum(), bool)))
