"""The odometry consistency measures in campaigns: per measure over N runs against chi2_bounds(N, 6), on fake
and on synthetic odometry trials, and a run's per-scan layout and ellipsoid coverage (validation.campaign,
validation.campaign_consistency, validation.run_consistency)."""

from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from rodo.commands.montecarlo import print_consistency
from rodo.validation.campaign import Trial, TrialOutcome, make_trials, read_results, run_campaign, \
    summarize_campaign, write_summary
from rodo.validation.campaign_consistency import campaign_consistency, consistency_lines, \
    fraction_within_per_scan_factor, gross_failure_runs, mean_interval_per_dof, measure_summary, scans_outside, \
    spread_between_runs
from rodo.validation.consistency import chi2_bounds
from rodo.validation.odometry_consistency import MEASURES
from tests.validation.test_campaign import MODELS, FakeTrial


@pytest.mark.parametrize("scale", [1.0, 4.0])
def test_campaign_consistency_per_measure_consistent_and_overconfident(tmp_path, scale, capsys):
    """Per model and measure: the average over N runs per scan against chi2_bounds(N, 6); a consistent trial set
    lies inside, one whose NEES is 4 times chi2(6) (a covariance 4 times too small) outside; a CV model has no
    acceleration measure; summary.md has the table."""
    trials = make_trials(3, 12, MODELS)
    with ProcessPoolExecutor(2) as ex:
        run_campaign(FakeTrial(scans=40, scale=scale), trials, ex, tmp_path)
    s = summarize_campaign(tmp_path)
    lo, hi = chi2_bounds(12, 6)
    for m in MODELS:
        cons, curves = s["models"][m]["consistency"], s["models"][m]["consistency_curves"]
        assert set(cons) == set(MEASURES) and len(curves["t"]) == 40
        for name in MEASURES:
            c = cons[name]
            if name == "acceleration" and m == "cv-cartesian":
                assert c["runs"] == 0 and c["mean_per_dof"] is None and c["fraction_scans_within"] is None
                assert name not in curves
                continue
            assert c["runs"] == 12 and c["dof"] == 6
            assert c["bounds_for_runs"] == pytest.approx([lo, hi]) and c["bounds_per_dof"] == pytest.approx([lo / 6, hi / 6])
            curve = curves[name]
            assert curve["upper"][-1] == pytest.approx(hi) and curve["count"][-1] == 12
            if scale == 1.0:
                assert lo / 6 < c["mean_per_dof"] < hi / 6 and c["fraction_scans_within"] >= 0.85, (m, name, c)
            else:
                assert c["mean_per_dof"] > hi / 6 and c["fraction_scans_within"] <= 0.05, (m, name, c)
            rows = [r for r in read_results(tmp_path / "results.csv") if r["model"] == m]
            assert all(float(r[f"nees_{name}_per_dof"]) > 0 for r in rows)
    write_summary(tmp_path, s)
    md = (tmp_path / "summary.md").read_text()
    assert "| relative_span | 12 |" in md and "| acceleration | 0 | - |" in md
    assert "| spread | with a per-scan factor |" in md
    c = s["models"][MODELS[0]]["consistency"]["velocity"]
    outside = f"{c['scans_below']} / {c['scans_above']} ({c['scans_above_one_run']})"
    assert f"| {c['spread_between_runs']:.4g} | {100 * c['fraction_within_per_scan_factor']:.4g} % | {outside} |" in md
    if scale > 1.0:  # scaled up, the scans' averages are over-confident, none cautious
        assert c["scans_above"] > 0 and c["scans_below"] == 0
    print_consistency(s)
    line = next(x for x in capsys.readouterr().out.splitlines() if MODELS[0] in x and "velocity" in x)
    assert f"spread {c['spread_between_runs']:.2f} (with a per-scan factor" in line
    assert f"below / above {c['scans_below']} / {c['scans_above']} ({c['scans_above_one_run']} one run's)" in line


@dataclass(frozen=True)
class SyntheticOdometryTrial:
    """Runs whose errors are drawn from the covariances they report (times report_scale), measured by the real
    `odometry_nees` through `trial.consistency_of` (the construction of test_odometry_consistency)."""

    report_scale: float = 1.0

    def __call__(self, trial: Trial):
        from rodo.validation.trial import consistency_of
        from tests.validation.test_odometry_consistency import _run

        states, truth = _run(np.random.default_rng(trial.seed), self.report_scale)
        states["velocity_correlation_time"] = 0.0  # the synthetic runs compose without a velocity term
        metrics, arrays = consistency_of(states, truth, states["t"])
        return [TrialOutcome(m, metrics, {"t": states["t"], "nees": np.zeros(len(states["t"])), "nees_dim": 18,
                                          **arrays}) for m in trial.models]


