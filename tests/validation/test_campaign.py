"""The campaign runner: both executor paths, persistence, resume after an interruption, seeds, summary (its
failures: test_campaign_failures.py)."""

import csv
import json
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass

import numpy as np
import pytest

from rodo.estimator.errors import InputError
from rodo.validation.campaign import (FIELDS, Trial, TrialOutcome, make_executor, make_trials, npz_path, read_results,
                                 remaining, run_campaign, summarize_campaign, trial_seeds, write_summary)
from rodo.validation.consistency import chi2_bounds
from rodo.validation.odometry_consistency import MEASURES

MODELS = ("ca-polar", "cv-cartesian")
DIMS = {"ca-polar": 18, "cv-cartesian": 12}


@dataclass(frozen=True)
class FakeTrial:
    """A cheap stand-in: metrics and chi-square NEES drawn from the trial's seed; some trials fail."""

    fail: frozenset = frozenset()
    model_fail: frozenset = frozenset()  # (trial, model) pairs whose model run reports an error
    scans: int = 30
    scale: float = 1.0  # the odometry measures are chi2(6) times this (4: an overconfident estimator)

    def __call__(self, trial: Trial):
        if trial.index in self.fail:
            raise ValueError(f"simulated failure in trial {trial.index}")
        out = []
        for m in trial.models:
            if (trial.index, m) in self.model_fail:
                out.append(TrialOutcome(m, error="non-finite estimate from scan 3"))
                continue
            rng = np.random.default_rng(np.random.SeedSequence([trial.seed, DIMS[m]]))
            nees = rng.chisquare(DIMS[m], self.scans)
            out.append(TrialOutcome(m, {"kitti_t_err_pct": rng.uniform(1, 3), "ate_rmse_m": rng.uniform(0, 1),
                                        "nees_mean": nees.mean(), "nees_dim": DIMS[m], "ms_per_scan": 10.0},
                                    {"t": np.arange(self.scans) / 13, "nees": nees, "nees_dim": DIMS[m]}))
            measures = _fake_measures(np.random.default_rng(np.random.SeedSequence([trial.seed, DIMS[m], 1])),
                                      self.scans, self.scale, m)
            out[-1].arrays.update(measures)
            out[-1].metrics.update({f"{k}_per_dof": np.nanmean(v) / 6 if np.isfinite(v).any() else ""
                                    for k, v in measures.items()})
        return out


def _fake_measures(rng, scans, scale, model):
    """nees_<measure> arrays: chi2(6) * scale; acceleration NaN for a CV model, the first scan of the relative
    and pose measures NaN (as in a real run)."""
    out = {}
    for name in MEASURES:
        v = scale * rng.chisquare(6, scans)
        if name in ("relative_scan", "relative_span", "pose"):
            v[0] = np.nan
        if name == "acceleration" and model.startswith("cv"):
            v[:] = np.nan
        out[f"nees_{name}"] = v
    return out


class InterruptAfter:
    """A progress object that raises KeyboardInterrupt after n updates (an interrupted campaign)."""

    def __init__(self, n):
        self.n = n
        self.done = 0

    def update(self, k=1):
        self.done += k
        if self.done >= self.n:
            raise KeyboardInterrupt


def _key_rows(rows):
    return sorted((int(r["trial"]), r["model"], r["status"], r["seed"], r["kitti_t_err_pct"], r["error"])
                  for r in rows)


def test_trial_seeds_reproducible():
    a = trial_seeds(7, 5)
    assert a == trial_seeds(7, 5) and trial_seeds(7, 3) == a[:3]  # a trial's seed does not depend on N
    assert len(set(a)) == 5 and all(isinstance(s, int) and 0 <= s < 2**63 for s in a)
    assert a[2] == int(np.random.SeedSequence(7).spawn(5)[2].generate_state(1, np.uint64)[0] >> np.uint64(1))
    assert trial_seeds(8, 5) != a
    for bad in (-1, 1.5, True):
        with pytest.raises(InputError, match="seed"):
            trial_seeds(bad, 3)
    with pytest.raises(InputError, match="runs"):
        trial_seeds(1, 0)


