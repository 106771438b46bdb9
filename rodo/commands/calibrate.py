"""`rodo calibrate SEQ_DIR [SEQ_DIR ...] --out CONFIG.toml [--model M] [--config BASE.toml] [--no-truth]
[--iterations N] [--duration S] [--floor Q[,Q,...]]`: learn the noise from a sequence (with ground truth: from several,
pooled) and write a config for `rodo run --config` (docs/calibration.md), with CONFIG.json and CONFIG.md
reports beside it."""

from __future__ import annotations

import argparse
import json
from contextlib import contextmanager
from pathlib import Path

import numpy as np

from rodo.estimator.config import MODELS
from rodo.estimator.errors import InputError
from rodo.outputs import check_not_input, check_output_file, sequence_inputs, write_text_atomic
from rodo.sim.sequence import read_sequence
from rodo.sim.simulate import TRUTH_NPZ, load_truth
from rodo.validation.calibrate import COMPONENTS, DEFAULT_FLOOR, QC_MAX, QC_MIN, floors
from rodo.validation.calibrate_config import calibrate_with_truth, calibrate_without_truth, config_toml
from rodo.validation.velocity_growth import growth_figure_path

from .calibrate_report import header, markdown
from .run import load_config


# the uncertainty section's terms a flag asks for, learned with truth (refused with --no-truth or --no-consistency):
# (flag, with a --no- form (default None: the term's own default), help after "with truth: ")
UNCERTAINTY_FLAGS = (
    ("--velocity-axes", True, "learn the velocity variance per axis too (uncertainty.velocity_axis_inflation; "
     "docs/calibration.md): on by default with truth; --no-velocity-axes leaves them at 1"),
    ("--velocity-lag", True, "learn the velocity's lag behind a manoeuvre (uncertainty.velocity_lag_*; "
     "docs/calibration.md): by default with truth for the constant-velocity models; --no-velocity-lag leaves it at "
     "0, --velocity-lag learns it for every model"),
    ("--heading-reversion", False, "learn the yaw error's reversion too (uncertainty.heading_reversion_time and "
     "heading_anchor_time; docs/calibration.md)"),
    ("--attitude-jitter", True, "learn the roll and pitch jitter's variance (uncertainty.attitude_jitter_variance, "
     "at the config's attitude_jitter_time; docs/calibration.md): on by default with truth; --no-attitude-jitter "
     "keeps the config's"),
    ("--stationary-error", False, "learn a bounded pose error per axis last (uncertainty.stationary_variance and "
     "stationary_time, from the error's growth over 0.5-20 s; docs/calibration.md)"),
    ("--axis-correlation", True, "learn the registration's correlation per axis (uncertainty."
     "registration_axis_correlation, from the error's growth over 0.5-20 s; docs/calibration.md): on by default "
     "with truth; --no-axis-correlation keeps the config's"),
)


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("calibrate", help="learn Qc (and R) from a sequence; write a config for rodo run --config",
                       description="With truth.npz (simulated sequences): maximum-likelihood Qc of both motion "
                                   "priors from the true states, and the measurement noise from the static "
                                   "detections. With --no-truth: EM over the estimator's posteriors for the "
                                   "Qc of the model's prior (the CA prior's checked against the estimated "
                                   "velocity's growth over seconds). Writes CONFIG.toml, CONFIG.json and CONFIG.md.")
    p.add_argument("sequence", metavar="SEQ_DIR", nargs="+",
                   help="sequence directory (radar.csv, sensor.toml[, truth.npz]); with ground truth several, pooled "
                        "(docs/calibration.md)")
    p.add_argument("--model", choices=MODELS, default=None, help="the config's model (default ca-polar)")
    p.add_argument("--out", required=True, metavar="CONFIG.toml", help="the config to write")
    p.add_argument("--config", metavar="FILE", help="base TOML config (its other settings are kept)")
    p.add_argument("--no-truth", action="store_true", help="ignore truth.npz; EM without ground truth")
    p.add_argument("--sensor-noise", action="store_true",
                   help="with --no-truth: learn the measurement noise too, from the static detections seen in "
                        "consecutive scans (assumes persistent scatterers; docs/calibration.md)")
    p.add_argument("--no-consistency", action="store_true",
                   help="with truth: skip the uncertainty section (kappa, drift rate, tau; a few estimator runs)")
    for flag, optional, text in UNCERTAINTY_FLAGS:
        p.add_argument(flag, action=argparse.BooleanOptionalAction if optional else "store_true",
                       default=None if optional else False, help="with truth: " + text)
    p.add_argument("--vehicle-rates", action="store_true",
                   help="with truth: learn the road-vehicle terms on the roll and pitch rates (vehicle.sigma_roll_rate "
                        "and sigma_pitch_rate, sqrt(window) x the true rates' RMS while moving; docs/calibration.md; "
                        "off by default: more accurate on three scenarios of four, but the uncertainty section's "
                        "learned terms do not carry over at them)")
    p.add_argument("--iterations", type=int, default=30, help="EM iterations at most (%(default)s; one estimator "
                                                              "run each, then EM to its fixed point in the run's "
                                                              "linear-Gaussian stand-in)")
    p.add_argument("--tolerance", type=float, default=0.05, help="EM stops when the fixed point its runs' steps "
                                                                 "extrapolate to is within this (relative) of Qc "
                                                                 "(%(default)s)")
    p.add_argument("--duration", type=float, default=None, help="use the first S seconds only")
    p.add_argument("--learn", default=",".join(COMPONENTS), metavar="x,y,...",
                   help="EM: the Qc components to learn, the others keep the base config's (%(default)s)")
    p.add_argument("--floor", default=str(DEFAULT_FLOOR), metavar="Q[,Q,...]",
                   help="lower bound of each Qc element: one for all, or six (x,y,z,roll,pitch,yaw) (%(default)s)")
    p.set_defaults(func=main)


