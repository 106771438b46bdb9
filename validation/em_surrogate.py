"""EM without ground truth in the drive's linear-Gaussian stand-in (`rodo calibrate --no-truth`, docs/calibration.md).

One estimator run at Qc = diag(q_run) gives, per scan, its posterior (x_k, P_k). Read as a Kalman filter's, each scan
added the information Lambda_k = P_k^-1 - Pp_k^-1 (Pp_k = F_k P_{k-1} F_k^T + Q_k(q_run); its PSD part) and, in the
error coordinates delta_k = x_k (-) x^_k around the estimate, the information vector eta_k = Pp_k^-1 r_k, where
r_k = x^_k (-) f(x^_{k-1}) is the estimate's own prior residual, projected onto Lambda_k's range (`surrogates`; for
a Kalman filter exactly its measurement's H^T R^-1 (y_k - H x^_k)). With these pseudo-measurements fixed, the drive is a linear-Gaussian model

    delta_k = F_k delta_{k-1} - r_k + w_k,  w_k ~ N(0, Q_k(q)),  Q_k(q) = sum_i q_i B_k^(i),
    each delta_k measured with information (Lambda_k, eta_k),

in which EM's E-step is a Kalman filter and Rauch-Tung-Striebel smoother at any q (`noise_moments`: the residual
e_k = delta_k - F_k delta_{k-1} + r_k's second moments under the smoother) and the M-step is `calibrate.fit_qc`.
`surrogate_em` runs that EM to its fixed point, which costs a smoother per step instead of an estimator run. At
q = q_run the E-step is the estimator's own posteriors smoothed (a test checks it against a Kalman filter's exact
joint Gaussian), so EM's fixed points are those of EM with an estimator run per step; `calibrate.em_qc` re-runs the
estimator at the stand-in's answer until that answer stops moving (the pseudo-measurements depend a little on the
Qc the estimator ran with). EM with an estimator run per step (sessions 12-56) stopped far from its fixed point:
where the data say little its steps are small and each run's own changes made them look converged (seed 3's 30 s
drive: 2.03 x the truth in y after 18 runs, where the fixed point is 0.74 x).

Checked by: tests/validation/test_em_surrogate.py
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from rodo.estimator.errors import InputError

from . import calibrate as cal

INFORMATION_FLOOR = 1e-6  # a scan's information counts where it is at least this share of the posterior's, per axis
STEP_TOLERANCE = 1e-3  # the stand-in's EM stops when no log q_i moves by more than this in a step
STEPS = 1000  # ... or after this many steps


def spd_inverse(A: np.ndarray) -> np.ndarray:
    """Inverse of symmetric positive-semidefinite matrices (..., d, d), Jacobi-scaled (poses in m, rates in rad/s and
    jerks side by side span many orders of magnitude); a singular one's pseudo-inverse (a direction without
    variance has no information to give). Non-finite input is an InputError."""
    A = np.asarray(A, dtype=float)
    if not np.all(np.isfinite(A)):
        raise InputError("states.P: a covariance is not finite")
    diag = np.einsum("...aa->...a", A)
    D = np.where(diag > 0, 1.0 / np.sqrt(np.where(diag > 0, diag, 1.0)), 0.0)
    scaled = A * D[..., :, None] * D[..., None, :]
    try:
        inv = np.linalg.inv(scaled)
        if not np.all(np.isfinite(inv)) or np.any(np.einsum("...aa->...a", inv) < 0):
            raise np.linalg.LinAlgError
    except np.linalg.LinAlgError:
        inv = np.linalg.pinv(scaled, hermitian=True)
    inv = inv * D[..., :, None] * D[..., None, :]
    return 0.5 * (inv + np.swapaxes(inv, -1, -2))


def psd_part(A: np.ndarray) -> np.ndarray:
    """The PSD part of symmetric matrices (..., d, d): negative eigenvalues set to 0."""
    vals, vecs = np.linalg.eigh(0.5 * (A + np.swapaxes(A, -1, -2)))
    return (vecs * np.clip(vals, 0.0, None)[..., None, :]) @ np.swapaxes(vecs, -1, -2)


def segments(track: cal.StateTrack) -> list[slice]:
    """The runs of states joined by valid intervals (an interval ending in a re-initialisation breaks the
    drive), each of at least two states."""
    valid = np.ones(len(track.t) - 1, bool) if track.valid is None else np.asarray(track.valid, dtype=bool)
    out, start = [], 0
    for k, ok in enumerate(valid, 1):
        if not ok:
            out.append(slice(start, k))
            start = k
    out.append(slice(start, len(track.t)))
    return [s for s in out if s.stop - s.start >= 2]


@dataclass(frozen=True)
class Surrogate:
    """One stretch of a drive as the linear-Gaussian stand-in: transitions F (K, d, d), noise basis B (K, 6, d, d),
    the estimate's prior residuals r (K, d), each scan's information Lambda (K, d, d) and information vector eta
    (K, d) (scans 1..K), and the first state's covariance P0 (d, d)."""

    F: np.ndarray
    B: np.ndarray
    r: np.ndarray
    info: np.ndarray
    eta: np.ndarray
    P0: np.ndarray

    @property
    def state_information(self) -> np.ndarray:
        """Every state's information (K + 1, d, d): the first state's none (its covariance P0 alone), then info."""
        return np.concatenate([np.zeros((1, *self.P0.shape)), self.info])