@pytest.mark.parametrize("report_scale", [1.0, 0.25])
def test_campaign_consistency_of_synthetic_odometry_runs(tmp_path, report_scale):
    runs = 40
    with ProcessPoolExecutor(2) as ex:
        run_campaign(SyntheticOdometryTrial(report_scale), make_trials(8, runs, MODELS[:1]), ex, tmp_path)
    cons = summarize_campaign(tmp_path)["models"]["ca-polar"]["consistency"]
    lo, hi = chi2_bounds(runs, 6) / 6
    for name in ("velocity", "relative_scan", "relative_span", "pose"):
        c = cons[name]
        assert c["runs"] == runs
        if report_scale == 1.0:
            assert 0.8 < c["mean_per_dof"] < 1.25 and c["fraction_scans_within"] >= 0.75, (name, c)
        else:
            assert c["mean_per_dof"] > 2 * hi and c["fraction_scans_within"] <= 0.1, (name, c)


def test_run_consistency_per_scan_and_ellipsoid_coverage():
    """scan_measures lays odometry_nees out per state row (NaN where a scan has no truth); consistency_of gives
    the columns and arrays; the ellipsoid of Gaussian position errors holds the truth chi2.cdf(9, 3) of the
    time."""
    from scipy.stats import chi2

    from rodo.estimator.lie import se3
    from rodo.validation.odometry_consistency import odometry_nees
    from rodo.validation.run_consistency import ellipsoid_coverage, scan_measures
    from rodo.validation.trial import consistency_of
    from tests.validation.test_odometry_consistency import _run

    states, truth = _run(np.random.default_rng(1))
    states["velocity_correlation_time"] = 0.0
    cut = {k: np.delete(v, 5, axis=0) for k, v in truth.items()}  # scan 5 has no truth
    m = scan_measures(states, cut, span=0.5)
    ref = odometry_nees(states, cut, span=0.5, tau=0.0)
    assert len(m["pose"]) == len(states["t"]) and np.isnan(m["velocity"][5])
    np.testing.assert_array_equal(np.delete(m["velocity"], 5), ref["velocity"])
    metrics, arrays = consistency_of(states, truth, states["t"])
    assert set(metrics) == {f"nees_{k}_per_dof" for k in MEASURES} | {"ellipsoid_3sigma_pct"}
    assert metrics["nees_pose_per_dof"] == pytest.approx(np.nanmean(arrays["nees_pose"]) / 6)
    assert arrays["nees_measure_dof"] == 6 and arrays["nees_span"] == 1.0
    rng = np.random.default_rng(2)
    n = 4000
    T = se3.exp(rng.normal(size=(n, 6)))
    P = np.zeros((n, 6, 6))
    P[:, :3, :3] = np.diag([0.5, 2.0, 0.1])
    C = T[:, :3, :3]
    Sigma_w = np.swapaxes(C, 1, 2) @ P[:, :3, :3] @ C
    p_est = rng.normal(size=(n, 3))
    p_true = p_est + np.einsum("nij,nj->ni", np.linalg.cholesky(Sigma_w), rng.normal(size=(n, 3)))
    P[0] = 0.0  # a singular covariance: undefined, left out
    cov = ellipsoid_coverage(p_est, p_true, T, P)
    assert np.isnan(cov["inside"][0]) and np.isnan(cov["running_fraction"][0])
    assert cov["claimed"] == pytest.approx(chi2.cdf(9.0, 3))
    assert abs(cov["fraction"] - cov["claimed"]) < 0.01 and cov["running_fraction"][-1] == cov["fraction"]
    far = ellipsoid_coverage(p_est, p_est + 10.0, T, P)
    assert far["fraction"] == 0.0


