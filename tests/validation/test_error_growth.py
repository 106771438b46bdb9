"""validation/error_growth.py: per axis and span, E[e^2 / sigma^2] of runs whose errors follow their covariance
comes out near 1, and near s^2 on an axis whose errors are s times what it states, the velocity and the
acceleration at the scan as the pose's spans; the sums pool by adding."""

import numpy as np
import pytest

from rodo.estimator.lie import se3
from rodo.validation import replayed_states as rs
from rodo.validation.error_growth import AXES, error_growth, growth_lines, growth_table, pooled_growth
from tests.validation.synthetic_drives import stated_run, straight_drive

DT, N = 0.1, 600
SIGMA = np.array([3e-3, 3e-3, 3e-3, 2e-4, 2e-4, 5e-4])  # per scan
SPANS = (0.0, 1.0, 5.0)
RUNS = 12


def _run(seed: int, scale=np.ones(6)):
    """(states, truth) of a drive whose pose error is the drift recursion's at tau 0 (xi_k = Ad(R_k) xi_{k-1} +
    delta_k, delta_k ~ N(0, diag((scale SIGMA)^2))) while its states say diag(SIGMA^2): driven slowly
    (0.06-0.1 m per scan), so the rotation errors carried over the distance are a small part of the position's."""
    rng = np.random.default_rng(np.random.SeedSequence([2026, 46, seed]))
    T_true = straight_drive(rng, N, step_range=(0.06, 0.1))
    x = [np.zeros(6)]
    for k in range(1, N):
        x.append(se3.adjoint(T_true[k] @ se3.inverse(T_true[k - 1])) @ x[-1] + rng.normal(size=6) * SIGMA * scale)
    states, truth = stated_run(DT, T_true, x, np.diag(SIGMA**2))
    return rs.replayed(states, 0.0, None), truth


@pytest.fixture(scope="module")
def growths():
    scale = np.array([2.0, 1.0, 1.0, 1.0, 1.0, 1.0])  # the forward errors twice what the covariance says
    return [error_growth(*_run(seed, scale), spans=SPANS) for seed in range(RUNS)]


def test_errors_that_follow_their_covariance_read_one_and_a_scaled_axis_its_square(growths):
    """One scan, 1 s and 5 s: x (twice its stated sigma) near 4, the other axes near 1 (within 15 % over the
    one-scan and 1 s spans of twelve 60 s drives, within 30 % over 5 s: 144 independent spans, a standard error
    of 12 %); each span counted as its starts say, the drive's absolute pose too."""
    table = growth_table(pooled_growth(growths))
    assert [r["label"] for r in table] == ["1 scan", "1 s", "5 s", "drive", "velocity", "acceleration"]
    assert [r["scans"] for r in table] == [1, 10, 50, None, None, None]
    assert [r["count"] for r in table] == [RUNS * (N - 1), RUNS * (N - 10), RUNS * len(range(0, N - 50, 6)),
                                           RUNS * (N - 1), RUNS * N, 0]  # no acceleration in these runs
    want = np.array([4.0, 1.0, 1.0, 1.0, 1.0, 1.0])
    for r, tol in zip(table[:3], (0.15, 0.15, 0.3)):
        np.testing.assert_allclose(r["ratio"], want, rtol=tol, err_msg=r["label"])
    np.testing.assert_allclose(table[0]["rms_sigma"], SIGMA, rtol=1e-6)  # the stated one-scan sigmas
    np.testing.assert_allclose(table[0]["rms_error"], SIGMA * np.sqrt(want), rtol=0.15)
    assert table[3]["ratio"][0] > 2.0  # the absolute pose's forward error: over-confident too


