"""Vehicle trajectories drawn from the motion priors' own SDEs (prior-consistent trajectories, issue 15).

The CA prior (paper eq. 13-14): dT/dt = varpi^ T, d varpi/dt = varpi_dot, d varpi_dot/dt = w(t); the CV prior:
dT/dt = varpi^ T, d varpi/dt = w(t); in both w ~ GP(0, Qc delta(t - t')) with Qc = diag(qc), body frame,
[linear x, y, z; angular x, y, z] (jerk for CA, m^2/s^5 and rad^2/s^5; acceleration for CV, m^2/s^3 and
rad^2/s^3). Unlike the CA segments of `sim.trajectory`, the motion here is exactly what the estimator's prior
describes, so its consistency can be checked where the model is exact.

The SDE is integrated with `sim.prior_sampling`'s sub-steps (the same code as the prior Monte Carlo): w is
piecewise constant on a grid of step h = 1 / (rate_hz * substeps), aligned with the scan times k / rate_hz,
w_j ~ N(0, Qc / h). On that grid the CA varpi_dot (CV varpi) are exact samples of the SDE's Brownian path,
so their increments between scans are exactly N(0, Qc dt); the other components converge as h^2 (the
variance of the CA varpi increment is low by 1 / (4 substeps^2); the conditional (whitened) components are
more sensitive: the mean NEES of the prior residuals was 1 % low at 16 sub-steps and is within 0.1 % at the
default 64, docs/simulator.md). Between knots the
path is the sub-step's own polynomial, so `sample` and `twist` are exact at any time (the radar's scan
times, the world's route, movers riding on it).

Start: T_vehicle_world = T0 (identity), varpi = [-speed0, 0, 0, 0, 0, 0] (driving forward, docs/conventions.md),
varpi_dot = 0. A free SDE random-walks: the default qc (`DEFAULT_QC`, docs/simulator.md) keep a 60 s drive
plausible (1 sigma at 60 s: speed +-3 m/s, lateral/vertical body velocity +-0.3/0.2 m/s, yaw rate +-0.1
rad/s, roll/pitch angle +-2 deg); larger qc are the caller's choice (speeds may then reverse).

Checked by: tests/sim/test_sde_trajectory.py
"""

from __future__ import annotations

import numpy as np

from rodo.estimator.errors import InputError, check_finite
from rodo.estimator.lie import se3

from .prior_sampling import ca_substeps, compose_poses, cv_substeps, substep_sigma
from .trajectory import Motion

KINDS = ("ca", "cv")
# 1 sigma at 60 s from 10 m/s: CA var(speed) = q t^3/3, var(angle) ~ q t^5/20; CV var(speed) = q t, var(angle)
# = q t^3/3 (docs/simulator.md, "Prior-consistent trajectories").
DEFAULT_QC = {
    "ca": (1e-4, 1e-6, 5e-7, 2e-11, 2e-11, 1e-7),  # jerk PSD, m^2/s^5, rad^2/s^5
    "cv": (0.15, 1e-3, 5e-4, 1e-8, 1e-8, 1e-4),  # acceleration PSD, m^2/s^3, rad^2/s^3
}
SPEED0 = 10.0  # m/s, initial forward speed
SUBSTEPS = 64  # sub-steps per scan interval (h = 1.2 ms at 13 Hz; see the module docstring)


def check_qc(qc, name: str = "qc") -> np.ndarray:
    """qc: 6 positive finite numbers (the diagonal of Qc) -> (6,) float array; InputError naming `name`."""
    try:
        arr = np.asarray(qc, dtype=float)
    except (TypeError, ValueError):
        raise InputError(f"{name}: expected 6 positive finite numbers, got {qc!r}") from None
    if arr.shape != (6,) or not np.all(np.isfinite(arr)) or np.any(arr <= 0):
        raise InputError(f"{name}: expected 6 positive finite numbers [linear x, y, z, angular x, y, z], "
                         f"got {np.asarray(qc).tolist() if arr.size < 50 else arr.shape}")
    return arr


def check_kind(kind: str) -> str:
    if kind not in KINDS:
        raise InputError(f"kind: must be one of {KINDS}, got {kind!r}")
    return kind