def _chi2_runs(rng, n_runs, scans, per_run_sigma=0.0, per_scan_mean=None):
    """(n_runs, scans) NEES: chi-square(6) draws, each run scaled by its own lognormal factor (drives that
    disagree beyond chi-square's spread) and each scan by a common mean (a time structure)."""
    X = rng.chisquare(6, (n_runs, scans)) * np.exp(per_run_sigma * rng.standard_normal((n_runs, 1)))
    return X if per_scan_mean is None else X * per_scan_mean


def test_spread_between_runs_and_the_share_with_a_per_scan_factor():
    """Chi-square runs: spread about 1 and about 95 % within with a per-scan factor, as many as are; runs that
    disagree (a lognormal factor per run) spread more and no common per-scan factor brings 90 % within; a mean
    that moves over the scans (the same for every run) loses scans within but changes neither."""
    rng = np.random.default_rng(np.random.SeedSequence(28))
    n = 20
    X = _chi2_runs(rng, n, 2000)
    spread = spread_between_runs(list(X))
    assert 0.95 < spread < 1.05
    share = fraction_within_per_scan_factor(spread, n)
    assert share == pytest.approx(0.95, abs=0.01)
    summary, _ = measure_summary(list(X))
    assert summary["spread_between_runs"] == spread and summary["fraction_within_per_scan_factor"] == share
    assert summary["fraction_scans_within"] == pytest.approx(share, abs=0.02)

    wide = _chi2_runs(rng, n, 2000, per_run_sigma=0.4)
    w_spread = spread_between_runs(list(wide))
    assert w_spread > 1.3 and fraction_within_per_scan_factor(w_spread, n) < 0.9

    moving = np.where(np.arange(2000) < 1000, 0.7, 1.3)
    shaped, _ = measure_summary(list(_chi2_runs(rng, n, 2000, per_scan_mean=moving)))
    assert shaped["spread_between_runs"] == pytest.approx(1.0, abs=0.05)
    assert shaped["fraction_within_per_scan_factor"] == pytest.approx(0.95, abs=0.01)
    assert shaped["fraction_scans_within"] < 0.7


@pytest.mark.parametrize("per_run_sigma", [0.0, 0.5, 1.0])
def test_the_means_interval_holds_the_true_mean_about_as_often_as_it_claims(per_run_sigma):
    """Over 400 campaigns of 20 runs whose NEES is chi-square(6) times a lognormal factor per run (drives that
    disagree beyond chi-square's spread: the absolute pose's case), the 95 % interval of the mean NEES/dof holds
    the true mean exp(sigma^2 / 2) in 92-98 % of them, and the interval narrows with more runs; runs whose mean is 0
    (no log) take the t interval, not below 0."""
    rng = np.random.default_rng(np.random.SeedSequence(71))
    truth = np.exp(per_run_sigma**2 / 2)
    held, widths = [], []
    for _ in range(400):
        X = _chi2_runs(rng, 20, 50, per_run_sigma)
        lo, hi = mean_interval_per_dof(list(X))
        held.append(lo <= truth <= hi)
        widths.append(hi - lo)
    assert 0.92 <= np.mean(held) <= 0.98
    lo80, hi80 = mean_interval_per_dof(list(_chi2_runs(rng, 80, 50, per_run_sigma)))
    assert hi80 - lo80 < 0.75 * np.median(widths)
    assert mean_interval_per_dof([np.full(4, 6.0), np.full(4, 6.0)]) == pytest.approx([1.0, 1.0])
    assert mean_interval_per_dof([np.full(4, 6.0), np.full(4, np.nan)]) is None  # one run with a scan
    assert mean_interval_per_dof([np.full(4, 60.0), np.full(4, 0.0), np.zeros(4)])[0] == 0.0  # not below 0


