"""Sliding-window MAP (paper eq. 1-2): Gauss-Newton over a prior, motion-prior and measurement terms.

The cost is J = J_v0 + sum_k J_vk + sum_k J_zk: a Gaussian prior on the oldest state (the marginalised past),
the motion prior between consecutive states (e = x_k (-) f(x_{k-1}), weight Q_k^-1, eq. 49-50), and for each
state the associated detections (e = z - g(x_k, p_j), weight S^-1 with S the measurement noise plus the
map-point uncertainty, eq. 83), with an optional Cauchy loss applied by iterative re-weighting, and zero-mean
terms on the rates the odometry knows more about than the motion prior does (`set_rate_prior`: all of them at
rest, roll and pitch rates of a moving road vehicle).
Every term is linearised as e + J d with d the left perturbation of the states; the normal equations are
solved densely (the window is small), the Gauss-Newton loop in one compiled call. When the window is full the
oldest state is marginalised with the Schur complement into a prior on the next one, kept as (Lam, g) at its
linearisation point: cost 1/2 e^T Lam e + g^T e.

Checked by: tests/estimator/test_window.py, tests/estimator/test_window_solve.py
"""

from __future__ import annotations

import math

import numpy as np

from . import motion_kernels, window_kernels
from .lie import se3
from .measurement_models import MeasurementModel
from .motion import MotionPrior
from .spd import inv_spd, solve_spd, trailing_inverse
from .state import State, stacked
from .window_sets import MeasurementSet, SetPacks


