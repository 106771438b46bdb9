"""Fuzzing the loaders: whatever the bytes, a loader gives a valid result or an InputError naming the file,
never another exception. Configs (generated TOML documents over the real and unknown keys, with NaN, infinity,
huge integers, wrong types; and raw damaged text), groundtruth.txt (TUM) text, and states/truth .npz arrays for
`rodo evaluate`. Sizes follow the hypothesis profile of tests/conftest.py (ci/dev fast; nightly 1000 cases).
The radar.csv and sensor.toml mutations are in tests/sim/test_sequence_fuzz.py."""

import dataclasses
import math
import tempfile
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st

from rodo.commands.evaluate import load_npz
from rodo.estimator.config import OdometryConfig
from rodo.estimator.config_rules import check_values
from rodo.estimator.errors import InputError
from rodo.sim.sequence import read_tum

SECTIONS = {f.name: [g.name for g in dataclasses.fields(getattr(OdometryConfig(), f.name))]
            for f in dataclasses.fields(OdometryConfig) if dataclasses.is_dataclass(getattr(OdometryConfig(), f.name))}
TOP = ["model", "window", "seed"]

floats = st.one_of(st.floats(allow_nan=True, allow_infinity=True), st.sampled_from([0.0, -0.0, 1.0, 1e-300, 1e300]))
ints = st.one_of(st.integers(-5, 3000), st.sampled_from([2**62, -(2**62)]))
scalars = st.one_of(floats, ints, st.booleans(), st.text(max_size=5))
values = st.one_of(scalars, st.lists(st.one_of(floats, ints, st.booleans()), max_size=7))


def toml_value(v) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, float):
        return "nan" if math.isnan(v) else ("inf" if v > 0 else "-inf") if math.isinf(v) else repr(v)
    if isinstance(v, str):
        return '"' + v.encode("unicode_escape").decode("ascii").replace('"', '\\"') + '"'
    if isinstance(v, list):
        return "[" + ", ".join(toml_value(x) for x in v) + "]"
    return str(v)


@st.composite
def config_documents(draw) -> str:
    """A TOML config: some real top-level and section keys (a few unknown ones) with any values."""
    lines = []
    for key in draw(st.lists(st.sampled_from(TOP + ["windw"]), unique=True, max_size=3)):
        lines.append(f"{key} = {toml_value(draw(values if key != 'model' else st.sampled_from(['ca-polar', 'x'])))}")
    for section in draw(st.lists(st.sampled_from(sorted(SECTIONS)), unique=True, max_size=3)):
        lines.append(f"[{section}]")
        keys = draw(st.lists(st.sampled_from(SECTIONS[section] + ["bogus"]), unique=True, min_size=1, max_size=3))
        lines += [f"{k} = {toml_value(draw(values))}" for k in keys]
    return "\n".join(lines) + "\n"


def _load_config(text: str | bytes):
    with tempfile.TemporaryDirectory() as d:
        path = Path(d) / "fuzz.toml"
        path.write_bytes(text if isinstance(text, bytes) else text.encode("utf-8"))
        try:
            cfg = OdometryConfig.from_toml(path)
        except InputError as exc:
            assert str(exc).startswith(f"{path}: ") and "\n" not in str(exc), str(exc)
            return None
    check_values(cfg)  # a config that loads obeys every rule (finite, in range)
    return cfg


@given(config_documents())
def test_generated_configs_load_or_give_a_located_input_error(text):
    _load_config(text)


@given(st.data())
@settings(suppress_health_check=[HealthCheck.too_slow])
def test_damaged_config_text_loads_or_gives_a_located_input_error(data):
    good = "model = \"cv-polar\"\nwindow = 5\n[noise]\nmap_sigma_polar = 0.2\n[solver]\nrobust_c = 2.0\n"
    raw = bytearray(good.encode())
    for _ in range(data.draw(st.integers(1, 4))):
        i = data.draw(st.integers(0, len(raw) - 1))
        raw[i] = data.draw(st.integers(0, 255))
    _load_config(bytes(raw))


def test_a_good_config_survives_the_fuzz_harness():
    cfg = _load_config("window = 5\n[noise]\nmap_sigma_polar = 0.2\n")
    assert cfg.window == 5 and cfg.noise.map_sigma_polar == 0.2


tum_tokens = st.one_of(st.sampled_from(["0", "1.5", "-2", "nan", "inf", "1e400", "x", "#", "", "0.0"]),
                       st.floats(allow_nan=False, allow_infinity=False).map(repr))


@given(st.lists(st.lists(tum_tokens, min_size=0, max_size=9).map(" ".join), max_size=6))
@example(["0 0 0 0 0 0 0 1.3407807929942597e+154"])  # its quaternion's norm overflowed (found by this fuzzer)
def test_groundtruth_text_reads_or_gives_a_located_input_error(lines):
    with tempfile.TemporaryDirectory() as d:
        path = Path(d) / "groundtruth.txt"
        path.write_text("\n".join(lines) + "\n")
        try:
            traj = read_tum(path)
        except InputError as exc:
            assert str(path) in str(exc), str(exc)
            return
    assert traj.t.ndim == 1 and np.all(np.isfinite(traj.t)) and np.all(np.isfinite(traj.T_world_vehicle))
    assert traj.T_world_vehicle.shape == (len(traj.t), 4, 4)


shapes = st.lists(st.integers(0, 5), min_size=0, max_size=4).map(tuple)


@given(st.dictionaries(st.sampled_from(["t", "T_vehicle_world", "varpi", "P", "x"]),
                       st.tuples(shapes, st.sampled_from(["f8", "i4", "U2", "?"])), max_size=5))
def test_states_npz_loads_or_gives_an_input_error_naming_the_array(spec):
    with tempfile.TemporaryDirectory() as d:
        path = Path(d) / "states.npz"
        np.savez(path, **{k: np.zeros(shape, dtype=dt) for k, (shape, dt) in spec.items()})
        try:
            arrays = load_npz(str(path), "--states", ("t", "T_vehicle_world", "varpi", "P"))
        except InputError as exc:
            assert str(exc).startswith(f"--states {path}: "), str(exc)
            return
    n = len(arrays["t"])
    assert arrays["T_vehicle_world"].shape == (n, 4, 4) and arrays["varpi"].shape == (n, 6)
    assert arrays["P"].ndim == 3 and arrays["P"].shape[1] == arrays["P"].shape[2] >= 6


@pytest.mark.parametrize("key, shape", [("T_vehicle_world", (3, 3, 3)), ("varpi", (3, 5)), ("P", (3, 3, 3)),
                                        ("t", (3, 1))])
def test_evaluate_refuses_states_of_the_wrong_shape(tmp_path, capsys, key, shape):
    from tests.cli.helpers import fails

    arrays = {"t": np.arange(3.0), "T_vehicle_world": np.tile(np.eye(4), (3, 1, 1)), "varpi": np.zeros((3, 6)),
              "P": np.tile(np.eye(12), (3, 1, 1))}
    arrays[key] = np.zeros(shape)
    np.savez(tmp_path / "states.npz", **arrays)
    gt = tmp_path / "gt.txt"
    gt.write_text("".join(f"{t} 0 0 0 0 0 0 1\n" for t in range(3)))
    fails(capsys, ["evaluate", "--gt", gt, "--est", gt, "--states", tmp_path / "states.npz"], "--states",
           f"array {key} has shape {shape}")
