"""sim.faults: parsing and validation of the fault options, ghosts, jitter and the per-scan application."""

from __future__ import annotations

import numpy as np
import pytest

from rodo.estimator.errors import InputError
from rodo.sim import faults as fl
from rodo.sim.objects import CLUTTER, STATIC_POINT
from rodo.sim.radar import Detections, RadarConfig


def _dets(n: int, rng) -> Detections:
    r = rng.uniform(5, 100, n)
    label = np.where(np.arange(n) % 4 == 0, CLUTTER, STATIC_POINT)
    true = np.stack([r, rng.uniform(-1, 1, n), rng.uniform(-0.2, 0.2, n), rng.uniform(-5, 5, n)], axis=-1)
    return Detections(true[:, 0] + 0.01, true[:, 1], true[:, 2], true[:, 3], label, np.full(n, -1),
                      np.arange(n), rng.normal(size=(n, 3)), true)


def test_parse_faults_reads_every_name_and_accumulates_outages():
    f = fl.parse_faults(["clutter=2.5", "ghosts=3", "dropped=0.05", "jitter=0.002", "outage=5:2",
                         "outage=10.5:0.5", "clutter=4"])
    assert f == fl.Faults(clutter=4.0, ghosts=3.0, dropped=0.05, jitter=0.002, outage=((5.0, 2.0), (10.5, 0.5)))
    assert f.active and not fl.parse_faults([]).active


@pytest.mark.parametrize("text, named", [
    ("clutter=nan", "clutter"), ("clutter=-1", "clutter"), ("clutter=1e9", "clutter"), ("ghosts=inf", "ghosts"),
    ("ghosts=x", "ghosts"), ("dropped=1", "dropped"), ("dropped=-0.1", "dropped"), ("jitter=-1e-3", "jitter"),
    ("jitter=nan", "jitter"), ("outage=5", "outage"), ("outage=5:0", "outage"), ("outage=-1:2", "outage"),
    ("outage=a:b", "outage"), ("outage=1:inf", "outage"), ("nosuch=1", "--fault"), ("clutter", "--fault"),
    ("outages=2", "outages"), ("outages=-1:1", "outages"), ("outages=2:0", "outages"), ("outages=nan:1", "outages"),
    ("outages=1e6:1", "outages"), ("outages=a:b", "outages"), ("outages=2:inf", "outages")])
def test_bad_values_are_input_errors_naming_the_fault(text, named):
    with pytest.raises(InputError) as err:
        fl.parse_faults([text])
    assert named in str(err.value) and "--fault" in str(err.value)


def test_python_outages_are_checked_and_normalised():
    assert fl.Faults(outage=[[1.0, 2.0]]).outage == ((1.0, 2.0),)
    for bad in ((5.0, 2.0), [(1.0, 2.0, 3.0)], 7, [(1.0, float("nan"))]):
        with pytest.raises(InputError, match="--fault outage"):
            fl.Faults(outage=bad)


def test_jitter_is_bounded_by_the_scan_period():
    fl.Faults(jitter=0.15 / 13.0 * 0.99).check_rate(13.0)
    with pytest.raises(InputError, match="jitter"):
        fl.Faults(jitter=0.02).check_rate(13.0)


def test_clutter_sets_the_radar_clutter_rate_and_nothing_else():
    cfg = RadarConfig()
    assert fl.Faults().radar(cfg) is cfg
    faulty = fl.Faults(clutter=3.0).radar(cfg)
    assert faulty.clutter_rate == 3.0 and faulty.sigmas == cfg.sigmas and cfg.clutter_rate == 20.0


def test_jittered_times_stay_strictly_increasing_with_the_asked_sigma():
    rate = 13.0
    t = np.arange(20000) / rate
    sigma = fl.JITTER_MAX / rate
    rec = fl.jittered_times(t, sigma, rate, np.random.default_rng(1))
    e = rec - t
    assert np.all(np.diff(rec) > 0.05 / rate)
    assert np.max(np.abs(e)) <= fl.JITTER_CLIP / rate + 1e-9
    assert abs(np.mean(e)) < 4 * sigma / np.sqrt(len(t))
    assert np.std(e) == pytest.approx(sigma, rel=0.03)  # clipped at 3.0 sigma: about 1 % less spread
    assert np.array_equal(fl.jittered_times(t, 0.0, rate, np.random.default_rng(1)), t)


