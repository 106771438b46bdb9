"""Sliding-window MAP: the compiled normal equations against the terms assembled in NumPy, Schur marginalisation,
the newest covariances, the lagged terms, the zero-mean rate terms and the packed-set cache. The solve (Gauss-Newton,
compiled and in Python) is in test_window_solve.py, the kernels the window is built from in
test_window_kernels.py, the odometry end to end in test_odometry.py."""

import copy

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from rodo.estimator import measurements
from rodo.estimator.lie import se3
from rodo.estimator.measurement_models import PolarModel
from rodo.estimator.motion import motion_prior
from rodo.estimator.state import State, stacked
from rodo.estimator.spd import solve_spd, trailing_inverse
from rodo.estimator.window import MeasurementSet, SlidingWindow
from tests.estimator import scene
from tests.estimator.window_scene import window_with_scene
from tests.strategies import covariances, hypothesis_rngs


def test_marginalisation_keeps_the_solution_and_the_newest_covariance():
    """Schur complement at the optimum: re-solving after marginalising the oldest state changes nothing,
    and the newest state's covariance is the same before and after (robust loss off: re-weighting would
    be an outer iteration that legitimately moves the solution)."""
    win, _ = window_with_scene(noisy=True, robust_c=0.0)
    win.optimize(10)
    before = [x.copy() for x in win.states[1:]]
    P_before = win.newest_covariance()
    win.marginalize_oldest()
    P_after = win.newest_covariance()
    np.testing.assert_allclose(P_after, P_before, rtol=1e-6, atol=1e-14)
    win.optimize(10)
    for a, b in zip(before, win.states):
        assert np.abs(a.ominus(b)).max() < 1e-7


@settings(max_examples=60, deadline=None)
@given(st.sampled_from([(12, 6), (18, 12), (36, 12), (60, 24)]).flatmap(
    lambda nk: st.tuples(st.just(nk[1]), covariances(nk[0]))), st.booleans())
def test_trailing_inverse_is_the_block_of_the_inverse(k_and_H, factored):
    """The trailing k x k block of H^-1 from the trailing block of H's Cholesky factor, whether the factor is
    passed in (the solve's) or computed: equal to the block of a full solve to the conditioning's rounding, and
    exactly symmetric."""
    k, H = k_and_H
    factor = solve_spd(H, np.ones(len(H)), factor=True)[1] if factored else None  # dposv's: H above the diagonal
    X = trailing_inverse(H, k, factor)
    E = np.zeros((len(H), k))
    E[-k:] = np.eye(k)
    reference = np.linalg.solve(H, E)[-k:]
    assert np.array_equal(X, X.T)
    np.testing.assert_allclose(X, reference, rtol=0, atol=1e-12 * np.linalg.cond(H) * np.abs(reference).max())


def test_trailing_inverse_of_a_semidefinite_information_is_the_jittered_solve():
    """An H whose leading block is singular (a state nothing constrains) has no Cholesky factor: the trailing
    block, decoupled from it, is still the inverse of its own block (the solve's relative jitter, 1e-12)."""
    B = np.array([[4.0, 1.0, 0.5], [1.0, 3.0, 0.2], [0.5, 0.2, 2.0]])
    H = np.zeros((5, 5))
    H[2:, 2:] = B
    np.testing.assert_allclose(trailing_inverse(H, 3), np.linalg.inv(B), rtol=1e-10)


@pytest.mark.parametrize("kind", ["ca", "cv"])
def test_newest_covariances_are_the_trailing_block_of_the_inverse_information(kind):
    """After a solve (the factor of its last step reused) and after a fresh linearisation (factored anew), P of
    the newest state and the joint P of the two newest are the trailing blocks of the inverse of the window's
    information."""
    win, _ = window_with_scene(kind)
    win.optimize(10)
    d = win.motion.dim
    for fresh in (False, True):
        if fresh:
            win.set_measurements(len(win.states) - 1, win.meas[-1])  # forgets the kept information
        assert (win._factor[0] is win._H) is not fresh  # the solve's factor is the kept information's, or stale
        P, P_pair = win.newest_covariances()
        inverse = np.linalg.inv(win._H if not fresh else win.linearize()[0])[-2 * d:, -2 * d:]
        atol = 1e-10 * np.abs(inverse).max()
        np.testing.assert_allclose(P_pair, inverse, rtol=1e-8, atol=atol)
        np.testing.assert_allclose(P, inverse[-d:, -d:], rtol=1e-8, atol=atol)


