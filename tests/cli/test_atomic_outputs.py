"""Results are never lost to an interrupted write: the simulator's truth.npz, a campaign's summaries, Table I and
every figure are written through `atomic_write_bytes` (a temporary file, fsync, rename), Rerun's recordings into a
uniquely named temporary file that is synced and renamed (`replace_synced`). A write that fails
part-way (here: fsync raising, as on a full disk) leaves the previous file whole and no temporary file behind."""

import os

import numpy as np
import pytest

from rodo.sim.simulate import save_npz
from rodo.validation.campaign import write_summary
from rodo.validation.table1 import build_table, write_table
from tests.validation.test_table1 import _run


def _failing_fsync(monkeypatch):
    def fail(fd):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(os, "fsync", fail)


def _truth(path, value):
    save_npz(path / "truth.npz", {"t": np.array([value])})


def _summary(path, value):
    write_summary(path, {"models": {}, "trials": 0, "alpha": 0.05, "value": value})


def _table(path, value):
    runs = [_run("a", "ca-polar", 0.01 * value, 1e-4, [10.0]), _run("a", "cv-cartesian", 0.02, 2e-4, [20.0])]
    write_table(path, build_table(runs))


def _figure(path, value):
    pytest.importorskip("matplotlib")
    from rodo.viz.figures import _figure as new_figure, save_png

    fig = new_figure(2, 2)
    fig.suptitle(str(value))
    save_png(fig, path / "figure.png")


def _recording(path, value):
    pytest.importorskip("rerun")
    from rodo import scenarios
    from rodo.viz.recording import record_sequence

    seq, _ = scenarios.get("city").simulate(int(value), duration=0.2)
    record_sequence(path / "seq.rrd", seq)


@pytest.mark.parametrize("write, names", [(_truth, ["truth.npz"]), (_summary, ["summary.json", "summary.md"]),
                                          (_table, ["table1.md", "table1.json"]), (_figure, ["figure.png"]),
                                          (_recording, ["seq.rrd"])])
def test_an_interrupted_write_keeps_the_previous_file(tmp_path, monkeypatch, write, names):
    write(tmp_path, 1.0)
    before = {n: (tmp_path / n).read_bytes() for n in names}
    _failing_fsync(monkeypatch)
    with pytest.raises(OSError, match="No space"):
        write(tmp_path, 2.0)
    monkeypatch.undo()
    assert {n: (tmp_path / n).read_bytes() for n in names} == before
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(names)