def test_ghosts_copy_real_detections_at_a_longer_range():
    rng = np.random.default_rng(2)
    det = _dets(200, rng)
    counts = []
    for _ in range(300):
        out = fl.add_ghosts(det, 5.0, RadarConfig(), rng)
        ghost = out.label == fl.GHOST
        counts.append(ghost.sum())
        assert len(out) == len(det) + ghost.sum()
        real = out.label != fl.GHOST
        assert sorted(out.landmark_id[real]) == list(range(200))  # the real detections all kept
        for r, az, vr in zip(out.range[ghost], out.azimuth[ghost], out.radial_velocity[ghost]):
            src = np.flatnonzero((det.azimuth == az) & (det.radial_velocity == vr))
            assert src.size == 1 and det.label[src[0]] != CLUTTER
            assert fl.GHOST_OFFSET[0] <= r - det.range[src[0]] <= fl.GHOST_OFFSET[1]
        assert np.all(np.isnan(out.p_world[ghost])) and np.all(out.object_id[ghost] == -1)
    assert np.mean(counts) == pytest.approx(5.0, abs=4 * np.sqrt(5.0 / 300))


def test_no_ghosts_without_real_detections():
    rng = np.random.default_rng(3)
    det = _dets(8, rng)
    only_clutter = Detections(*(getattr(det, f)[det.label == CLUTTER] for f in fl._FIELDS))
    assert len(fl.add_ghosts(only_clutter, 50.0, RadarConfig(), rng)) == len(only_clutter)


def test_apply_empties_outages_drops_scans_and_leaves_the_input_alone():
    rng = np.random.default_rng(4)
    t = np.arange(400) / 10.0
    dets = [_dets(30, rng) for _ in t]
    before = [d.range.copy() for d in dets]
    f = fl.Faults(dropped=0.25, outage=((5.0, 2.0), (30.0, 0.5)))
    out = fl.apply(f, dets, t, RadarConfig(rate_hz=10.0), np.random.SeedSequence(9))
    in_outage = ((t >= 5.0) & (t < 7.0)) | ((t >= 30.0) & (t < 30.5))
    assert all(len(d) == 0 for d, o in zip(out.dets, in_outage) if o)
    assert all(len(d) == 30 for d, o in zip(out.dets, in_outage) if not o)
    assert out.dropped.mean() == pytest.approx(0.25, abs=4 * np.sqrt(0.25 * 0.75 / len(t)))
    assert np.array_equal(out.t_recorded, t)
    assert all(np.array_equal(d.range, b) for d, b in zip(dets, before))
    again = fl.apply(f, dets, t, RadarConfig(rate_hz=10.0), np.random.SeedSequence(9))
    assert np.array_equal(again.dropped, out.dropped)
    other = fl.apply(f, dets, t, RadarConfig(rate_hz=10.0), np.random.SeedSequence(10))
    assert not np.array_equal(other.dropped, out.dropped)


def test_each_fault_draws_from_its_own_stream():
    """Adding ghosts and jitter does not change which scans are dropped (and vice versa for jitter)."""
    rng = np.random.default_rng(5)
    t = np.arange(200) / 13.0
    dets = [_dets(20, rng) for _ in t]
    cfg = RadarConfig()
    a = fl.apply(fl.Faults(dropped=0.3, jitter=0.005), dets, t, cfg, np.random.SeedSequence(1))
    b = fl.apply(fl.Faults(dropped=0.3, jitter=0.005, ghosts=4.0), dets, t, cfg, np.random.SeedSequence(1))
    c = fl.apply(fl.Faults(jitter=0.005), dets, t, cfg, np.random.SeedSequence(1))
    assert np.array_equal(a.dropped, b.dropped) and np.array_equal(a.t_recorded, b.t_recorded)
    assert np.array_equal(a.t_recorded, c.t_recorded) and a.dropped.any()


def test_outages_at_a_rate_parse_and_the_last_one_wins():
    f = fl.parse_faults(["outages=2:1.5", "outage=3:1", "outages=4:0.5"])
    assert f == fl.Faults(outage=((3.0, 1.0),), outages=(4.0, 0.5)) and f.changes_scans
    with pytest.raises(InputError, match="--fault outages"):
        fl.Faults(outages=(1.0, 2.0, 3.0))


