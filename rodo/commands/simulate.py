"""`rodo scenarios` (list the registered scenarios) and `rodo simulate SCENARIO --seed N --out DIR
[--duration S] [--qc a,b,c,d,e,f]
[--fault NAME=VALUE ...] [--profile NAME]` (write a sequence directory and print a summary). Parse, call, print:
the work is in `scenarios` and `sim`."""

from __future__ import annotations

import argparse

import numpy as np

from rodo.estimator.config_rules import RULES
from rodo.estimator.errors import InputError


def register(subparsers) -> None:
    p = subparsers.add_parser("scenarios", help="list the simulation scenarios",
                              description="List the registered scenarios: name, version, default length, "
                                          "description.")
    p.set_defaults(func=run_scenarios)

    p = subparsers.add_parser("simulate", help="simulate a scenario into a sequence directory",
                              description="Simulate a named scenario and write radar.csv, sensor.toml, "
                                          "groundtruth.txt and truth.npz into --out.")
    p.add_argument("scenario", help="scenario name (see `rodo scenarios`)")
    p.add_argument("--seed", type=int, default=0, help="random seed (same seed -> same bytes; default 0)")
    p.add_argument("--out", required=True, metavar="SEQ_DIR", help="output sequence directory")
    p.add_argument("--duration", type=float, default=None,
                   help="seconds to simulate (default: the scenario's own length)")
    p.add_argument("--qc", metavar="X,Y,Z,RX,RY,RZ", default=None,
                   help="diagonal of the prior's Qc for prior_ca (jerk PSD) / prior_cv (acceleration PSD): 6 positive "
                        "numbers, body frame [linear x,y,z, angular x,y,z] (default: the scenario's, see "
                        "docs/simulator.md)")
    p.add_argument("--fault", metavar="NAME=VALUE", action="append", default=[],
                   help="inject a sensor fault (repeatable; all off by default, see docs/simulator.md, Faults): "
                        "clutter=RATE false alarms per scan (replaces the radar's 20); ghosts=RATE multipath "
                        "ghosts per scan (a real detection copied 1-10 m farther); dropped=P each scan missing "
                        "from radar.csv with probability P in [0, 1); jitter=SIGMA s on the recorded scan times "
                        "(clipped to +-0.45 scan periods so times stay increasing; SIGMA <= 0.15 periods); "
                        "outage=START:DURATION s of empty scans (repeat for several); outages=RATE:DURATION "
                        "random outages, RATE per minute, each DURATION s; doppler_common=SIGMA[:RHO] an error "
                        "of SIGMA m/s per axis common to a scan's radial velocities (a wrong sensor velocity), "
                        "correlated RHO (default 0.9) from scan to scan")
    p.add_argument("--profile", metavar="NAME", default=None,
                   help="sensor profile (see `rodo profiles`; default: the scenario's, normally 'generic')")
    p.add_argument("--rig", metavar="LAYOUT", default=None,
                   help="several radars on the vehicle, taking turns (front-corners: the front radar and two "
                        "corner radars; corners): --out becomes a rig directory (docs/sequence_format.md, Rigs) "
                        "that `rodo run` fuses")
    p.add_argument("--rerun", metavar="OUT.rrd", help="also write a Rerun recording of the simulated sequence")
    p.set_defaults(func=run_simulate)


def run_scenarios(args: argparse.Namespace) -> int:
    from rodo import scenarios

    for name in scenarios.names():
        print(scenarios.get(name).summary())
    return 0


def parse_qc(text: str | None, scenario) -> dict:
    """--qc "a,b,c,d,e,f" -> {"qc": [6 floats]} for a scenario with a `qc` parameter; InputError naming --qc."""
    from rodo import scenarios

    if text is None:
        return {}
    if "qc" not in scenario.params:
        takes = [n for n in scenarios.names() if "qc" in scenarios.get(n).params]
        raise InputError(f"--qc: scenario {scenario.name!r} has no Qc parameter (only {', '.join(takes)})")
    try:
        qc = [float(x) for x in text.split(",")]
    except ValueError:
        qc = []
    if len(qc) != 6 or not all(np.isfinite(qc)) or min(qc) <= 0:
        raise InputError(f"--qc: expected 6 positive finite numbers separated by commas "
                         f"(linear x,y,z, angular x,y,z), got {text!r}")
    rule = RULES["noise.qc_ca"]  # the estimator's bounds: beyond them the drawn motion overflows
    if not all(rule.holds(q) for q in qc):
        raise InputError(f"--qc: each element must be {rule.text()}, got {text!r}")
    return {"qc": qc}


