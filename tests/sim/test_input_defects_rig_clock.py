"""A rig's radars share one clock (docs/sequence_format.md, Rigs): `read_rig` refuses two radars whose scan times
do not overlap, naming both radar.csv files and their spans; radars taking turns are accepted."""

from __future__ import annotations

import numpy as np
import pytest

from rodo.estimator.errors import InputError
from rodo.sim.rig import Rig, read_rig, write_rig
from rodo.sim.sequence import NoiseSigmas, RadarScan, SensorConfig, Sequence
from tests.cli.helpers import fails


def _radar(times) -> Sequence:
    cfg = SensorConfig(13.0, np.eye(4), NoiseSigmas(0.1, 0.01, 0.02, 0.1), (-1.0, 1.0), (-0.2, 0.2), 100.0)
    scans = [RadarScan(k, float(t), [10.0 + k, 20.0], [0.1, -0.2], [0.0, 0.05], [-1.0, 2.0])
             for k, t in enumerate(times)]
    return Sequence(cfg, scans, None)


def test_radars_on_different_clocks_are_refused(tmp_path, capsys):
    t = np.arange(27) / 13.0
    write_rig(tmp_path / "rig", Rig(["front", "left"], [_radar(t), _radar(100.0 + t + 0.02)]))
    with pytest.raises(InputError, match="do not overlap in time") as err:
        read_rig(tmp_path / "rig")
    message = str(err.value)
    for needle in (tmp_path / "rig" / "front" / "radar.csv", tmp_path / "rig" / "left" / "radar.csv",
                   "scans at 0 to 2 s", "scans at 100.02 to 102.02 s", "one clock"):
        assert str(needle) in message, (needle, message)
    # `rodo run RIG` stops with that line (exit 2) instead of an estimate that jumps 100 s and far away
    fails(capsys, ["run", tmp_path / "rig", "--out", tmp_path / "out"], "left/radar.csv", "do not overlap")
    assert not (tmp_path / "out" / "estimate.txt").exists()


def test_radars_taking_turns_are_one_clock(tmp_path):
    """Spans that touch only within a scan period (a radar whose only scan comes after the other's last) and a
    radar without scans are accepted."""
    rig = Rig(["a", "b", "c"], [_radar([0.0, 0.077, 0.154]), _radar([0.2]), _radar([])])
    write_rig(tmp_path, rig)
    back = read_rig(tmp_path, use_cache=False)
    assert [(t, i) for t, i, _ in back.scans()] == [(0.0, 0), (0.077, 0), (0.154, 0), (0.2, 1)]
    write_rig(tmp_path, Rig(["a", "b"], [_radar([0.0, 0.077, 0.154]), _radar([0.154 + 2.1 / 13.0])]))
    with pytest.raises(InputError, match="do not overlap in time"):
        read_rig(tmp_path)