def test_process_pool_and_dask_give_the_same_persisted_results(tmp_path):
    pytest.importorskip("distributed", reason="needs the dask extra: pip install 'rodo[dask]'")
    trials = make_trials(3, 6, MODELS)
    fn = FakeTrial(fail=frozenset({4}))
    with ProcessPoolExecutor(2) as ex:
        rep = run_campaign(fn, trials, ex, tmp_path / "pool", meta={"runs": 6})
    with make_executor(2, "local", processes=False) as ex:
        rep_dask = run_campaign(fn, trials, ex, tmp_path / "dask", meta={"runs": 6})
    from distributed import LocalCluster

    with LocalCluster(n_workers=1, processes=False, dashboard_address=None) as cluster:  # connect by address
        with make_executor(1, cluster.scheduler_address) as ex:
            run_campaign(fn, trials, ex, tmp_path / "tcp")
    assert rep.ran == rep_dask.ran == 12 and rep.skipped == 0
    assert _key_rows(read_results(tmp_path / "tcp" / "results.csv")) == _key_rows(rep.rows)
    pool_rows = read_results(tmp_path / "pool" / "results.csv")
    assert _key_rows(pool_rows) == _key_rows(read_results(tmp_path / "dask" / "results.csv"))
    assert _key_rows(pool_rows) == _key_rows(rep.rows)
    for tr in trials:
        for m in MODELS:
            p, q = npz_path(tmp_path / "pool", tr.index, m), npz_path(tmp_path / "dask", tr.index, m)
            assert p.exists() == q.exists() == (tr.index != 4)
            if tr.index != 4:
                with np.load(p) as a, np.load(q) as b:
                    np.testing.assert_array_equal(a["nees"], b["nees"])
    # same seed -> same numbers: the rows' values follow from the trial seeds alone
    again = FakeTrial()(trials[0])[0].metrics["kitti_t_err_pct"]
    assert float(next(r for r in pool_rows if r["trial"] == "0" and r["model"] == MODELS[0])["kitti_t_err_pct"]) \
        == again


@pytest.mark.parametrize("dask", [False, True])
def test_resume_after_interruption_loses_nothing_and_duplicates_nothing(tmp_path, dask):
    if dask:
        pytest.importorskip("distributed", reason="needs the dask extra: pip install 'rodo[dask]'")
    trials = make_trials(11, 8, MODELS)
    fn = FakeTrial(fail=frozenset({5}))
    ctx = (lambda: make_executor(2, "local", processes=False)) if dask else (lambda: ProcessPoolExecutor(2))
    with pytest.raises(KeyboardInterrupt):
        with ctx() as ex:
            run_campaign(fn, trials, ex, tmp_path, progress=InterruptAfter(5), meta={"seed": 11})
    first = read_results(tmp_path / "results.csv")
    assert 5 <= len(first) < 16
    with open(tmp_path / "results.csv", "a") as fh:
        fh.write("7,123,ca-po")  # a torn row, as from a crash in the middle of a write
    with pytest.raises(InputError, match="exists; pass --resume"):
        with ProcessPoolExecutor(1) as ex:
            run_campaign(fn, trials, ex, tmp_path, meta={"seed": 11})
    with pytest.raises(InputError, match="different campaign .* seed"):
        with ProcessPoolExecutor(1) as ex:
            run_campaign(fn, trials, ex, tmp_path, resume=True, meta={"seed": 12})
    left = remaining(trials, tmp_path)
    with ctx() as ex:
        rep = run_campaign(fn, trials, ex, tmp_path, resume=True, meta={"seed": 11})
    assert rep.skipped == len(first) and rep.ran == 16 - len(first) == left
    rows = read_results(tmp_path / "results.csv")
    keys = [(int(r["trial"]), r["model"]) for r in rows]
    assert len(keys) == len(set(keys)) == 16
    assert [k for k in keys[:len(first)]] == [(int(r["trial"]), r["model"]) for r in first]
    with ProcessPoolExecutor(2) as ex:
        run_campaign(fn, trials, ex, tmp_path / "straight")
    assert _key_rows(rows) == _key_rows(read_results(tmp_path / "straight" / "results.csv"))
    straight = {(r["trial"], r["model"]): r for r in read_results(tmp_path / "straight" / "results.csv")}
    assert all(r == straight[(r["trial"], r["model"])] for r in rows)  # every column, the measures' too
    resumed, uninterrupted = summarize_campaign(tmp_path), summarize_campaign(tmp_path / "straight")
    assert resumed["models"] == uninterrupted["models"] and resumed["models"]["ca-polar"]["consistency"]["pose"]["runs"]
    with open(tmp_path / "results.csv", newline="") as fh:
        assert next(csv.reader(fh)) == list(FIELDS)