@pytest.mark.parametrize("memory", [0.05, 0.5, 5.0])
def test_a_forgetting_prior_is_the_schur_complement_scaled(memory):
    """marginalize_oldest(memory): the prior's information and linear term are the exact Schur complement's times
    exp(-dt / memory), dt the marginalised interval, at the same mean; memory 0 is the exact one, bit for bit
    (`uncertainty.prior_memory`)."""
    exact, _ = window_with_scene(noisy=True)
    exact.optimize(10)
    forgetting = copy.deepcopy(exact)
    default = copy.deepcopy(exact)
    dt = exact.states[1].t - exact.states[0].t
    exact.marginalize_oldest(0.0)
    default.marginalize_oldest()
    forgetting.marginalize_oldest(memory)
    assert np.array_equal(default.prior_info, exact.prior_info) and np.array_equal(default.prior_grad,
                                                                                    exact.prior_grad)
    keep = np.exp(-dt / memory)
    assert 0 < keep < 1
    np.testing.assert_allclose(forgetting.prior_info, keep * exact.prior_info, rtol=1e-12, atol=0)
    np.testing.assert_allclose(forgetting.prior_grad, keep * exact.prior_grad, rtol=1e-12, atol=1e-300)
    assert np.array_equal(forgetting.prior_mean.T_vehicle_world, exact.prior_mean.T_vehicle_world)
    # the newest state's covariance grows: less information, never more
    assert np.all(np.linalg.eigvalsh(forgetting.newest_covariance() - exact.newest_covariance()) > -1e-15)

@pytest.mark.parametrize("kind", ["ca", "cv"])
@given(roll=st.floats(-0.2, 0.2), pitch=st.floats(-0.2, 0.2), sigma=st.floats(1e-3, 0.1))
def test_rate_prior_is_a_zero_mean_gaussian_term(kind, roll, pitch, sigma):
    """One state with a Gaussian prior (rates with 1-sigma 0.02 rad/s around roll, pitch) and the zero-mean term
    on its roll and pitch rates (sigma): the solve gives the product of the two Gaussians, mean r s0^2^-1 /
    (s0^-2 + sigma^-2), and the covariance's rate block (s0^-2 + sigma^-2)^-1; nothing else moves."""
    motion = motion_prior(kind, (2.0, 0.05, 0.05, 1e-3, 1e-3, 0.05))
    d = motion.dim
    win = SlidingWindow(motion, 4, PolarModel(), scene.T_VEHICLE_SENSOR)
    varpi = np.array([-10.0, 0.1, 0.0, roll, pitch, 0.05])
    x0 = State(0.0, se3.exp(np.array([1.0, 2.0, 0.1, 0.01, -0.02, 0.3])), varpi, np.zeros(6) if kind == "ca" else None)
    s0 = 0.02
    win.initialize(x0, np.diag(np.full(d, s0**2)))
    info = np.zeros((d - 6, d - 6))
    info[3, 3] = info[4, 4] = sigma**-2
    win.set_rate_prior(0, info)
    win.optimize(5, 1e-12)
    x = win.newest
    shrink = s0**-2 / (s0**-2 + sigma**-2)
    np.testing.assert_allclose(x.varpi[3:5], shrink * varpi[3:5], rtol=1e-9, atol=1e-15)
    np.testing.assert_allclose(np.delete(x.varpi, [3, 4]), np.delete(varpi, [3, 4]), atol=1e-12)
    np.testing.assert_allclose(x.T_vehicle_world, x0.T_vehicle_world, atol=1e-12)
    P = win.newest_covariance()
    np.testing.assert_allclose(np.diag(P)[9:11], 1.0 / (s0**-2 + sigma**-2), rtol=1e-9)


@pytest.mark.parametrize("kind", ["ca", "cv"])
def test_rate_terms_are_read_as_they_were_set(kind):
    """`set_rate_prior` keeps its own copy, one for a term equal to the last one set (so a term set every scan
    keeps the window's kernel arrays): a term the caller changes afterwards, an equal term set on the next
    state, another term set on one state and a term removed are each read as set: each state's rate block of H
    is that of the window without terms plus its term, and every linearisation equals that of a fresh window
    given the terms once."""
    d = motion_prior(kind, (1, .05, .05, .01, .01, .05)).dim
    info = np.diag(np.arange(1.0, d - 5)) * 1e6
    terms = {}
    bare = window_with_scene(kind)[0].linearize()[0]

    def check(k, term):
        terms[k] = None if term is None else term.copy()
        win.set_rate_prior(k, term)
        fresh, _ = window_with_scene(kind)
        for k_, term_ in terms.items():
            fresh.set_rate_prior(k_, term_)
        H = win.linearize()[0]
        for k_ in range(len(win.states)):
            rates = slice(k_ * d + 6, (k_ + 1) * d)
            want = 0.0 if terms.get(k_) is None else terms[k_]
            np.testing.assert_allclose(H[rates, rates] - bare[rates, rates], want, rtol=1e-9, atol=1e-3)
        for got, want in zip(win.linearize(), fresh.linearize()):
            assert np.array_equal(got, want)

    win, _ = window_with_scene(kind)
    check(0, info)
    info *= 3  # the caller's array changes: the window's term does not
    check(1, info / 3)  # equal to the last one set: the same copy
    assert win.rate_prior[1] is win.rate_prior[0]
    check(2, info)
    check(3, info / 3)
    check(1, None)
    check(0, 2 * info)


