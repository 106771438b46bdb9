"""The default Rerun layout of a run recording: 3D view, bird's-eye view, time series tabs, event log.

Imported only from `viz.recording.record_run` (it imports rerun). Entity paths are those documented in
docs/visualisation.md.
"""

from __future__ import annotations

import numpy as np

# entity roots of the time-series tabs: (origin, tab title)
SERIES_TABS = (
    ("metrics/error", "error vs truth"),
    ("metrics/drift", "drift per axis"),
    ("metrics/nees", "NEES"),
    ("metrics/ellipsoid", "truth in 3-sigma ellipsoid"),
    ("metrics/nis", "NIS"),
    ("metrics/counts", "detections"),
    ("metrics/timing", "ms per scan"),
    ("velocity", "velocity"),
    ("acceleration", "acceleration"),
)


def birds_eye_eye(positions: np.ndarray) -> dict:
    """Eye of a top-down camera over the (N, 3) positions: centred on their bounding box, high enough to see
    all of it, screen-up = world +x (so driving forward goes up the screen at the start)."""
    p = np.asarray(positions, dtype=float).reshape(-1, 3)
    p = p[np.all(np.isfinite(p), axis=1)]
    if len(p) == 0:
        p = np.zeros((1, 3))
    lo, hi = p.min(axis=0), p.max(axis=0)
    centre = 0.5 * (lo + hi)
    extent = max(float(np.max(hi[:2] - lo[:2])), 20.0)
    return {"position": [centre[0], centre[1], hi[2] + 1.3 * extent], "look_target": centre.tolist(),
            "eye_up": [1.0, 0.0, 0.0]}


def build_blueprint(positions: np.ndarray, has_series: set[str]):
    """The default layout; `has_series` lists the SERIES_TABS origins that were logged (others are left out)."""
    import rerun.blueprint as rrb

    eye = birds_eye_eye(positions)
    tabs = [rrb.TimeSeriesView(origin=origin, name=title) for origin, title in SERIES_TABS if origin in has_series]
    return rrb.Blueprint(
        rrb.Horizontal(
            rrb.Vertical(
                rrb.Spatial3DView(origin="world", name="3D (estimator frame)"),
                rrb.Spatial3DView(origin="world", name="bird's-eye",
                                  eye_controls=rrb.EyeControls3D(kind=rrb.Eye3DKind.Orbital, **eye)),
            ),
            rrb.Vertical(
                rrb.Tabs(*tabs) if tabs else rrb.TextLogView(origin="events", name="events"),
                rrb.TextLogView(origin="events", name="events"),
                row_shares=[3, 1],
            ),
            column_shares=[3, 2],
        ),
        collapse_panels=False,
    )