def _check_args(args) -> Path:
    if args.iterations < 1:
        raise InputError(f"--iterations: must be >= 1, got {args.iterations}")
    if not (np.isfinite(args.tolerance) and args.tolerance > 0):
        raise InputError(f"--tolerance: must be > 0, got {args.tolerance}")
    if args.duration is not None and not (np.isfinite(args.duration) and args.duration > 0):
        raise InputError(f"--duration: must be a positive number of seconds, got {args.duration}")
    args.floor = parse_floor(args.floor)
    if args.vehicle_rates and args.no_truth:
        raise InputError("--vehicle-rates: learned from the true motion, which --no-truth leaves out; drop one of "
                         "the two")
    if args.sensor_noise and not args.no_truth:
        raise InputError("--sensor-noise: learns the measurement noise without ground truth (with --no-truth); "
                         "with truth.npz it is learned from the truth anyway")
    for flag, *_ in UNCERTAINTY_FLAGS:
        given = getattr(args, flag[2:].replace("-", "_"))
        for other, off in (("--no-truth", args.no_truth), ("--no-consistency", args.no_consistency)):
            if given and off:
                raise InputError(f"{flag}: learned in the uncertainty section with ground truth, which {other} "
                                 "leaves out; drop one of the two")
    out = Path(args.out)
    if out.is_dir():
        raise InputError(f"--out: {out} is a directory, expected a .toml file name")
    if out.suffix in (".json", ".md"):
        raise InputError(f"--out: {out} would be overwritten by the report; name the config CONFIG.toml")
    inputs = [p for d in args.sequence for p in sequence_inputs(d)]  # (--config may be the output: read first)
    figure = [growth_figure_path(out)] if args.no_truth else []  # EM's check, drawn
    for path in (out, out.with_suffix(".json"), out.with_suffix(".md"), *figure):  # the config and its reports
        check_output_file(path, "--out")
        check_not_input(path, "--out", inputs)
    return out


def parse_floor(text: str, option: str = "--floor") -> float | list[float]:
    """--floor: one number (every Qc element) or six, comma-separated (COMPONENTS' order); errors name `option`
    (`rodo verdict` passes --floor-ca and --floor-cv)."""
    try:
        values = [float(x) for x in text.split(",")]
        floor = values[0] if len(values) == 1 else values
        floors(floor)  # six, each in range (NaN fails too)
    except (ValueError, InputError):
        raise InputError(f"{option}: one number or six ({','.join(COMPONENTS)}), each from {QC_MIN:g} (the "
                         f"config's lower bound) to below the fit's upper bound {QC_MAX:g}, got {text!r}") from None
    return floor


