"""The consistency verdict: CA/P against CV/C, each at the noise `rodo calibrate` learned for it, judged by issue
15's acceptance criteria (docs/consistency.md, "The verdict with everything learned").

`rodo verdict` (rodo/commands/verdict.py) produces, per scenario S, a calibration drive, the two learned configs
and a campaign of both; this module reads them back and builds the verdict:

- accuracy: the KITTI translational error (%) per model, mean with its 95 % Student-t interval over the trials,
  and the paired difference CA/P - CV/C over the trials both have (`campaign_compare`);
- consistency: per model and measure (`odometry_consistency.MEASURES`) the campaign summary's mean NEES per dof
  and share of scans whose N-run average lies inside its 95 % bounds;
- the criteria: a "cell" (a model's velocity or one-scan relative pose on a scenario) meets the scan-by-scan
  criterion when at least `SHARE_TARGET` of its scans are inside; the relative pose over the span and the
  absolute pose meet theirs when their mean NEES per dof is at most `SPAN_LIMIT`;
- the 3-sigma ellipsoids: the mean over the runs of the % of scans whose true position lies inside;
- what was learned: the uncertainty terms of each config that set its reported covariances (`stationary`: the
  axes of its bounded error per axis, `estimator.stationary_error`), and the scans its calibration left out as
  gross failures (`gross_failures`).

Checked by: tests/validation/test_verdict.py
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from rodo.estimator.errors import InputError
from rodo.sim.sequence import atomic_write_bytes

from .campaign_compare import mean_interval, paired
from .campaign_files import read_results
from .error_growth import AXES
from .gross_failures import GROSS_NEES_PER_DOF
from .metrics import jsonable

MODELS = {"CA/P": ("ca-learned", "ca-polar", "ca"), "CV/C": ("cv-learned", "cv-cartesian", "cv")}  # label, model, file
# rodo calibrate's --floor per model (file key), x,y,z,roll,pitch,yaw. CA's Qc is a jerk PSD, CV's an acceleration
# PSD: the same number is a stiffer prior on the CA model's rates. CA/P's roll and pitch at 3e-4 let its rates follow
# the profiles' pitch and roll bumps (docs/consistency.md, "The floor per model").
FLOORS = {"ca": "1e-4,1e-4,1e-4,3e-4,3e-4,1e-4", "cv": "1e-4"}
SCENARIOS = ("city", "hills", "stop_and_go", "highway")
CELLS = ("velocity", "relative_scan")  # judged scan by scan
SPANS = ("relative_span", "pose")  # judged by their mean
OUTSIDE = ("scans_below", "scans_above", "scans_above_one_run")  # where a cell's scans miss (campaign_consistency)
GROWTH_ROWS = ("velocity", "1 s", "5 s", "drive")  # the error growth's rows a verdict shows per cell (`error_growth`)
SHARE_TARGET = 0.90
SPAN_LIMIT = 2.0
LEARNED = ("velocity_correlation_time", "velocity_error_share", "velocity_error_share_per_speed",
           "registration_correlation", "axis_correlation", "inflation", "inflation_per_pull", "velocity_inflation",
           "yaw_rate_lag", "stationary", "vehicle_rates", "gross_failures")


def config_path(out_dir, scenario: str, name: str) -> Path:
    """DIR/calibration/<scenario>_<ca|cv>.toml, the learned config of model `name` ("CA/P" or "CV/C")."""
    return Path(out_dir) / "calibration" / f"{scenario}_{MODELS[name][2]}.toml"


def _learned(path: Path) -> dict:
    from rodo.estimator.config import OdometryConfig

    config = OdometryConfig.from_toml(path)
    u, v = config.uncertainty, config.vehicle
    derived = {"vehicle_rates": [f"{v.sigma_roll_rate:.3g}", f"{v.sigma_pitch_rate:.3g}"],  # roll + pitch, rad/s
               "yaw_rate_lag": u.velocity_lag_per_yaw_acceleration[5],  # CV/C's lag behind a turn (s)
               "axis_correlation": [f"{a} {x:g}" for a, x in zip(AXES, u.registration_axis_correlation) if x],
               "stationary": [f"{a} {T:g} s" for a, V, T in zip(AXES, u.stationary_variance, u.stationary_time) if V],
               "gross_failures": _gross_failures(path.with_suffix(".json"))}
    return {k: derived[k] if k in derived else getattr(u, k) for k in LEARNED}


def _gross_failures(report: Path) -> list[int] | None:
    """[velocity, one scan]: the scans the calibration's velocity and one-scan fits left out as gross failures
    (`gross_failures`; its report CONFIG.json), None where the report has no such count (written before them)."""
    try:
        c = json.loads(report.read_text(encoding="utf-8"))["consistency"]
        return [int(c["velocity_inflation"]["gross_failures"]["scans"]), int(c["relative_inflation"]["gross_failures"])]
    except (OSError, ValueError, KeyError, TypeError):
        return None


def scenario_verdict(out_dir, scenario: str) -> dict:
    """The verdict's row of one scenario from DIR/<scenario>/summary.json, results.csv and the two configs."""
    camp = Path(out_dir) / scenario
    path = camp / "summary.json"
    if not path.is_file():
        raise InputError(f"{path}: not found (the campaign of {scenario} has not finished); run `rodo verdict` "
                         "again with --resume")
    summary = json.loads(path.read_text())
    rows = read_results(camp / "results.csv")
    row = {"scenario": scenario, "models": {}}
    for name, (label, _, _) in MODELS.items():
        entry = summary["models"].get(label)
        if entry is None:
            raise InputError(f"{path}: no model {label!r} (a campaign of another command?)")
        ok = [float(r["kitti_t_err_pct"]) for r in rows if r["model"] == label and r["status"] == "ok"
              and r["kitti_t_err_pct"] not in ("", "None")]
        mean, lo, hi = mean_interval(np.array(ok, dtype=float))
        coverage = entry["metrics"].get("ellipsoid_3sigma_pct", {}).get("mean")
        row["models"][name] = {
            "runs": entry["runs"], "ok": entry["ok"], "kitti_t_err_pct": {"mean": mean, "lower": lo, "upper": hi,
                                                                         "n": int(np.isfinite(ok).sum())},
            "consistency": {m: {k: c[k] for k in ("mean_per_dof", "fraction_scans_within", "mean_interval_per_dof",
                                                  *OUTSIDE) if k in c}
                            for m, c in entry["consistency"].items() if c["runs"]},
            "gross_failure_runs": entry.get("gross_failure_runs", []),
            "ellipsoid_3sigma_pct": coverage, "learned": _learned(config_path(out_dir, scenario, name)),
            "error_growth": {r["label"]: r["ratio"] for r in (entry.get("error_growth") or {}).get("table", [])}}
    row["paired_kitti_t_err_pct"] = paired(rows, "kitti_t_err_pct", MODELS["CA/P"][0], MODELS["CV/C"][0])
    return row


