"""The PNG files of the paper's figures (viz.figures draws the dicts of validation.experiments, whose numbers
are tested in tests/validation/test_experiments.py), the NEES plot, and `rodo figures`."""

from __future__ import annotations

import struct
from pathlib import Path

import numpy as np
import pytest

from rodo.estimator.errors import InputError
from rodo.validation import experiments
from rodo.validation.consistency import chi2_bounds
from rodo.viz import figures


def assert_png(path, min_bytes: int = 20_000):
    """A real PNG of a plausible size (a figure with content compresses to tens of kB)."""
    data = path.read_bytes()
    assert data[:8] == b"\x89PNG\r\n\x1a\n"
    width, height = struct.unpack(">II", data[16:24])
    assert width >= 600 and height >= 300
    assert len(data) >= min_bytes, f"{path.name}: only {len(data)} bytes"


def fake_fig4() -> dict:
    """A dict shaped like experiments.fig4_data (viz only draws: no simulation needed)."""
    s = np.linspace(0.0, 100.0, 60)
    truth = np.c_[s, 5 * np.sin(s / 20), 0.02 * s]
    cv, ca = truth + np.c_[0 * s, 0.01 * s, -0.01 * s], truth + np.c_[0 * s, 0.003 * s, 0.002 * s]
    return dict(t=s / 10, truth=truth, cv=cv, ca=ca, distance=s, path_length=100.0, scenario="hills", seed=0,
                duration=6.0, final_error={"cv-cartesian": 1.4, "ca-polar": 0.4})


def fake_fig5() -> dict:
    """A dict shaped like experiments.fig5_data."""
    d = np.linspace(0.0, 240.0, 80)
    runs, final = {}, {}
    for k, name in enumerate(("CV/C", "CA/P", "CV/C, no roll/pitch rate terms", "CA/P, no roll/pitch rate terms")):
        series = np.outer(d / 240.0, [0.5, -0.3, 0.1 * (k + 1), 0.5 * (k + 1), -0.3 * (k + 1), 1.0])
        runs[name] = series
        final[name] = dict(zip(("z", "roll", "pitch"), series[-1, 2:5]))
    return dict(distance=d, runs=runs, final=final, path_length=240.0, scenario="city", seed=2, duration=30.0)


@pytest.fixture(scope="module")
def data() -> dict:
    """Figures 1-3 from small experiments, 4 and 5 from the dicts above."""
    return {1: experiments.fig1_data(n_samples=150, n_times=2, horizon=1.0, substeps=20), 2: experiments.fig2_data(),
            3: experiments.fig3_data(), 4: fake_fig4(), 5: fake_fig5()}


@pytest.mark.parametrize("number", [1, 2, 3, 4, 5])
def test_figure_png(number, data, tmp_path):
    _, name, draw = figures.FIGURES[number - 1]
    assert_png(draw(tmp_path / name, data[number]))


def test_write_all_draws_the_figures_it_is_given(data, tmp_path):
    paths = figures.write_all(tmp_path, {3: data[3], 1: data[1]})
    assert [p.name for p in paths] == ["fig1_prior.png", "fig3_association.png"]
    for p in paths:
        assert_png(p)
    with pytest.raises(InputError, match="no figure"):
        figures.write_all(tmp_path, {7: {}})


def test_plot_nees(tmp_path):
    t = np.arange(50) * 0.1
    rng = np.random.default_rng(np.random.SeedSequence(3))
    y = rng.chisquare(60, size=(50, 2)) / 10
    assert_png(figures.plot_nees(tmp_path / "nees.png", t, y, chi2_bounds(10, 6), ["pose (6 dof)", "velocity"]))
    assert_png(figures.plot_nees(tmp_path / "one.png", t, y[:, 0], (np.full(50, 4.0), 8.0), "pose"))
    with pytest.raises(InputError, match="nees_mean"):
        figures.plot_nees(tmp_path / "bad.png", t, y[:10], (4, 8), "pose")
    with pytest.raises(InputError, match="labels"):
        figures.plot_nees(tmp_path / "bad.png", t, y, (4, 8), ["one"])


def test_plot_nees_of_several_measures_per_dof(tmp_path, monkeypatch):
    """(N, m) curves per dof with the N-run band: a measure with no value is left out of the legend, one far
    above the band switches to a log axis."""
    t = np.arange(40) * 0.1
    rng = np.random.default_rng(np.random.SeedSequence(4))
    y = np.c_[rng.chisquare(60, 40) / 60, np.full(40, np.nan), 100 * rng.chisquare(60, 40) / 60]
    drawn = []
    save = figures.save_png
    monkeypatch.setattr(figures, "save_png", lambda fig, path: (drawn.append(fig), save(fig, path))[1])
    lo, hi = chi2_bounds(10, 6) / 6
    assert_png(figures.plot_nees(tmp_path / "c.png", t, y, (lo, hi), ["velocity", "acceleration", "pose_window"],
                                 title="m", ylabel="average NEES / dof"))
    ax = drawn[-1].axes[0]
    labels = [x.get_text() for x in ax.get_legend().get_texts()]
    assert ax.get_yscale() == "log" and ax.get_ylabel() == "average NEES / dof"
    assert any(x.startswith("velocity") for x in labels) and not any(x.startswith("acceleration") for x in labels)
    assert_png(figures.plot_nees(tmp_path / "lin.png", t, y[:, :1], (lo, hi), "velocity"))
    assert drawn[-1].axes[0].get_yscale() == "linear"


