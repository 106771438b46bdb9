"""Association of the local map with one scan, as the odometry runs it (paper eq. 86-88).

`MapAssociation.associate` windows the map points and the detections to the field of view, evaluates per map
point the prediction, S = G P G^T + R + map term, its inverse, the pair information (R + map term)^-1 and the
search radius in one compiled pass over blocks of points (`prepare_kernels.prepare`; the NumPy reference is
`measurements.predict` with
`association.innovation_covariance` and `MeasurementModel.search_radius`) and matches as `association.match`
does. `MapAssociation.reassociate` makes the association again at the solve's state from every candidate the
first one scored (docs/estimator.md, step 5). A `ScanMeasurements` caches the scan's detection grid.

Checked by: tests/estimator/test_scan_association.py::test_prepared_association_equals_the_reference,
    ::test_association_window_is_the_same_for_map_points_and_detections,
    ::test_compiled_map_window_equals_the_reference,
    ::test_reassociation_rescores_the_candidates_at_the_new_state
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from . import association_kernels, prepare_kernels
from . import association
from .association import Association, Candidates
from .lie import se3
from .local_map import LocalMap
from .measurement_models import MeasurementModel
from .radar_geometry import polar_to_cartesian
from .state import State

NO_PAIRS = Association(np.zeros(0, int), np.zeros(0, int), np.zeros(0), 0)


@dataclass
class ScanMeasurements:
    """A scan's static detections as the solve and association use them.

    Attributes:
        polar: (n, 4) static detections [r, az, el, v_r].
        z: (n, 4) the same in the measurement model's space.
        points: (n, 3) their Cartesian sensor-frame positions.
        cache: the detections inside the window, in the model's space, and their grid.
    """

    polar: np.ndarray
    z: np.ndarray
    points: np.ndarray
    cache: dict = field(default_factory=dict)

    @classmethod
    def of(cls, polar_static: np.ndarray, model: MeasurementModel) -> "ScanMeasurements":
        if not len(polar_static):
            return cls(polar_static, np.zeros((0, 4)), np.zeros((0, 3)))
        return cls(polar_static, model.to_model_space(polar_static), polar_to_cartesian(polar_static))


class MapAssociation:
    """The association settings of one odometry run.

    Args:
        model: the measurement model.
        R: (4, 4) its noise.
        T_vehicle_sensor: (4, 4) extrinsics.
        gate: chi-square gate of d2 (4 dof).
        max_radius: cap (m) of the candidate search radius.
        map_sigma: isotropic sigma (m) added to every map point.
        fov: ((az_min, az_max), (el_min, el_max)) radians or None (no window).
        angle_sigmas: (2,) the azimuth and elevation 1-sigma (rad) that shrink the window.
    """

    def __init__(self, model: MeasurementModel, R: np.ndarray, T_vehicle_sensor: np.ndarray, gate: float,
                 max_radius: float, map_sigma: float, fov, angle_sigmas):
        self.model = model
        self.R = R
        self.T_vehicle_sensor = T_vehicle_sensor
        self.gate = gate
        self.max_radius = max_radius
        self.map_sigma = map_sigma
        self.fov = fov
        self.angle_sigmas = angle_sigmas
        self.T_sensor_vehicle = se3.inverse(T_vehicle_sensor)
        self.limits = self._limits()

    def _limits(self) -> np.ndarray:
        """[az_lo, az_hi, el_lo, el_hi] of the window (`window_masks`); infinite where an angle is not windowed."""
        limits = np.array([-np.inf, np.inf, -np.inf, np.inf])
        if self.fov is None:
            return limits
        for i, ((lo, hi), sigma) in enumerate(zip(self.fov, self.angle_sigmas)):
            if (hi - lo) - 6 * sigma >= 0.1 * (hi - lo):  # else the margin would eat the field of view
                limits[2 * i:2 * i + 2] = lo + 3 * sigma, hi - 3 * sigma
        return limits

    def window_masks(self, p_sensor: np.ndarray, polar: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Map points (predicted) and detections (measured) inside the field of view shrunk by 3 sigma of the
        angle noise. Detections exist only inside the field of view but map points are not cut there: a map
        point that has left it (ground passing below the lower edge) would be paired with the detections at
        the edge, all on one side of it, a bias the solve turns into pitch. The same window on both sides
        keeps the pairs symmetric. An angle whose field of view is narrower than the margin (a 2D radar's
        elevation) is not windowed. (The readable reference: `associate` windows the map points with the
        compiled `association_kernels.window_points` and the detections with `detection_window`.)"""
        r = np.maximum(np.linalg.norm(p_sensor, axis=1), 1e-12)
        az_lo, az_hi, el_lo, el_hi = self.limits
        pred_az, pred_el = np.arctan2(p_sensor[:, 1], p_sensor[:, 0]), np.arcsin(np.clip(p_sensor[:, 2] / r, -1, 1))
        m_in = (pred_az >= az_lo) & (pred_az <= az_hi) & (pred_el >= el_lo) & (pred_el <= el_hi)
        return m_in, self.detection_window(polar)

    def detection_window(self, polar: np.ndarray) -> np.ndarray:
        """The detection side of `window_masks`: (n,) the detections whose measured angles are inside."""
        az_lo, az_hi, el_lo, el_hi = self.limits
        return (polar[:, 1] >= az_lo) & (polar[:, 1] <= az_hi) & (polar[:, 2] >= el_lo) & (polar[:, 2] <= el_hi)

    def associate(self, x: State, P: np.ndarray, local_map: LocalMap, scan: ScanMeasurements):
        """Map points and detections paired inside the window: (W, Association).

        W (k, 4, 4) is the information of each of the k pairs in the solve, (R + map term)^-1, in the order of
        the Association's pairs; None when nothing could be associated (an empty map or scan).
        """
        if len(local_map) == 0 or len(scan.z) == 0:
            return None, NO_PAIRS
        # the window first (positions only), then the compiled pass over the map points inside it
        m_in = np.empty(len(local_map), bool)
        association_kernels.window_points(local_map.points, self.T_sensor_vehicle @ x.T_vehicle_world, self.limits,
                                          m_in)
        mi = np.flatnonzero(m_in)
        m = len(mi)
        zp, p_s = np.empty((m, 4)), np.empty((m, 3))
        S, S_inv, W_pair = np.empty((m, 4, 4)), np.empty((m, 4, 4)), np.empty((m, 4, 4))
        radius = np.empty(m)
        bad = prepare_kernels.prepare(self.model.is_polar, x.T_vehicle_world, x.varpi, local_map.points,
                                      local_map.covariances, mi, self.map_sigma**2, np.ascontiguousarray(P[:12, :12]),
                                      self.R, self.T_vehicle_sensor, self.gate, zp, p_s, S, S_inv, W_pair, radius)
        if bad >= 0:  # a map point at the sensor, or an innovation covariance that is not positive definite
            raise FloatingPointError(f"association: map point {mi[bad % m]} has "
                                     + ("range 0" if bad < m else "a non positive definite S"))
        cache = scan.cache
        if "grid" not in cache:
            cache["di"] = np.flatnonzero(self.detection_window(scan.polar))
            cache["z"] = scan.z[cache["di"]]
            cache["grid"] = association.DetectionGrid.of(scan.points[cache["di"]])
        di = cache["di"]
        jc, ic, d2 = association.candidates(self.model, cache["z"], cache["grid"], zp, p_s, S_inv,
                                            np.minimum(radius, self.max_radius))
        j, i, d2 = association.choose(jc, ic, d2, self.gate, m, len(di))
        W = W_pair[j]
        bad = np.flatnonzero(np.isnan(W[:, 0, 0]))
        if len(bad):
            raise FloatingPointError(f"association: map point {mi[j[bad[0]]]} has a non positive definite "
                                     "R + map term")
        candidates = Candidates(mi, S_inv, jc, ic, len(local_map), len(di))
        return W, Association(mi[j], di[i], d2, len(jc), candidates)

    def reassociate(self, x: State, local_map: LocalMap, scan: ScanMeasurements, pairs: Association):
        """The association `pairs` (this scan's with this map, from `associate`) made again at the state x, a
        solve away from the state it was made at: (W, Association) as `associate` gives them.

        Its candidates (each map point's 16 nearest detections inside its search radius, gated or not) are
        scored again with the map points' predictions at x and the S^-1 they were gated with (the same P; with
        S formed at x a pair's d2 differs by at most a few per cent on city), gated and chosen one to one; each
        chosen pair's information, (R + map term)^-1, is taken at x as `associate` takes it (it holds the polar
        Jacobian and the Doppler row's velocity, which the solve moves by up to 12 % on city). Only detections
        outside a map point's search radius at the first state, or beyond its 16 nearest there, do not come
        back (the radius holds the prediction's uncertainty), and the map points are those inside the
        field-of-view window at the first state (a solve's step moves their angles by about a milliradian
        against the window's 3-sigma margin). At the state `pairs` was made at, the result is `pairs` itself,
        bit for bit. Accuracy and speed against a second association: docs/estimator.md, step 5.
        """
        c = pairs.candidates
        if c is None:
            return None, NO_PAIRS
        di = scan.cache.get("di")
        if di is None or len(di) != c.n_detections or len(local_map) != c.map_size:
            raise ValueError("reassociate: pairs must come from `associate` with this scan and this map")
        d2 = np.empty(len(c.j))
        bad = association_kernels.rescore(self.model.is_polar, x.T_vehicle_world, x.varpi, local_map.points, c.rows,
                                          self.T_vehicle_sensor, scan.cache["z"], c.S_inv, c.j, c.i, d2)
        if bad >= 0:
            raise FloatingPointError(f"association: map point {c.rows[bad]} has range 0")
        j, i, d2 = association.choose(c.j, c.i, d2, self.gate, len(c.rows), len(di))
        rows = c.rows[j]
        W = np.empty((len(rows), 4, 4))
        bad = prepare_kernels.pair_information(self.model.is_polar, x.T_vehicle_world, x.varpi, local_map.points,
                                               local_map.covariances, rows, self.map_sigma**2, self.R,
                                               self.T_vehicle_sensor, W)
        if bad >= 0:
            raise FloatingPointError(f"association: map point {rows[bad % len(rows)]} has "
                                     + ("range 0" if bad < len(rows) else "a non positive definite R + map term"))
        return W, Association(rows, di[i], d2, len(c.j), c)
