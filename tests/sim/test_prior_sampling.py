"""Prior Monte Carlo (Fig. 1): SDE samples against the prior's propagated Gaussian; the CLI command."""

import json

import numpy as np
import pytest

from rodo.estimator.errors import InputError
from rodo.estimator.priors import ConstantAccelerationPrior
from rodo.estimator.priors.exact import exact_predict
from rodo import cli
from rodo.commands import prior as prior_cmd
from rodo.sim import prior_sampling as ps

N = 2000


@pytest.fixture(scope="module")
def case():
    c = ps.yaw_acceleration_case()
    prior = ConstantAccelerationPrior(c["Qc"])
    state = {k: c[k] for k in ("T0", "varpi0", "vd0", "P0", "dt")}
    mean, P = ps.propagate_mean_cov(prior, **state)
    samples = ps.sample_prior(prior, **state, n_samples=N, rng=np.random.default_rng(np.random.SeedSequence(1)))
    return c, prior, state, mean, P, samples


def test_monte_carlo_nees_within_chi2_bounds(case):
    _, _, _, mean, P, samples = case
    lo, hi = ps.nees_bounds(N)
    np.testing.assert_allclose([lo, hi], [17.74, 18.26], atol=0.01)
    assert lo <= ps.nees(samples, mean, P).mean() <= hi


def test_sample_covariance_matches_propagated_covariance(case):
    """Likelihood-ratio test of Cov(x (-) x_mean) = P (171 dof) and Hotelling-type test of a zero mean."""
    _, _, _, mean, P, samples = case
    stat, dof, p = ps.covariance_test(samples, mean, P)
    assert dof == 171 and p > 1e-3
    z = np.linalg.solve(np.linalg.cholesky(P), ps.errors(samples, mean).T)
    from scipy import stats

    assert stats.chi2.sf(N * np.sum(z.mean(axis=1) ** 2), 18) > 1e-3


def test_checks_have_power(case):
    """The same samples reject a Gaussian with a 20 % wrong Q_k, without Q_k, or from the first-order prior."""
    c, prior, _, mean, _, samples = case
    F, Q = prior.transition_and_noise(c["varpi0"], c["vd0"], c["dt"])
    F1, Q1 = ConstantAccelerationPrior(c["Qc"], magnus_order=1).transition_and_noise(c["varpi0"], c["vd0"], c["dt"])
    for P_wrong in (F @ c["P0"] @ F.T + 1.2 * Q, F @ c["P0"] @ F.T + 1e-9 * np.eye(18),
                    F1 @ c["P0"] @ F1.T + Q1):
        assert ps.covariance_test(samples, mean, P_wrong)[2] < 1e-6


def test_sampling_is_reproducible_and_starts_from_p0(case):
    c, prior, state, _, _, _ = case
    a = ps.sample_prior(prior, **state, n_samples=5, rng=np.random.default_rng(np.random.SeedSequence(3)),
                        substeps=4)
    b = ps.sample_prior(prior, **state, n_samples=5, rng=np.random.default_rng(np.random.SeedSequence(3)),
                        substeps=4)
    for x, y in zip(a, b):
        assert x.tobytes() == y.tobytes()
    # zero noise and zero P0: every sample follows the exact mean flow (sub-step Magnus error only)
    quiet = ConstantAccelerationPrior(c["Qc"] * 1e-30)
    st = dict(state, P0=np.zeros((18, 18)))
    T, varpi, varpi_dot = ps.sample_prior(quiet, **st, n_samples=3, rng=np.random.default_rng(0), substeps=20)
    T_mean, varpi_mean, varpi_dot_mean = exact_predict(c["T0"], c["varpi0"], c["vd0"], c["dt"])
    assert np.abs(T - T_mean).max() < 1e-9
    assert np.abs(varpi - varpi_mean).max() < 1e-12 and np.abs(varpi_dot - varpi_dot_mean).max() < 1e-15


@pytest.mark.parametrize("kwargs, name", [
    (dict(rng=np.random.RandomState(0)), "rng"), (dict(n_samples=0), "n_samples"), (dict(substeps=0), "substeps"),
    (dict(dt=0.0), "dt"), (dict(P0=-np.eye(18)), "P0"), (dict(P0=np.eye(6)), "P0"),
    (dict(varpi0=np.zeros(5)), "varpi0"), (dict(T0=np.full((4, 4), np.nan)), "T0"),
])
def test_sample_prior_bad_input(case, kwargs, name):
    _, prior, state, _, _, _ = case
    args = dict(state, n_samples=3, rng=np.random.default_rng(0))
    args.update(kwargs)
    with pytest.raises(InputError, match=name):
        ps.sample_prior(prior, **args)


def test_cli_prior_montecarlo(tmp_path, capsys):
    out = tmp_path / "mc"
    argv = ["prior-montecarlo", "--samples", "400", "--seed", "2", "--substeps", "50", "--noise", "subinterval",
            "--out", str(out)]
    code = cli.main(argv, commands=[prior_cmd])
    result = json.loads((out / "prior_montecarlo.json").read_text())
    assert code == 0 and result["pass"] is True and result["noise"] == "subinterval"
    lo, hi = result["nees_bounds_95"]
    assert lo <= result["mean_nees"] <= hi
    data = np.load(out / "prior_montecarlo.npz")
    assert data["T"].shape == (400, 4, 4) and data["covariance"].shape == (18, 18)
    assert "mean NEES" in capsys.readouterr().out
    assert cli.main(["prior-montecarlo", "--samples", "1", "--out", str(out)], commands=[prior_cmd]) == 2
    assert cli.main(["prior-montecarlo", "--dt", "-1", "--out", str(out)], commands=[prior_cmd]) == 2
