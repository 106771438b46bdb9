"""Every key of the estimator's configuration with its default, unit and description, read from the dataclasses
of `rodo.estimator.config` (so a key added there appears here by itself), and two renderings of it: commented
TOML that `rodo run --config` accepts (`rodo config dump`) and the tables of docs/configuration.md.

Where a key's text comes from: DESCRIPTIONS below for the keys whose source says too little, else the
`name: text` entries of its section's docstring and the comment on its line with the comment lines under it
(the house style of estimator/config.py).
Its unit: UNITS below, else a leading unit in its comment (`# m/s, ...`), else none.

Checked by: tests/cli/test_config_cli.py
"""

from __future__ import annotations

import ast
import dataclasses
import inspect
import io
import json
import re
import textwrap
import tokenize
from dataclasses import dataclass

from rodo.estimator.config import MODELS, OdometryConfig

UNITS = {
    "window": "states", "seed": "integer",
    "noise.qc_ca": "m^2/s^5, rad^2/s^5", "noise.qc_cv": "m^2/s^3, rad^2/s^3", "noise.cartesian_sigma": "m",
    "noise.map_sigma_polar": "m", "noise.map_sigma_cartesian": "m", "noise.sensor_sigma_scale": "factor",
    "noise.sensor_sigma_scales": "factors", "noise.sigma_floor": "m, rad, rad, m/s",
    "association.gate_probability": "probability", "association.max_radius": "m",
    "association.reassociate": "times", "association.consensus_switch_ratio": "ratio",
    "association.moving_group_z": "standard errors",
    "association.doppler_update_probability": "probability", "association.ground_band": "m",
    "map.capacity": "points", "map.max_age": "scans", "map.voxel": "m", "map.fuse": "true/false",
    "map.max_fused": "observations",
    "solver.iterations": "steps", "solver.step_tolerance": "m, rad, m/s, ...", "solver.step_sigma_tolerance": "posterior sigmas", "solver.refine_iterations": "steps",
    "solver.relinearize_older": "true/false", "solver.reweight_older": "true/false",
    "solver.robust_c": "whitened units", "solver.init_velocity_sigma": "m/s",
    "solver.init_rate_sigma": "rad/s", "solver.init_accel_sigma": "m/s^2", "solver.init_angular_accel_sigma": "rad/s^2",
    "outage.reinit_after": "s", "uncertainty.inflation": "factor", "uncertainty.measurement_inflation": "factor",
    "uncertainty.drift_rate_sigma": "m/m, rad/m", "uncertainty.prior_memory": "s",
    "uncertainty.velocity_inflation": "factor", "uncertainty.velocity_inflation_per_speed": "s/m",
    "uncertainty.velocity_inflation_per_doppler": "factor per ln(1 + NIS)",
    "uncertainty.velocity_inflation_per_rate": "s/rad",
    "uncertainty.inflation_per_rate": "s/rad",
    "uncertainty.inflation_per_doppler": "factor per ln(1 + NIS)",
    "uncertainty.inflation_per_pull": "factor per unit pull per dof",
    "uncertainty.velocity_error_share": "factor", "uncertainty.velocity_error_share_per_speed": "s/m",
    "uncertainty.registration_correlation": "fraction",
    "uncertainty.registration_axis_correlation": "fractions",
    "uncertainty.velocity_axis_inflation": "factors",
    "uncertainty.velocity_lag_per_acceleration": "s (rad s/m for the rates)",
    "uncertainty.velocity_lag_per_yaw_acceleration": "s m/rad (s for the rates)", "uncertainty.velocity_lag_time": "s",
    "uncertainty.heading_reversion_time": "s", "uncertainty.heading_anchor_time": "s",
    "uncertainty.attitude_jitter_variance": "rad^2", "uncertainty.attitude_jitter_time": "s",
    "uncertainty.stationary_variance": "m^2 (rad^2 for the rotation)", "uncertainty.stationary_time": "s",
}