def describe_faults(faults, truth: dict) -> str:
    """One line on the injected faults, with what they did (counts from the truth)."""
    from rodo.sim.faults import GHOST
    from rodo.sim.objects import CLUTTER

    parts = []
    if faults.clutter is not None:
        parts.append(f"clutter {faults.clutter:g}/scan ({int(np.sum(truth['det_label'] == CLUTTER))} false alarms)")
    if faults.ghosts > 0:
        parts.append(f"ghosts {faults.ghosts:g}/scan ({int(np.sum(truth['det_label'] == GHOST))} ghosts)")
    if faults.dropped > 0:
        parts.append(f"dropped p={faults.dropped:g} ({int(np.sum(truth['fault_dropped']))} scans dropped)")
    if faults.jitter > 0:
        parts.append(f"jitter {faults.jitter:g} s")
    for start, dur in faults.outage:
        parts.append(f"outage {start:g}-{start + dur:g} s")
    if faults.outages is not None:
        parts.append(f"outages {faults.outages[0]:g}/min, {faults.outages[1]:g} s each")
    if faults.doppler_common is not None:
        parts.append(f"common Doppler error {faults.doppler_common[0]:g} m/s, rho {faults.doppler_common[1]:g}")
    return "; ".join(parts)


def run_simulate(args: argparse.Namespace) -> int:
    from rodo import scenarios
    from rodo.progress import Progress
    from rodo.sim.faults import parse_faults
    from rodo.sim.simulate import path_length

    scenario = scenarios.get(args.scenario)  # InputError listing the known names -> exit 2
    if args.duration is not None and not (np.isfinite(args.duration) and args.duration > 0):
        raise InputError(f"--duration: must be a positive number of seconds, got {args.duration}")
    params = parse_qc(args.qc, scenario)
    faults = parse_faults(args.fault)  # InputError naming --fault NAME -> exit 2
    radar = scenario.radar_config(args.profile)  # InputError listing the known profiles -> exit 2
    faults.check_rate(faults.radar(radar).rate_hz)
    from rodo.outputs import (check_layout_target, check_not_input, check_output_dir, check_output_file,
                              sequence_inputs)

    check_output_dir(args.out, create=False)  # before the simulation, not after it
    check_layout_target(args.out, "--out", rig=args.rig is not None)
    if args.rig is not None:
        return _simulate_rig(args, scenario, params, faults)
    if args.rerun:
        check_output_file(args.rerun, "--rerun", parents=True)
        check_not_input(args.rerun, "--rerun", sequence_inputs(args.out))  # the sequence it writes
    duration = scenario.default_duration(args.seed, **params) if args.duration is None else args.duration
    faults.check_duration(duration)  # an outage after the end: refused before the simulation
    n_scans = int(np.floor(duration * radar.rate_hz + 1e-9)) + 1
    with Progress(n_scans, f"simulate {scenario.name}", unit="scan") as bar:
        seq, truth = scenarios.simulate_to(scenario.name, args.seed, args.out, duration, progress=bar,
                                           faults=faults, sensor_profile=args.profile, **params)
    counts = np.diff(truth["scan_offsets"])
    profile = f", profile {args.profile}" if args.profile is not None else ""
    print(f"{scenario.name} v{scenario.version}{profile} seed {args.seed} -> {args.out}")
    print(f"scans {len(counts)} ({truth['t'][-1]:.1f} s), detections per scan median {np.median(counts):.0f} "
          f"(min {counts.min()}, max {counts.max()}), empty scans {int(np.sum(counts == 0))}, "
          f"path length {path_length(seq.groundtruth.T_world_vehicle):.1f} m")
    if faults.active:
        print(f"faults: {describe_faults(faults, truth)}")
    if "prior_kind" in truth:
        speed = -truth["varpi"][:, 0]
        print(f"motion from the {str(truth['prior_kind'][0]).upper()} prior SDE, Qc = diag("
              f"{', '.join(f'{q:g}' for q in truth['prior_qc'])}); forward speed {speed.min():.1f} to "
              f"{speed.max():.1f} m/s (recorded in truth.npz: prior_kind, prior_qc)")
    if args.rerun:
        from rodo.viz.recording import record_sequence  # viz is the only package importing rerun

        record_sequence(args.rerun, seq, truth)
        from rodo.commands.run import rodo_command

        print(f"wrote {args.rerun} (open it with: {rodo_command()} view {args.rerun})")
    return 0


def _simulate_rig(args: argparse.Namespace, scenario, params: dict, faults) -> int:
    """`rodo simulate SCENARIO --rig LAYOUT`: one drive seen by the layout's radars, as a rig directory."""
    from rodo import scenarios
    from rodo.sim.rig import LAYOUTS

    if args.rig not in LAYOUTS:
        raise InputError(f"--rig: unknown layout {args.rig!r}; known layouts: {', '.join(LAYOUTS)}")
    if args.rerun:
        raise InputError("--rig: --rerun is for a single radar; simulate the rig without it")
    duration = scenario.default_duration(args.seed, **params) if args.duration is None else args.duration
    faults.check_duration(duration)
    radars = scenarios.simulate_rig_to(scenario.name, args.seed, args.out, args.rig, duration,
                                       sensor_profile=args.profile, faults=faults, **params)
    print(f"{scenario.name} v{scenario.version} seed {args.seed}, rig {args.rig} -> {args.out}")
    for name, _, truth in radars:
        counts = np.diff(truth["scan_offsets"])
        print(f"  {name}: scans {len(counts)} from t = {truth['t'][0]:.3f} s, detections per scan median "
              f"{np.median(counts):.0f}")
    return 0
