"""The CA prior's jerk PSD from how the estimated velocity grows over seconds: a check on EM without ground truth.

Over a lag tau the second difference of a velocity track, d = v(t + 2 tau) - 2 v(t + tau) + v(t), has the variance

    CA (white jerk of PSD q):         (2/3) q tau^3
    CV (white acceleration of PSD q):  2 q tau

(exact for point samples of the prior's SDE, whose velocity part is linear; tests/validation/test_velocity_growth.py
checks g against the propagated covariance). The estimator's own velocity error,
bounded however correlated, adds a constant c once tau is past its correlation time, so over lags of 0.5-5 s
D(tau) = E[d^2] = c + q g(tau) gives q free of that error, which EM books as motion (docs/calibration.md, "Without
ground truth"). It is far less precise than EM where EM is right: only the seconds-long lags count, so a 30 s drive
holds a few independent samples of each (its 99 % interval spans a factor 7 on the forward axis there, two to four
orders of magnitude on the weakly excited ones). What it does is catch EM where it runs away, as on a 60 s drive of
`prior_ca_points` at seed 3, where EM stopped at 2.3-25 x the simulator's Qc (11-25 x in y, z, roll and pitch) while
this estimate was within 0.8-1.9 x in all six: five of the six are flagged. It tests the CA prior's random walk over
seconds, which a car's roll and pitch do not follow (they revert): on a 180 s city drive it flags EM's roll and pitch,
near the truth's maximum-likelihood one-step values, as well as its lateral and vertical ones, which are the
estimator's error. The CV prior is not checked: its velocity's
second difference grows only linearly with the lag, as a correlated error's does over a few of its correlation
times, and on 60 s drives the two do not come apart.

The interval is a delete-a-block jackknife over `BLOCKS` contiguous stretches of the drive (the squared differences
overlapping a stretch left out), Student-t with BLOCKS - 1 degrees of freedom, on ln q where every replicate is
positive, else on q with no lower bound. Differences spanning a re-initialisation are left out; lags count scans
at the median scan interval (a recording with jittered scan times is taken as evenly spaced).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.stats import t as student_t

from rodo.estimator.errors import InputError

from .calibrate import COMPONENTS, StateTrack

LAGS = (0.5, 5.0)  # s: from past the estimator's error correlation (0.3-2 s where measured) to a sixth of a drive
N_LAGS = 12
BLOCKS = 8
LEVEL = 0.99  # per component: a check over six flags a right EM on about one drive in twenty


@dataclass(frozen=True)
class VelocityGrowth:
    """q (6,) per component (NaN where the track does not move on that axis, e.g. a planar radar's z, roll and
    pitch), its interval lo, hi (6,) at `LEVEL`, the lags used (s), the mean squared second differences D (lags, 6)
    and the fitted constant c (6,): D ~ c + q g(lag)."""

    qc: np.ndarray
    lo: np.ndarray
    hi: np.ndarray
    lags: np.ndarray
    D: np.ndarray
    c: np.ndarray


def growth_kernel(kind: str, tau) -> np.ndarray:
    """g(tau): E[d^2] = q g(tau) for the prior `kind` ("ca", "cv")."""
    tau = np.asarray(tau, dtype=float)
    if kind == "ca":
        return (2.0 / 3.0) * tau**3
    if kind == "cv":
        return 2.0 * tau
    raise InputError(f"kind: expected 'ca' or 'cv', got {kind!r}")


def _squared_differences(track: StateTrack, m: int) -> tuple[np.ndarray, np.ndarray]:
    """(d^2 (n, 6), first index k (n,)) of the second differences over m scans that span no re-initialisation."""
    v = track.varpi
    broken = np.r_[0, np.cumsum(~np.asarray(track.valid, bool))] if track.valid is not None else np.zeros(len(v))
    k = np.arange(len(v) - 2 * m)
    keep = broken[k + 2 * m] == broken[k]
    d = v[k + 2 * m] - 2.0 * v[k + m] + v[k]
    return d[keep] ** 2, k[keep]


def _fit(D: np.ndarray, g: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(c, q) of D = c + q g per column (c >= 0: refitted without c where it comes out negative), weighted least
    squares (weights 1 / model^2: a mean of squares' variance grows with its mean squared), iterated."""
    c, q = np.full(D.shape[1], np.nan), np.full(D.shape[1], np.nan)
    for i in range(D.shape[1]):
        y = D[:, i]
        if not np.all(np.isfinite(y)) or np.max(y) <= 0:
            continue
        for A in (np.column_stack([np.ones_like(g), g]), g[:, None]):
            model = y
            for _ in range(5):
                w = 1.0 / np.maximum(model, 1e-12 * np.max(y))
                x = np.linalg.lstsq(A * w[:, None], y * w, rcond=None)[0]
                model = A @ x
            if len(x) == 1 or x[0] >= 0:
                break
        c[i], q[i] = (x[0] if len(x) == 2 else 0.0), x[-1]
    return c, q