DESCRIPTIONS = {  # keys whose source has no comment or docstring entry, or only a unit
    "model": "motion prior and measurement model: " + ", ".join(MODELS) + " (ca-polar is the paper's method, "
             "cv-cartesian its baseline)",
    "window": "number of states in the sliding window (>= 2)",
    "seed": "seed of the estimator's own randomness (the RANSAC Doppler fit): same seed, same run",
    "association.gate_probability": "chi-square probability of the association gate (the paper: 0.95)",
    "association.max_radius": "largest distance between a detection and a map point it may be associated with",
    "association.consensus_switch_ratio": "see consensus_switch_after",
    "solver.step_sigma_tolerance": "Gauss-Newton also stops after a full step whose length in the information "
                                   "metric, sqrt(d^T H d), is below this: no state element then moves by more "
                                   "than this many of its posterior standard deviations (0: off)",
    "association.consensus_voxel": "voxel size in which the space a Doppler consensus covers is counted (see "
                                   "consensus_switch_after), and the moving-group test groups detections",
    "association.moving_group_margin": "added to the moving-group test's threshold (see moving_group_z)",
    "association.ground_band": "half-height of the band about each scan's fitted road plane whose static "
                               "detections stay out of the map and the pairs (they still serve the Doppler "
                               "front end): the road, resampled every scan, biases point-to-point pairs "
                               "upwards (estimator/ground.py, docs/consistency.md); 0: off, the paper's",
    "map.capacity": "largest number of points in the local map (the paper: 1500)",
    "map.max_age": "scans after which a map point that was not associated again is dropped",
    "map.voxel": "voxel size of the map's downsampling; 0 keeps every point",
    "map.fuse": "refine associated map points with the new detections (see the section)",
    "map.max_fused": "fading memory of a fused point, in observations (0: none)",
    "solver.iterations": "Gauss-Newton iterations per scan, at most",
    "solver.init_velocity_sigma": "1-sigma of the initial velocity from the Doppler initialisation",
    "solver.init_rate_sigma": "1-sigma of the initial angular rates about x, y, z (roll, pitch, yaw)",
    "solver.init_accel_sigma": "1-sigma of the initial acceleration along x, y, z",
    "solver.init_angular_accel_sigma": "1-sigma of the initial angular acceleration about x, y, z",
    "standstill.speed": "Doppler speed below which (with the tests above) the sensor is at rest; 0 disables the "
                        "zero-velocity term",
    "standstill.sigma_velocity": "1-sigma of the zero-velocity term on the linear velocity",
    "standstill.sigma_rate": "1-sigma of the zero-velocity term on the angular rates",
    "standstill.sigma_accel": "1-sigma of the zero-velocity term on the linear acceleration",
    "standstill.sigma_angular_accel": "1-sigma of the zero-velocity term on the angular acceleration",
    "standstill.sigma_accel_jump": "1-sigma of the linear acceleration's jump when the vehicle stops or moves off "
                                   "(the prior noise of the interval into it); 0 disables it",
    "vehicle.sigma_roll_rate": "1-sigma of the zero-mean term on the roll rate; 0 disables it",
    "vehicle.sigma_pitch_rate": "1-sigma of the zero-mean term on the pitch rate; 0 disables it",
    "vehicle.sigma_lateral_velocity": "1-sigma of the zero-mean term on the lateral velocity at the vehicle origin "
                                      "(non-holonomic); 0 disables it",
    "vehicle.sigma_vertical_velocity": "1-sigma of the zero-mean term on the vertical velocity at the vehicle "
                                       "origin (non-holonomic); 0 disables it",
    "outage.reinit_after": "seconds without associations after which the estimator re-initialises; 0 disables it",
}

SECTION_DOCS = {  # sections without a docstring
    "": "The model and the sliding window.",
    "association": "Data association: the gates, the Doppler test of static detections and the consensus switch.",
}