def surrogates(kind: str, track: cal.StateTrack, qc_run) -> list[Surrogate]:
    """The stand-in of each stretch of the track between re-initialisations (`segments`), from the
    estimator's posteriors run at Qc = diag(qc_run).

    Checked by: tests/validation/test_em_surrogate.py::test_at_the_runs_qc_the_stand_in_smooths_the_posteriors
    """
    if track.P is None:
        raise InputError("states: the E-step needs the posterior covariances P")
    out = []
    for s in segments(track):
        part = cal.StateTrack(track.t[s], track.T_vehicle_world[s], track.varpi[s], track.varpi_dot[s], track.P[s])
        F, B = cal.transitions_and_basis(kind, part, qc_run)
        P = np.asarray(part.P, dtype=float)
        Pp_inv = spd_inverse(F @ P[:-1] @ np.swapaxes(F, -1, -2) + cal.process_noise(qc_run, B))
        r = cal.prior_residuals(kind, part)
        info, within = _information(spd_inverse(P[1:]) - Pp_inv, P[1:])
        out.append(Surrogate(F, B, r, info, np.einsum("kab,kbc,kc->ka", within, Pp_inv, r), P[0]))
    return out


def _information(difference: np.ndarray, P: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The PSD part of P_k^-1 - Pp_k^-1 (K, d, d), its directions that carry information, and the projector onto
    them: an information vector has no part outside them (a Kalman filter's H^T R^-1 y lies in H^T's range).
    Where the estimator moved the state along a direction no scan measures (a planar radar's z, roll and pitch,
    which its other terms hold; a scan without detections), that move is no measurement: kept, it would pull the
    stand-in's state with no information to weigh it, and EM's Qc of that direction ran away (the TI demo's z:
    0.05 to 1e8 in nine steps). A direction counts where it adds at least INFORMATION_FLOOR of the information the
    posterior holds on that axis (P scaled to unit variances: round-off of the difference stays far below)."""
    D = np.sqrt(np.einsum("kaa->ka", P))
    scaled = 0.5 * (difference + np.swapaxes(difference, -1, -2)) * D[:, :, None] * D[:, None, :]
    vals, vecs = np.linalg.eigh(scaled)
    keep = vals > INFORMATION_FLOOR
    unscale = np.where(D > 0, 1.0 / np.where(D > 0, D, 1.0), 0.0)
    info = (vecs * np.where(keep, vals, 0.0)[..., None, :]) @ np.swapaxes(vecs, -1, -2)
    info = info * unscale[:, :, None] * unscale[:, None, :]
    basis = vecs * keep[..., None, :] * unscale[:, :, None]  # the kept directions in the state's own units
    within = basis @ np.linalg.pinv(basis)  # the orthogonal projector onto their span
    return info, within


def filter_covariances(F, Q, info, P0):
    """The Kalman filter's covariance pass, which depends on no data: the filtered covariances P_k (K + 1, d, d),
    the predicted ones Pp_k and their inverses (Pp_0 = P0), and the smoother's gains C_k = P_k F_k^T Pp_{k+1}^-1
    (K, d, d); transitions F and noises Q (K, d, d), each state's information info (K + 1, d, d)."""
    K, d = F.shape[0], F.shape[-1]
    P, Pp, Pp_inv = np.empty((K + 1, d, d)), np.empty((K + 1, d, d)), np.empty((K + 1, d, d))
    Pp[0] = P0
    Pp_inv[0] = spd_inverse(P0)
    P[0] = spd_inverse(Pp_inv[0] + info[0])
    for k in range(1, K + 1):
        Pp[k] = F[k - 1] @ P[k - 1] @ F[k - 1].T + Q[k - 1]
        Pp_inv[k] = spd_inverse(Pp[k])
        P[k] = spd_inverse(Pp_inv[k] + info[k])
    return P, Pp, Pp_inv, P[:-1] @ np.swapaxes(F, -1, -2) @ Pp_inv[1:]


def smoothed(s: Surrogate, q) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Kalman filter and Rauch-Tung-Striebel smoother of the stand-in at Qc = diag(q): the smoothed means (K + 1, d)
    and covariances (K + 1, d, d) of delta, and cov(delta_{k-1}, delta_k) (K, d, d)."""
    F, K, d = s.F, s.F.shape[0], s.F.shape[-1]
    P, Pp, Pp_inv, C = filter_covariances(F, cal.process_noise(q, s.B), s.state_information, s.P0)
    m, mp = np.zeros((K + 1, d)), np.zeros((K + 1, d))
    for k in range(1, K + 1):
        mp[k] = F[k - 1] @ m[k - 1] - s.r[k - 1]
        m[k] = P[k] @ (Pp_inv[k] @ mp[k] + s.eta[k - 1])
    cross = np.empty((K, d, d))
    for k in range(K - 1, -1, -1):
        m[k] = m[k] + C[k] @ (m[k + 1] - mp[k + 1])
        P[k] = P[k] + C[k] @ (P[k + 1] - Pp[k + 1]) @ C[k].T
        P[k] = 0.5 * (P[k] + P[k].T)
        cross[k] = C[k] @ P[k + 1]
    return m, P, cross


def noise_moments(s: Surrogate, q) -> np.ndarray:
    """E-step: S_k = E[e_k e_k^T | the pseudo-measurements] of e_k = delta_k - F_k delta_{k-1} + r_k under the
    stand-in at Qc = diag(q), (K, d, d), each projected onto the PSD cone."""
    m, P, cross = smoothed(s, q)
    e = m[1:] - np.einsum("kab,kb->ka", s.F, m[:-1]) + s.r
    FC = s.F @ cross
    S = e[:, :, None] * e[:, None, :] + P[1:] + s.F @ P[:-1] @ np.swapaxes(s.F, -1, -2) - FC - np.swapaxes(FC, -1, -2)
    return psd_part(S)


def surrogate_em(parts: list[Surrogate], qc0, floor=cal.DEFAULT_FLOOR, fixed=None,
                 tolerance: float = STEP_TOLERANCE, steps: int = STEPS) -> tuple[cal.QcFit, int]:
    """EM in the stand-in from Qc = diag(qc0) to its fixed point (Aitken-accelerated, `calibrate.aitken_step`):
    the last M-step's fit and the steps taken. It stops when no log q_i moves by more than `tolerance` in a step,
    after `steps`, when a learned component reaches the fit's upper bound (a runaway: no fixed point), or when a
    step's algebra fails (the last good fit then). Where the data say little, a small step is not yet the fixed
    point: 1-2 % short on the Kalman-filter test's drives, 7 % in the review's case with a hundredth of the roll
    information; a criterion on the extrapolated distance (`remaining_distance`) at 1e-6 closes the gap but takes
    800-1000 steps a run on a 30 s radar drive (session 57).
    `fixed` (6,) bool: components held at qc0.

    Checked by: tests/validation/test_em_surrogate.py::test_em_in_the_stand_in_recovers_qc_with_a_kalman_filter
    """
    if not parts:
        raise InputError("states: no interval between re-initialisations to learn Qc from")
    q, previous, fit = np.asarray(qc0, dtype=float), None, None
    floor = cal.floors(floor)
    fixed = np.zeros(6, bool) if fixed is None else np.asarray(fixed, dtype=bool)
    B = np.concatenate([s.B for s in parts])
    for step in range(1, int(steps) + 1):
        try:
            new = cal.fit_qc(B, np.concatenate([noise_moments(s, q) for s in parts]), floor, qc0=q, fixed=fixed)
        except np.linalg.LinAlgError:
            if fit is None:
                raise InputError("states: the posteriors' covariances give no usable information") from None
            return fit, step - 1
        fit, move = new, np.log(new.qc) - np.log(q)
        if np.max(np.abs(move)) < tolerance or np.any(new.qc[~fixed] >= cal.QC_MAX):
            return fit, step
        q = np.where(fixed, q, np.clip(q * np.exp(cal.aitken_step(move, previous)), floor, cal.QC_MAX))
        previous = move
    return fit, int(steps)
