"""Validation: the driver, every metric (each computed in exactly one place), Monte Carlo campaigns and the
experiments behind the figures. No plotting and no rerun here: `rodo.viz` draws what this package computes.

Layers (imports run one way): `association` (time matching) <- `alignment`, `covariance` <- `consistency`
(NEES, NIS, chi-square bounds) <- `kitti`, `metrics` (ATE, RPE, drift, the `rodo evaluate` report) <-
`campaign_files`, `campaign`, `trial`, `table1`; `driver` runs the estimator; `experiments` (figures 1-5) and
`icp_baseline` use the driver.

Modules:
- `association`: `associate` (mutual nearest time stamps), `match_index` (the same pairs per stamp);
- `alignment`: `align_to_first`, `truth_in_estimator_frame`;
- `covariance`: `position_covariance_world`, `covariance_ellipsoid`;
- `consistency`: `pose_error`, `state_error`, `nees`, `marginal_nees`, `chi2_bounds` (the one convention:
  two-sided, `alpha` outside, N runs), `nees_sequence`, `average_nees`, `nis_summary`, `gated_mean`;
- `kitti`: devkit-exact KITTI drift; `metrics`: `ate`, `rpe`, `drift`, `pose_errors`, `velocity_errors`,
  `evaluate`, `jsonable`;
- `campaign`, `campaign_files`, `trial`, `table1`: Monte Carlo campaigns and the paper's Table I;
- `driver`: `run_sequence`, `write_run`; `icp_baseline`: `run_icp`;
- `experiments`: `fig1_data` ... `fig5_data`, `figure_data`.

Documentation: docs/evaluation.md (metrics, campaigns), docs/visualisation.md (figures).
"""

from .alignment import align_to_first, truth_in_estimator_frame
from .association import DEFAULT_TOLERANCE, associate, match_index
from .campaign import (
    CampaignReport,
    Trial,
    TrialOutcome,
    make_executor,
    make_trials,
    remaining,
    run_campaign,
    summarize_campaign,
    trial_seeds,
    write_summary,
)
from .campaign_files import FIELDS, npz_path, read_results
from .consistency import (
    NIS_DOF,
    average_nees,
    chi2_bounds,
    gated_mean,
    marginal_nees,
    nees,
    nees_sequence,
    nis_summary,
    pose_error,
    state_error,
)
from .covariance import covariance_ellipsoid, position_covariance_world
from .driver import RunResult, run_sequence, scan_times, write_run
from .experiments import fig1_data, fig2_data, fig3_data, fig4_data, fig5_data, figure_data
from .icp_baseline import run_icp
from .kitti import LENGTHS, KittiResult, kitti_errors, trajectory_distances
from .metrics import (
    DRIFT_AXES,
    PoseErrors,
    ate,
    drift,
    euler_zyx,
    evaluate,
    jsonable,
    path_distances,
    pose_errors,
    rpe,
    umeyama_se3,
    velocity_errors,
)
from .table1 import Table1Trial, build_table, render_markdown, write_table
from .trial import ScenarioTrial, evaluate_result

__all__ = [
    "CampaignReport", "DEFAULT_TOLERANCE", "DRIFT_AXES", "FIELDS", "KittiResult", "LENGTHS", "NIS_DOF", "PoseErrors",
    "RunResult", "ScenarioTrial", "Table1Trial", "Trial", "TrialOutcome", "align_to_first", "associate", "ate",
    "average_nees", "build_table", "chi2_bounds", "covariance_ellipsoid", "drift", "euler_zyx", "evaluate",
    "evaluate_result", "fig1_data", "fig2_data", "fig3_data", "fig4_data", "fig5_data", "figure_data",
    "gated_mean", "jsonable", "kitti_errors", "make_executor", "make_trials", "marginal_nees", "match_index",
    "nees", "nees_sequence", "nis_summary", "npz_path", "path_distances", "pose_error", "pose_errors",
    "position_covariance_world", "read_results", "remaining", "render_markdown", "rpe", "run_campaign", "run_icp",
    "run_sequence", "scan_times", "state_error", "summarize_campaign", "trajectory_distances", "trial_seeds",
    "truth_in_estimator_frame", "umeyama_se3", "velocity_errors", "write_run", "write_summary", "write_table",
]
