"""Visual debugging (Rerun recordings) and the paper's figures (matplotlib, Agg backend): viz only draws.

`viz` is the only package that imports rerun or matplotlib, and it imports them only inside the functions that
draw, so `import rodo.viz` (or `rodo run` without `--rerun`) loads neither. Every number it shows is computed
in `rodo.validation` (viz sits above validation; validation never imports viz).

- `viz.recording`: `record_run(path, seq, result, truth=None, detail=None)`, a `.rrd` file of one run (the
  estimator's `ScanDetail` carries the per-scan association detail), and `record_sequence` for a sequence on
  its own;
- `viz.blueprint`: the default layout of a recording;
- `viz.sequence_layers`: what a sequence recording adds (Doppler-coloured scans, the moving objects as boxes
  with their velocities, its layout);
- `viz.live`: `LiveRun`, the live stream of `rodo run --connect/--serve` (scan by scan, while it runs);
- `viz.figures`: `plot_nees` and `plot_growth` (Monte Carlo summaries) and the paper's figures 1-4 plus our
  Fig. 5, drawn from the dicts of `validation.experiments`.

Documentation: docs/visualisation.md.
"""

from .figures import (
    FIGURES,
    figure1_prior,
    figure2_measurement_models,
    figure3_association,
    figure4_trajectories,
    figure5_out_of_plane,
    plot_growth,
    plot_nees,
    write_all,
)
from .recording import DETECTION_CLASSES, detection_classes, record_run, record_sequence

__all__ = [
    "DETECTION_CLASSES",
    "FIGURES",
    "detection_classes",
    "figure1_prior",
    "figure2_measurement_models",
    "figure3_association",
    "figure4_trajectories",
    "figure5_out_of_plane",
    "plot_growth",
    "plot_nees",
    "record_run",
    "record_sequence",
    "write_all",
]