def test_runs_with_a_gross_failure_are_named_and_summarised_without():
    """A run with one scan whose velocity (or one-scan relative pose) NEES is above 100 per dof is named by its
    trial and every measure is summarised again without it, as over the other runs alone; a huge absolute pose or
    span NEES alone (drift, not a failure) names no run; summary.md's lines say so."""
    rng = np.random.default_rng(np.random.SeedSequence(72))

    def run(trial, **bad):
        a = {"t": np.arange(30) / 10.0, "trial": trial,
             **{f"nees_{k}": rng.chisquare(6, 30) for k in MEASURES if k != "acceleration"}}
        for k, scan in bad.items():
            a[f"nees_{k}"][scan] = 601.0 * 6
        return a

    arrays = [run(10), run(11, velocity=4), run(12, pose=3, relative_span=8), run(13, relative_scan=29), run(14)]
    assert gross_failure_runs(arrays) == [1, 3]
    out = campaign_consistency(arrays)
    assert out["gross_failure_runs"] == [11, 13]
    kept = [arrays[i] for i in (0, 2, 4)]
    for name in ("velocity", "relative_scan", "pose"):
        assert out["consistency_without_gross"][name] == measure_summary([a[f"nees_{name}"] for a in kept])[0]
        assert out["consistency"][name]["runs"] == 5 and out["consistency_without_gross"][name]["runs"] == 3
    assert out["consistency"]["velocity"]["mean_per_dof"] > 4  # one scan of 601 per dof in 5 runs of 30 scans
    assert out["consistency_without_gross"]["velocity"]["mean_per_dof"] == pytest.approx(1.0, abs=0.3)
    text = "\n".join(consistency_lines(out, lambda v: "-" if v is None else f"{v:.4g}"))
    assert "trials 11, 13. Without them:" in text and text.count("| velocity | 3 |") == 1
    clean = campaign_consistency([arrays[0], arrays[2], arrays[4]])
    assert clean["gross_failure_runs"] == [] and clean["consistency_without_gross"] is None
    assert "gross failure" not in "\n".join(consistency_lines(clean, str))


def test_scans_outside_below_above_and_one_run():
    """Chi-square runs with a cautious stretch (every run's NEES halved), an over-confident one (doubled) and
    scans where one run alone is far out: the counts name each, against a direct count of the averages and of
    the averages without each scan's largest run; the summary carries them."""
    rng = np.random.default_rng(np.random.SeedSequence(44))
    n, K = 20, 3000
    X = _chi2_runs(rng, n, K, per_scan_mean=np.r_[np.full(500, 0.5), np.full(500, 2.0), np.ones(K - 1000)])
    X[3, 1500:1600] = 400.0  # one run's tail: 100 scans
    lo, hi = chi2_bounds(n, 6)
    lo1, hi1 = chi2_bounds(n - 1, 6)
    mean, rest = X.mean(axis=0), (X.sum(axis=0) - X.max(axis=0)) / (n - 1)
    out = scans_outside(list(X))
    assert out["scans_below"] == np.sum(mean < lo) and 520 <= out["scans_below"] <= 580  # 500 + 2.5 % of 2000
    assert out["scans_above"] == np.sum(mean > hi) and 620 <= out["scans_above"] <= 680  # 500 + 100 + 2.5 %
    assert out["scans_above_one_run"] == np.sum((mean > hi) & (rest >= lo1) & (rest <= hi1))
    assert 100 <= out["scans_above_one_run"] <= 170  # the tail's 100, and most of chi-square's own 2.5 %
    assert np.sum((mean[500:1000] > hi) & (rest[500:1000] >= lo1) & (rest[500:1000] <= hi1)) < 20
    summary, _ = measure_summary(list(X))
    assert {k: summary[k] for k in out} == out
    assert scans_outside([np.full(5, np.nan), np.full(5, 6.0)]) == {"scans_below": 0, "scans_above": 0,
                                                                    "scans_above_one_run": 0}


@pytest.mark.parametrize("n_runs, sigma", [(2, 1.0), (5, 1.5), (20, 1.5), (20, 2.0), (40, 3.0)])
def test_the_spread_and_the_share_match_runs_drawn_with_that_spread(n_runs, sigma):
    """Runs whose NEES is sigma chi-square(6 / sigma), independent per scan (mean 6, variance sigma times
    chi-square(6)'s): the spread reads sigma, without bias also for two runs, and the share it predicts is the
    share of scans whose N-run average lies within the bounds."""
    rng = np.random.default_rng(np.random.SeedSequence([28, n_runs, int(10 * sigma)]))
    X = sigma * rng.chisquare(6 / sigma, (n_runs, 20_000))
    summary, _ = measure_summary(list(X))
    assert summary["spread_between_runs"] == pytest.approx(sigma, rel=0.03)
    assert summary["fraction_within_per_scan_factor"] == pytest.approx(summary["fraction_scans_within"], abs=0.01)