def judge(rows: list[dict]) -> dict:
    """The criteria over the scenarios' rows: every cell with its share and whether it meets SHARE_TARGET, every
    span measure with its mean and whether it meets SPAN_LIMIT, and the counts."""
    cells, spans = [], []
    for row in rows:
        for name, m in row["models"].items():
            for measure in CELLS:
                c = m["consistency"].get(measure, {})
                share = c.get("fraction_scans_within")
                cells.append({"scenario": row["scenario"], "model": name, "measure": measure, "share": share,
                              "met": share is not None and share >= SHARE_TARGET,
                              **{k: c[k] for k in OUTSIDE if k in c}})
            for measure in SPANS:
                mean = m["consistency"].get(measure, {}).get("mean_per_dof")
                spans.append({"scenario": row["scenario"], "model": name, "measure": measure, "mean_per_dof": mean,
                              "met": mean is not None and mean <= SPAN_LIMIT})
    return {"share_target": SHARE_TARGET, "span_limit": SPAN_LIMIT, "cells": cells, "spans": spans,
            "cells_met": sum(c["met"] for c in cells), "spans_met": sum(s["met"] for s in spans)}


def build_verdict(out_dir, scenarios) -> dict:
    rows = [scenario_verdict(out_dir, s) for s in scenarios]
    return {"rows": rows, "criteria": judge(rows)}