def test_replaced_measurement_sets_are_never_read_stale():
    """The window caches its measurement sets packed for the kernel. A set replaced by a new one (which CPython
    often allocates at the freed set's address, so the same id()) must be packed anew: every linearisation
    equals that of a fresh window holding the same set. (The cache once compared id()s and read a freed set's
    pairs: a stop_and_go run ended with an improper rotation.)"""
    rng = np.random.default_rng(3)
    motion = motion_prior("ca", (2.0, 0.05, 0.05, 1e-3, 1e-3, 0.05))
    t, T, varpi, vd = scene.trajectory(2)
    x0 = State(t[0], T[0], varpi[0], vd[0])
    R_inv = np.linalg.inv(np.diag(scene.SIGMAS**2))

    def one_set(n):
        p = scene.landmarks(rng, n=n)
        z = measurements.predict("polar", T[0], varpi[0], p, scene.T_VEHICLE_SENSOR).z
        return MeasurementSet(p, z + rng.normal(size=z.shape) * scene.SIGMAS, np.broadcast_to(R_inv, (n, 4, 4)).copy())

    win = SlidingWindow(motion, 4, PolarModel(), scene.T_VEHICLE_SENSOR)
    win.initialize(x0, np.eye(18) * 0.01)
    for n in rng.integers(5, 60, 40):
        win.set_measurements(0, None)  # the previous set has no other reference: freed here
        win.set_measurements(0, one_set(int(n)))
        fresh = SlidingWindow(motion, 4, PolarModel(), scene.T_VEHICLE_SENSOR)
        fresh.initialize(x0, np.eye(18) * 0.01)
        fresh.set_measurements(0, MeasurementSet(win.meas[0].p_world, win.meas[0].z, win.meas[0].W))
        win.reset_robust_weights()
        for a, b in zip(win.linearize(), fresh.linearize()):
            np.testing.assert_array_equal(a, b)
        del fresh


def _gaps(win, moved):
    """(lagged, exact) (H, b, cost) of the window at the states `moved`, the robust weights held."""
    win._set_states(moved, *stacked(moved)[:2])
    lagged = win.linearize(lagged=True)
    win.relinearize_older = True  # the same weights, every state linearised afresh
    exact = win.linearize(lagged=True)
    win.relinearize_older = False
    return lagged, exact


@pytest.mark.parametrize("kind", ["ca", "cv"])
@given(rng=hypothesis_rngs())
@settings(max_examples=5, deadline=None)
def test_lagged_terms_are_the_quadratic_model_of_the_last_linearisation(kind, rng):
    """`relinearize_older` False: between two linearisations of a solve, the older states' measurement terms come
    from the quadratic model of the last one. Where the states have not moved they equal a fresh linearisation.
    Every state moved by about 1e-3 (m, rad, m/s, ...; the older states' moves between linearisations in the
    odometry are 1e-4 median, a few 1e-3 at most), the model reproduces the change of the cost and of the gradient
    to 0.2 % and 0.5 % (measured: at most 5e-4 and 1.4e-3, CV; the CA terms are dominated by the stiff prior), and
    H differs at first order in the move (the Jacobians' change, which the model leaves out: halving the move
    halves the gap)."""
    win, _ = window_with_scene(kind)
    win.relinearize_older = False
    win.optimize(10, 1e-10)
    at = list(win.states)
    win.reset_robust_weights()
    H0, b0, c0 = win.linearize()
    for a, b in zip(*_gaps(win, at)):
        np.testing.assert_allclose(a, b, rtol=1e-12, atol=1e-9 * np.max(np.abs(H0)))
    direction = rng.uniform(0.5, 1.5, (len(at), win.motion.dim)) * rng.choice([-1.0, 1.0], (len(at), win.motion.dim))
    H_gaps = []
    for eps in (1e-3, 5e-4):
        (H, b, c), (H1, b1, c1) = _gaps(win, [x.oplus(eps * d) for x, d in zip(at, direction)])
        win._set_states(at, *stacked(at)[:2])
        assert abs(c - c1) < 2e-3 * abs(c1 - c0)
        assert np.max(np.abs(b - b1)) < 5e-3 * np.max(np.abs(b1 - b0))
        H_gaps.append(np.max(np.abs(H - H1)))
    assert 0.4 < H_gaps[1] / H_gaps[0] < 0.6, H_gaps


