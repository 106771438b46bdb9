"""The covariance likelihood-ratio test of the prior Monte Carlo (sim/prior_sampling.py) at small sample counts:
Bartlett-corrected, it holds its level on N(0, I) data from its minimum sample count on; below that count it is
refused (in Python and by `rodo prior-montecarlo --samples`), instead of failing a correct prior."""

import json

import numpy as np
import pytest
from scipy import stats

from rodo.estimator.errors import InputError
from rodo.sim import prior_sampling as ps
from tests.cli.helpers import fails

TRIALS = 4000


@pytest.mark.parametrize("d, n", [(18, 62), (18, 300), (6, 22)])
def test_covariance_test_holds_its_level_on_normal_data(d, n):
    """On TRIALS sets of n draws of N(0, I_d) the share of p < alpha lies in the 99.9 % binomial interval of alpha
    for alpha = 1e-3, 1e-2 and 0.05. (The plain statistic against chi2 rejected 2 % of them at alpha = 1e-3 for
    d = 18, n = 62, and 0.2 % at n = 300; the reviewer's n = 19 .. 50: 98 % .. 4.8 %.)"""
    rng = np.random.default_rng(np.random.SeedSequence([d, n]))
    p = np.array([ps.whitened_covariance_test(rng.standard_normal((n, d)))[2] for _ in range(TRIALS)])
    assert np.all((0 <= p) & (p <= 1))
    for alpha in (1e-3, 1e-2, 0.05):
        lo, hi = stats.binom.interval(0.999, TRIALS, alpha)
        assert lo <= np.sum(p < alpha) <= hi, (alpha, np.sum(p < alpha), lo, hi)


def test_covariance_test_keeps_its_power():
    """Errors 1.3x their claimed sigma (a covariance 40 % too small) are rejected at alpha = 1e-3 on every set of
    the minimum count, 62; errors 1.2x their sigma on every set of 300 samples."""
    rng = np.random.default_rng(5)
    for n, scale in ((62, 1.3), (300, 1.2)):
        p = np.array([ps.whitened_covariance_test(scale * rng.standard_normal((n, 18)))[2] for _ in range(200)])
        assert np.all(p < 1e-3), (n, np.mean(p < 1e-3))


def test_too_few_samples_are_refused():
    """n <= d (a singular sample covariance) and n below the minimum (the approximation's level gone) are refused
    with the count and the minimum; the minimum itself is accepted."""
    assert [ps.covariance_test_min_samples(d) for d in (1, 6, 12, 18)] == [4, 22, 42, 62]
    rng = np.random.default_rng(0)
    for n in (10, 18, 19, 61):
        with pytest.raises(InputError, match=f"{n} samples of dimension 18 are too few.*at least 62"):
            ps.whitened_covariance_test(rng.standard_normal((n, 18)))
    stat, dof, p = ps.whitened_covariance_test(rng.standard_normal((62, 18)))
    assert dof == 171 and np.isfinite(stat) and 0 < p <= 1
    with pytest.raises(InputError, match="finite"):
        ps.whitened_covariance_test(np.full((100, 3), np.nan))


def test_cli_refuses_too_few_samples_and_passes_a_correct_prior_at_the_minimum(tmp_path, capsys):
    """`--samples 10` (the reviewer's case: 'covariance LRT p = 0: FAIL') is refused with one line naming --samples
    and the minimum, before anything is written; 62 samples of the correct prior pass."""
    from rodo.cli import main

    fails(capsys, ["prior-montecarlo", "--samples", "10", "--out", tmp_path / "p10"], "--samples", "10",
          "at least 62")
    assert not (tmp_path / "p10").exists()
    out = tmp_path / "p62"
    assert main(["prior-montecarlo", "--samples", "62", "--substeps", "20", "--out", str(out)]) == 0
    result = json.loads((out / "prior_montecarlo.json").read_text())
    assert result["pass"] is True and result["covariance_lrt_p"] > 1e-3
    assert result["covariance_lrt_bartlett_factor"] == pytest.approx(1 - 701 / (6 * 62 * 19))
    assert "covariance LRT p = " in capsys.readouterr().out