USED_BY = {  # keys that only some models read: key -> the model part that reads it
    "noise.qc_ca": "ca", "noise.qc_cv": "cv", "noise.cartesian_sigma": "cartesian",
    "noise.map_sigma_polar": "polar", "noise.map_sigma_cartesian": "cartesian",
    "solver.init_accel_sigma": "ca", "solver.init_angular_accel_sigma": "ca",
    "standstill.sigma_accel": "ca", "standstill.sigma_angular_accel": "ca", "standstill.sigma_accel_jump": "ca",
}

UNIT_RE = re.compile(r"^(m|s|seconds|m/s|rad/s|m/s\^2|rad/s\^2|deg|rad)(?=$|[,:;)\s])")
ENTRY_RE = re.compile(r"^([a-z_][a-z0-9_]*(?:, [a-z_][a-z0-9_]*)*): (.*)$")


@dataclass(frozen=True)
class Key:
    name: str         # "noise.qc_ca", or "model" for a top-level key
    default: object   # the default value (tuples stay tuples)
    unit: str         # "" when unknown
    description: str  # "" when the source says nothing


@dataclass(frozen=True)
class Section:
    name: str         # "noise", or "" for the top-level keys
    description: str
    keys: tuple[Key, ...]


def _comments(cls) -> dict[str, str]:
    """Field name -> its trailing comment plus the comment-only lines right under it, from the class source."""
    source = textwrap.dedent(inspect.getsource(cls))
    by_line: dict[int, str] = {}
    for tok in tokenize.generate_tokens(io.StringIO(source).readline):
        if tok.type == tokenize.COMMENT:
            by_line[tok.start[0]] = tok.string.lstrip("#").strip()
    lines = source.splitlines()
    out = {}
    for node in ast.parse(source).body[0].body:
        if isinstance(node, ast.AnnAssign) and isinstance(node.target, ast.Name):
            text, k = [], node.end_lineno
            if k in by_line:
                text.append(by_line[k])
            while k < len(lines) and lines[k].strip().startswith("#"):
                k += 1
                text.append(by_line.get(k, ""))
            out[node.target.id] = " ".join(t for t in text if t)
    return out


def _docstring(cls, names) -> tuple[str, dict[str, str]]:
    """(section description, {field: text}) from the class docstring's `name[, name]: text` entries."""
    doc = cls.__doc__ if cls.__doc__ and not cls.__doc__.startswith(f"{cls.__name__}(") else ""
    entries: dict[str, list[str]] = {}
    rest: list[str] = []
    current = None
    for line in inspect.cleandoc(doc).splitlines():
        m = ENTRY_RE.match(line)
        if m and all(n in names for n in m.group(1).split(", ")):
            current = m.group(1).split(", ")
            for n in current:
                entries.setdefault(n, []).append(m.group(2))
        elif current and line.startswith(" "):
            for n in current:
                entries[n].append(line.strip())
        else:
            current = None
            rest.append(line.strip())
    return " ".join(r for r in rest if r), {n: " ".join(t) for n, t in entries.items()}


def section_keys(cls, instance, prefix: str, skip=()) -> tuple[str, tuple[Key, ...]]:
    fields = [f for f in dataclasses.fields(cls) if f.name not in skip]
    names = {f.name for f in fields}
    described, from_doc = _docstring(cls, names)
    comments = _comments(cls)
    keys = []
    for f in fields:
        full = f"{prefix}{f.name}"
        comment = comments.get(f.name, "")
        m = UNIT_RE.match(comment)
        if m:  # "# m/s, floor of ..." -> unit m/s, text "floor of ..."
            comment = comment[m.end():].lstrip(",:; ")
        text = DESCRIPTIONS.get(full) or " ".join(t for t in (from_doc.get(f.name, ""), comment) if t)
        unit = UNITS.get(full) or (m.group(1) if m else "")
        keys.append(Key(full, getattr(instance, f.name), unit, text))
    return described, tuple(keys)


