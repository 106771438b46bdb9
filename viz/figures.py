"""Static figures (PNG): the NEES plot of Monte Carlo summaries, the paper's figures 1-4 and Fig. 5 (out-of-plane
drift with and without the road-vehicle roll and pitch rate terms; not in the paper).

matplotlib is used through `matplotlib.figure.Figure` with the Agg canvas (no pyplot, no global state, no
display). viz only draws: each figure function takes an output path and the dict computed by
`validation.experiments` (`figN_data`, or `figure_data(N, quick)`) and returns the path written.

Checked by: tests/viz/test_figures.py
"""

from __future__ import annotations

import io
from pathlib import Path

import numpy as np

from rodo.estimator.errors import InputError
from rodo.sim.sequence import atomic_write_bytes
from rodo.validation.consistency import fraction_within
from rodo.validation.covariance import covariance_axes

SAMPLE = "#3b6fd8"  # Monte Carlo samples (blue, as in the paper)
MEAN = "#e0479e"  # prior mean / full model (pink, as in the paper)
BIASED = "#f08a24"  # acceleration ignored (orange)
TRUTH, CV, CA = "black", "#d62728", "#1f5fd6"  # Fig. 4: as in the paper (black, red, blue)


def _figure(w: float, h: float):
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(w, h), dpi=110, layout="constrained")
    FigureCanvasAgg(fig)
    return fig


