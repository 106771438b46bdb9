"""`rodo verdict [--scenarios city,hills,stop_and_go,highway] [--runs 20] [--duration 30] [--seed 7]
[--calibration-seed 100] [--calibration-duration 180] [--calibration-drives 1] [--floor-ca Q[,Q,...]]
[--floor-cv Q[,Q,...]] [--heading-reversion] [--stationary-error] [--no-axis-correlation] [--vehicle-rates]
[--config BASE.toml] [--jobs J] --out DIR [--resume]`:
the consistency verdict of CA/P against CV/C, each at its learned noise (validation/verdict.py).

Per scenario S, the recipe of docs/consistency.md ("The verdict with everything learned") as one command:

    rodo simulate S --seed 100 --duration 180 --out DIR/calibration/S      # a drive the campaign never sees
    rodo calibrate DIR/calibration/S --model ca-polar --floor 1e-4,1e-4,1e-4,3e-4,3e-4,1e-4
        --out DIR/calibration/S_ca.toml
    rodo calibrate DIR/calibration/S --model cv-cartesian --floor 1e-4 --out DIR/calibration/S_cv.toml
    rodo montecarlo S --runs 20 --duration 30 --seed 7 --models ca-learned=...S_ca.toml,cv-learned=...S_cv.toml
        --out DIR/S

then DIR/verdict.md and verdict.json. With --calibration-drives N, N drives per scenario (seeds 100, 101, ...; the
first in DIR/calibration/S, the others in S-1, S-2, ...), pooled by each calibration: the verdict's cells depend
on the calibration drive as much as on the campaign's seed (docs/consistency.md, "The calibration drive's draw").
With --heading-reversion both calibrations learn the yaw's reversion too (`rodo calibrate --heading-reversion`;
docs/consistency.md, "The heading reverts"), with --stationary-error a bounded pose error per axis
(`rodo calibrate --stationary-error`; docs/consistency.md, "A bounded error per axis"); with
--no-axis-correlation neither learns the registration's correlation per axis (`rodo calibrate
--no-axis-correlation`; docs/consistency.md, "The registration's correlation per axis"), with --vehicle-rates both
learn the road-vehicle terms on the roll and pitch rates (`rodo calibrate --vehicle-rates`; docs/consistency.md,
"The vehicle's rate terms learned"). With --config BASE.toml both calibrations start from that estimator config
instead of the defaults (`rodo calibrate --config`: what they do not learn, e.g. `[vehicle]
sigma_vertical_velocity`, is kept); it is copied to DIR/base.toml, which the calibrations read, and its hash is a
parameter of the verdict. Each step's output goes to DIR/logs/; the simulations and calibrations run
--jobs at a time. With --resume a finished step is skipped (a sequence with all its files, a config with its report)
and the campaigns resume; DIR/campaign.json holds the parameters, and a resume with other ones is refused.
"""

from __future__ import annotations

import argparse
import contextlib
import hashlib
import os
import sys
import time
from pathlib import Path

from rodo.estimator.errors import InputError
from rodo.validation.workers import spawn_pool

from .table1 import parse_scenarios

MAX_CALIBRATION_DRIVES = 20
MIN_CALIBRATION_DURATION = 1.0  # s: the common Doppler error's fit needs 10 scans with static detections (13 Hz)
INTERRUPTED = 130  # a step's exit code after Ctrl-C (rodo.cli)
BASE_CONFIG = "base.toml"  # --config's copy in DIR, what the calibrations read


