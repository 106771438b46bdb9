"""The real campaign trial: simulate a scenario with the trial's seed, run each model, evaluate it.

`validation.campaign` runs trials (any picklable callable `trial(Trial) -> list[TrialOutcome]`) and persists
them; this module holds the one that ties scenarios, the estimator and the metrics together.

Checked by: tests/validation/test_campaign.py, tests/validation/test_table1.py
"""

from __future__ import annotations

import time
import traceback
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from rodo.estimator.errors import is_environment_error

from .campaign import Trial, TrialOutcome, error_text
from .association import associate
from .consistency import nees_sequence, nis_summary
from .error_growth import error_growth
from .kitti import LENGTHS, kitti_errors
from .metrics import ate, drift, path_distances, rpe, velocity_errors
from .odometry_consistency import DOF, MEASURES, summarise
from .run_consistency import run_states, scan_measures, truth_coverage

SPAN = 1.0  # s, the span of the relative_span measure
ELLIPSOID_SIGMA = 3.0  # the ellipsoid of ellipsoid_3sigma_pct (the Rerun recording's: docs/visualisation.md)


@dataclass(frozen=True)
class ScenarioTrial:
    """The real trial: simulate `scenario` with the trial's seed, run each model, evaluate against the truth.

    Picklable (a frozen dataclass of plain values), so it runs in a process pool or on a Dask worker. A model
    whose run raises, or whose estimate stops being finite, yields status=error with the message; the other
    models of the trial still run.
    """

    scenario: str
    duration: float | None = None
    lengths: tuple[float, ...] | None = None
    step: int = 10
    configs: tuple[tuple[str, str], ...] = ()  # (label, TOML text): that label runs this config
    faults: tuple[str, ...] = ()  # `--fault NAME=VALUE` strings (sim.faults.parse_faults), default none
    profile: str | None = None  # sensor profile (sim.profiles), default the scenario's
    qc: tuple[float, ...] | None = None  # the prior-consistent scenarios' Qc, default the scenario's

    def config(self, label: str):
        """The OdometryConfig of a model label: its TOML from `configs`, else the named model's defaults."""
        from rodo.estimator.tomlcompat import tomllib

        from rodo.estimator.config import OdometryConfig

        text = dict(self.configs).get(label)
        if text is None:
            return OdometryConfig.for_model(label)
        return OdometryConfig.from_dict(tomllib.loads(text), source=f"config of {label}")

    def __call__(self, trial: Trial) -> list[TrialOutcome]:
        from rodo import scenarios
        from rodo.sim.sequence import Trajectory

        from .driver import run_sequence

        from rodo.sim.faults import parse_faults

        faults = parse_faults(self.faults)
        t0 = time.perf_counter()
        params = {} if self.qc is None else {"qc": list(self.qc)}
        seq, truth = scenarios.get(self.scenario).simulate(trial.seed, self.duration, faults=faults,
                                                            sensor_profile=self.profile, **params)
        gt = Trajectory(truth["t"], np.linalg.inv(truth["T_vehicle_world"]))
        simulate_s = time.perf_counter() - t0
        outcomes = []
        for model in trial.models:  # every model on the one simulated sequence, in memory
            t0 = time.perf_counter()
            try:
                result = run_sequence(seq, self.config(model), keep_estimates=False)
                run_s = time.perf_counter() - t0
                out = evaluate_result(model, result, gt, truth, self.lengths, self.step, run_s)
                if out.error is None:
                    out.arrays.update(self.extra_arrays(gt, result))
                out.timings = {"simulate": simulate_s, "run": run_s, "evaluate": time.perf_counter() - t0 - run_s}
                outcomes.append(out)
            except Exception as exc:  # noqa: BLE001 - recorded per model
                if is_environment_error(exc):  # a full disk is not the trial's failure: the campaign stops
                    raise
                frames = traceback.extract_tb(exc.__traceback__)
                where = next((f for f in reversed(frames) if not f.filename.endswith("errors.py")), frames[-1])
                outcomes.append(TrialOutcome(model, error=f"{error_text(exc)} (at {Path(where.filename).name}:"
                                                          f"{where.lineno})"))
        return outcomes

    def extra_arrays(self, gt, result) -> dict:
        """More per-trial arrays to store in trials/*.npz (subclasses add theirs, e.g. table1's segments)."""
        return {}


