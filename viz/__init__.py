"""Visual debugging (Rerun recordings) and the paper's figures (matplotlib, Agg backend).

`viz` is the only package that imports rerun or matplotlib, and it imports them only inside the functions that
need them, so `import viz` (or `rodo run` without `--rerun`) costs nothing.

- `viz.recording.record_run(path, seq, result, truth=None, detail=None)`: a `.rrd` file of one run
  (`viz.recording.ScanDetail` carries the per-scan association detail when the estimator provides it);
- `viz.run_metrics`: the numbers the recording plots (truth alignment, errors, NEES and its chi-square bounds,
  the world-frame position covariance and its ellipsoid), plain numpy;
- `viz.figures`: `plot_nees` and the paper's figures 1-4 (`viz.paper_figures`).

Documentation: docs/visualisation.md.
"""