def test_the_sums_pool_by_adding(growths):
    """Two runs pooled: every sum the two runs' added, the mean the pooled one (not the mean of the runs'
    means); runs over other spans are refused; the markdown table has a row per span and one for the drive."""
    a, b = growths[:2]
    pooled = pooled_growth([a, b])
    for k in ("count", "z2", "e2", "var"):
        np.testing.assert_array_equal(pooled[k], np.asarray(a[k]) + np.asarray(b[k]))
    mean = (a["z2"][1] + b["z2"][1]) / (a["count"][1] + b["count"][1])
    assert growth_table(pooled)[1]["ratio"] == pytest.approx(list(mean))
    assert pooled_growth([]) is None
    with pytest.raises(ValueError, match="different spans"):
        pooled_growth([a, dict(b, span=np.array([0.0, 2.0, 5.0]))])
    lines = growth_lines(pooled, lambda v: f"{v:.3g}")
    assert lines[3] == "| span | scans | spans | " + " | ".join(AXES) + " |" and len(lines) == 5 + len(SPANS) + 3
    assert lines[-3].startswith("| drive | - |")
    assert lines[-1] == "| acceleration | - | 0 | " + " | ".join("-" * 6) + " |"
    old = [{k: v for k, v in g.items() if not k.startswith("vel_")} for g in (a, b)]  # runs before session 51
    assert [r["label"] for r in growth_table(pooled_growth([old[0], b]))][-1] == "drive"
    assert "velocity" not in growth_lines(pooled_growth(old), str)[1]


@pytest.mark.parametrize("kind", ["ca", "cv"])
def test_the_velocity_and_the_acceleration_per_axis(kind):
    """Velocity (and, for a CA run, acceleration) errors drawn from the reported covariance's diagonal, the pitch
    rate's three times it: per axis E[e^2 / P_ii] near 1 and 9 on the pitch rate (within 12 %: 2,400 scans, a
    standard error of 3 %); its RMS sigma the stated one; a CV run's acceleration row empty."""
    v = np.array([1e-3, 4e-3, 2e-3, 1e-3, 5e-4, 2e-3]) ** 2
    scale = np.array([1.0, 1.0, 1.0, 1.0, 3.0, 1.0])
    dim = 18 if kind == "ca" else 12
    runs = []
    for seed in range(4):
        states, truth = _run(seed)
        rng = np.random.default_rng(np.random.SeedSequence([2026, 51, seed]))
        P = np.tile(np.diag(np.r_[np.full(6, 1e-12), v, v][:dim]), (N, 1, 1))
        truth = {**truth, "varpi": rng.normal(size=(N, 6)), "varpi_dot": rng.normal(size=(N, 6))}
        states = {**states, "P": P, "varpi": truth["varpi"] - rng.normal(size=(N, 6)) * np.sqrt(v) * scale}
        if kind == "ca":
            states["varpi_dot"] = truth["varpi_dot"] - rng.normal(size=(N, 6)) * np.sqrt(v) * scale
        runs.append(error_growth(states, truth, spans=SPANS))
    velocity, acceleration = growth_table(pooled_growth(runs))[-2:]
    assert velocity["label"] == "velocity" and velocity["count"] == 4 * N
    np.testing.assert_allclose(velocity["ratio"], scale**2, rtol=0.12)
    np.testing.assert_allclose(velocity["rms_sigma"], np.sqrt(v), rtol=1e-12)
    if kind == "ca":
        np.testing.assert_allclose(acceleration["ratio"], scale**2, rtol=0.12)
    else:
        assert acceleration["count"] == 0 and acceleration["ratio"] is None


def test_a_run_too_short_for_a_span_counts_none():
    """A 3 s drive has no 5 s span: its row is counted 0 and tabled without ratios."""
    states, truth = _run(9)
    short = {k: (v[:30] if np.ndim(v) and len(v) == N else v) for k, v in states.items()}
    g = error_growth(short, {k: v[:30] for k, v in truth.items()}, spans=SPANS)
    assert g["count"][2] == 0 and g["scans"][2] == 0 and g["count"][1] > 0
    assert growth_table(g)[2]["ratio"] is None
