"""The paper's Table I on the simulated suite: KITTI drift and runtime of CV/C and CA/P per scenario and overall.

Per scenario, N seeded trials (one `run_campaign` per scenario, in DIR/<scenario>/, resumable) run both models on
the same simulated sequence. The table then reports, per scenario and model:

- distance: the mean ground-truth path length of the runs (km);
- translational error (%) and rotational error (deg/m): the KITTI devkit means (validation/kitti.py) over all
  (first frame, length) segments of all runs of the scenario, pooled as the devkit pools segments over
  sequences: t_err = 100 * mean(|t(E)| / L), r_err = mean(angle(E) / L) in deg/m;
- runtime: the median over all scans of all runs of the wall time per scan (ms).

The "overall" row pools the segments of every scenario (as the paper's overall row is over all 70 km) and takes
the median over every scan of every run.

Segment lengths: the devkit's 100, 200, ..., 800 m (`kitti.LENGTHS`). A scenario in which some run of some model
has no 100 m segment (its path is shorter than 100 m, e.g. `blockage`, or any scenario cut short by --duration)
is evaluated with the lengths divided by ten (10, 20, ..., 80 m, `SHORT_LENGTHS`) and marked with a footnote;
if even those give no segment its errors are n/a. Drift over 10-80 m is not comparable with drift over
100-800 m (a fixed error is a larger fraction of a shorter length), so the overall row pools only scenarios on
the standard lengths; when no scenario reaches 100 m it pools the short-length ones and says so.

The better (lower) of CV/C and CA/P is bold per column, as in the paper; equal printed values are both bold.

Every trial saves, next to the campaign's per-scan arrays, `kitti_segments` (k, 4) and `kitti_segments_short`
(k, 4) rows [first frame, length m, t_err (fraction), r_err (rad/m)] and `path_length_m` (`Table1Trial`).

Checked by: tests/validation/test_table1.py
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from rodo.estimator.errors import InputError
from rodo.sim.sequence import atomic_write_bytes

from .campaign import npz_path, read_results
from .campaign_files import load_trial_arrays
from .trial import ScenarioTrial
from .kitti import LENGTHS, kitti_errors
from .metrics import jsonable

SCENARIOS = ("city", "highway", "hills", "stop_and_go", "blockage")
MODELS = ("cv-cartesian", "ca-polar")  # the paper's CV/C baseline and its CA/P method, in the paper's order
LABELS = {"cv-cartesian": "CV/C", "ca-polar": "CA/P"}
SHORT_LENGTHS = tuple(L / 10.0 for L in LENGTHS)
STANDARD, SHORT, NA = "standard", "short", "n/a"


@dataclass(frozen=True)
class Table1Trial(ScenarioTrial):
    """A campaign trial (picklable): `validation.trial.ScenarioTrial` on the standard KITTI lengths, plus
    the per-segment KITTI arrays on both length sets and the path length, which the table needs to pool
    segments over runs (the campaign stores only per-run means)."""

    def extra_arrays(self, gt, result) -> dict:
        return segment_arrays(gt, result.trajectory(), self.step)


def segment_arrays(gt, est, step: int = 10) -> dict:
    """KITTI segments of `est` against `gt` (Trajectory-like: t, T_world_vehicle) on both length sets.

    Returns:
        dict: kitti_segments (k, 4), kitti_segments_short (m, 4) [first, length, t_err, r_err], path_length_m.
    """
    from .association import associate
    from .metrics import path_distances

    ig, ie = associate(gt.t, est.t)
    G, E = gt.T_world_vehicle[ig], est.T_world_vehicle[ie]
    return {"kitti_segments": kitti_errors(G, E, LENGTHS, step).segments,
            "kitti_segments_short": kitti_errors(G, E, SHORT_LENGTHS, step).segments,
            "path_length_m": float(path_distances(G)[-1])}


def _pooled(segments: list[np.ndarray]) -> tuple[float, float, int]:
    seg = np.concatenate([s.reshape(-1, 4) for s in segments]) if segments else np.zeros((0, 4))
    if not len(seg):
        return float("nan"), float("nan"), 0
    return float(seg[:, 2].mean() * 100), float(np.rad2deg(seg[:, 3].mean())), len(seg)


def _median(arrays: list[np.ndarray]) -> float:
    x = np.concatenate([np.ravel(a) for a in arrays]) if arrays else np.zeros(0)
    x = x[np.isfinite(x)]
    return float(np.median(x)) if x.size else float("nan")


def _check_runs(runs: list[dict]) -> None:
    need = ("scenario", "model", "path_length_m", "kitti_segments", "kitti_segments_short", "ms_per_scan")
    for i, r in enumerate(runs):
        missing = [k for k in need if k not in r]
        if missing:
            raise InputError(f"runs[{i}]: missing field(s) {', '.join(missing)}")
        if r["model"] not in MODELS:
            raise InputError(f"runs[{i}].model: expected one of {', '.join(MODELS)}, got {r['model']!r}")
        for k in ("kitti_segments", "kitti_segments_short"):
            a = np.asarray(r[k], dtype=float)
            if a.size and (a.ndim != 2 or a.shape[1] != 4):
                raise InputError(f"runs[{i}].{k}: expected (k, 4) segment rows, got shape {a.shape}")


def build_table(runs: list[dict], scenarios_order=None) -> dict:
    """Table I from per-run records (module docstring: pooling, length sets, overall row).

    Args:
        runs: one dict per ok (trial, model) run: scenario, model ("cv-cartesian" or "ca-polar"),
            path_length_m, kitti_segments (k, 4), kitti_segments_short (m, 4), ms_per_scan (n,).
        scenarios_order: row order (default: order of first appearance).

    Returns:
        dict with `rows` (one per scenario, then "overall"), each: scenario, lengths (standard/short/n/a),
        distance_km, runs, and per model label (CV/C, CA/P): t_err_pct, r_err_deg_per_m, ms_per_scan,
        segments, runs; and `best`: per row and column the bold label(s).

    Checked by: tests/validation/test_table1.py::test_build_table_*
    """
    _check_runs(runs)
    order = list(scenarios_order) if scenarios_order else list(dict.fromkeys(r["scenario"] for r in runs))
    rows, pooled_std, pooled_short, ms_all = [], {}, {}, {}
    for sc in order:
        mine = [r for r in runs if r["scenario"] == sc]
        by_model = {m: [r for r in mine if r["model"] == m] for m in MODELS}
        have_all = all(by_model[m] for m in MODELS)
        kind = NA
        if have_all and all(len(r["kitti_segments"]) for r in mine):
            kind, key = STANDARD, "kitti_segments"
        elif have_all and all(len(r["kitti_segments_short"]) for r in mine):
            kind, key = SHORT, "kitti_segments_short"
        # distance: mean path length over the trials (both models drive the same path: count each trial once)
        dist = [float(r["path_length_m"]) for r in by_model[MODELS[0]] or by_model[MODELS[1]]]
        row = {"scenario": sc, "lengths": kind, "distance_km": float(np.mean(dist)) / 1e3 if dist else float("nan"),
               "runs": len(dist)}
        for m in MODELS:
            rs = by_model[m]
            t, r_, n = _pooled([np.asarray(r[key], float) for r in rs]) if kind != NA else (float("nan"),) * 2 + (0,)
            ms = [np.asarray(r["ms_per_scan"], float) for r in rs]
            row[LABELS[m]] = {"t_err_pct": t, "r_err_deg_per_m": r_, "segments": n,
                              "ms_per_scan": _median(ms), "runs": len(rs)}
            ms_all.setdefault(m, []).extend(ms)
            if kind == STANDARD:
                pooled_std.setdefault(m, []).extend(np.asarray(r[key], float) for r in rs)
            elif kind == SHORT:
                pooled_short.setdefault(m, []).extend(np.asarray(r[key], float) for r in rs)
        rows.append(row)
    pooled, okind = (pooled_std, STANDARD) if pooled_std else (pooled_short, SHORT) if pooled_short else ({}, NA)
    means = [r["distance_km"] for r in rows if np.isfinite(r["distance_km"])]
    overall = {"scenario": "overall", "lengths": okind, "distance_km": float(np.sum(means)),
               "total_km_all_runs": float(sum(r["distance_km"] * r["runs"] for r in rows if r["runs"])),
               "runs": int(sum(r["runs"] for r in rows)),
               "pooled_scenarios": [r["scenario"] for r in rows if r["lengths"] == okind] if okind != NA else []}
    for m in MODELS:
        t, r_, n = _pooled(pooled.get(m, []))
        overall[LABELS[m]] = {"t_err_pct": t, "r_err_deg_per_m": r_, "segments": n,
                              "ms_per_scan": _median(ms_all.get(m, [])),
                              "runs": int(sum(row[LABELS[m]]["runs"] for row in rows))}
    rows.append(overall)
    for row in rows:
        row["best"] = {k: _best(row, k) for k in ("t_err_pct", "r_err_deg_per_m", "ms_per_scan")}
    return {"models": {LABELS[m]: m for m in MODELS}, "rows": rows, "lengths_standard_m": list(LENGTHS),
            "lengths_short_m": list(SHORT_LENGTHS)}


FORMATS = {"t_err_pct": "{:.2f}", "r_err_deg_per_m": "{:.4f}", "ms_per_scan": "{:.1f}"}


def _best(row: dict, key: str) -> list[str]:
    """Labels whose printed value is the lowest (both when they print equal); [] when either is missing."""
    vals = {LABELS[m]: row[LABELS[m]][key] for m in MODELS}
    if not all(np.isfinite(v) for v in vals.values()):
        return []
    printed = {k: float(FORMATS[key].format(v)) for k, v in vals.items()}
    lo = min(printed.values())
    return [k for k, v in printed.items() if v == lo]


def _fmt(fmt: str, v: float) -> str:
    return fmt.format(v) if np.isfinite(v) else "n/a"


def render_markdown(table: dict, title: str = "Table I (simulated suite)") -> str:
    """The table as markdown: columns as the paper's Table I, the better value of each pair in **bold**."""
    labels = [LABELS[m] for m in MODELS]
    head = ["Sequence", "Dist. (km)", "Runs"]
    for name in ("t. err (%)", "r. err (deg/m)", "runtime (ms)"):
        head += [f"{name} {lab}" for lab in labels]
    lines = [f"# {title}", "", "| " + " | ".join(head) + " |", "| --- | " + " | ".join(["---:"] * (len(head) - 1))
             + " |"]
    notes = {SHORT: "†", NA: "‡"}
    for row in table["rows"]:
        name = row["scenario"]
        if row["lengths"] in notes:
            name += " " + notes[row["lengths"]]
        cells = [f"**{name}**" if name.startswith("overall") else name, _fmt("{:.3f}", row["distance_km"]),
                 str(row["runs"])]
        for key in ("t_err_pct", "r_err_deg_per_m", "ms_per_scan"):
            for lab in labels:
                v = row[lab][key]
                text = _fmt(FORMATS[key], v)
                cells.append(f"**{text}**" if lab in row["best"][key] else text)
        lines.append("| " + " | ".join(cells) + " |")
    overall = table["rows"][-1]
    lines += ["", "Errors: KITTI devkit means over all (first frame, length) segments of all runs of a row, pooled; "
                  "runtime: median over all scans of all runs (wall time per scan, single BLAS thread, measured "
                  "inside a worker pool: compare the two models, not with the paper's hardware).",
              f"Segment lengths {', '.join(f'{L:g}' for L in LENGTHS)} m unless marked. "
              f"† path shorter than 100 m in some run: lengths {', '.join(f'{L:g}' for L in SHORT_LENGTHS)} m "
              "(not comparable with the 100-800 m rows). ‡ no segment at all (path shorter than 10 m): n/a.",
              f"Overall: errors pooled over the segments of {', '.join(overall['pooled_scenarios']) or 'no row'} "
              f"({overall['lengths']} lengths); distance: the suite's length (sum of the rows' mean distances; "
              f"{overall['total_km_all_runs']:.3f} km over all runs); runtime: the median over every scan.", ""]
    return "\n".join(lines)


