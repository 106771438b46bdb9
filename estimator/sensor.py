"""One radar of a `RadarOdometry` (`RadarOdometry.add_sensor`): what the odometry keeps per radar."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .doppler import DopplerFrontEnd
from .scan_association import MapAssociation


@dataclass
class Sensor:
    """One radar of the odometry: extrinsics, the estimator's 1-sigma noise, range, association, Doppler."""

    T_vehicle_sensor: np.ndarray
    sigmas: np.ndarray
    max_range: float
    associator: MapAssociation
    doppler: DopplerFrontEnd