def register(sub: argparse._SubParsersAction) -> None:
    from rodo.validation.verdict import FLOORS, SCENARIOS

    p = sub.add_parser("verdict", help="the consistency verdict: calibrate both models on a drive of their own, "
                                       "then campaigns of both at the learned noise (docs/consistency.md)",
                       description="Per scenario: simulate a calibration drive, learn each model's noise and "
                                   "uncertainty terms on it (rodo calibrate), run a campaign of both models "
                                   "(rodo montecarlo), then write DIR/verdict.md and verdict.json: accuracy, "
                                   "the share of scans inside the bounds per cell, the mean NEES of every "
                                   "measure and the ellipsoids' coverage.")
    p.add_argument("--scenarios", default=",".join(SCENARIOS), help="comma-separated scenarios (%(default)s)")
    p.add_argument("--runs", type=int, default=20, help="trials per scenario (default 20)")
    p.add_argument("--duration", type=float, default=30.0, help="seconds of each trial (default 30)")
    p.add_argument("--seed", type=int, default=7, help="the campaigns' seed (default 7)")
    p.add_argument("--calibration-seed", type=int, default=100, help="the calibration drives' seed (default 100)")
    p.add_argument("--calibration-duration", type=float, default=180.0,
                   help="seconds of each calibration drive (default 180)")
    p.add_argument("--calibration-drives", type=int, default=1,
                   help="calibration drives per scenario, seeds --calibration-seed, +1, ..., pooled by rodo "
                        "calibrate (default 1)")
    for key, name in (("ca", "CA/P"), ("cv", "CV/C")):
        p.add_argument(f"--floor-{key}", default=FLOORS[key], metavar="Q[,Q,...]",
                       help=f"rodo calibrate's --floor for {name}: one for every Qc element or six, "
                            f"x,y,z,roll,pitch,yaw (default {FLOORS[key]})")
    p.add_argument("--heading-reversion", action="store_true",
                   help="rodo calibrate's --heading-reversion for both models: the yaw error's reversion learned "
                        "from its error growth (default off)")
    p.add_argument("--stationary-error", action="store_true",
                   help="rodo calibrate's --stationary-error for both models: a bounded pose error per axis learned "
                        "from its error growth (default off)")
    p.add_argument("--no-axis-correlation", dest="axis_correlation", action="store_false",
                   help="rodo calibrate's --no-axis-correlation for both models: the registration's correlation per "
                        "axis not learned (learned by default)")
    p.add_argument("--vehicle-rates", action="store_true",
                   help="rodo calibrate's --vehicle-rates for both models: the road-vehicle terms on the roll and "
                        "pitch rates learned from the truth (default off)")
    p.add_argument("--config", metavar="BASE.toml",
                   help="base estimator config for both calibrations, without a model (rodo calibrate's --config: "
                        "the settings they do not learn are kept; default: the built-in defaults)")
    p.add_argument("--jobs", type=int, default=os.cpu_count() or 1, help="parallel workers (default: cores)")
    p.add_argument("--out", required=True, metavar="DIR", help="the verdict's directory")
    p.add_argument("--resume", action="store_true", help="continue the verdict in DIR (skip finished steps)")
    p.set_defaults(func=main)


def _check(args) -> list[str]:
    from rodo.scenarios.registry import MAX_DURATION

    names = parse_scenarios(args.scenarios)
    if args.runs < 2:
        raise InputError(f"--runs: at least 2 (the intervals and the spread need two), got {args.runs}")
    if args.jobs < 1:
        raise InputError(f"--jobs: must be >= 1, got {args.jobs}")
    if not 1 <= args.calibration_drives <= MAX_CALIBRATION_DRIVES:
        raise InputError(f"--calibration-drives: from 1 to {MAX_CALIBRATION_DRIVES}, got {args.calibration_drives}")
    for flag, v in (("--duration", args.duration), ("--calibration-duration", args.calibration_duration)):
        if not 0 < v <= MAX_DURATION:  # NaN too
            raise InputError(f"{flag}: must be > 0 and at most {MAX_DURATION:g} s, got {v}")
    if args.calibration_duration < MIN_CALIBRATION_DURATION:  # refused now, not after the drives are simulated
        raise InputError(f"--calibration-duration: at least {MIN_CALIBRATION_DURATION:g} s (the calibration needs "
                         f"10 scans or more with static detections), got {args.calibration_duration:g}")
    from .calibrate import parse_floor

    for option, floor in (("--floor-ca", args.floor_ca), ("--floor-cv", args.floor_cv)):  # as rodo calibrate
        parse_floor(floor, option)  # checks them, before any work
    return names