def evaluate_result(model: str, result, gt, truth: dict, lengths, step: int, wall_s: float) -> TrialOutcome:
    """Metrics row and per-scan arrays of one `validation.driver.RunResult` against the simulator's truth.

    The row's values are those of `metrics.evaluate` (the same functions on the same inputs), computed without
    the parts a campaign row does not keep: `evaluate` also summarises the odometry consistency measures, which
    `consistency_of` computes here per scan anyway (their span covariances are the evaluation's costliest part),
    and the NEES sequence is computed once for the row and the arrays.
    """
    states = run_states(result)
    T = states["T_vehicle_world"]
    bad = ~np.all(np.isfinite(T), axis=(1, 2))
    if bad.any():
        k = int(np.flatnonzero(bad)[0])
        return TrialOutcome(model, error=f"non-finite estimate from scan {k} (t = {float(states['t'][k]):.3f} s)")
    d = states["P"].shape[-1]
    est = result.trajectory()
    ig, ie = associate(gt.t, est.t)
    G, E = gt.T_world_vehicle[ig], est.T_world_vehicle[ie]
    k = kitti_errors(G, E, LENGTHS if lengths is None else lengths, step)
    dr = drift(G, E)
    fin, mx = dr["final"], dr["max_abs"]
    ns = nees_sequence(states, truth)
    v = ns["nees"][np.isfinite(ns["nees"])]
    nis = nis_summary(states["nis"], states["n_associated"])
    velocity = velocity_errors(states["t"], states["varpi"], truth["t"], truth["varpi"], states.get("varpi_dot"),
                               truth.get("varpi_dot"))
    metrics = {"kitti_t_err_pct": k.t_err_pct, "kitti_r_err_deg_per_m": k.r_err_deg_per_m,
               "ate_rmse_m": ate(G, E)["ate_rmse_m"], "rpe_trans_pct": rpe(G, E)["rpe_trans_pct"],
               **{f"drift_{a}_{'m' if a in 'xyz' else 'deg'}": fin[a] for a in fin},
               "max_abs_z_m": mx["z"], "max_abs_roll_deg": mx["roll"], "max_abs_pitch_deg": mx["pitch"],
               "nees_mean": float(v.mean()) if v.size else float("nan"), "nees_dim": d, "nis_mean": nis["mean"],
               "nu_rmse_mps": velocity["nu_rmse_mps"],
               "ms_per_scan": float(np.median(result.wall_ms)), "scans": result.n_scans,
               "path_length_m": float(path_distances(G)[-1]), "wall_s": wall_s}
    arrays = {"t": ns["t"], "nees": ns["nees"], "nees_dim": d, "nis": states["nis"],
              "n_associated": states["n_associated"], "ms_per_scan": result.wall_ms,
              "nis_pairs": nis["pairs"], "T_world_vehicle_est": est.T_world_vehicle}
    metrics_c, arrays_c = consistency_of(states, truth, ns["t"])
    metrics.update(metrics_c)
    arrays.update(arrays_c)
    return TrialOutcome(model, metrics, arrays)


def consistency_of(states: dict, truth: dict, t: np.ndarray) -> tuple[dict, dict]:
    """The odometry consistency measures of one run (`odometry_consistency.odometry_nees`, relative_span over
    SPAN seconds) for a campaign: the results.csv columns `nees_<measure>_per_dof` (mean NEES / 6 over the
    run's scans, "" where undefined), `ellipsoid_3sigma_pct` (the % of its scans whose true position is inside
    the 3-sigma ellipsoid of the absolute pose covariance, `run_consistency.truth_coverage`; 97.1 % claimed) and
    the trial npz arrays `nees_<measure>` (per scan, on the times t of
    `nees`), `nees_measure_dof`, `nees_span` and `growth_<sum>`, the run's `error_growth.error_growth` sums.

    Checked by: tests/validation/test_campaign_consistency.py::test_run_consistency_per_scan_and_ellipsoid_coverage
    """
    m = scan_measures(states, truth, span=SPAN)
    keep = np.isin(m["t"], t)
    s = summarise({k: m[k][keep] for k in MEASURES})
    metrics = {f"nees_{k}_per_dof": "" if s[k]["mean_per_dof"] is None else s[k]["mean_per_dof"] for k in MEASURES}
    inside = truth_coverage(states, truth, ELLIPSOID_SIGMA)["fraction"]
    metrics["ellipsoid_3sigma_pct"] = 100.0 * inside if np.isfinite(inside) else ""
    arrays = {f"nees_{k}": m[k][keep] for k in MEASURES}
    arrays.update({"nees_measure_dof": DOF, "nees_span": m["span"]})
    arrays.update({f"growth_{k}": v for k, v in error_growth(states, truth).items()})
    return metrics, arrays