def _num(v, fmt: str = ".2f") -> str:
    return "-" if v is None or not np.isfinite(v) else format(v, fmt)


def _learned_cell(v) -> str:
    """A learned term (a number, "-" when absent), the gross failures [velocity, one scan] as "v + r" or the axes
    of the stationary error ("yaw 0.5 s + y 0.25 s"), of the registration's correlation ("x 0.25") or the vehicle's
    roll + pitch rate sigmas ("0.01 + 0.015"); "-" where none."""
    return (" + ".join(map(str, v)) or "-") if isinstance(v, list) else _num(v, ".3g")


def _mean_cell(c: dict, interval: bool) -> str:
    """A measure's mean NEES per dof, with `interval` its interval over the runs ("1.04 (0.80-1.35)") where the
    summary has one."""
    ci = c.get("mean_interval_per_dof") if interval else None
    return _num(c.get("mean_per_dof")) + ("" if ci is None else f" ({_num(ci[0])}-{_num(ci[1])})")


def _pct(v) -> str:
    return "-" if v is None else f"{100 * v:.1f} %"


def render_markdown(verdict: dict, meta: dict | None = None) -> str:
    """verdict.md: accuracy, the criteria's cells, the spans and ellipsoids, and what was learned."""
    rows, crit = verdict["rows"], verdict["criteria"]
    lines = ["# The consistency verdict: CA/P against CV/C, each at its learned noise", "",
             "## Accuracy (KITTI t. err %, mean [95 %]; paired difference over the same trials)", "",
             "| scenario | CA/P | CV/C | CA/P - CV/C | CA/P lower in |", "| --- | ---: | ---: | --- | ---: |"]
    for r in rows:
        a, c, d = r["models"]["CA/P"]["kitti_t_err_pct"], r["models"]["CV/C"]["kitti_t_err_pct"], \
            r["paired_kitti_t_err_pct"]
        lines.append(f"| {r['scenario']} | {_num(a['mean'])} [{_num(a['lower'])}, {_num(a['upper'])}] | "
                     f"{_num(c['mean'])} [{_num(c['lower'])}, {_num(c['upper'])}] | {_num(d['mean_difference'])} "
                     f"[{_num(d['lower'])}, {_num(d['upper'])}] | {d['a_lower']}/{d['trials']} |")
    lines += ["", f"## Scan by scan: the share of scans whose N-run average NEES is inside its 95 % bounds "
                  f"(target {100 * crit['share_target']:.0f} %): {crit['cells_met']} of {len(crit['cells'])} cells",
              "", "| scenario | CA/P velocity | CA/P one scan | CV/C velocity | CV/C one scan |",
              "| --- | ---: | ---: | ---: | ---: |"]
    for r in rows:
        shares = [c for c in crit["cells"] if c["scenario"] == r["scenario"]]
        lines.append(f"| {r['scenario']} | " + " | ".join(
            ("**" if not c["met"] else "") + _pct(c["share"]) + ("**" if not c["met"] else "") for c in shares) + " |")
    lines += ["", "Short of the target in bold."] + _misses(crit["cells"]) + ["",
              f"## On average: mean NEES per dof (the relative pose over the span and the absolute pose: at most "
              f"{crit['span_limit']:g}; {crit['spans_met']} of {len(crit['spans'])} met; theirs with the 95 % "
              "interval of the mean over the runs' own means), and the 3-sigma ellipsoids (% of scans whose true "
              "position is inside, 97.1 % claimed)", "",
              "| scenario | model | velocity | acceleration | one scan | span | absolute pose | ellipsoid |",
              "| --- | --- | ---: | ---: | ---: | ---: | ---: | ---: |"]
    for r in rows:
        for name, m in r["models"].items():
            c = m["consistency"]
            means = [_mean_cell(c.get(k, {}), k in SPANS) for k in
                     ("velocity", "acceleration", "relative_scan", "relative_span", "pose")]
            lines.append(f"| {r['scenario']} | {name} | " + " | ".join(means) + f" | "
                         f"{_num(m['ellipsoid_3sigma_pct'], '.1f')} |")
    gross = [f"{r['scenario']} {name} (trials {', '.join(map(str, m['gross_failure_runs']))})" for r in rows
             for name, m in r["models"].items() if m.get("gross_failure_runs")]
    if gross:
        lines += ["", f"Campaign runs with a gross failure (a scan above {GROSS_NEES_PER_DOF:g} per dof; every measure "
                      "without them in <scenario>/summary.md): " + "; ".join(gross) + "."]
    lines += _growth_lines(rows)
    lines += ["", "## What was learned (the `[uncertainty]` terms; the whole configs in calibration/; gross_failures: "
                  "the calibration drives' scans its velocity + one-scan fits left out)", "",
              "| scenario | model | " + " | ".join(LEARNED) + " |", "| --- | --- |" + " ---: |" * len(LEARNED)]
    for r in rows:
        for name, m in r["models"].items():
            cells = " | ".join(_learned_cell(m["learned"].get(k)) for k in LEARNED)
            lines.append(f"| {r['scenario']} | {name} | {cells} |")
    if meta and "config_sha256" in meta:
        lines += ["", "Both calibrations started from base.toml in this directory (`--config`): its settings that "
                      "calibration does not learn are in every learned config."]
    if meta:
        lines += ["", "Parameters: " + ", ".join(f"{k}={v}" for k, v in sorted(meta.items()))]
    return "\n".join(lines) + "\n"


