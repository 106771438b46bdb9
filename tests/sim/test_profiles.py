"""sim.profiles: the registry, the default profile's output frozen (to round-off), each profile's
points per scan within its real sensor's range, Doppler wrap-around and 2D output in simulations, the rcs/snr
columns through the sequence format and the estimator."""

from __future__ import annotations

import numpy as np
import pytest

from rodo import scenarios
from rodo.estimator.errors import InputError
from rodo.sim import profiles
from rodo.sim.objects import GHOST
from rodo.sim.radar import RadarConfig
from rodo.sim.sequence import read_sequence
from rodo.validation import realism

from tests.fingerprint import fingerprint

# tests.fingerprint of `simulate_to(name, seed, d, 10.0)` (floats to 1e-6; the same under OpenBLAS's SkylakeX, Zen,
# Haswell and Sandybridge kernels, OPENBLAS_CORETYPE), of radar.csv and truth.npz. Since the trajectory's
# checkpoint grid; any change of what the simulator draws or detects changes it (city: since its version 3, the
# traffic clear of itself and of the parked cars).
FROZEN = {
    ("city", 0): {"radar.csv": "a0b27a175b4ae318ca5681063e9bcc13e06984eed65c3435b115e8814f873916",
                  "truth.npz": "5a1a25a10843d6fe75d233586a6ebcbacf5d8290531336841c0c88bc164d08f1"},
    ("highway", 1): {"radar.csv": "ac313079e0360ffbe6d5f395eb86c722cb536a9ab1a2e1df2f56dcbbe567b827",
                     "truth.npz": "a07a85852874a95f1aa63da60896dae02861c749d1f3f513420e67098dca1ceb"},
}


@pytest.mark.slow
@pytest.mark.parametrize("name, seed", sorted(FROZEN))
@pytest.mark.parametrize("how", [{}, {"sensor_profile": "generic"}])
def test_default_profile_output_is_frozen(tmp_path, name, seed, how):
    scenarios.simulate_to(name, seed, tmp_path, 10.0, **how)
    got = fingerprint(tmp_path)
    assert {f: got[f] for f in FROZEN[(name, seed)]} == FROZEN[(name, seed)]


def test_fingerprint_sees_a_change_below_the_noise_and_ignores_round_off(tmp_path):
    """One detection's range moved by 1e-5 m changes the fingerprint; every float of truth.npz moved by a
    relative 1e-15 (round-off) does not."""
    scenarios.simulate_to("yaw_accel", 0, tmp_path, 1.0)
    base = fingerprint(tmp_path)
    lines = (tmp_path / "radar.csv").read_text().splitlines()
    row, i = lines[1].split(","), lines[0].split(",").index("range")
    row[i] = repr(float(row[i]) + 1e-5)
    (tmp_path / "radar.csv").write_text("\n".join([lines[0], ",".join(row), *lines[2:]]) + "\n")
    assert fingerprint(tmp_path)["radar.csv"] != base["radar.csv"]
    truth = dict(np.load(tmp_path / "truth.npz"))
    np.savez(tmp_path / "truth.npz", **{k: v * (1 + 1e-15) if v.dtype.kind == "f" else v for k, v in truth.items()})
    assert fingerprint(tmp_path)["truth.npz"] == base["truth.npz"]


def test_registry_names_versions_and_unknown_names():
    assert profiles.names()[0] == profiles.DEFAULT == "generic"
    assert {"lrr30f", "iwr6843aop", "corner2d"} <= set(profiles.names())
    for name in profiles.names():
        p = profiles.get(name)
        assert p.version >= 1 and p.sources and isinstance(p.config(), RadarConfig)
    assert profiles.get("generic").config().physics is None
    with pytest.raises(InputError) as err:
        profiles.get("hasco")
    assert "hasco" in str(err.value) and all(n in str(err.value) for n in profiles.names())
    with pytest.raises(ValueError, match="twice"):
        profiles.register(profiles.GENERIC)


def test_a_scenario_chooses_a_profile():
    city = scenarios.get("city")
    assert city.sensor_profile == "generic" and city.radar_config().physics is None
    assert city.radar_config("lrr30f").physics is not None
    with pytest.raises(InputError, match="known profiles"):
        city.simulate(0, 0.5, sensor_profile="nope")