def test_the_spread_counts_runs_of_different_lengths_and_gaps():
    """A short run and a run with a gap do not cut the spread down to the scans every run reaches: scans that
    half of the runs reach count, each with its own number of runs."""
    rng = np.random.default_rng(np.random.SeedSequence(281))
    X = list(2.0 * rng.chisquare(3.0, (20, 3000)))  # spread 2
    X[0] = X[0][:10]
    X[1] = X[1].copy()
    X[1][100:2900] = np.nan
    assert spread_between_runs(X) == pytest.approx(2.0, rel=0.04)
    assert spread_between_runs(X[:2] + [np.full(3000, np.nan)] * 18) is None  # no scan reached by half the runs


@settings(max_examples=25, deadline=None)
@given(st.integers(2, 30), st.floats(1e-3, 1e3), st.integers(0, 2**32 - 1))
def test_spread_is_scale_free_and_the_share_falls_with_it(n_runs, scale, seed):
    """Scaling every NEES (a covariance off by a factor) leaves the spread unchanged; more spread never brings
    more scans within, and spread 1 gives 1 - alpha."""
    X = np.random.default_rng(seed).chisquare(6, (n_runs, 50))
    assert spread_between_runs(list(scale * X)) == pytest.approx(spread_between_runs(list(X)), rel=1e-9)
    values = [fraction_within_per_scan_factor(s, n_runs) for s in (0.5, 1.0, 1.5, 3.0)]
    assert all(a >= b for a, b in zip(values, values[1:]))
    assert values[1] == pytest.approx(0.95, abs=1e-9)


def test_spread_is_undefined_without_two_runs_or_a_positive_mean():
    """None (and "-" in the reports) rather than a number from too little."""
    assert spread_between_runs([np.ones(5)]) is None and fraction_within_per_scan_factor(None, 3) is None
    assert spread_between_runs([np.full(3, np.nan), np.ones(3)]) is None
    assert spread_between_runs([np.zeros(4), np.zeros(4)]) is None
    assert measure_summary([np.ones(4)])[0]["fraction_within_per_scan_factor"] is None


def test_campaign_trials_report_the_ellipsoid_coverage():
    """truth_coverage: true positions drawn about the estimates from the absolute pose covariance (translation
    only, the first pose exact, so the alignment is the identity) lie inside the 3-sigma ellipsoid chi2.cdf(9, 3)
    of the time (3000 scans: within 1.5 points, 5 binomial standard deviations), twice that covariance's error
    less often; a campaign trial's ellipsoid_3sigma_pct is that percentage."""
    from scipy.stats import chi2

    from rodo.estimator.lie import se3
    from rodo.validation.run_consistency import truth_coverage
    from rodo.validation.trial import consistency_of
    from tests.validation.test_odometry_consistency import _run

    rng = np.random.default_rng(np.random.SeedSequence([2026, 36, 3]))
    n = 3000
    T_est = se3.exp(rng.normal(size=(n, 6)))
    L = rng.normal(size=(n, 3, 3)) * 0.1
    P = np.zeros((n, 6, 6))
    P[:, :3, :3] = L @ np.swapaxes(L, 1, 2) + 1e-3 * np.eye(3)
    P[:, 3:, 3:] = 1e-6 * np.eye(3)

    def truth_with(scale):
        xi = np.zeros((n, 6))
        xi[:, :3] = scale * np.einsum("nij,nj->ni", np.linalg.cholesky(P[:, :3, :3]), rng.normal(size=(n, 3)))
        xi[0] = 0.0
        return {"t": np.arange(n) * 0.1, "T_vehicle_world": se3.exp(xi) @ T_est}

    states = {"t": np.arange(n) * 0.1, "T_vehicle_world": T_est, "P_pose_absolute": P}
    honest, doubled = truth_coverage(states, truth_with(1.0)), truth_coverage(states, truth_with(2.0))
    assert honest["claimed"] == pytest.approx(chi2.cdf(9.0, 3))
    assert honest["fraction"] == pytest.approx(honest["claimed"], abs=0.015)
    assert doubled["fraction"] == pytest.approx(chi2.cdf(9.0 / 4.0, 3), abs=0.03)
    assert np.isnan(truth_coverage({k: v for k, v in states.items() if k != "P_pose_absolute"},
                                   truth_with(1.0))["fraction"])
    run, run_truth = _run(np.random.default_rng(1))
    metrics, _ = consistency_of(run, run_truth, run["t"])
    assert metrics["ellipsoid_3sigma_pct"] == pytest.approx(100 * truth_coverage(run, run_truth)["fraction"])
