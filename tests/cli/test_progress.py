"""Progress bars (rodo.progress, on tqdm): on a terminal they show the label and done/total counts; on anything
else (a file, a pipe, captured output) they write nothing at all, so no carriage-return spam in logs.
Campaign summaries print rounded numbers and "-" where a value is undefined, never None or nan.

Sizing: two 1 s simulations and two conversions of a 4-message bag; a few seconds.
"""

import io
import re
import sys

from rodo.cli import main
from rodo.commands import montecarlo as montecarlo_cmd
from rodo.commands import simulate as simulate_cmd
from rodo.progress import Progress, is_terminal


class FakeTerminal(io.StringIO):
    def isatty(self):
        return True


def test_bar_on_a_terminal_shows_label_and_counts():
    term = FakeTerminal()
    with Progress(7, "rodo run ca-polar", stream=term, unit="scan") as bar:
        for _ in range(7):
            bar.update()
    text = term.getvalue()
    assert bar.done == 7
    assert "rodo run ca-polar" in text and "7/7" in text and "scan/s" in text
    assert text.endswith("\n")  # closed: the next line starts clean


def test_bar_counts_batched_updates():
    term = FakeTerminal()
    with Progress(6, "montecarlo city", stream=term, unit="run") as bar:
        bar.update(2)
        bar.update(4)
    assert bar.done == 6 and "6/6" in term.getvalue()


def test_no_output_at_all_off_a_terminal():
    for stream in (io.StringIO(), FakeTerminal()):
        forced_off = isinstance(stream, FakeTerminal)
        with Progress(50, "table1", stream=stream, enabled=False if forced_off else None) as bar:
            for _ in range(50):
                bar.update()
        assert stream.getvalue() == "" and bar.done == 50


def test_empty_total_and_closed_streams_do_not_fail():
    term = FakeTerminal()
    with Progress(0, "nothing left", stream=term):
        pass
    assert "nothing left" in term.getvalue()
    closed = io.StringIO()
    closed.close()
    assert not is_terminal(closed) and not is_terminal(object())


def test_print_goes_to_stdout_around_the_bar(capsys):
    term = FakeTerminal()
    with Progress(2, "figures", stream=term, unit="figure") as bar:
        bar.update()
        bar.print("fig1.png")
        bar.update()
    assert capsys.readouterr().out == "fig1.png\n"
    with Progress(1, "figures", stream=io.StringIO()) as bar:
        bar.print("fig2.png")
    assert capsys.readouterr().out == "fig2.png\n"


def test_simulate_shows_progress_on_a_terminal_only(tmp_path, capsys, monkeypatch):
    term = FakeTerminal()
    monkeypatch.setattr(sys, "stderr", term)
    assert main(["simulate", "city", "--duration", "1", "--out", str(tmp_path / "a")], commands=[simulate_cmd]) == 0
    monkeypatch.undo()
    n = re.search(r"scans (\d+)", capsys.readouterr().out).group(1)
    assert "simulate city" in term.getvalue() and f"{n}/{n}" in term.getvalue()
    assert main(["simulate", "city", "--duration", "1", "--out", str(tmp_path / "b")], commands=[simulate_cmd]) == 0
    assert capsys.readouterr().err == ""


def test_summary_numbers_are_rounded_or_a_dash():
    assert montecarlo_cmd._num(None) == "-" and montecarlo_cmd._num(float("nan")) == "-"
    assert montecarlo_cmd._num(1.23456) == "1.23" and montecarlo_cmd._num(12.7, 0) == "13"


def test_convert_rosbag_counts_messages_on_a_terminal(tmp_path, capsys, monkeypatch):
    """`rodo convert rosbag` shows the messages read (the total is unknown before reading) and the sequences
    converted; off a terminal it writes nothing on stderr."""
    import numpy as np

    from rodo.commands import convert as convert_cmd
    from tests.sim.test_convert_rosbag import _rng, _static_scene, _write_bag

    rng, v = _rng(1), np.array([3.0, -0.4, 0.1])
    stamps = [1_700_000_000_000_000_000 + 50_000_000 * k for k in range(4)]
    bag = _write_bag(tmp_path / "bag", "sqlite3", [(_static_scene(rng, 20, v), s) for s in stamps])
    argv = ["convert", "rosbag", str(bag), "--topic", "/radar", "--out"]
    term = FakeTerminal()
    monkeypatch.setattr(sys, "stderr", term)
    assert main([*argv, str(tmp_path / "a")], commands=[convert_cmd]) == 0
    monkeypatch.undo()
    text = term.getvalue()
    assert "reading /radar: 4msg" in text and "convert rosbag" in text and "1/1" in text
    assert main([*argv, str(tmp_path / "b")], commands=[convert_cmd]) == 0
    cap = capsys.readouterr()
    assert cap.err == "" and cap.out.count("rosbag -> ") == 2


def test_figures_counts_figures_and_prints_each_path(tmp_path, capsys, monkeypatch):
    """`rodo figures`: a bar over the figures on a terminal, each path on stdout (the drawing is replaced by a
    stub here: the real run takes a minute and is covered by the figure tests)."""
    from rodo.commands import figures as figures_cmd
    from rodo.viz.figures import FIGURES

    monkeypatch.setattr(figures_cmd, "write_figures",
                        lambda out, quick=False: (out / name for _, name, _ in FIGURES))
    term = FakeTerminal()
    monkeypatch.setattr(sys, "stderr", term)
    assert main(["figures", "--out", str(tmp_path / "f"), "--quick"], commands=[figures_cmd]) == 0
    n = len(FIGURES)
    assert "figures" in term.getvalue() and f"{n}/{n}" in term.getvalue()
    assert capsys.readouterr().out.splitlines() == [str(tmp_path / "f" / name) for _, name, _ in FIGURES]