def load_runs(out_dir, scenarios_order) -> list[dict]:
    """Per-run records of the ok rows of DIR/<scenario>/results.csv with their trials/*.npz arrays."""
    runs = []
    for sc in scenarios_order:
        d = Path(out_dir) / sc
        for r in read_results(d / "results.csv"):
            if r["status"] != "ok" or r["model"] not in MODELS:
                continue
            p = npz_path(d, int(r["trial"]), r["model"])
            if not p.exists():
                raise InputError(f"{p}: missing trial arrays for the ok row of trial {r['trial']} ({r['model']})")
            z = load_trial_arrays(p)
            if "kitti_segments" not in z:
                raise InputError(f"{p}: no kitti_segments array (written by another campaign than rodo table1?)")
            runs.append({"scenario": sc, "model": r["model"], "trial": int(r["trial"]),
                         "path_length_m": float(z["path_length_m"]),
                         "kitti_segments": z["kitti_segments"], "kitti_segments_short": z["kitti_segments_short"],
                         "ms_per_scan": z["ms_per_scan"]})
    return runs


def write_table(out_dir, table: dict, meta: dict | None = None) -> str:
    """Write DIR/table1.md and DIR/table1.json; returns the markdown."""
    out = Path(out_dir)
    text = render_markdown(table)
    if meta:
        text += "Parameters: " + ", ".join(f"{k}={v}" for k, v in sorted(meta.items())) + "\n"
    atomic_write_bytes(out / "table1.md", text.encode())
    meta_table = jsonable({**table, "parameters": meta or {}})
    atomic_write_bytes(out / "table1.json", (json.dumps(meta_table, indent=1) + "\n").encode())
    return text