class SdeTrajectory:
    """A trajectory drawn from the CA or CV prior SDE; used like a `sim.trajectory.Profile` (`duration`,
    `sample`, `twist`, `path_length`, `speed_range`).

    Attributes:
        kind: "ca" or "cv"; qc: (6,) the diagonal of Qc; h: sub-step, s.
        T_knots (N + 1, 4, 4), varpi_knots (N + 1, 6): the state at the knots j h.
        acc (N, 6): varpi_dot at the start of each sub-step (CA) or the sub-step's acceleration (CV);
        jerk (N, 6): the sub-step's jerk (CA) or zeros (CV).
    """

    def __init__(self, kind, qc, h, T_knots, varpi_knots, acc, jerk):
        self.kind = check_kind(kind)
        self.qc = check_qc(qc)
        self.h = float(h)
        self.T_knots, self.varpi_knots, self.acc, self.jerk = T_knots, varpi_knots, acc, jerk

    @property
    def duration(self) -> float:
        return len(self.acc) * self.h

    def _locate(self, t) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        t = check_finite("times", np.atleast_1d(np.asarray(t, dtype=float)), (-1,))
        if t.ndim != 1:
            raise InputError("times: must be a 1-D array")
        if t.size and (t.min() < -1e-9 or t.max() > self.duration + 1e-9):
            raise InputError(f"times: must lie in [0, {self.duration:.3f}] s, got [{t.min()}, {t.max()}]")
        j = np.clip(np.floor(t / self.h + 1e-9).astype(np.int64), 0, len(self.acc) - 1)
        s = np.clip(t - j * self.h, 0.0, self.h)
        return t, j, s

    def _twist_at(self, j, s):
        varpi = self.varpi_knots[j] + s[:, None] * self.acc[j] + (s**2 / 2)[:, None] * self.jerk[j]
        varpi_dot = self.acc[j] + s[:, None] * self.jerk[j] if self.kind == "ca" else np.zeros_like(varpi)
        return varpi, varpi_dot

    def twist(self, t) -> tuple[np.ndarray, np.ndarray]:
        """varpi(t), varpi_dot(t) for times (M,) -> (M, 6), (M, 6) (varpi_dot = 0 for CV)."""
        _, j, s = self._locate(t)
        return self._twist_at(j, s)

    def sample(self, times) -> Motion:
        """The motion at `times` (M,) in [0, duration] (any order): pose, varpi, varpi_dot, exact on the path."""
        t, j, s = self._locate(times)
        sigma = substep_sigma(self.varpi_knots[j], self.acc[j], self.jerk[j], s[:, None])
        T = se3.exp(sigma) @ self.T_knots[j]
        varpi, varpi_dot = self._twist_at(j, s)
        return Motion(t.copy(), T, varpi, varpi_dot)

    def path_length(self, t_end: float | None = None) -> float:
        """Distance driven in [0, t_end], the integral of |nu| (trapezoid on the knots)."""
        t_end = self.duration if t_end is None else min(float(t_end), self.duration)
        n = int(np.floor(t_end / self.h + 1e-9))
        speed = np.linalg.norm(np.concatenate([self.varpi_knots[:n + 1], self.twist([t_end])[0]])[:, :3], axis=1)
        knots = np.concatenate([np.arange(n + 1) * self.h, [t_end]])
        return float(np.sum(0.5 * (speed[1:] + speed[:-1]) * np.diff(knots)))

    def speed_range(self) -> tuple[float, float]:
        """Minimum and maximum forward speed -nu_x over the knots."""
        s = -self.varpi_knots[:, 0]
        return float(s.min()), float(s.max())

    def truth_arrays(self) -> dict:
        """What truth.npz records about the prior: prior_kind (1,) "ca" or "cv", prior_qc (6,), prior_substep (1,) s."""
        return {"prior_kind": np.array([self.kind]), "prior_qc": self.qc.copy(),
                "prior_substep": np.array([self.h])}


def draw(kind: str, qc, duration: float, rng: np.random.Generator, speed0: float = SPEED0,
         T0: np.ndarray | None = None, rate_hz: float = 13.0, substeps: int = SUBSTEPS) -> SdeTrajectory:
    """Draw a trajectory of at least `duration` seconds from the CA or CV prior SDE.

    Args:
        kind: "ca" (white jerk) or "cv" (white acceleration).
        qc: 6 positive numbers, the diagonal of Qc (body frame, [linear; angular]).
        duration: seconds (> 0); the draw is extended to whole sub-steps. A longer duration extends the
            same draw (the noise is drawn sub-step by sub-step).
        rng: numpy Generator (from a SeedSequence).
        speed0: initial forward speed, m/s, >= 0 (varpi = [-speed0, 0, ...], varpi_dot = 0).
        T0: (4, 4) initial T_vehicle_world (default identity).
        rate_hz, substeps: the grid h = 1 / (rate_hz substeps), aligned with the scan times k / rate_hz.

    Checked by: tests/sim/test_sde_trajectory.py::test_prior_residuals_are_consistent
    """
    kind, qc = check_kind(kind), check_qc(qc)
    if not isinstance(rng, np.random.Generator):
        raise InputError("rng: expected a numpy.random.Generator (seeded from a SeedSequence)")
    for name, v, lo in (("duration", duration, 0.0), ("rate_hz", rate_hz, 0.0), ("speed0", speed0, -1.0)):
        if not (isinstance(v, (int, float, np.integer, np.floating)) and np.isfinite(v) and v > lo):
            raise InputError(f"{name}: must be a finite number {'>= 0' if lo < 0 else '> 0'}, got {v!r}")
    if int(substeps) != substeps or substeps < 1:
        raise InputError(f"substeps: expected a positive integer, got {substeps!r}")
    T0 = np.eye(4) if T0 is None else check_finite("T0", T0, (4, 4))
    h = 1.0 / (float(rate_hz) * int(substeps))
    n = int(np.ceil(float(duration) / h - 1e-9))
    noise = rng.standard_normal((n, 6)) * np.sqrt(qc / h)
    varpi0 = np.array([-float(speed0), 0, 0, 0, 0, 0])
    if kind == "ca":
        varpi, vd, sigma = ca_substeps(varpi0, np.zeros(6), noise, h)
        acc, jerk = vd[:-1], noise
    else:
        varpi, sigma = cv_substeps(varpi0, noise, h)
        acc, jerk = noise, np.zeros_like(noise)
    return SdeTrajectory(kind, qc, h, compose_poses(T0, sigma), varpi, acc, jerk)


__all__ = ["DEFAULT_QC", "KINDS", "SPEED0", "SUBSTEPS", "SdeTrajectory", "check_qc", "draw"]