@contextmanager
def _naming(dirs: list[str]):
    """An InputError of the calibration (measurement noise: no static detections, ...) prefixed with the sequence
    directories it came from, as `rodo evaluate` names its files (outputs are written after it)."""
    try:
        yield
    except InputError as exc:
        raise InputError(f"{' + '.join(str(d) for d in dirs)}: {exc}") from None


def parse_learn(text: str) -> np.ndarray:
    names = [x.strip() for x in text.split(",") if x.strip()]
    unknown = [x for x in names if x not in COMPONENTS]
    if unknown or not names:
        raise InputError(f"--learn: expected names from {','.join(COMPONENTS)}, got {text!r}")
    return np.array([c in names for c in COMPONENTS])


def main(args) -> int:
    out = _check_args(args)
    learn = parse_learn(args.learn)
    config = load_config(args)
    attitude_jitter = args.attitude_jitter is not False  # the default: learned where the uncertainty section is
    if args.no_truth and len(args.sequence) > 1:
        raise InputError(f"--no-truth: EM learns from one sequence, got {len(args.sequence)}")
    seqs = [read_sequence(d) for d in args.sequence]
    seq = seqs[0]
    for d, other in zip(args.sequence[1:], seqs[1:]):
        if other.sensor != seq.sensor:
            raise InputError(f"{Path(d) / 'sensor.toml'}: another sensor than {Path(args.sequence[0]) / 'sensor.toml'}"
                             "; calibrate the sequences of one sensor together")
    if args.no_truth and not any(len(scan) for scan in seq.scans):
        raise InputError(f"{Path(args.sequence[0]) / 'radar.csv'}: no detections; EM learns from the estimator's "
                         "solutions on them")
    if args.no_truth:
        def say(h):
            print(f"EM iteration: qc {np.array2string(h.qc_out, precision=4)} ({h.steps} steps in the run's "
                  f"stand-in), change {h.change:.3g}, left {h.remaining:.3g}")
        config, report = calibrate_without_truth(seq, config, args.iterations, args.tolerance, args.duration,
                                                 args.floor, progress=say, learn=learn,
                                                 sensor_noise=args.sensor_noise)
    else:
        for d in args.sequence:
            if not (Path(d) / TRUTH_NPZ).is_file():
                raise InputError(f"{Path(d) / TRUTH_NPZ}: not found (ground truth for the calibration); "
                                 "use --no-truth for EM without ground truth")
        def step(s):
            print(f"uncertainty: measurement_inflation {s.kappa:.3g}, median NEES ratio "
                  + ", ".join(f"{k} {v:.3g}" for k, v in s.ratios.items()))
        truths = [load_truth(d) for d in args.sequence]
        with _naming(args.sequence):
            config, report = calibrate_with_truth(seqs, truths, config, args.duration, args.floor,
                                                  consistency=not args.no_consistency, progress=step,
                                                  velocity_axes=args.velocity_axes is not False,
                                                  velocity_lag=args.velocity_lag,
                                                  heading_reversion=args.heading_reversion,
                                                  attitude_jitter=attitude_jitter,
                                                  stationary_error=args.stationary_error,
                                                  axis_correlation=args.axis_correlation is not False,
                                                  vehicle_rates=args.vehicle_rates)
    write_text_atomic(out, config_toml(config, header(report, " ".join(args.sequence), config.model)))
    write_text_atomic(out.with_suffix(".json"), json.dumps(report, indent=1) + "\n")
    write_text_atomic(out.with_suffix(".md"), markdown(report))
    print(markdown(report), end="")
    written = [out, out.with_suffix(".json"), out.with_suffix(".md")]
    if isinstance(report.get("velocity_growth"), list):
        from rodo import extras

        if extras.is_installed("matplotlib"):
            from rodo.viz.figures import plot_velocity_growth  # viz is the only package importing matplotlib
            written.append(plot_velocity_growth(growth_figure_path(out), report["velocity_growth"]))
        else:
            print(f"no growth figure: matplotlib is not installed ({extras.install_hint('viz')} adds it)")
    print(f"wrote {', '.join(str(w) for w in written)}")
    return 0