@pytest.mark.parametrize("name, duration", [("lrr30f", 3.0), ("iwr6843aop", 20.0), ("corner2d", 3.0)])
def test_points_per_scan_within_the_real_sensors_range(name, duration):
    """The calibrated set-up (validation.realism) gives a mean count per scan inside the real sensor's range
    (LRR30-F 260-477 in the RaFlow data, TI 19-87 in the rio demo, RadarScenes radar 3 140-365 (5-95 %))."""
    lo, hi = profiles.get(name).points_per_scan
    (seq, truth), = realism.SETUPS[name].simulate((0,), duration)
    counts = np.diff(truth["scan_offsets"])
    assert lo <= counts.mean() <= hi, counts.mean()


def test_doppler_wraps_into_the_unambiguous_interval_in_a_simulation():
    """The TI profile (+-4 m/s) on the highway (80-130 km/h): every reported v_r inside [-4, 4), on the 0.125
    m/s grid, while the true static v_r are far outside."""
    seq, truth = scenarios.get("highway").simulate(0, 1.0, sensor_profile="iwr6843aop")
    vr = np.concatenate([s.radial_velocity for s in seq.scans])
    assert vr.size > 0 and np.all(vr >= -4.0) and np.all(vr < 4.0 + 1e-9)
    assert np.allclose(vr / 0.125, np.round(vr / 0.125))
    assert np.max(np.abs(truth["det_true_polar"][:, 3])) > 15.0


def test_corner_radar_is_2d():
    seq, truth = scenarios.get("city").simulate(1, 1.0, sensor_profile="corner2d")
    el = np.concatenate([s.elevation for s in seq.scans])
    assert el.size > 0 and np.all(el == 0.0)


def test_rcs_and_snr_columns_round_trip_and_the_estimator_ignores_them(tmp_path):
    """radar.csv gets rcs and snr (no truth column); reading keeps them in RadarScan.extra; the odometry runs
    on the sequence unchanged."""
    from rodo.estimator.config import OdometryConfig
    from rodo.validation.driver import run_sequence

    seq, truth = scenarios.simulate_to("city", 2, tmp_path, 1.5, sensor_profile="lrr30f")
    header = (tmp_path / "radar.csv").read_text().split("\n", 1)[0]
    assert header == "scan,t,range,azimuth,elevation,radial_velocity,rcs,snr"
    back = read_sequence(tmp_path)
    for a, b in zip(seq.scans, back.scans):
        assert np.array_equal(a.extra["rcs"], b.extra["rcs"]) and np.array_equal(a.extra["snr"], b.extra["snr"])
    snr = np.concatenate([s.extra["snr"] for s in back.scans])
    assert np.all(snr > 10 * np.log10(-np.log(1e-4)) - 1e-9)  # every detection passed the threshold
    assert np.any(truth["det_label"] == GHOST)
    est = run_sequence(back, OdometryConfig.for_model("ca-polar")).estimates
    assert len(est) == len(back.scans) and np.all(np.isfinite(est[-1].T_vehicle_world))


def test_simulate_cli_profile_flag(tmp_path, capsys):
    from rodo.cli import main
    from tests.cli.helpers import fails

    fails(capsys, ["simulate", "city", "--out", tmp_path / "x", "--duration", "1", "--profile", "nope"],
          "unknown sensor profile 'nope'", "lrr30f", "generic")
    assert main(["simulate", "city", "--out", str(tmp_path / "y"), "--duration", "1", "--profile", "iwr6843aop"]) == 0
    assert "profile iwr6843aop" in capsys.readouterr().out
    assert (tmp_path / "y" / "radar.csv").read_text().startswith("scan,t,range,azimuth,elevation,radial_velocity,rcs")


def test_a_profile_streams_the_simulated_scans():
    """sim.stream with a physical radar yields simulate's scans bit for bit, rcs and snr included (the ghost
    generator is spawned from the scan generator the same way in both)."""
    from rodo.sim.simulate import simulate
    from rodo.sim.stream import stream

    parts = scenarios.get("city").build(0, 1.5)
    cfg = profiles.radar_config("lrr30f")
    seq, _ = simulate(parts.world, parts.profile, cfg, np.random.default_rng(5), parts.duration)
    streamed = stream(parts.world, parts.profile, cfg, np.random.default_rng(5), parts.duration).scans()
    for a, b in zip(seq.scans, streamed, strict=True):
        assert np.array_equal(a.range, b.range) and np.array_equal(a.radial_velocity, b.radial_velocity)
        assert a.extra.keys() == b.extra.keys() and np.array_equal(a.extra["snr"], b.extra["snr"])