def test_rodo_figures_writes_five_pngs(tmp_path, monkeypatch, capsys, data):
    """The command computes each figure through validation.experiments and draws it (the experiments are
    replaced by the data above, so this checks the wiring, not the simulations)."""
    from rodo import cli
    from rodo.commands import figures as command

    asked = []
    monkeypatch.setattr(experiments, "fig1_data", lambda **kw: asked.append((1, kw)) or data[1])
    monkeypatch.setattr(experiments, "fig4_data", lambda **kw: asked.append((4, kw)) or data[4])
    monkeypatch.setattr(experiments, "fig5_data", lambda **kw: asked.append((5, kw)) or data[5])
    assert cli.main(["figures", "--out", str(tmp_path / "figs"), "--quick"], commands=[command]) == 0
    printed = capsys.readouterr().out.split()
    assert len(printed) == 5
    for p in printed:
        assert_png(Path(p))
    assert [n for n, _ in asked] == [1, 4, 5] and asked[0][1]["n_samples"] == 200  # the quick sizes


def test_plot_velocity_growth_draws_the_points_the_fit_and_ems_line(tmp_path, monkeypatch):
    """EM's check (`validation.velocity_growth` rows of SDE tracks): per moving component its points and the two
    curves c + q g(lag) with the growth's and EM's q; a component without motion gets a panel saying so."""
    from tests.validation.test_velocity_growth import QC_CA, _rng, _track
    from rodo.validation.velocity_growth import growth_check, growth_kernel, velocity_growth

    tr = _track(_rng(11), "ca", QC_CA, 40.0, np.sqrt(0.5 * QC_CA * growth_kernel("ca", 1.0) / 6))
    tr.varpi[:, 3] = 0.0  # roll never moves
    rows = growth_check(10 * QC_CA, velocity_growth(tr, "ca"))
    drawn = []
    save = figures.save_png
    monkeypatch.setattr(figures, "save_png", lambda fig, path: (drawn.append(fig), save(fig, path))[1])
    assert_png(figures.plot_velocity_growth(tmp_path / "g.png", rows))
    axes = drawn[-1].axes
    assert len(axes) == 6 and not axes[3].axison and axes[3].texts[0].get_text() == "no motion"
    x = axes[0]
    points, fit, em = x.lines
    np.testing.assert_allclose(points.get_ydata(), rows[0]["D"])
    lag = fit.get_xdata()[-1]
    assert fit.get_ydata()[-1] == pytest.approx(rows[0]["c"] + rows[0]["growth"] * float(growth_kernel("ca", lag)))
    assert em.get_ydata()[-1] == pytest.approx(rows[0]["c"] + rows[0]["em"] * float(growth_kernel("ca", lag)))
    assert x.get_title() == "x: EM outside" and x.get_xscale() == x.get_yscale() == "log"


@pytest.mark.parametrize("with_drive", [True, False])
def test_plot_growth_draws_the_spans_and_the_drive_not_the_velocity(tmp_path, monkeypatch, with_drive):
    """The error growth's figure: one line per axis over the spans with a count, the drive's absolute pose as a
    marker at the right where it has one; the velocity and acceleration rows (scans None, as the drive's) are not
    taken for the drive."""
    from rodo.validation.error_growth import empty_growth, growth_table

    g = empty_growth((0.0, 1.0))
    g["scans"][:] = (1, 10)
    rows = [0, 1, 2] if with_drive else [0, 1]
    g["count"][rows] = 10.0
    g["z2"][rows] = 10.0 * np.arange(1, len(rows) + 1)[:, None]
    g["e2"][rows] = g["var"][rows] = 1.0
    g.update({"vel_count": np.array([10.0, 0.0]), "vel_z2": np.full((2, 6), 70.0), "vel_e2": np.ones((2, 6)),
              "vel_var": np.ones((2, 6))})
    drawn = []
    save = figures.save_png
    monkeypatch.setattr(figures, "save_png", lambda fig, path: (drawn.append(fig), save(fig, path))[1])
    assert_png(figures.plot_growth(tmp_path / "g.png", growth_table(g)), min_bytes=5_000)
    ax = drawn[-1].axes[0]
    markers = [line for line in ax.lines if line.get_marker() == "s"]
    assert len(markers) == (6 if with_drive else 0)
    assert all(line.get_ydata()[0] == 3.0 for line in markers)  # the drive's ratio, not the velocity's 7
    assert [t.get_text() for t in ax.get_xticklabels()] == ["1 scan", "1 s"] + (["drive"] if with_drive else [])