def base_config(path: str) -> bytes:
    """The bytes of --config, checked as `rodo calibrate` will read them: a TOML estimator config (every
    setting valid) that leaves the model to the verdict, which calibrates both."""
    import tomllib

    from rodo.estimator.config import OdometryConfig

    OdometryConfig.from_toml(path)  # InputError naming the file and the setting
    data = Path(path).read_bytes()
    if "model" in tomllib.loads(data.decode("utf-8")):
        raise InputError(f"--config: {path} sets model; the verdict calibrates both models, so leave it out")
    return data


def calibration_drives(out: Path, scenario: str, n: int) -> list[Path]:
    """The calibration drives' directories of a scenario: DIR/calibration/<scenario>, then <scenario>-1, ...
    (drive i simulated at --calibration-seed + i)."""
    return [out / "calibration" / (scenario if i == 0 else f"{scenario}-{i}") for i in range(n)]


def _steps(args, names: list[str]) -> tuple[list, list, list]:
    """(simulations, calibrations, campaigns): (label, argv, done) of every step."""
    from rodo.sim.sequence import GROUNDTRUTH_TXT, RADAR_CSV, SENSOR_TOML
    from rodo.sim.simulate import TRUTH_NPZ
    from rodo.validation.verdict import MODELS, config_path

    files = (RADAR_CSV, SENSOR_TOML, GROUNDTRUTH_TXT, TRUTH_NPZ)  # a simulated sequence, all written
    out, sims, cals, camps = Path(args.out), [], [], []
    for s in names:
        seqs = calibration_drives(out, s, args.calibration_drives)
        for i, seq in enumerate(seqs):
            sims.append((f"simulate {seq.name}", ["simulate", s, "--seed", str(args.calibration_seed + i),
                                                  "--duration", str(args.calibration_duration), "--out", str(seq)],
                         all((seq / f).is_file() for f in files)))
        labels = []
        for name, (label, model, key) in MODELS.items():
            cfg = config_path(out, s, name)
            cals.append((f"calibrate {s} {name}", ["calibrate", *map(str, seqs), "--model", model, "--floor",
                                                   getattr(args, f"floor_{key}"), "--out", str(cfg)]
                         + ([] if args.config is None else ["--config", str(out / BASE_CONFIG)])
                         + (["--heading-reversion"] if args.heading_reversion else [])
                         + (["--stationary-error"] if args.stationary_error else [])
                         + ([] if args.axis_correlation else ["--no-axis-correlation"])
                         + (["--vehicle-rates"] if args.vehicle_rates else []),
                         cfg.is_file() and cfg.with_suffix(".md").is_file()))
            labels.append(f"{label}={cfg}")
        camps.append((f"montecarlo {s}", ["montecarlo", s, "--runs", str(args.runs), "--duration", str(args.duration),
                                          "--seed", str(args.seed), "--jobs", str(args.jobs), "--models",
                                          ",".join(labels), "--out", str(out / s)]
                      + (["--resume"] if (out / s / "results.csv").exists() else []), False))
    return sims, cals, camps


def run_step(argv: list[str], log: str | None) -> int:
    """`rodo argv` with its output in `log` (a worker's task), or on the terminal (log None: the campaigns,
    which show their progress); its exit code."""
    from rodo import cli

    if log is None:
        return cli.main(argv)
    with open(log, "w", encoding="utf-8") as f, contextlib.redirect_stdout(f), contextlib.redirect_stderr(f):
        return cli.main(argv)


def _last_line(log: Path) -> str:
    lines = [ln for ln in log.read_text(encoding="utf-8", errors="replace").splitlines() if ln.strip()]
    return lines[-1] if lines else "(no output)"