def save_png(fig, path) -> Path:
    """The figure as PNG at path, written atomically (an interrupted run leaves no half-written figure)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    buf = io.BytesIO()
    fig.savefig(buf, format="png")
    atomic_write_bytes(path, buf.getvalue())
    return path


def ellipse_xy(mean, cov, n_sigma: float = 3.0, n: int = 100) -> np.ndarray:
    """(n, 2) points of the n-sigma ellipse {x : (x - m)^T cov^-1 (x - m) = n_sigma^2} of a 2x2 covariance
    (axes from `validation.covariance.covariance_axes`)."""
    half, V = covariance_axes(cov, n_sigma)
    a = np.linspace(0.0, 2 * np.pi, n)
    circle = np.stack([np.cos(a), np.sin(a)], axis=1)
    return np.asarray(mean, float) + (circle * half) @ V.T


# ------------------------------------------------------------------------------------------------ NEES
def plot_nees(path, t, nees_mean, bounds, labels, title: str = "Normalised estimation error squared",
              ylabel: str = "average NEES", log_scale: bool | None = None) -> Path:
    """Average NEES over time with its chi-square band (Monte Carlo summaries).

    Args:
        path: output PNG.
        t: (N,) times in seconds.
        nees_mean: (N,) or (N, m) mean NEES of m quantities (e.g. the consistency measures of one model, each
            divided by its dof so that they share one band).
        bounds: (lower, upper) scalars or (N,) arrays (e.g. `validation.consistency.chi2_bounds(n_runs, dof)`).
        labels: a label or m labels (with the dof, e.g. "pose (6 dof)").
        title, ylabel: of the axes.
        log_scale: a logarithmic y axis; None: when the curves reach over 20 times the upper bound (an
            overconfident measure would otherwise flatten the others).

    Returns:
        path. The legend gives each series' fraction of time inside the band (about 95 % when consistent);
        columns with no finite value are left out of the plot (e.g. acceleration of a CV model).
    """
    t = np.asarray(t, dtype=float).reshape(-1)
    y = np.asarray(nees_mean, dtype=float)
    y = y[:, None] if y.ndim == 1 else y
    if y.ndim != 2 or y.shape[0] != len(t) or len(t) == 0:
        raise InputError(f"nees_mean: expected shape ({len(t)},) or ({len(t)}, m), got {np.shape(nees_mean)}")
    labels = [labels] if isinstance(labels, str) else list(labels)
    if len(labels) != y.shape[1]:
        raise InputError(f"labels: expected {y.shape[1]} labels, got {len(labels)}")
    try:
        lo, hi = (np.broadcast_to(np.asarray(b, dtype=float), t.shape) for b in bounds)
    except (TypeError, ValueError):
        raise InputError(f"bounds: expected (lower, upper) scalars or ({len(t)},) arrays") from None
    fig = _figure(7.5, 4.0)
    ax = fig.add_subplot()
    ax.fill_between(t, lo, hi, color="0.85", label="95 % chi-square band")
    for j, lab in enumerate(labels):
        if not np.isfinite(y[:, j]).any():
            continue
        inside = fraction_within(y[:, j], np.stack([lo, hi], axis=-1)) * 100
        ax.plot(t, y[:, j], lw=1.3, label=f"{lab}: {inside:.0f} % inside")
    ax.set_xlabel("time (s)")
    ax.set_ylabel(ylabel)
    top = np.nanmax(np.r_[hi, y.ravel()]) if np.isfinite(y).any() else float(np.nanmax(hi))
    if log_scale is None:
        log_scale = bool(np.isfinite(top) and top > 20 * np.nanmax(hi))
    if log_scale:
        floor = np.nanmin(lo) if np.isfinite(lo).any() and np.nanmin(lo) > 0 else 1.0
        ax.set_yscale("log")
        ax.set_ylim(0.05 * floor, 2 * top)  # values far below the band are clipped at the bottom
    else:
        ax.set_ylim(0, 1.1 * top)
    ax.grid(alpha=0.3)
    ax.legend(loc="upper left", fontsize=8)
    ax.set_title(title)
    return save_png(fig, path)


def plot_growth(path, table: list[dict], title: str = "How the error grows, per axis") -> Path:
    """Per axis, E[e^2 / sigma^2] of the relative pose against the span (log-log; the rows of
    `validation.error_growth.growth_table`, spans first, then the drive's absolute pose as markers at the right),
    with the consistent value 1: an axis below it is cautious at that horizon, above it over-confident. Rows
    without a count are left out."""
    spans = [r for r in table if r["ratio"] and r["scans"]]
    drive = next((r for r in table if r["label"] == "drive" and r["ratio"]), None)  # the velocity rows: not plotted
    if not spans and drive is None:
        raise InputError("error growth: no span or drive with a count to plot")
    x = np.array([r["scans"] for r in spans], dtype=float)
    y = np.array([r["ratio"] for r in spans], dtype=float).reshape(len(spans), 6)
    x_drive = 2.0 * x.max() if len(x) else 1.0
    fig = _figure(7.5, 4.0)
    ax = fig.add_subplot()
    ax.axhline(1.0, color="0.3", lw=1.0, ls="--", label="consistent")
    for j, (axis, style) in enumerate(zip(("x", "y", "z", "roll", "pitch", "yaw"), ["-"] * 3 + [":"] * 3)):
        line = ax.plot(x, y[:, j], style, marker="o", ms=3, lw=1.3, label=axis)[0]
        if drive is not None:
            ax.plot([x_drive], [drive["ratio"][j]], marker="s", ms=6, color=line.get_color(), ls="none")
    ax.set_xscale("log")
    ax.set_yscale("log")
    ticks = list(x) + ([x_drive] if drive is not None else [])
    ax.set_xticks(ticks, [r["label"] for r in spans] + (["drive"] if drive is not None else []), fontsize=7)
    ax.minorticks_off()
    ax.set_xlabel("span of the relative pose (the drive's absolute pose at the right)")
    ax.set_ylabel("E[e^2 / sigma^2] per axis")
    ax.grid(alpha=0.3)
    ax.legend(loc="best", fontsize=8, ncol=2)
    ax.set_title(title)
    return save_png(fig, path)


def plot_velocity_growth(path, rows: list[dict]) -> Path:
    """EM's check without ground truth (`validation.velocity_growth.growth_check` rows), one panel per component:
    the mean squared second difference of the estimated velocity against the lag (log-log, points), the fit
    c + q (2/3) lag^3 (solid: growing as lag^3 where the axis random-walks, flat where it is the estimator's error or
    a motion that reverts) and c + q_EM (2/3) lag^3 with EM's Qc (dashed: far above the points where EM books error
    as motion)."""
    from rodo.validation.velocity_growth import growth_kernel

    fig = _figure(10.0, 5.6)
    for ax, r in zip(fig.subplots(2, 3).ravel(), rows):
        ax.set_title(f"{r['component']}" + {True: ": EM outside", False: ": EM inside", None: ""}[r["outside"]],
                     fontsize=9)
        if r["growth"] is None:
            ax.text(0.5, 0.5, "no motion", ha="center", va="center", transform=ax.transAxes)
            ax.set_axis_off()
            continue
        lags = np.asarray(r["lags"], float)
        fine = np.geomspace(lags[0], lags[-1], 60)
        g = growth_kernel("ca", fine)
        ax.plot(lags, r["D"], "o", ms=3.5, color="0.2", label="estimated velocity")
        ax.plot(fine, r["c"] + max(r["growth"], 0.0) * g, "-", color=CA, label=f"fit: q {r['growth']:.2g}")
        ax.plot(fine, r["c"] + r["em"] * g, "--", color=CV, label=f"EM: q {r['em']:.2g}")
        ax.set_xscale("log")
        ax.set_yscale("log")
        ticks = [t for t in (0.5, 1.0, 2.0, 5.0) if lags[0] <= t <= lags[-1] * 1.01]
        ax.set_xticks(ticks, [f"{t:g}" for t in ticks])
        ax.xaxis.set_minor_formatter("")
        ax.set_xlabel("lag (s)", fontsize=8)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7, loc="upper left")
    fig.suptitle("EM's check: the estimated velocity's mean squared second difference against the lag", fontsize=10)
    return save_png(fig, path)


def figure1_prior(path, data: dict) -> Path:
    """Fig. 1: the CA prior under pure yaw acceleration: Monte Carlo samples (blue) and the prior's mean with
    3-sigma ellipses (pink) for position (top view), velocity and acceleration (forward and yaw components)."""
    d = data
    fig = _figure(13.0, 4.3)
    ax_p, ax_v, ax_a = fig.subplots(1, 3, gridspec_kw={"width_ratios": [1.4, 1, 1]})
    for i, t in enumerate(d["t"]):
        s = d["samples_pos"][i]
        ax_p.scatter(s[:, 0], s[:, 1], s=3, color=SAMPLE, alpha=0.35, lw=0,
                     label="Monte Carlo samples" if i == 0 else None)
        e = ellipse_xy(d["mean_pos"][i, :2], d["cov_pos"][i, :2, :2])
        ax_p.plot(e[:, 0], e[:, 1], color=MEAN, lw=1.5, label="prior mean and 3-sigma" if i == 0 else None)
        ax_p.plot(*d["mean_pos"][i, :2], "o", color=MEAN, ms=4)
        ax_p.annotate(f"t = {t:.2f} s", d["mean_pos"][i, :2], textcoords="offset points", xytext=(-10, 12),
                      fontsize=8)
    ax_p.plot(d["mean_path"][:, 0], d["mean_path"][:, 1], color=MEAN, lw=0.8, ls="--", label="mean path")
    ax_p.plot(0, 0, "k^", ms=7, label="start")
    ax_p.set_xlabel("world x (m)")
    ax_p.set_ylabel("world y (m)")
    ax_p.set_aspect("equal", adjustable="datalim")
    ax_p.set_title("position (top view)")
    ax_p.legend(loc="upper left", fontsize=8)
    # vehicle quantities: forward speed v_x = -nu_x, yaw rate w_z = -omega_z (docs/conventions.md)
    for ax, key, title, xl, yl in ((ax_v, "varpi", "velocity", "forward speed -nu_x (m/s)",
                                     "yaw rate -omega_z (rad/s)"),
                                    (ax_a, "varpi_dot", "acceleration", "forward acceleration -nu_dot_x (m/s^2)",
                                     "yaw acceleration -omega_dot_z (rad/s^2)")):
        sel = [0, 5]
        for i, t in enumerate(d["t"]):
            s = -d[f"samples_{key}"][i][:, sel]
            ax.scatter(s[:, 0], s[:, 1], s=3, color=SAMPLE, alpha=0.35, lw=0)
            m = -d[f"mean_{key}"][i][sel]
            e = ellipse_xy(m, d[f"cov_{key}"][i][np.ix_(sel, sel)])
            ax.plot(e[:, 0], e[:, 1], color=MEAN, lw=1.5)
            ax.plot(*m, "o", color=MEAN, ms=4)
            if key == "varpi" or i == 0:
                ax.annotate(f"{t:.2f} s" if key == "varpi" else "all t (constant mean)", m,
                            textcoords="offset points", xytext=(6, 4), fontsize=7)
        ax.set_xlabel(xl)
        ax.set_ylabel(yl)
        ax.set_title(title)
        ax.grid(alpha=0.3)
    c = d["case"]
    fig.suptitle(f"Fig. 1: constant-acceleration prior, pure yaw acceleration {-c['vd0'][5]:.2f} rad/s^2 at "
                 f"{-c['varpi0'][0]:.0f} m/s ({d['samples_pos'].shape[1]} samples per time)", fontsize=11)
    return save_png(fig, path)


# ------------------------------------------------------------------------------------------------ Fig. 2
def figure2_measurement_models(path, data: dict, magnify: float = 5.0) -> Path:
    """Fig. 2: 3-sigma position ellipses (top view) of a simulated scan under the polar model (true polar noise
    propagated to Cartesian) and the fixed Cartesian model; right: 3-sigma semi-axes against range."""
    d = data
    fig = _figure(13.0, 5.0)
    ax, ax_r = fig.subplots(1, 2, gridspec_kw={"width_ratios": [1.5, 1]})
    pts = d["points"]
    ax.scatter(pts[:, 0], pts[:, 1], s=4, color="0.3", zorder=3, label="detections")
    circle = ellipse_xy([0, 0], d["cov_cartesian"][:2, :2])
    for i, p in enumerate(pts):
        e = ellipse_xy(p[:2], d["cov_polar"][i, :2, :2] * magnify**2)
        ax.plot(e[:, 0], e[:, 1], color=CA, lw=0.8, label="polar model" if i == 0 else None)
        ax.plot(p[0] + magnify * circle[:, 0], p[1] + magnify * circle[:, 1], color=CV, lw=0.8,
                label="Cartesian model" if i == 0 else None)
    ax.plot(0, 0, "k^", ms=7, label="sensor")
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_xlabel("sensor x (m)")
    ax.set_ylabel("sensor y (m)")
    ax.set_title(f"3-sigma ellipses of one scan (magnified x{magnify:g})")
    ax.legend(loc="upper left", fontsize=8)
    r = d["ranges"]
    ax_r.plot(r, d["semi_polar"][:, 1], color=CA, label="polar, lateral (3 r sigma_az)")
    ax_r.plot(r, d["semi_polar"][:, 0], color=CA, ls="--", label="polar, radial (3 sigma_r)")
    ax_r.axhline(d["semi_cartesian"], color=CV, label=f"Cartesian (3 x {d['cartesian_sigma']:g} m)")
    ax_r.axvline(d["crossover_range"], color="0.5", ls=":", label=f"crossover r* = {d['crossover_range']:.0f} m")
    ax_r.set_yscale("log")
    ax_r.set_xlabel("range (m)")
    ax_r.set_ylabel("3-sigma semi-axis (m)")
    ax_r.set_title("Cartesian: too large near, too small far")
    ax_r.grid(alpha=0.3, which="both")
    ax_r.legend(fontsize=8, loc="lower right")
    fig.suptitle("Fig. 2: polar vs Cartesian measurement model", fontsize=11)
    return save_png(fig, path)


# ------------------------------------------------------------------------------------------------ Fig. 3
def figure3_association(path, data: dict) -> Path:
    """Fig. 3: association ellipses (azimuth-range, 3-sigma) and radial-velocity pdfs predicted with the
    acceleration (S, pink) and ignoring it (S~ = S + b b^T, orange); correct target pink, distractor orange."""
    d = data
    fig = _figure(12.0, 4.6)
    ax, ax_v = fig.subplots(1, 2)
    k = np.array([1, 0])  # (azimuth, range)
    scale = np.array([np.degrees(1.0), 1.0])
    for z, S, colour, name in ((d["z"], d["S"], MEAN, "with acceleration: S"),
                               (d["z_noacc"], d["S_tilde"], BIASED, "acceleration ignored: S~ = S + b b^T")):
        e = ellipse_xy(z[k] * scale, S[np.ix_(k, k)] * np.outer(scale, scale))
        ax.plot(e[:, 0], e[:, 1], color=colour, lw=1.8, label=name)
        ax.plot(*(z[k] * scale), "+", color=colour, ms=10)
    for det, colour, name, i in ((d["detections"][0], MEAN, "correct target", 0),
                                 (d["detections"][1], BIASED, "distractor", 1)):
        ax.plot(*(det[k] * scale), "x", color=colour, ms=10, mew=2.5,
                label=f"{name}: d2 = {d['d2_full'][i]:.2f} (S), {d['d2_noacc'][i]:.2f} (S~)")
    ax.set_xlabel("azimuth (deg)")
    ax.set_ylabel("range (m)")
    ax.set_title("marginal 3-sigma association ellipses")
    ax.legend(fontsize=7.5, loc="upper left")
    ax.grid(alpha=0.3)
    for z, S, colour, name in ((d["z"], d["S"], MEAN, "p(v_r), full state"),
                               (d["z_noacc"], d["S_tilde"], BIASED, "p(v_r~), acceleration ignored")):
        sd = np.sqrt(S[3, 3])
        v = np.linspace(z[3] - 4 * sd, z[3] + 4 * sd, 300)
        ax_v.plot(v, np.exp(-0.5 * ((v - z[3]) / sd) ** 2) / (sd * np.sqrt(2 * np.pi)), color=colour, lw=1.8,
                  label=name)
    for det, colour in ((d["detections"][0], MEAN), (d["detections"][1], BIASED)):
        ax_v.axvline(det[3], color=colour, ls=":", lw=1.5)
    ax_v.set_xlabel("radial velocity (m/s)")
    ax_v.set_ylabel("probability density (s/m)")
    ax_v.set_title(f"bias b_vr = {d['bias'][3]:+.3f} m/s")
    ax_v.legend(fontsize=8)
    ax_v.grid(alpha=0.3)
    fig.suptitle(f"Fig. 3: unmodelled yaw acceleration {d['yaw_accel']:.2f} rad/s^2 over dt = {d['dt']*1e3:.0f} ms "
                 f"(azimuth bias {np.degrees(d['bias'][1]):.3f} deg)", fontsize=11)
    return save_png(fig, path)


# ------------------------------------------------------------------------------------------------ Fig. 4
def figure4_trajectories(path, data: dict) -> Path:
    """Fig. 4: ground truth (black), CV/C (red) and CA/P (blue) trajectories: top view and height over the
    distance travelled (`validation.experiments.fig4_data`)."""
    d = data
    fig = _figure(12.0, 4.8)
    ax, ax_h = fig.subplots(1, 2, gridspec_kw={"width_ratios": [1.2, 1]})
    err = d["final_error"]
    for key, colour, name in (("truth", TRUTH, "ground truth"),
                              ("cv", CV, f"CV/C (final error {err['cv-cartesian']:.2f} m)"),
                              ("ca", CA, f"CA/P (final error {err['ca-polar']:.2f} m)")):
        p = d[key]
        ax.plot(p[:, 0], p[:, 1], color=colour, lw=1.4, label=name)
        ax_h.plot(d["distance"], p[:, 2], color=colour, lw=1.4, label=name)
    ax.plot(*d["truth"][0, :2], "k^", ms=7)
    span = np.ptp(d["truth"][:, :2], axis=0)
    if span.min() > 0.1 * span.max():
        ax.set_aspect("equal", adjustable="datalim")
    else:  # a nearly straight route: equal axes would hide the lateral drift
        ax.set_title("top view (axes not to scale)")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    if not ax.get_title():
        ax.set_title("top view")
    ax.legend(fontsize=8)
    ax.grid(alpha=0.3)
    ax_h.set_xlabel("distance travelled (m)")
    ax_h.set_ylabel("height z (m)")
    ax_h.set_title("height over distance")
    ax_h.grid(alpha=0.3)
    fig.suptitle(f"Fig. 4: odometry on simulated '{d['scenario']}' (seed {d['seed']}, {d['duration']:.0f} s, "
                 f"{d['path_length']:.0f} m)", fontsize=11)
    return save_png(fig, path)


def figure5_out_of_plane(path, data: dict) -> Path:
    """Fig. 5 (ours, not the paper's): z, roll and pitch drift over the distance travelled, CV/C (red) and CA/P
    (blue), solid with the road-vehicle roll and pitch rate terms (the default), dashed without them
    (`validation.experiments.fig5_data`)."""
    d = data
    fig = _figure(12.0, 7.0)
    axes = fig.subplots(3, 1, sharex=True)
    for column, (ax, label, unit) in enumerate(zip(axes, ("z", "roll", "pitch"), ("m", "deg", "deg"))):
        for name, series in d["runs"].items():
            colour = CA if name.startswith("CA/P") else CV
            ax.plot(d["distance"], series[:, 2 + column], color=colour, lw=1.4,
                    ls="--" if "no roll/pitch" in name else "-",
                    label=f"{name} (final {d['final'][name][label]:+.2f} {unit})")
        ax.axhline(0.0, color=TRUTH, lw=0.8)
        ax.set_ylabel(f"{label} error ({unit})")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7, loc="upper left")
    axes[-1].set_xlabel("distance travelled (m)")
    fig.suptitle(f"Fig. 5: out-of-plane drift on simulated '{d['scenario']}' (seed {d['seed']}, "
                 f"{d['duration']:.0f} s, {d['path_length']:.0f} m): solid with the roll and pitch rate terms, "
                 "dashed without", fontsize=10)
    return save_png(fig, path)


FIGURES = ((1, "fig1_prior.png", figure1_prior), (2, "fig2_measurement_models.png", figure2_measurement_models),
           (3, "fig3_association.png", figure3_association), (4, "fig4_trajectories.png", figure4_trajectories),
           (5, "fig5_out_of_plane.png", figure5_out_of_plane))


def write_all(out_dir, data: dict) -> list[Path]:
    """Draw the figures whose data is given into out_dir: data[N] is the dict of `validation.experiments`
    for figure N (1-5, the paper's 1-4 and our Fig. 5); returns the paths written, in figure order.

    Checked by: tests/viz/test_figures.py::test_write_all_draws_the_figures_it_is_given
    """
    unknown = sorted(set(data) - {number for number, _, _ in FIGURES})
    if unknown:
        raise InputError(f"data: no figure {unknown} (figures 1-5)")
    out = Path(out_dir)
    return [draw(out / name, data[number]) for number, name, draw in FIGURES if number in data]