def velocity_growth(track: StateTrack, kind: str, lags=LAGS, blocks: int = BLOCKS) -> VelocityGrowth:
    """q per component from the growth of `track.varpi`'s second differences over `lags` (s). The CA prior only:
    under the CV prior the velocity's second difference grows only linearly with the lag, as a correlated error's
    does over a few of its correlation times, and on 60 s drives the two do not come apart (tests/validation/
    test_velocity_growth.py)."""
    if kind != "ca":
        raise InputError(f"velocity growth: checks the CA prior's jerk PSD only, not the {kind.upper()} prior's "
                         "(docs/calibration.md, \"EM's check\")")
    dt = float(np.median(np.diff(track.t)))
    span = float(track.t[-1] - track.t[0])
    top = min(lags[1], span / 6.0)
    ms = np.unique(np.round(np.geomspace(lags[0] / dt, top / dt, N_LAGS)).astype(int))
    ms = ms[ms >= 1]
    if top < 2 * lags[0] or len(ms) < 3:  # lags over a factor of two at least
        raise InputError(f"velocity growth: the track spans {span:.3g} s; lags from {lags[0]:g} s need at least "
                         f"{12 * lags[0]:g} s")
    g = growth_kernel(kind, ms * dt)
    diffs = [_squared_differences(track, int(m)) for m in ms]
    if min(len(k) for _, k in diffs) < 2 * blocks:
        raise InputError("velocity growth: too few second differences between re-initialisations")
    moving = np.max(np.abs(track.varpi - track.varpi[0]), axis=0) > 0
    D = np.array([d2.mean(axis=0) for d2, _ in diffs])
    D[:, ~moving] = np.nan
    c, q = _fit(D, g)
    edges = np.linspace(0, len(track.t), blocks + 1)
    replicates = []
    for b in range(blocks):
        Db = []
        for (d2, k), m in zip(diffs, ms):
            out = (k + 2 * m >= edges[b]) & (k < edges[b + 1])
            Db.append(d2[~out].mean(axis=0))
        Db = np.array(Db)
        Db[:, ~moving] = np.nan
        replicates.append(_fit(Db, g)[1])
    lo, hi = _intervals(q, np.array(replicates), blocks)
    return VelocityGrowth(q, lo, hi, ms * dt, D, c)


def _intervals(q: np.ndarray, reps: np.ndarray, blocks: int) -> tuple[np.ndarray, np.ndarray]:
    """The jackknife interval per component: on ln q where q and every replicate are positive, else on q (lower
    bound 0)."""
    z = student_t.ppf(0.5 + LEVEL / 2, blocks - 1)
    jack = np.sqrt((blocks - 1) / blocks)
    lo, hi = np.full_like(q, np.nan), np.full_like(q, np.nan)
    for i in np.flatnonzero(np.isfinite(q)):
        r = reps[:, i]
        if q[i] > 0 and np.all(r > 0):
            se = jack * np.sqrt(np.sum((np.log(r) - np.log(r).mean()) ** 2))
            lo[i], hi[i] = q[i] * np.exp(-z * se), q[i] * np.exp(z * se)
        else:
            se = jack * np.sqrt(np.sum((r - r.mean()) ** 2))
            lo[i], hi[i] = 0.0, max(q[i], 0.0) + z * se
    return lo, hi


