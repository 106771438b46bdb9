"""The estimator's state x = {T_vehicle_world, varpi, varpi_dot} (paper eq. 3) and its left perturbation.

The constant-velocity prior has no acceleration (`varpi_dot is None`); which layout a state has is the motion
prior's business (`rodo.estimator.motion`). Perturbations are left ones:
x (+) d = {exp(d_xi^) T_vehicle_world, varpi + d_eta, varpi_dot + d_zeta}, d = [xi; eta; zeta].

Checked by: tests/estimator/test_window_kernels.py::test_window_update_equals_state_oplus
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .lie import se3


@dataclass
class State:
    """One state of the trajectory.

    Attributes:
        t: time (s).
        T_vehicle_world: (4, 4) pose.
        varpi: (6,) body velocity [nu; omega].
        varpi_dot: (6,) body acceleration, or None (constant-velocity prior).
    """

    t: float
    T_vehicle_world: np.ndarray
    varpi: np.ndarray
    varpi_dot: np.ndarray | None = None

    def copy(self) -> "State":
        return State(self.t, self.T_vehicle_world.copy(), self.varpi.copy(),
                     None if self.varpi_dot is None else self.varpi_dot.copy())

    def vector_tail(self) -> np.ndarray:
        """[varpi; varpi_dot] (the Euclidean part of the state)."""
        return self.varpi if self.varpi_dot is None else np.concatenate((self.varpi, self.varpi_dot))

    def oplus(self, d: np.ndarray) -> "State":
        """x (+) d with a left perturbation of the pose."""
        varpi_dot = None if self.varpi_dot is None else self.varpi_dot + d[12:18]
        return State(self.t, se3.exp(d[:6]) @ self.T_vehicle_world, self.varpi + d[6:12], varpi_dot)

    def ominus(self, other: "State") -> np.ndarray:
        """x (-) other (paper eq. 12)."""
        xi = se3.log(self.T_vehicle_world @ se3.inverse(other.T_vehicle_world))
        return np.concatenate((xi, self.vector_tail() - other.vector_tail()))


def stacked(states: list[State]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """States as arrays for the batched kernels: T_vehicle_world (n, 4, 4), `State.vector_tail` (n, d - 6), t (n,)."""
    # np.array of equal-shaped arrays is np.stack's result in about a third of its time for lists this short
    return (np.array([x.T_vehicle_world for x in states], dtype=float),
            np.array([x.vector_tail() for x in states], dtype=float), np.array([x.t for x in states]))
