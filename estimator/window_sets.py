"""The sliding window's measurement sets (`MeasurementSet`: a scan's associated pairs) and their packing for the
compiled kernels (`SetPacks`: the sets of a linearisation concatenated, cached while the same sets come back).

Checked by: tests/estimator/test_window.py::test_replaced_measurement_sets_are_never_read_stale
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass

import numpy as np


@dataclass
class MeasurementSet:
    """Associated pairs of one scan: map points, detections (model space) and their information matrices."""

    p_world: np.ndarray  # (m, 3)
    z: np.ndarray  # (m, 4) in the model's space
    W: np.ndarray  # (m, 4, 4) information (inverse covariance)
    T_vehicle_sensor: np.ndarray | None = None  # (4, 4) the radar that measured z; None: the window's
    weights: np.ndarray | None = None  # (m,) robust weights, set by SlidingWindow.optimize

    def __len__(self) -> int:
        return len(self.z)


class SetPacks:
    """Measurement sets concatenated for the kernels, cached per tuple of sets (the sets change only when scans
    come and go)."""

    def __init__(self):
        self._packs: dict = {}

    def pack(self, sets: list[MeasurementSet], T_vehicle_sensor: np.ndarray):
        """(offsets, p, z, W, Tvs, weights) of the sets (Tvs: each set's radar, `T_vehicle_sensor` where it has
        none); the weights -1 where a set has none (the kernel sets its Cauchy weights), else the set's."""
        if not sets:
            return _NO_PACK
        # by id() against entries that hold their sets alive, so equal ids are the same sets (an id() of a freed
        # set can be reused by the next one: a stale pack once read past the new set's end)
        key = tuple(map(id, sets))
        packed = self._packs.get(key)
        if packed is None:
            if len(self._packs) > 4:
                self._packs.clear()
            offsets = np.array([0, *itertools.accumulate(len(m) for m in sets)], np.int64)
            Tvs = np.array([T_vehicle_sensor if m.T_vehicle_sensor is None else m.T_vehicle_sensor for m in sets],
                           dtype=float)  # np.stack's result, faster for a few sets
            w = np.empty(offsets[-1])  # filled below
            self._packs[key] = packed = (sets, offsets, _joined([m.p_world for m in sets]),
                                         _joined([m.z for m in sets]), _joined([m.W for m in sets]), Tvs, w)
        _, offsets, p, z, W, Tvs, w = packed
        for q, m in enumerate(sets):  # a fresh set's weights to be set; weights set in another pack copied in
            if m.weights is None:
                w[offsets[q]:offsets[q + 1]] = -1.0
            elif m.weights.base is not w:
                w[offsets[q]:offsets[q + 1]] = m.weights
        return offsets, p, z, W, Tvs, w


_NO_PACK = (np.zeros(1, np.int64), np.zeros((0, 3)), np.zeros((0, 4)), np.zeros((0, 4, 4)), np.zeros((0, 4, 4)),
            np.zeros(0))  # the pack of no sets


def _joined(arrays: list[np.ndarray]) -> np.ndarray:
    """The arrays concatenated along their first axis for the kernel; one array as it is (C-contiguous floats)."""
    return np.ascontiguousarray(arrays[0], dtype=float) if len(arrays) == 1 else np.concatenate(arrays)
