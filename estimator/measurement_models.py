"""The two radar measurement models behind one interface (navlie's MeasurementModel is the anchor).

A `MeasurementModel` says, for its measurement space: how detections [r, az, el, v_r] map into it, its noise R,
the sensor-frame covariance of a detection's position (new map points), the map-point sigma it uses, how a
residual is formed, and which branch the compiled kernels take (`kernel_code`). The odometry, the sliding
window and association hold a model object and never branch on its name.

    PolarModel      z = [r, azimuth, elevation, v_r], R = diag(sigmas^2)             (the paper's, eq. 79-82)
    CartesianModel  z = [x_s, y_s, z_s, v_r], R = diag(c^2, c^2, c^2, sigma_vr^2)   (the CV/C baseline, fixed c)

The configurations are the product of a motion prior (`rodo.estimator.motion`) and one of these.

Checked by: tests/estimator/test_measurements.py::test_noise_covariance, ::test_to_model_space_matches_prediction
"""

from __future__ import annotations

from abc import ABC, abstractmethod

import numpy as np

from .errors import InputError, check_finite
from .radar_geometry import cartesian_position_covariance, cartesian_to_polar_jacobian, check_polar, \
    polar_to_cartesian, polar_to_cartesian_jacobian, wrap_angle

# the compiled kernels' branch codes (rodo.estimator measurement and association kernels)
POLAR, CARTESIAN = 0, 1


def _check_sigmas(sigmas) -> np.ndarray:
    sigmas = check_finite("sigmas", sigmas, (4,))
    if sigmas.shape != (4,) or np.any(sigmas <= 0):
        raise InputError(f"sigmas: expected 4 positive values [range, azimuth, elevation, radial_velocity], "
                         f"got {sigmas.tolist()}")
    return sigmas


class MeasurementModel(ABC):
    """One measurement space of a 4D radar detection. Subclasses are stateless; the noise values come in as
    arguments (sensor sigmas from sensor.toml, the configured Cartesian sigma)."""

    name: str
    kernel_code: int  # POLAR or CARTESIAN: the compiled kernels' branch

    @property
    def is_polar(self) -> bool:
        return self.kernel_code == POLAR

    @abstractmethod
    def to_model_space(self, polar: np.ndarray) -> np.ndarray:
        """Detections (n, 4) [r, az, el, v_r] -> (n, 4) in this model's space (checked input)."""

    @abstractmethod
    def noise_diagonal(self, sigmas: np.ndarray, cartesian_sigma: float) -> np.ndarray:
        """(4,) variances of R for sensor 1-sigmas [range, az, el, v_r] (checked)."""

    @abstractmethod
    def position_covariance_sensor(self, polar: np.ndarray, sigmas: np.ndarray,
                                   cartesian_sigma: float) -> np.ndarray:
        """(n, 3, 3) sensor-frame covariance of the detections' positions under this model's own noise
        assumption (what a new map point inherits)."""

    def world_position_covariance(self, polar: np.ndarray, sigmas: np.ndarray, cartesian_sigma: float,
                                  C: np.ndarray) -> np.ndarray:
        """(n, 3, 3) `position_covariance_sensor` rotated into the world, C P C^T (C: world from sensor)."""
        return C @ self.position_covariance_sensor(polar, sigmas, cartesian_sigma) @ C.T

    @abstractmethod
    def map_sigma(self, noise) -> float:
        """The map-point sigma (m) this model uses, from a `NoiseConfig`."""

    @abstractmethod
    def position_part(self, p_sensor: np.ndarray) -> tuple[np.ndarray, np.ndarray | None]:
        """The first three measurement components of sensor-frame points and their Jacobian d/dp_sensor
        (None: the identity). Used by the NumPy reference `rodo.estimator.measurements.predict`."""

    @abstractmethod
    def search_radius(self, z_pred: np.ndarray, S: np.ndarray, gate: float) -> np.ndarray:
        """(m,) search radius around each predicted position that holds every detection with d2 <= gate."""

    def residual(self, e: np.ndarray) -> np.ndarray:
        """The raw difference z_meas - z_pred made a residual (in place; polar: azimuth wrapped)."""
        return e

    def noise_covariance(self, sigmas, cartesian_sigma: float) -> np.ndarray:
        """R (4, 4) for sensor 1-sigmas [range, az, el, v_r] (paper eq. 78, 82).

        Checked by: tests/estimator/test_measurements.py::test_noise_covariance
        """
        return np.diag(self.noise_diagonal(_check_sigmas(sigmas), cartesian_sigma))


