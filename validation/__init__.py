"""Validation: the driver, every metric (each computed in exactly one place), Monte Carlo campaigns and the
experiments behind the figures. No plotting and no rerun here: `rodo.viz` draws what this package computes.

Imports run one way: `consistency` (NEES, NIS, chi-square bounds) uses `association` (time matching) and
`alignment`; `metrics` (ATE, RPE, drift, the `rodo evaluate` report) uses those and `kitti`; `campaign`, `trial`
and `table1` use `metrics`; `experiments` (figures 1-5) and `icp_baseline` use the `driver`, which runs the
estimator. Nothing here imports `rodo.viz`.

Modules:
- `association`: `associate` (mutual nearest time stamps), `match_index` (the same pairs per stamp);
- `alignment`: `align_to_first`, `truth_in_estimator_frame`;
- `covariance`: `position_covariance_world`, `covariance_axes`, `covariance_ellipsoid`;
- `consistency`: `pose_error`, `state_error`, `nees`, `chi2_bounds` (the one convention:
  two-sided, `alpha` outside, N runs), `fraction_within`, `nees_sequence`, `average_nees`, `nis_summary`,
  `gated_mean`;
- `kitti`: devkit-exact KITTI drift; `metrics`: `ate`, `rpe`, `drift`, `pose_errors`, `velocity_errors`,
  `evaluate`, `jsonable`; `evaluation_inputs`: the checks that states and a truth belong to the trajectories
  evaluated (`evaluate` and `rodo evaluate`);
- `campaign`, `campaign_files`, `trial`, `table1`: Monte Carlo campaigns and the paper's Table I; `workers`:
  their executors (`make_executor`: spawned workers that leave with their parent, or Dask's); `plugins`: the
  user's modules of scenarios and profiles that `rodo --plugin` and RODO_PLUGINS import, workers included;
- `driver`: `run_sequence`, `write_run`; `icp_baseline`: `run_icp`;
- `experiments`: `fig1_data` ... `fig5_data`, `figure_data`;
- `odometry_consistency`: `odometry_nees`, `summarise` (NEES of velocity, acceleration, relative pose over a
  scan and a span, absolute pose: docs/consistency.md); `run_consistency` (the same for a run in memory, the
  ellipsoid coverage); `campaign_consistency` (over N runs); `error_growth` (per axis, over spans from one scan
  to 20 s and the drive, and of the velocity and acceleration at the scan);
- `calibrate`, `calibrate_sensor`, `calibrate_config`: noise learned from data (`rodo calibrate`,
  docs/calibration.md), `calibrate_sensor_em` the measurement noise without ground truth, `velocity_growth` EM's
  check (the CA prior's jerk PSD from the estimated velocity's growth over seconds), `qc_information` the
  Cramér-Rao bound of Qc on a drive without truth; `calibrate_consistency`:
  the uncertainty parameters (kappa, the factors, drift rate, tau) fitted against the truth, `calibrate_velocity`
  the velocity factor, `calibrate_relative` the one-scan relative pose's, `calibrate_drift` the drift rate,
  `calibrate_jitter` the roll and pitch
  jitter's variance last, `calibrate_axis_correlation` the registration's correlation per axis,
  `calibrate_stationary` the bounded error per axis, `gross_failures` the scans those fits leave out; `replayed_states`: a run's states at
  other uncertainty settings, without running again.

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
    fraction_within,
    gated_mean,
    nees,
    nees_sequence,
    nis_summary,
    pose_error,
    state_error,
)
from .covariance import covariance_axes, covariance_ellipsoid, position_covariance_world
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
from .calibrate import QcFit, StateTrack, em_qc, fit_qc, fit_qc_to_truth
from .calibrate_config import calibrate_with_truth, calibrate_without_truth, config_toml
from .calibrate_sensor import channel_noise, detection_residuals, sigma_scale
from .campaign_consistency import campaign_consistency
from .odometry_consistency import MEASURES, odometry_nees, summarise
from .run_consistency import ellipsoid_coverage, run_states, scan_measures
from .table1 import Table1Trial, build_table, render_markdown, write_table
from .trial import ScenarioTrial, evaluate_result

__all__ = [
    "align_to_first", "associate", "ate", "average_nees", "build_table", "CampaignReport", "chi2_bounds",
    "covariance_axes", "covariance_ellipsoid", "DEFAULT_TOLERANCE", "drift", "DRIFT_AXES", "euler_zyx",
    "evaluate", "evaluate_result", "FIELDS", "fig1_data", "fig2_data", "fig3_data", "fig4_data", "fig5_data",
    "figure_data", "fraction_within", "gated_mean", "jsonable", "kitti_errors", "KittiResult", "LENGTHS",
    "make_executor", "make_trials", "match_index", "nees", "nees_sequence", "NIS_DOF",
    "nis_summary", "npz_path", "path_distances", "pose_error", "pose_errors", "PoseErrors",
    "position_covariance_world", "read_results", "remaining", "render_markdown", "rpe", "run_campaign",
    "run_icp", "run_sequence", "RunResult", "scan_times", "ScenarioTrial", "state_error", "summarize_campaign",
    "Table1Trial", "trajectory_distances", "Trial", "trial_seeds", "TrialOutcome", "truth_in_estimator_frame",
    "umeyama_se3", "velocity_errors", "write_run", "write_summary", "write_table",
    "QcFit", "StateTrack", "em_qc", "fit_qc", "fit_qc_to_truth", "calibrate_with_truth", "calibrate_without_truth",
    "config_toml", "channel_noise", "detection_residuals", "sigma_scale", "campaign_consistency", "MEASURES",
    "odometry_nees", "summarise", "ellipsoid_coverage", "run_states", "scan_measures",
]