@pytest.mark.parametrize("kind", ["ca", "cv"])
def test_compiled_normal_equations_equal_the_python_assembly(kind):
    """`window_kernels.normal_equations` (through `SlidingWindow.linearize`) = the window's terms assembled in
    NumPy from the references: the prior on the oldest state (its mean moved off, a linear term g), the motion
    terms (`MotionPrior.residuals`), each state's measurements (`measurements.predict`, Cauchy weights) and
    a rate term; the cost with them. And the marginalisation's (the oldest state's terms only) equals the same
    restricted to the two oldest states."""
    win, _ = window_with_scene(kind)
    rng = np.random.default_rng(9)
    d, n = win.motion.dim, len(win.states)
    win.prior_mean = win.states[0].oplus(rng.normal(size=d) * 1e-2)
    win.prior_grad = rng.normal(size=d) * 1e3
    A = rng.normal(size=(d, d))
    win.prior_info = 1e6 * (A @ A.T + np.eye(d))  # as strong as the measurements: every term shows in H
    info = np.diag(rng.uniform(1, 10, d - 6)) * 1e6
    win.set_rate_prior(0, info)
    win.set_rate_prior(2, 2 * info)
    H, b, cost = win.linearize()

    def reference(n_states, first_only):
        states = win.states[:n_states]
        Hr, br = np.zeros((n_states * d, n_states * d)), np.zeros(n_states * d)
        x0, mean = states[0], win.prior_mean
        xi = se3.log(x0.T_vehicle_world @ se3.inverse(mean.T_vehicle_world))
        e = np.concatenate([xi, x0.vector_tail() - mean.vector_tail()])
        J = np.eye(d)
        J[:6, :6] = se3.left_jacobian_inv(xi)
        Hr[:d, :d] += J.T @ win.prior_info @ J
        br[:d] += J.T @ (win.prior_info @ e + win.prior_grad)
        c = 0.5 * e @ win.prior_info @ e + win.prior_grad @ e
        E, J1, J2 = win.motion.residuals(states)
        for k in range(n_states - 1):
            Jk = np.concatenate([J1[k], J2[k]], axis=1)
            sl = slice(k * d, (k + 2) * d)
            Hr[sl, sl] += Jk.T @ win.motion_info[k] @ Jk
            br[sl] += Jk.T @ win.motion_info[k] @ E[k]
            c += 0.5 * E[k] @ win.motion_info[k] @ E[k]
        for k, x in enumerate(states[:1] if first_only else states):
            if win.rate_prior[k] is not None:
                tail = x.vector_tail()
                Hr[k * d + 6:(k + 1) * d, k * d + 6:(k + 1) * d] += win.rate_prior[k]
                br[k * d + 6:(k + 1) * d] += win.rate_prior[k] @ tail
                c += 0.5 * tail @ win.rate_prior[k] @ tail
            m = win.meas[k]
            pred = measurements.predict("polar", x.T_vehicle_world, x.varpi, m.p_world, scene.T_VEHICLE_SENSOR)
            r = measurements.residual("polar", m.z, pred.z)
            Jm = np.concatenate([pred.J_z_xi, pred.J_z_varpi], axis=2)
            d2 = np.einsum("ma,mab,mb->m", r, m.W, r)
            w = m.weights if m.weights is not None else 1.0 / (1.0 + d2 / win.robust_c**2)
            WJ = m.W @ Jm * w[:, None, None]
            Hr[k * d:k * d + 12, k * d:k * d + 12] += np.einsum("mai,maj->ij", Jm, WJ)
            br[k * d:k * d + 12] -= np.einsum("mai,ma->i", WJ, r)
            c += 0.5 * np.sum(w * d2)
        return Hr, br, c

    for (got, want) in ((win.linearize(), reference(n, False)),
                        (win._normal_equations(2, lagged=False, first_only=True), reference(2, True))):
        np.testing.assert_allclose(got[0], want[0], rtol=1e-9, atol=1e-9 * np.abs(want[0]).max())
        np.testing.assert_allclose(got[1], want[1], rtol=1e-9, atol=1e-9 * np.abs(want[1]).max())
        assert got[2] == pytest.approx(want[2], rel=1e-9)
    np.testing.assert_array_equal(H, win.linearize()[0])  # the weights set by the first stay