class PolarModel(MeasurementModel):
    """z = [range, azimuth, elevation, radial velocity]: the radar's own space, R diagonal (paper eq. 79-82)."""

    name = "polar"
    kernel_code = POLAR

    def to_model_space(self, polar):
        return check_polar("polar", polar, 4)[:, :4].copy()

    def noise_diagonal(self, sigmas, cartesian_sigma):
        return sigmas**2

    def position_covariance_sensor(self, polar, sigmas, cartesian_sigma):
        return cartesian_position_covariance(polar, sigmas)

    def world_position_covariance(self, polar, sigmas, cartesian_sigma, C):
        # compiled: (C J) diag(s^2) (C J)^T per detection, J = d[x, y, z]/d[r, az, el] (one pass, no temporaries;
        # imported here: this module is the models' definition, numba is the odometry's)
        from .measurement_kernels import position_covariances

        out = np.empty((len(polar), 3, 3))
        position_covariances(np.ascontiguousarray(polar, dtype=float), np.asarray(sigmas, dtype=float),
                             np.ascontiguousarray(C, dtype=float), out)
        return out

    def map_sigma(self, noise):
        return noise.map_sigma_polar

    def position_part(self, p_sensor):
        return cartesian_to_polar_jacobian(p_sensor)

    def residual(self, e):
        e[..., 1] = wrap_angle(e[..., 1])
        return e

    def search_radius(self, z_pred, S, gate):
        """sqrt(gate * lambda_max(A S[:3, :3] A^T)) with A = d(cartesian)/d(polar) at the prediction bounds the
        LINEARISED distance |A e|. The exact chord obeys |dp|^2 = dr^2 + 4 r1 r2 hav(gamma) <=
        dr^2 + r1 r2 (del^2 + cos(el1) cos(el2) daz^2) <= k^2 |A e|^2 with k^2 = max(1, (r1 + dr_max) / (r1 cos
        el1)), dr_max = sqrt(gate S_rr), so the radius is multiplied by k (~1 for the usual small range
        uncertainty).

        Checked by: tests/estimator/test_association.py::test_matches_brute_force_and_is_one_to_one
        """
        A = polar_to_cartesian_jacobian(z_pred[:, :3])
        lam = np.linalg.eigvalsh(A @ S[:, :3, :3] @ np.swapaxes(A, 1, 2))[:, -1]
        r1, el1 = z_pred[:, 0], z_pred[:, 2]
        k2 = np.maximum(1.0, (r1 + np.sqrt(gate * S[:, 0, 0])) / (r1 * np.cos(el1)))
        return np.sqrt(gate * np.maximum(lam, 0.0) * k2)


class CartesianModel(MeasurementModel):
    """z = [x_s, y_s, z_s, radial velocity] with a FIXED Cartesian sigma c whatever the range (the CV/C
    baseline): over-confident far away and under-confident close (paper Fig. 2)."""

    name = "cartesian"
    kernel_code = CARTESIAN

    def to_model_space(self, polar):
        polar = check_polar("polar", polar, 4)
        return np.concatenate([polar_to_cartesian(polar), polar[:, 3:4]], axis=1)

    def noise_diagonal(self, sigmas, cartesian_sigma):
        c = float(check_finite("cartesian_sigma", cartesian_sigma))
        if not c > 0:
            raise InputError(f"cartesian_sigma: must be > 0, got {c}")
        return np.array([c * c, c * c, c * c, sigmas[3] ** 2])

    def position_covariance_sensor(self, polar, sigmas, cartesian_sigma):
        return np.broadcast_to(cartesian_sigma**2 * np.eye(3), (len(polar), 3, 3))

    def world_position_covariance(self, polar, sigmas, cartesian_sigma, C):
        # C (c^2 I) C^T is c^2 I in any frame: no n rotations (exactly, where they left rounding off the diagonal)
        return np.tile(cartesian_sigma**2 * np.eye(3), (len(polar), 1, 1))

    def map_sigma(self, noise):
        return noise.map_sigma_cartesian

    def position_part(self, p_sensor):
        return p_sensor, None

    def search_radius(self, z_pred, S, gate):
        """The 3-D marginal of the gate, sqrt(gate * lambda_max(S[:3, :3])).

        Checked by: tests/estimator/test_association.py::test_matches_brute_force_and_is_one_to_one
        """
        return np.sqrt(gate * np.maximum(np.linalg.eigvalsh(S[:, :3, :3])[:, -1], 0.0))


MEASUREMENT_MODELS: dict[str, MeasurementModel] = {m.name: m for m in (PolarModel(), CartesianModel())}
MODELS = tuple(MEASUREMENT_MODELS)


def measurement_model(model: str | MeasurementModel) -> MeasurementModel:
    """The model object for a name ("polar", "cartesian"), or the object itself.

    Checked by: tests/estimator/test_measurements.py::test_bad_input_names_the_argument
    """
    if isinstance(model, MeasurementModel):
        return model
    try:
        return MEASUREMENT_MODELS[model]
    except (KeyError, TypeError):
        raise InputError(f"model: expected one of {MODELS}, got {model!r}") from None