def test_outages_at_a_rate_count_close_to_the_rate():
    """6 per minute over 10^4 s: Poisson(1000) outages (within 4 sigma), sorted starts inside the span."""
    rng = np.random.default_rng(np.random.SeedSequence(3))
    intervals = fl.outage_intervals(6.0, 0.5, 100.0, 10_100.0, rng)
    starts = np.array([s for s, _ in intervals])
    assert abs(len(starts) - 1000) < 4 * np.sqrt(1000)
    assert np.all(np.diff(starts) >= 0) and starts.min() >= 100.0 and starts.max() < 10_100.0
    assert all(d == 0.5 for _, d in intervals)
    assert fl.outage_intervals(0.0, 0.5, 0.0, 1e4, rng) == ()


def test_apply_outages_at_a_rate_empties_the_drawn_intervals_deterministically():
    """The scans inside the intervals drawn from the fourth fault stream are empty, all others untouched; the
    same seed gives the same outages, another seed others; the dropped scans' draws do not change."""
    rng = np.random.default_rng(np.random.SeedSequence(6))
    t = np.arange(6000) / 10.0  # 600 s
    dets = [_dets(3, rng) for _ in t]
    cfg = RadarConfig(rate_hz=10.0)
    f = fl.Faults(dropped=0.1, outages=(4.0, 1.0))
    out = fl.apply(f, dets, t, cfg, np.random.SeedSequence(9))
    stream = np.random.default_rng(np.random.SeedSequence(9).spawn(4)[3])
    intervals = fl.outage_intervals(4.0, 1.0, 0.0, 600.0, stream)
    assert abs(len(intervals) - 40) < 4 * np.sqrt(40)
    inside = np.zeros(len(t), bool)
    for start, duration in intervals:
        inside |= (t >= start) & (t < start + duration)
    assert inside.any() and not inside.all()
    assert [len(d) for d in out.dets] == [0 if o else 3 for o in inside]
    again = fl.apply(f, dets, t, cfg, np.random.SeedSequence(9))
    assert [len(d) for d in again.dets] == [len(d) for d in out.dets]
    other = fl.apply(f, dets, t, cfg, np.random.SeedSequence(10))
    assert [len(d) for d in other.dets] != [len(d) for d in out.dets]
    no_outages = fl.apply(fl.Faults(dropped=0.1), dets, t, cfg, np.random.SeedSequence(9))
    assert np.array_equal(no_outages.dropped, out.dropped)


def test_common_doppler_error_is_one_sensor_velocity_error_per_scan():
    """doppler_common=SIGMA:RHO changes only the radial velocities, by -u . b_k with one b_k per scan (u the true
    directions; recovered to round-off by least squares, ghosts included: they copy a shifted detection); the b_k
    are AR(1) with sigma SIGMA per axis and lag-1 correlation RHO (2000 scans: within sampling error); ghosts and
    drops draw as without it."""
    rng = np.random.default_rng(6)
    t = np.arange(2000) / 13.0
    dets = [_dets(12, rng) for _ in t]
    cfg = RadarConfig()
    f = fl.parse_faults(["doppler_common=0.05:0.8", "dropped=0.2", "ghosts=1"])
    assert f.doppler_common == (0.05, 0.8) and fl.parse_faults(["doppler_common=0.05"]).doppler_common == (0.05, 0.9)
    out = fl.apply(f, dets, t, cfg, np.random.SeedSequence(3))
    clean = fl.apply(fl.Faults(dropped=0.2, ghosts=1.0), dets, t, cfg, np.random.SeedSequence(3))
    assert np.array_equal(out.dropped, clean.dropped)
    b = []
    for got, base in zip(out.dets, clean.dets):
        for field in ("range", "azimuth", "elevation", "label", "true_polar"):
            np.testing.assert_array_equal(getattr(got, field), getattr(base, field))
        az, el = base.true_polar[:, 1], base.true_polar[:, 2]
        u = np.c_[np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)]
        delta = base.radial_velocity - got.radial_velocity
        b_k = np.linalg.lstsq(u, delta, rcond=None)[0]
        np.testing.assert_allclose(u @ b_k, delta, atol=1e-12)
        b.append(b_k)
    b = np.array(b)
    np.testing.assert_allclose(b.std(axis=0), 0.05, rtol=0.15)
    np.testing.assert_allclose([np.corrcoef(b[1:, i], b[:-1, i])[0, 1] for i in range(3)], 0.8, atol=0.05)


@pytest.mark.parametrize("text", ["doppler_common=-0.1", "doppler_common=nan", "doppler_common=0.05:1",
                                  "doppler_common=0.05:-0.1", "doppler_common=a", "doppler_common=0.1:x"])
def test_bad_common_doppler_errors_name_the_fault(text):
    with pytest.raises(InputError, match="--fault doppler_common"):
        fl.parse_faults([text])
