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


@pytest.mark.parametrize("code, words, advice", [(28, "No space left on device", "free some space"),
                                                 (122, "Disk quota exceeded", "free some space"),
                                                 (27, "File too large", "a file larger than this place allows")])
def test_a_full_disk_is_one_line_and_exit_1_not_a_traceback(tmp_path, monkeypatch, capsys, code, words, advice):
    """`rodo simulate` on a full disk, over quota or past a file-size limit: exit 1 with one line naming the error,
    the file being written (not its temporary name: fsync's error names none) and what to do, no traceback, and
    no file half-written (the sequence's directory holds no temporary file)."""
    from rodo import cli

    _failing_fsync_with(monkeypatch, code, words)
    out = tmp_path / "seq"
    assert cli.main(["simulate", "city", "--duration", "0.2", "--out", str(out)]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith(f"rodo simulate: error: {words} ({out / 'radar.csv'}): {advice}"), err
    assert "Traceback" not in err[0]
    assert not [p.name for p in out.rglob("*") if p.is_file() and p.name.startswith(".")]


def test_results_csv_names_itself_when_its_append_fails(tmp_path, monkeypatch):
    """A row appended to results.csv on a full disk: the OSError names results.csv (write and fsync name none)."""
    from rodo.validation.campaign_files import append_rows

    _failing_fsync_with(monkeypatch, 28, "No space left on device")
    with pytest.raises(OSError) as raised:
        append_rows(tmp_path / "results.csv", [{"trial": 0}])
    assert raised.value.filename == str(tmp_path / "results.csv")


def test_other_os_errors_still_raise(monkeypatch):
    """Only the output place's errors become a message: any other OSError is a defect and keeps its traceback."""
    from rodo import cli

    def broken(args):
        raise OSError(5, "Input/output error")

    monkeypatch.setattr(cli.simulate, "run_simulate", broken)
    with pytest.raises(OSError, match="Input/output"):
        cli.main(["simulate", "city", "--duration", "0.2", "--out", "unused"])


def _failing_fsync_with(monkeypatch, code, words):
    def fail(fd):
        raise OSError(code, words)

    monkeypatch.setattr(os, "fsync", fail)


@pytest.mark.parametrize("code, environment", [(28, True), (122, True), (27, True), (13, False)])
def test_writers_that_name_their_output_keep_a_full_disk_the_machines(tmp_path, monkeypatch, code, environment):
    """export's writer turns a place it cannot write into an InputError naming it (exit 2: the user's choice of
    output), but a full disk, a quota or a file-size limit stays the OSError it is, naming the file, for the CLI's
    one line and exit 1 (they were exit 2 without the advice: the review of session 56, finding 6)."""
    from rodo.estimator.errors import InputError
    from rodo.sim import export

    _failing_fsync_with(monkeypatch, code, os.strerror(code))  # the write itself, as on the disk
    target = tmp_path / "000000.ply"
    with pytest.raises((OSError, InputError)) as raised:
        export._atomic_write(target, b"")
    assert isinstance(raised.value, InputError) != environment
    if environment:
        assert raised.value.errno == code and raised.value.filename == str(target)
    else:
        assert str(target) in str(raised.value)


def test_a_torn_header_is_an_empty_campaign_that_resumes(tmp_path):
    """results.csv cut inside its header (a full disk in the campaign's first write, on a file system that writes
    short): no rows, and the resume the error message recommends writes the header whole and runs every trial. It
    was refused as an unexpected header (the review of session 56, finding 8)."""
    from concurrent.futures import ProcessPoolExecutor

    from rodo.validation.campaign import make_trials, read_results, run_campaign
    from rodo.validation.campaign_files import FIELDS
    from tests.validation.test_campaign import MODELS, FakeTrial

    path = tmp_path / "results.csv"
    path.write_text(",".join(FIELDS)[:17])
    assert read_results(path) == []
    with ProcessPoolExecutor(1) as ex:
        run_campaign(FakeTrial(), make_trials(4, 2, MODELS), ex, tmp_path, resume=True)
    assert path.read_text().splitlines()[0] == ",".join(FIELDS) and len(read_results(path)) == 4
    path.write_text("trial,seed,nonsense")
    with pytest.raises(ValueError, match="line 1: unexpected header"):
        read_results(path)


def test_a_full_disk_under_the_figures_is_not_a_note(tmp_path, monkeypatch):
    """A campaign's figures on a full disk: the OSError propagates (the CLI's one line, exit 1) instead of a note
    in summary.md beside the previous campaign's figures (the review of session 56, finding 9); any other
    failure of a plot stays a note."""
    pytest.importorskip("matplotlib")
    from rodo.commands import montecarlo
    from rodo.viz import figures

    summary = {"models": {"ca-polar": {"nees_curve": {"t": [0.0, 0.1], "mean": [1.0, 1.0], "lower": [0.5, 0.5],
                                                      "upper": [2.0, 2.0]}, "nees": {"dim": 18}}}}
    for exc, raises in ((OSError(28, "No space left on device"), True), (ValueError("bad curve"), False)):
        def fail(*args, exc=exc, **kwargs):
            raise exc

        monkeypatch.setattr(figures, "plot_nees", fail)
        if raises:
            with pytest.raises(OSError, match="No space"):
                montecarlo.plot_summary(tmp_path, summary)
        else:
            assert montecarlo.plot_summary(tmp_path, summary).startswith("No NEES plot: viz.figures.plot_nees failed")


def test_a_local_dask_cluster_on_a_full_disk_is_the_machines_error(monkeypatch):
    """`--dask local` whose scratch space is on a full disk: Dask wraps the OSError in "Cluster failed to start";
    make_executor unwraps it for the CLI's one line and exit 1 (it was a traceback: the review of session 56,
    finding 7). Another failure to start stays Dask's own error."""
    distributed = pytest.importorskip("distributed")
    from rodo.validation.workers import make_executor

    for cause, expected in ((OSError(28, "No space left on device"), OSError), (ValueError("bad"), RuntimeError)):
        def failing(*args, cause=cause, **kwargs):
            raise RuntimeError(f"Cluster failed to start: {cause}") from cause

        monkeypatch.setattr(distributed, "LocalCluster", failing)
        with pytest.raises(expected) as raised:
            with make_executor(1, dask="local"):
                pass
        assert type(raised.value) is expected