def schema(model: str = "ca-polar") -> tuple[Section, ...]:
    """The configuration of `model` (OdometryConfig.for_model) as sections of keys, in dataclass order."""
    config = OdometryConfig.for_model(model)
    tables = [f for f in dataclasses.fields(OdometryConfig) if dataclasses.is_dataclass(getattr(config, f.name))]
    _, top = section_keys(OdometryConfig, config, "", skip={f.name for f in tables})
    sections = [Section("", SECTION_DOCS[""], top)]
    for f in tables:
        value = getattr(config, f.name)
        described, keys = section_keys(type(value), value, f"{f.name}.")
        sections.append(Section(f.name, described or SECTION_DOCS.get(f.name, ""), keys))
    return tuple(sections)


def toml_value(v) -> str:
    """A TOML literal that tomllib reads back to the same value (floats exactly: Python's repr)."""
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, (int, float)):
        return repr(v)
    if isinstance(v, str):
        return json.dumps(v)
    if isinstance(v, (tuple, list)):
        return "[" + ", ".join(toml_value(x) for x in v) + "]"
    raise TypeError(f"no TOML literal for {v!r}")


def _comment_lines(text: str, width: int = 100) -> list[str]:
    return textwrap.wrap(text, width, initial_indent="# ", subsequent_indent="# ", break_on_hyphens=False,
                         break_long_words=False) if text else []


def _used_note(key: Key, model: str) -> str:
    part = USED_BY.get(key.name)
    return "" if part is None or part in model.split("-") else f" (not used by {model})"


def render_toml(model: str = "ca-polar") -> str:
    """The complete default configuration of `model` as commented TOML (what `rodo config dump` prints)."""
    out = [f"# rodo estimator configuration: every key with its default for model {model}",
           f"# (rodo config dump --model {model}). Use it with `rodo run SEQ_DIR --config FILE --out OUT`; keys",
           "# left out keep their defaults. Units and details: docs/configuration.md.", ""]
    for section in schema(model):
        if section.name:
            out += ["", f"[{section.name}]"]
        out += _comment_lines(section.description)
        for key in section.keys:
            unit = f" [{key.unit}]" if key.unit else ""
            out += _comment_lines(f"{key.name.rsplit('.', 1)[-1]}{unit}: {key.description or 'undocumented'}"
                                  f"{_used_note(key, model)}")
            out.append(f"{key.name.rsplit('.', 1)[-1]} = {toml_value(key.default)}")
    return "\n".join(out) + "\n"


def _cell(text: str) -> str:
    return text.replace("|", "\\|")


def render_markdown() -> str:
    """docs/configuration.md: every key of every section with its default, unit and description."""
    out = ["# Configuration", "",
           "<!-- Generated by `rodo config dump --markdown > docs/configuration.md`; do not edit by hand: the text",
           "comes from the dataclasses of estimator/config.py (their docstrings and comments) and",
           "rodo/config_schema.py. tests/cli/test_config_cli.py fails when this file is out of date. -->", "",
           "`rodo run SEQ_DIR --config FILE.toml` reads a TOML file that overrides any of the keys below; keys left",
           "out keep their defaults, unknown keys and bad values are errors naming the file and the key.",
           "`rodo config dump [--model MODEL]` prints every key with its default as commented TOML, a complete",
           "file to start from. The defaults are the same for every model except `model` itself; keys marked",
           "*CA*, *CV*, *polar* or *Cartesian* are read only by the models with that prior or measurement model.",
           f"The models: {', '.join(f'`{m}`' for m in MODELS)}. An example that changes two keys:",
           "[examples/handheld.toml](examples/handheld.toml) (a hand-held sensor).", ""]
    for section in schema():
        out += [f"## {'[' + section.name + ']' if section.name else 'Top level'}", ""]
        if section.description:
            out += [section.description, ""]
        out += ["| key | default | unit | description |", "| --- | --- | --- | --- |"]
        for key in section.keys:
            part = USED_BY.get(key.name)
            only = f" *{part.upper() if len(part) == 2 else part.capitalize()} only.*" if part else ""
            out.append(f"| `{key.name.rsplit('.', 1)[-1]}` | `{toml_value(key.default)}` | {_cell(key.unit or '-')} | "
                       f"{_cell(key.description or 'undocumented')}{only} |")
        out.append("")
    return "\n".join(out)