class SlidingWindow:
    def __init__(self, motion: MotionPrior, size: int, measurement_model: MeasurementModel,
                 T_vehicle_sensor: np.ndarray, robust_c: float = 3.0, relinearize_older: bool = True):
        self.motion = motion
        self.size = size
        self.measurement_model = measurement_model
        self.T_vehicle_sensor = T_vehicle_sensor
        self.robust_c = robust_c
        self.states: list[State] = []
        self.meas: list[MeasurementSet | None] = []
        self.rate_prior: list[np.ndarray | None] = []  # per state: information of a zero-mean term on its rates
        self.motion_info: list[np.ndarray] = []  # Q_k^-1 between states k and k+1
        self.prior_mean: State | None = None  # linearisation point of the prior on the oldest state
        self.prior_info: np.ndarray | None = None
        self.prior_grad: np.ndarray | None = None  # linear term g: cost 1/2 e^T Lam e + g^T e, e = x0 (-) mean
        self._packs = SetPacks()  # the measurement sets concatenated for the kernel (cached)
        self._rates: dict = {}  # the rate terms as the kernel takes them, per (n, first_only, terms) (cached)
        self._rate_copy: np.ndarray | None = None  # the window's copy of the rate term set last
        # False: an older state's measurement terms are linearised once per solve (the first linearisation after
        # a re-weighting), then taken from their quadratic model (`_arguments`); the newest state's always
        self.relinearize_older = relinearize_older
        self._terms: dict = {}  # id(set) -> (set, its weights, T^-1, varpi, H, b, cost) at its last linearisation
        self._H: np.ndarray | None = None
        self._marginal: tuple | None = None  # (what it was taken at, Lam, g): the last solve's Schur complement
        self._factor: tuple[np.ndarray, np.ndarray] | None = None  # (H, its Cholesky factor) of the last step
        self._motion_info: np.ndarray | None = None  # motion_info stacked for the kernel (cached)
        self._stack = None  # (ids, T, tail, t, states): the states as arrays (`state.stacked`), for those states
        self._prior_inverse: tuple | None = None  # (prior_mean, its T^-1, its tail), while prior_mean is that object

    # --- building -------------------------------------------------------------------------------------
    def initialize(self, x0: State, P0: np.ndarray) -> None:
        self.states = [x0.copy()]
        self.meas = [None]
        self.motion_info = []
        self._motion_info = None
        self.prior_mean = x0.copy()
        self.prior_info = inv_spd(P0)
        self.prior_grad = np.zeros(len(P0))
        self.rate_prior = [None]
        self._H = None

    def push(self, x: State, Q: np.ndarray) -> None:
        """Append a new (predicted) state linked to the newest by the motion prior with noise Q."""
        self.states.append(x.copy())
        self.meas.append(None)
        self.rate_prior.append(None)
        self.motion_info.append(inv_spd(Q))
        self._motion_info = None
        self._H = None

    def replace_newest(self, x: State) -> None:
        """Move the newest (predicted) state to x before the solve (a re-centred prediction)."""
        self.states[-1] = x.copy()
        self._H = None

    def set_rate_prior(self, k: int, info: np.ndarray | None) -> None:
        """A zero-mean term on state k's rates: cost 1/2 t^T info t with t = [varpi; varpi_dot] (a standstill seen by
        the Doppler: a wheeled vehicle at rest neither moves nor turns; or a moving road vehicle's roll and pitch
        rates), or None to remove it. The window keeps a copy, one for a term equal to the last one set (its kernel
        arrays are kept per term, `_rate_terms`, so a term set again every scan is one term)."""
        if info is not None:  # the same term as the last one set: the same copy, so `_rate_terms` keeps its arrays
            kept = self._rate_copy
            if kept is None or kept.shape != np.shape(info) or not np.array_equal(kept, info):
                kept = self._rate_copy = np.array(info, dtype=float)
            info = kept
        self.rate_prior[k] = info
        self._H = None

    def set_measurements(self, k: int, mset: MeasurementSet | None) -> None:
        self.meas[k] = mset if mset is not None and len(mset) else None
        self._H = None

    @property
    def newest(self) -> State:
        return self.states[-1]

    def _stacked(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The window's states as arrays (`state.stacked`), kept while the states are the same objects (an
        update sets them with its own arrays, `_set_states`)."""
        c, ids = self._stack, tuple(map(id, self.states))  # c[4] holds c's states alive: equal ids, the same states
        if c is None or c[0] != ids:
            self._stack = c = (ids, *stacked(self.states), list(self.states))
        return c[1], c[2], c[3]

    def _set_states(self, states: list[State], T: np.ndarray, tail: np.ndarray) -> None:
        self.states = states
        self._stack = (tuple(map(id, states)), T, tail, np.array([x.t for x in states]), list(states))

    # --- linearisation ----------------------------------------------------------------------------------
    def _lag_ready(self, m: MeasurementSet) -> bool:
        kept = self._terms.get(id(m))
        return not self.relinearize_older and kept is not None and kept[0] is m and kept[1] is m.weights

    def _linearized(self, sets, rows, ks, w, offsets, T0_inverse, varpi0, H, b, costs) -> None:
        """After a linearisation that took `sets` afresh, in a pack with weights w: a fresh set's weights are a view
        of the pack's; with `relinearize_older` False the older states' blocks (row rows[s] of the per-state
        arrays, state ks[rows[s]]) are kept to lag (`_arguments`). A kept Schur complement is dropped: its oldest
        state's terms may have been taken afresh."""
        self._marginal = None
        for s, m in enumerate(sets):
            if m.weights is None:
                m.weights = w[offsets[s]:offsets[s + 1]]
        if self.relinearize_older:
            return
        for m, q in zip(sets, rows):
            if ks[q] != len(self.states) - 1:
                self._terms[id(m)] = (m, m.weights, T0_inverse[q], varpi0[q], H[q], b[q], costs[q])
        if len(self._terms) > len(self.meas):  # forget the sets that left the window
            live = {id(m) for m in self.meas if m is not None}
            self._terms = {i: v for i, v in self._terms.items() if i in live}

    def reset_robust_weights(self) -> None:
        """Forget the Cauchy weights: the next linearisation sets them from the current residuals, and they
        stay fixed while Gauss-Newton iterates (re-weighting inside the iterations turns its quadratic
        convergence linear)."""
        for m in self.meas:
            if m is not None:
                m.weights = None
        self._H = None

    def linearize(self, lagged: bool = False):
        """Normal equations (H, b) with H d = -b, and the cost, at the current estimate (lagged: `_arguments`)."""
        return self._normal_equations(len(self.states), lagged)

    def _rate_terms(self, n: int, first_only: bool) -> tuple[np.ndarray, np.ndarray]:
        """(rate_on (n,), rate_info (n, d - 6, d - 6)) of the first n states for the kernel: each state's rate
        term, only the oldest's with first_only. Kept while the window holds the same rate terms (compared by
        identity: `set_rate_prior` stores its own copy of a term, which nothing changes in place)."""
        key = (n, first_only, *map(id, self.rate_prior[:n]))
        kept = self._rates.get(key)  # kept[0] holds the terms alive, so equal ids are the same objects
        if kept is not None:
            return kept[1], kept[2]
        d = self.motion.dim
        rate_on, rate_info = np.zeros(n, dtype=bool), np.zeros((n, d - 6, d - 6))
        for k, info in enumerate(self.rate_prior[:1 if first_only else n]):
            if info is not None:
                rate_on[k] = True
                rate_info[k] = info
        if len(self._rates) > 8:
            self._rates.clear()
        self._rates[key] = (list(self.rate_prior[:n]), rate_on, rate_info)  # the terms held alive: ids stay theirs
        return rate_on, rate_info

    def _arguments(self, n: int, lagged: bool, first_only: bool = False):
        """`window_kernels.normal_equations`' arguments (up to c0) for the window's first n states, and what
        `_linearized` takes after it. The normal equations:
        the prior on the oldest, the motion terms between them, and the measurement and rate terms of all n, or
        with first_only of the oldest alone (the marginalisation's). An older state's measurement terms lag (come
        from the quadratic model of their last linearisation, cost c0 + b0^T d + 1/2 d^T H0 d and gradient
        b0 + H0 d, d the state's move since: its pose part the SE(3) log) when `lagged`, `relinearize_older` is
        False and its set and weights are those of that linearisation. Between two linearisations of one solve
        an older state moves by 1e-4 median (m, rad, m/s), where the cost is right to second order in the move
        and the gradient and H to first. The newest state's never lag.

        Checked by: tests/estimator/test_window.py::test_lagged_terms_are_the_quadratic_model_of_the_last_linearisation
        """
        d, newest = self.motion.dim, len(self.states) - 1
        T_all, tail, t = self._stacked()
        if n < len(self.states):
            T_all, tail, t = T_all[:n], tail[:n], t[:n]
        if self._prior_inverse is None or self._prior_inverse[0] is not self.prior_mean:
            mean = self.prior_mean
            self._prior_inverse = (mean, se3.inverse(mean.T_vehicle_world), mean.vector_tail())
        if len(self.states) > 1 and (self._motion_info is None or len(self._motion_info) != len(self.states) - 1):
            self._motion_info = np.array(self.motion_info, dtype=float)  # np.stack's result, faster
        motion_info = self._motion_info[:n - 1] if n > 1 else np.zeros((0, d, d))
        rate_on, rate_info = self._rate_terms(n, first_only)
        ks_list = [k for k, m in enumerate(self.meas[:1 if first_only else n]) if m is not None]
        sets = [self.meas[k] for k in ks_list]
        ks, K = np.array(ks_list, np.int64), len(ks_list)
        lag = [lagged and k != newest and self._lag_ready(m) for k, m in zip(ks_list, sets)]
        fresh = [q for q in range(K) if not lag[q]]
        slot_list = [-1] * K  # a fresh state's slot in the pack; -1: its terms lag
        for s, q in enumerate(fresh):
            slot_list[q] = s
        slot = np.array(slot_list, np.int64)
        T0_inverse, varpi0 = np.empty((K, 4, 4)), np.empty((K, 6))
        H0, b0, c0 = np.empty((K, 12, 12)), np.empty((K, 12)), np.empty(K)
        for q in range(K):
            if lag[q]:
                _, _, T0_inverse[q], varpi0[q], H0[q], b0[q], c0[q] = self._terms[id(sets[q])]
        fresh_sets = [sets[q] for q in fresh]
        offsets, p, z, W, Tvs, w = self._packs.pack(fresh_sets, self.T_vehicle_sensor)
        args = (*self.motion.kernel_args, T_all, tail, t, self._prior_inverse[1], self._prior_inverse[2],
                self.prior_info, self.prior_grad, motion_info, rate_info, rate_on, self.measurement_model.kernel_code,
                ks, slot, offsets, p, z, W, Tvs, w, float(self.robust_c), np.empty(len(z)), T0_inverse, varpi0, H0,
                b0, c0)
        return args, (fresh_sets, fresh, ks, w, offsets, T0_inverse, varpi0)

    def _normal_equations(self, n: int, lagged: bool, first_only: bool = False):
        """(H, b, cost) of the window's first n states in one compiled call (`_arguments`)."""
        args, kept = self._arguments(n, lagged, first_only)
        d, K = self.motion.dim, len(kept[2])
        H, b = np.zeros((n * d, n * d)), np.zeros(n * d)
        Hm, bm, cm = np.empty((K, 12, 12)), np.empty((K, 12)), np.empty(K)
        cost = window_kernels.normal_equations(*args, H, b, Hm, bm, cm)
        self._linearized(*kept, Hm, bm, cm)  # views: fresh arrays
        return H, b, float(cost)

    # --- solving ----------------------------------------------------------------------------------------
    def optimize(self, iterations: int = 5, tol: float = 1e-6, sigma_tol: float = 0.0,
                 check_last: bool = True, reweight: bool = True, marginal: bool = False) -> dict:
        """Gauss-Newton; a step that increases the cost is halved (one linearisation per iteration).

        A full step whose largest element is below tol, or whose length in the information metric,
        sqrt(d^T H d), is below sigma_tol, is the last: it is applied without linearising again (near the
        solution convergence is quadratic, so the step after it would be ~tol^2 and the cost check cannot fail
        meaningfully; and sqrt(d^T H d) >= |d_i| / sigma_i for every element, sigma_i its posterior standard
        deviation, so no element of such a step moves by more than sigma_tol of its uncertainty).
        check_last=False applies the step of the last iteration without the cost check (for a refinement from a
        solution of a nearly identical problem). reweight=False (a refinement) keeps the robust weights the sets
        have (a new set gets its own) and the older states' terms lagged throughout, when `relinearize_older` is
        False; with it True every solve re-weights and re-linearises all. Returns {'iterations', 'cost', 'step'}
        (the cost at the last linearisation); the normal equations of the last linearisation (at the returned
        estimate, or one step before it) are kept for `newest_covariance`.

        The loop runs in one compiled call (`window_kernels.gauss_newton`); where an H is not numerically positive
        definite, the loop in Python (`_optimize`) does it all again, its solve with a jitter (`spd.solve_spd`).
        marginal: the compiled call also takes the oldest state's Schur complement at the solution, which
        `marginalize_oldest` then uses if nothing has changed since (the odometry's last solve of a scan).
        """
        if reweight or self.relinearize_older:
            self.reset_robust_weights()
        try:
            return self._gauss_newton(iterations, tol, sigma_tol, check_last, not reweight, marginal)
        except np.linalg.LinAlgError:
            return self._optimize(iterations, tol, sigma_tol, check_last, lagged=not reweight)

    def _gauss_newton(self, iterations: int, tol: float, sigma_tol: float, check_last: bool, lagged: bool,
                      marginal: bool = False) -> dict:
        """`optimize`'s loop compiled; if it raises, the window is as it was (`SetPacks.pack` resets the weights
        it set)."""
        n, d = len(self.states), self.motion.dim
        args, kept = self._arguments(n, lagged)
        K = len(kept[2])
        T, tail, H, b, L = (np.empty((n, 4, 4)), np.empty((n, d - 6)), np.empty((n * d, n * d)), np.empty(n * d),
                            np.empty((n * d, n * d)))
        Hm, bm, cm, out, Lam, g = (np.empty((K, 12, 12)), np.empty((K, 12)), np.empty(K), np.empty(4),
                                   np.empty((d, d)), np.empty(d))
        window_kernels.gauss_newton(*args, bool(self.relinearize_older), int(iterations), float(tol), float(sigma_tol),
                                    bool(check_last), T, tail, H, b, L, Hm, bm, cm, out, bool(marginal), Lam, g)
        self._linearized(*kept, Hm, bm, cm)
        self._set_states(_states_at(self.states, T, tail), T, tail)
        self._H, self._factor = H, ((H, L) if out[3] else None)
        self._marginal = (self._marginal_key(), Lam, g) if marginal and n > 1 else None
        return {"iterations": int(out[0]), "cost": float(out[1]), "step": float(out[2])}

    def _optimize(self, iterations: int, tol: float, sigma_tol: float, check_last: bool, lagged: bool) -> dict:
        """`optimize`'s loop in Python, the reference of the compiled one, with the jitter of `spd.solve_spd`."""
        H, b, cost = self.linearize(lagged=lagged)
        step, it = 1.0, 0
        for it in range(1, iterations + 1):
            delta, factor = solve_spd(H, -b, factor=True)
            self._factor = (H, factor)
            size = float(np.max(np.abs(delta)))  # NaN when delta holds one
            if not math.isfinite(size):
                break
            T_all, tail, _ = self._stacked()
            old, old_stack = self.states, self._stack
            if step == 1.0 and (size < tol or -(delta @ b) < sigma_tol**2):
                self._set_states(*_oplus_all(old, T_all, tail, delta.reshape(len(old), -1)))
                break
            self._set_states(*_oplus_all(old, T_all, tail, step * delta.reshape(len(old), -1)))
            if it == iterations and not check_last:
                break
            H2, b2, cost2 = self.linearize(lagged=True)
            if np.isfinite(cost2) and cost2 <= cost * (1 + 1e-12) + 1e-12:
                H, b, cost = H2, b2, cost2
                if step * size < tol:  # step a power of two: the largest element of step * delta, exactly
                    break
                step = 1.0
            else:
                self.states, self._stack = old, old_stack
                step *= 0.5
                if step < 1e-3:
                    break
        self._H = H
        return {"iterations": it, "cost": float(cost), "step": float(step)}

    def newest_covariance(self) -> np.ndarray:
        """Posterior covariance of the newest state (left perturbation), from the window's information."""
        return self.newest_covariances()[0]

    def newest_covariances(self) -> tuple[np.ndarray, np.ndarray | None]:
        """(P of the newest state, joint covariance (2 dim, 2 dim) of the two newest states [x_{n-2}; x_{n-1}] or
        None when the window holds one state): the trailing block of the inverse of the window's information
        (`spd.trailing_inverse`), from the Cholesky factor of the solve's last step when that was taken with the
        kept information (P is the newest block of the joint covariance)."""
        H = self._H if self._H is not None else self.linearize()[0]
        d = self.motion.dim
        k = min(len(self.states), 2) * d
        kept = self._factor if self._factor is not None and self._factor[0] is H else None
        X = trailing_inverse(H, k, None if kept is None else kept[1])
        return X[-d:, -d:].copy(), (X if k == 2 * d else None)

    def _marginal_key(self) -> tuple:
        """What the oldest state's Schur complement depends on besides the window's mutators (which all unset _H)
        and its linearisations (which drop it, `_linearized`): the solve's H, the two oldest states, the prior and
        the lag setting (compared by identity)."""
        return (self._H, *self.states[:2], self.prior_mean, self.prior_info, self.prior_grad, self.relinearize_older)

    def marginalize_oldest(self, memory: float = 0.0) -> None:
        """Schur complement of the oldest state into a Gaussian prior on the next one; with memory > 0 (s) its
        information and linear term are multiplied by keep = exp(-dt / memory), dt the marginalised interval
        (a prior that forgets, `uncertainty.prior_memory`; 0: the exact Schur complement)."""
        d = self.motion.dim
        x0, x1 = self.states[0], self.states[1]
        keep = float(np.exp((x0.t - x1.t) / memory)) if memory > 0 else 1.0
        kept = self._marginal
        if kept is not None and all(a is b for a, b in zip(kept[0], self._marginal_key())):  # the last solve's
            Lam, g = kept[1], kept[2]
        else:
            H, b, _ = self._normal_equations(2, lagged=True, first_only=True)
            H00, H01, H11 = H[:d, :d], H[:d, d:], H[d:, d:]
            X = solve_spd(H00, np.column_stack((H01, b[:d])))
            Lam = H11 - H01.T @ X[:, :d]
            g = b[d:] - H01.T @ X[:, d]
        self._marginal = None
        # the new prior on x1: 1/2 e^T Lam e + g^T e with e = x1 (-) x1_now, exactly the Schur complement here
        self.prior_mean = x1.copy()
        self.prior_info = 0.5 * keep * (Lam + Lam.T)  # keep = 1: bit for bit the Schur complement
        self.prior_grad = keep * g
        self.states.pop(0)
        self.meas.pop(0)
        self.rate_prior.pop(0)
        self.motion_info.pop(0)
        self._motion_info = None
        self._H = None


def _oplus_all(states: list[State], T_all: np.ndarray, tail: np.ndarray, d: np.ndarray):
    """[x_k (+) d_k] for the whole window with one compiled batched exponential (`State.oplus` for all k), T_all
    and tail the states stacked (`state.stacked`). Returns (states, T (n, 4, 4), tail (n, d - 6)); the states'
    arrays are views of T and tail."""
    T = np.empty((len(states), 4, 4))
    motion_kernels.exp_times(np.ascontiguousarray(d[:, :6]), T_all, T)
    tail = tail + d[:, 6:]
    return _states_at(states, T, tail), T, tail


def _states_at(states: list[State], T: np.ndarray, tail: np.ndarray) -> list[State]:
    """The states at T (n, 4, 4) and tail (n, d - 6) with the times of `states`; their arrays are views."""
    return [State(x.t, T[k], tail[k, :6], None if x.varpi_dot is None else tail[k, 6:12]) for k, x in enumerate(states)]
