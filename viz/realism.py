"""The realism figure (`rodo realism PROFILE`): simulated vs real histograms of points per scan, range, azimuth,
elevation, RCS or SNR and the static points' Doppler residual, each titled with its distance
(`validation.realism`). Agg canvas, no pyplot.

Checked by: tests/cli/test_realism_cli.py
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from .figures import save_png

SIM, REAL = "#3b6fd8", "#e0479e"


def plot_realism(path, report) -> Path:
    """Write the report's figure (PNG) to `path`; returns the path."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(13, 7), dpi=100, layout="constrained")
    FigureCanvasAgg(fig)
    sim, real = report.sim, report.real
    rows = {row.name.split(" (")[0]: row for row in report.rows}
    panels = [("points per scan", sim.counts, real.counts, 1.0),
              ("range", sim.range, real.range, 1.0),
              ("azimuth", sim.azimuth, real.azimuth, 180 / np.pi),
              ("elevation", sim.elevation, real.elevation, 180 / np.pi),
              (next(k for k in rows if k in ("rcs", "snr")), sim.value, real.value, 1.0),
              ("static Doppler residual spread", sim.residual, real.residual, 1.0)]
    axes = fig.subplots(2, 3).ravel()
    for ax, (name, a, b, scale) in zip(axes, panels):
        if name == "elevation" and name not in rows:  # a 2D radar: no elevation to compare
            ax.set_title("elevation: not reported (2D radar)", fontsize=10)
            ax.set_axis_off()
            continue
        a, b = np.asarray(a, float) * scale, np.asarray(b, float) * scale
        both = np.concatenate([a, b]) if a.size + b.size else np.zeros(1)
        lo, hi = np.percentile(both, [0.5, 99.5]) if both.size > 1 else (0.0, 1.0)
        bins = np.linspace(lo, hi if hi > lo else lo + 1.0, 40)
        for sample, color, label in ((a, SIM, "simulated"), (b, REAL, "real")):
            if sample.size:  # an empty sample (not computable: the report's notes say why) draws nothing
                ax.hist(sample, bins, density=True, histtype="step", color=color, lw=1.5, label=label)
        row = rows.get(name)
        dist = "" if row is None or row.distance is None else f"  ({row.measure} {row.distance:.2f})"
        ax.set_title(f"{name}{dist}", fontsize=10)
    axes[0].legend(fontsize=8)
    fig.suptitle(f"rodo realism {report.profile}: simulated vs real", fontsize=12)
    return save_png(fig, path)