def test_resume_runs_only_the_missing_model(tmp_path):
    trials = [Trial(0, 5, MODELS)]
    with ProcessPoolExecutor(1) as ex:
        run_campaign(FakeTrial(), [Trial(0, 5, MODELS[:1])], ex, tmp_path)
        rep = run_campaign(FakeTrial(), trials, ex, tmp_path, resume=True)
    assert rep.skipped == 1 and rep.ran == 1
    assert [r["model"] for r in read_results(tmp_path / "results.csv")] == list(MODELS)


def test_summary_statistics_and_nees_bounds(tmp_path):
    trials = make_trials(2, 12, MODELS)
    with ProcessPoolExecutor(2) as ex:
        run_campaign(FakeTrial(scans=40), trials, ex, tmp_path, meta={"scenario": "fake"})
    s = summarize_campaign(tmp_path)
    rows = read_results(tmp_path / "results.csv")
    for m in MODELS:
        vals = np.array([float(r["kitti_t_err_pct"]) for r in rows if r["model"] == m])
        got = s["models"][m]["metrics"]["kitti_t_err_pct"]
        assert got["n"] == 12 and got["mean"] == pytest.approx(vals.mean()) and \
            got["median"] == pytest.approx(np.median(vals))
        assert got["p2_5"] == pytest.approx(np.percentile(vals, 2.5))
        n = s["models"][m]["nees"]
        assert n["dim"] == DIMS[m] and n["runs"] == 12
        assert n["bounds_for_runs"] == pytest.approx(chi2_bounds(12, DIMS[m]).tolist())
        lo, hi = n["bounds_for_runs"]
        assert lo < n["mean_over_scans"] < hi and n["fraction_scans_within"] >= 0.85
        assert len(s["models"][m]["nees_curve"]["mean"]) == 40
    write_summary(tmp_path, s, "No NEES plot: test.")
    md = (tmp_path / "summary.md").read_text()
    assert "## ca-polar" in md and "kitti_t_err_pct" in md and "No NEES plot" in md and "scenario=fake" in md
    assert json.loads((tmp_path / "summary.json").read_text())["trials"] == 12


def test_make_executor_rejects_bad_arguments():
    with pytest.raises(InputError, match="jobs"):
        with make_executor(0):
            pass
    with pytest.raises(InputError, match="dask"):
        with make_executor(1, "localhost:8786"):
            pass


def test_montecarlo_cli_rejects_bad_arguments(tmp_path, capsys):
    from rodo.cli import main
    from rodo.commands import montecarlo

    assert main(["montecarlo", "city", "--runs", "1", "--models", "ca-polar,nope", "--out", str(tmp_path)],
                commands=[montecarlo]) == 2
    assert "--models: unknown model(s) nope" in capsys.readouterr().err
    assert main(["montecarlo", "atlantis", "--runs", "1", "--out", str(tmp_path)], commands=[montecarlo]) == 2
    assert "unknown scenario" in capsys.readouterr().err
    assert main(["montecarlo", "city", "--runs", "0", "--out", str(tmp_path)], commands=[montecarlo]) == 2


