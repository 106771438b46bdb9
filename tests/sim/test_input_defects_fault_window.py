"""`--fault outage=START:DURATION` starting after the simulation ends would empty no scan: refused with a message
naming the fault and the duration (docs/simulator.md, Faults), before anything is simulated or written."""

from __future__ import annotations

import numpy as np
import pytest

from rodo import scenarios
from rodo.cli import main
from rodo.estimator.errors import InputError
from rodo.sim.faults import Faults, parse_faults
from rodo.sim.sequence import read_sequence
from tests.cli.helpers import fails


@pytest.mark.parametrize("rig", [[], ["--rig", "corners"]])
def test_an_outage_after_the_end_is_refused(tmp_path, capsys, rig):
    out = tmp_path / "o"
    fails(capsys, ["simulate", "city", "--seed", "1", "--duration", "2", "--fault", "outage=5:1", "--out", out,
                   *rig], "--fault outage=5:1", "simulated 2 s", "--duration")
    assert not out.exists()


def test_an_outage_overlapping_the_end_still_empties_its_scans(tmp_path, capsys):
    assert main(["simulate", "city", "--seed", "1", "--duration", "1", "--fault", "outage=0.8:5",
                 "--out", str(tmp_path)]) == 0
    assert "faults: outage 0.8-5.8 s" in capsys.readouterr().out
    t = np.arange(14) / 13.0
    seq_t = np.array([s.t for s in read_sequence(tmp_path).scans])
    assert np.array_equal(seq_t, t[t < 0.8])


def test_the_python_api_refuses_it_too():
    Faults(outage=((2.0, 1.0),)).check_duration(2.0)  # starts at the last scan time: it empties that scan
    with pytest.raises(InputError, match=r"--fault outage=2.5:1: starts after the end of the simulated 2 s"):
        Faults(outage=((2.5, 1.0),)).check_duration(2.0)
    with pytest.raises(InputError, match="--fault outage=3:0.5"):
        scenarios.get("city").simulate(1, 1.0, faults=parse_faults(["outage=0.2:0.1", "outage=3:0.5"]))