def _growth_lines(rows: list[dict]) -> list[str]:
    """The error growth per axis of every cell over GROWTH_ROWS ([] when no campaign has it: summaries before
    session 46)."""
    if not any(m.get("error_growth") for r in rows for m in r["models"].values()):
        return []
    lines = ["", "## Per axis: E[e^2 / sigma^2] of the velocity at the scan (vx vy vz, then the roll, pitch and yaw "
                 "rates), of the relative pose over 1 s and 5 s and of the absolute pose over the drive (x y z roll "
                 "pitch yaw: 1 right, below 1 cautious, above over-confident; every span in <scenario>/summary.md)",
             "",
             "| scenario | model | " + " | ".join(GROWTH_ROWS) + " |", "| --- | --- |" + " --- |" * len(GROWTH_ROWS)]
    for r in rows:
        for name, m in r["models"].items():
            g = m.get("error_growth", {})
            cells = [" ".join(_num(x) for x in g[k]) if g.get(k) else "-" for k in GROWTH_ROWS]
            lines.append(f"| {r['scenario']} | {name} | " + " | ".join(cells) + " |")
    return lines


def _misses(cells: list[dict]) -> list[str]:
    """Where each short cell's scans miss: below the bounds (cautious), above (over-confident), and of those
    above, how many one run's value puts there (`campaign_consistency.scans_outside`)."""
    short = [c for c in cells if not c["met"] and "scans_above" in c]
    if not short:
        return []
    lines = ["", "Where the short cells miss (scans below the bounds: the covariance cautious; above: over-confident, "
                 "of which one run's value alone puts there):", ""]
    for c in short:
        measure = "velocity" if c["measure"] == "velocity" else "one scan"
        lines.append(f"- {c['scenario']} {c['model']} {measure}: {c['scans_below']} below, {c['scans_above']} above "
                     f"({c['scans_above_one_run']} of them one run's)")
    return lines


def write_verdict(out_dir, verdict: dict, meta: dict) -> str:
    """Write DIR/verdict.md and DIR/verdict.json; returns the markdown."""
    out = Path(out_dir)
    text = render_markdown(verdict, meta)
    atomic_write_bytes(out / "verdict.md", text.encode())
    atomic_write_bytes(out / "verdict.json", (json.dumps(jsonable({**verdict, "parameters": meta}), indent=1)
                                              + "\n").encode())
    return text