@pytest.mark.slow
def test_tiny_real_campaign_through_the_cli(tmp_path, capsys):
    from rodo.cli import main
    from rodo.commands import montecarlo

    out = tmp_path / "mc"
    argv = ["montecarlo", "city", "--runs", "2", "--models", "ca-polar,cv-cartesian", "--jobs", "2",
            "--duration", "1.0", "--seed", "4", "--out", str(out)]
    assert main(argv, commands=[montecarlo]) == 0
    rows = read_results(out / "results.csv")
    assert len(rows) == 4 and {r["model"] for r in rows} == set(MODELS)
    for r in rows:
        assert r["status"] == "ok", r["error"]
        assert float(r["ate_rmse_m"]) < 1.0 and int(r["scans"]) >= 12
        assert npz_path(out, int(r["trial"]), r["model"]).exists()
    summary = json.loads((out / "summary.json").read_text())
    assert summary["models"]["ca-polar"]["nees"]["dim"] == 18
    md = (out / "summary.md").read_text()
    assert "NEES" in md and "| pose | 2 |" in md and "consistency_ca-polar.png" in md
    printed = capsys.readouterr().out
    for m in MODELS:
        for name in MEASURES:  # every measure printed, rounded, never None
            line = next(x for x in printed.splitlines() if x.split()[:2] == [m, name])
            assert "None" not in line and "bounds/dof for" in line, line
        assert (out / f"consistency_{m}.png").stat().st_size > 1000
        cons = summary["models"][m]["consistency"]
        assert cons["pose"]["runs"] == 2 and cons["pose"]["mean_per_dof"] > 0
        for r in rows:
            with np.load(npz_path(out, int(r["trial"]), r["model"])) as z:
                assert all(f"nees_{k}" in z.files and len(z[f"nees_{k}"]) == len(z["t"]) for k in MEASURES)
        growth = summary["models"][m]["error_growth"]  # the runs' error growth pooled, tabled and drawn
        assert growth["runs"] == 2 and growth["table"][0]["label"] == "1 scan"
        assert growth["table"][0]["count"] == growth["count"][0] > 0 and len(growth["table"][0]["ratio"]) == 6
        assert (out / f"growth_{m}.png").stat().st_size > 1000
    assert "Error growth per axis" in md and "growth_ca-polar.png" in md
    assert next(x for x in printed.splitlines() if x.split()[:2] == ["cv-cartesian", "acceleration"]).count("-") >= 3
    assert main(argv + ["--resume"], commands=[montecarlo]) == 0  # nothing left to do
    assert "ran 0 (trial, model) runs, skipped 4" in capsys.readouterr().out
    assert json.loads((out / "summary.json").read_text()) == summary  # resuming a finished campaign changes nothing