def growth_check(qc, growth: VelocityGrowth) -> list[dict]:
    """Per component: EM's q, the growth's q and interval, and whether EM's lies outside it (None: not moving)."""
    rows = []
    for name, em, q, lo, hi in zip(COMPONENTS, np.asarray(qc, float), growth.qc, growth.lo, growth.hi):
        fitted = bool(np.isfinite(q))
        rows.append({"component": name, "em": float(em), "growth": float(q) if fitted else None,
                     "interval": [float(lo), float(hi)] if fitted else None,
                     "outside": bool(em < lo or em > hi) if fitted else None})
    for r, c, D in zip(rows, growth.c, growth.D.T):  # what the figure draws: D over the lags, and the fit's c
        r.update(lags=growth.lags.tolist(), D=D.tolist() if r["growth"] is not None else None,
                 c=float(c) if r["growth"] is not None else None)
    return rows


def growth_figure_path(out: Path) -> Path:
    """The figure of EM's check beside a calibration's CONFIG.toml: CONFIG_growth.png."""
    return Path(out).with_name(Path(out).stem + "_growth.png")


def growth_check_header(rows, learned: list[str]) -> list[str]:
    """The config header's line naming the learned components outside their interval (none: no line; `rows` a
    reason string where the drive was not checked)."""
    off = [r["component"] for r in (rows if isinstance(rows, list) else [])
           if r["outside"] and r["component"] in learned]
    return [f"CHECK: EM's {', '.join(off)} lie outside the interval the estimated velocity's growth over seconds "
            "gives (the .md report and _growth.png; docs/calibration.md, \"EM's check\")."] if off else []


def growth_check_lines(rows: list[dict] | str | None, learned: list[str]) -> list[str]:
    """The check as a Markdown table, and a line naming the learned components outside their interval (`rows` a
    reason string where the drive was not checked: that line; None: nothing)."""
    if not isinstance(rows, list):
        return [] if rows is None else [rows]
    lines = [f"The jerk PSD from the estimated velocity's growth over {LAGS[0]:g}-{LAGS[1]:g} s "
             f"({LEVEL:.0%} interval; docs/calibration.md, \"EM's check\"):", "",
             "| component | EM | from the velocity's growth | interval | EM outside |",
             "| --- | --- | --- | --- | --- |"]
    for r in rows:
        em = f"{r['em']:.3g}" + ("" if r["component"] in learned else " (not learned)")
        if r["growth"] is None:
            lines.append(f"| {r['component']} | {em} | - (no motion) | - | - |")
            continue
        lo, hi = r["interval"]
        verdict = "-" if r["component"] not in learned else "**yes**" if r["outside"] else "no"
        lines.append(f"| {r['component']} | {em} | {r['growth']:.3g} | {lo:.3g} - {hi:.3g} | {verdict} |")
    off = [r["component"] for r in rows if r["outside"] and r["component"] in learned]
    lines += ["", f"EM's value lies outside the velocity's growth for {', '.join(off)}: there EM books the "
              "estimator's own error as motion, stays near the base config where the drive says little, or the "
              "motion does not random-walk over seconds (a car's roll and pitch, which revert: EM's value may then "
              "be right for a scan's step, and the check cannot tell). Take these from a reference (or from this "
              "estimate where its interval is narrow enough) and --learn only the components that agree." if off else
              "EM's value lies inside the velocity's growth interval in every learned component."]
    return lines