def _run(steps: list, logs: Path | None, jobs: int) -> None:
    """Run the steps not done, `jobs` at a time (in-process for one), their output in logs/ (or on the terminal,
    logs None); StepFailed naming the first that failed, with its exit code."""
    todo = [(label, argv) for label, argv, done in steps if not done]
    for label, _, done in steps:
        if done:
            print(f"    {label}: done before, kept")
    if not todo:
        return
    paths = [None if logs is None else str(logs / (label.replace(" ", "_").replace("/", "") + ".log"))
             for label, _ in todo]
    start = time.monotonic()
    if jobs == 1 or len(todo) == 1:
        codes = []
        for (label, argv), log in zip(todo, paths):
            print(f"    {label}" + (f" (log: {log})" if log else ""), flush=True)
            codes.append(run_step(argv, log))
            if codes[-1] != 0:
                break
    else:
        for (label, _), log in zip(todo, paths):
            print(f"    {label} (log: {log})", flush=True)
        with spawn_pool(min(jobs, len(todo))) as pool:  # spawned workers that leave with the verdict
            codes = list(pool.map(run_step, [argv for _, argv in todo], paths))
    if INTERRUPTED in codes:  # a step stopped by Ctrl-C is the verdict interrupted, not a step that failed
        raise KeyboardInterrupt
    for (label, _), log, code in zip(todo, paths, codes):
        if code != 0:
            said = f"{_last_line(Path(log))} (log: {log})" if log else "its message is above"
            raise StepFailed(f"{label} failed (exit {code}): {said}; fix it and run again with --resume", code)
    print(f"    {len(todo)} done in {time.monotonic() - start:.0f} s", flush=True)


class StepFailed(Exception):
    """A step of the verdict that exited non-zero: the verdict exits with its code, 2 for the input's fault, 1 for
    the machine's (a full disk: `rodo.cli.environment_message`) or any other."""

    def __init__(self, message: str, code: int):
        super().__init__(message)
        self.code = code if code in (1, 2) else 1


def main(args) -> int:
    try:
        return _verdict(args)
    except StepFailed as exc:
        print(f"rodo verdict: error: {exc}", file=sys.stderr)
        return exc.code


def _verdict(args) -> int:
    from rodo.sim.sequence import atomic_write_bytes
    from rodo.validation.campaign_dir import campaign_lock, check_and_save_meta
    from rodo.validation.verdict import build_verdict, write_verdict

    from .calibrate import parse_floor

    names = _check(args)
    out = Path(args.out)
    base = None if args.config is None else base_config(args.config)  # checked before any work
    meta = {"scenarios": ",".join(names), "runs": args.runs, "duration": args.duration, "seed": args.seed,
            "calibration_seed": args.calibration_seed, "calibration_duration": args.calibration_duration,
            **({"calibration_drives": args.calibration_drives} if args.calibration_drives != 1 else {}),
            **({"heading_reversion": True} if args.heading_reversion else {}),
            **({"stationary_error": True} if args.stationary_error else {}),
            **({} if args.axis_correlation else {"axis_correlation": False}),
            **({"vehicle_rates": True} if args.vehicle_rates else {}),
            **({} if base is None else {"config_sha256": hashlib.sha256(base).hexdigest()}),
            "floor_ca": parse_floor(args.floor_ca), "floor_cv": parse_floor(args.floor_cv)}  # values: 1e-4 == 0.0001
    with campaign_lock(out):
        if not args.resume and (out / "campaign.json").exists():
            raise InputError(f"--out: {out / 'campaign.json'} exists (a verdict in progress or done); pass --resume "
                             "to continue it, or choose another directory")
        check_and_save_meta(out, meta, args.resume)
        if base is not None:
            atomic_write_bytes(out / BASE_CONFIG, base)
        logs = out / "logs"
        logs.mkdir(exist_ok=True)
        sims, cals, camps = _steps(args, names)
        for title, steps, where, jobs in (("calibration drives", sims, logs, args.jobs),
                                          ("calibrations", cals, logs, args.jobs), ("campaigns", camps, None, 1)):
            print(f"==> {title}", flush=True)
            _run(steps, where, jobs)
        text = write_verdict(out, build_verdict(out, names), meta)
    sys.stdout.write(text)
    print(f"wrote {out / 'verdict.md'}, {out / 'verdict.json'} (the campaigns in {out}/<scenario>/, the learned "
          f"configs in {out / 'calibration'}/)")
    return 0