# ------------------------------------------------------------------------ odometry consistency in campaigns
@pytest.mark.parametrize("version", ["FIELDS_V1", "FIELDS_V2"])
def test_results_with_the_older_header_are_read_and_resumed(tmp_path, version):
    """A results.csv written before the consistency columns (V1) or before the ellipsoid coverage (V2): read with
    "" in the columns it lacks; resume rewrites the header."""
    from rodo.validation import campaign_files

    header = getattr(campaign_files, version)
    with ProcessPoolExecutor(1) as ex:
        run_campaign(FakeTrial(), [Trial(0, 5, MODELS)], ex, tmp_path)
    rows = read_results(tmp_path / "results.csv")
    with open(tmp_path / "results.csv", "w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=header, extrasaction="ignore")
        w.writeheader()
        w.writerows(rows[:1])
    old = read_results(tmp_path / "results.csv")
    missing = set(campaign_files.FIELDS) - set(header)
    assert missing and all(old[0][k] == "" for k in missing)
    assert old[0]["kitti_t_err_pct"] == rows[0]["kitti_t_err_pct"]
    with ProcessPoolExecutor(1) as ex:
        rep = run_campaign(FakeTrial(), [Trial(0, 5, MODELS)], ex, tmp_path, resume=True)
    assert rep.skipped == 1 and rep.ran == 1
    with open(tmp_path / "results.csv", newline="") as fh:
        assert next(csv.reader(fh)) == list(FIELDS)
    assert [r["model"] for r in read_results(tmp_path / "results.csv")] == list(MODELS)


@pytest.mark.slow
def test_campaign_runs_a_config_under_a_label(tmp_path, capsys):
    """--models LABEL=CONFIG.toml runs that config (here CA/P with a 3x range sigma) beside a model name; the
    config is saved in campaign.json and a resume with an edited config is refused."""
    from rodo.cli import main
    from rodo.commands import montecarlo

    cfg = tmp_path / "wide.toml"
    cfg.write_text('model = "ca-polar"\n[noise]\nsensor_sigma_scales = [3.0, 1.0, 1.0, 1.0]\n')
    out = tmp_path / "mc"
    argv = ["montecarlo", "city", "--runs", "1", "--models", f"ca-polar,ca-wide={cfg}", "--jobs", "1",
            "--duration", "1.0", "--seed", "4", "--out", str(out)]
    assert main(argv, commands=[montecarlo]) == 0
    rows = {r["model"]: r for r in read_results(out / "results.csv")}
    assert set(rows) == {"ca-polar", "ca-wide"} and all(r["status"] == "ok" for r in rows.values())
    assert rows["ca-polar"]["nis_mean"] != rows["ca-wide"]["nis_mean"]  # the config was used
    assert "sensor_sigma_scales" in json.loads((out / "campaign.json").read_text())["configs"]["ca-wide"]
    cfg.write_text('model = "ca-polar"\n[noise]\nsensor_sigma_scales = [2.0, 1.0, 1.0, 1.0]\n')
    capsys.readouterr()
    assert main(argv + ["--resume"], commands=[montecarlo]) == 2
    assert "campaign.json" in capsys.readouterr().err
    bad = tmp_path / "missing.toml"
    assert main(argv[:5] + [f"x={bad}"] + argv[6:], commands=[montecarlo]) == 2
    assert "missing.toml" in capsys.readouterr().err


def test_campaign_draws_the_prior_consistent_motion_at_the_given_qc(tmp_path, capsys):
    """--qc: every trial of a prior-consistent scenario is the simulation of that scenario at the trial's seed
    with that Qc (the trial's sequence equals `simulate(seed, qc=...)`'s, not the default Qc's); the Qc is saved
    in campaign.json, a resume with another is refused, and a scenario without a Qc parameter refuses --qc."""
    from rodo import scenarios
    from rodo.cli import main
    from rodo.commands import montecarlo
    from rodo.validation.trial import ScenarioTrial

    qc = (5e-3, 1e-3, 5e-4, 1e-5, 1e-5, 1e-4)
    out = tmp_path / "mc"
    argv = ["montecarlo", "prior_ca_points", "--qc", ",".join(map(str, qc)), "--runs", "1", "--models",
            "ca-polar", "--jobs", "1", "--duration", "1.0", "--seed", "4", "--out", str(out)]
    assert main(argv, commands=[montecarlo]) == 0
    assert json.loads((out / "campaign.json").read_text())["qc"] == list(qc)
    trial = make_trials(4, 1, ("ca-polar",))[0]
    mine = ScenarioTrial("prior_ca_points", 1.0, qc=qc)(trial)[0]
    row = read_results(out / "results.csv")[0]
    assert float(row["ate_rmse_m"]) == pytest.approx(mine.metrics["ate_rmse_m"], rel=1e-12)
    _, truth = scenarios.get("prior_ca_points").simulate(trial.seed, 1.0, qc=list(qc))
    _, default = scenarios.get("prior_ca_points").simulate(trial.seed, 1.0)
    np.testing.assert_array_equal(truth["prior_qc"], qc)
    assert not np.array_equal(truth["varpi"], default["varpi"])
    capsys.readouterr()
    assert main(argv[:3] + ["1e-3,1e-3,5e-4,1e-5,1e-5,1e-4"] + argv[4:] + ["--resume"], commands=[montecarlo]) == 2
    assert "qc" in capsys.readouterr().err
    assert main(["montecarlo", "city", "--qc", ",".join(map(str, qc)), "--runs", "1", "--out", str(tmp_path / "c")],
                commands=[montecarlo]) == 2
    assert "--qc" in capsys.readouterr().err
