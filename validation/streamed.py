"""Long drives in bounded memory: a scenario simulated scan by scan (`sim.stream`) and run by the estimator as the
scans come (`driver.run_scans`), keeping only the per-scan arrays (`driver.ScanColumns`, about 3.5 kB per CA scan).

An hour of `city` (about 47,000 scans of ~900 detections) simulated whole (`Scenario.simulate`) holds every scan
and the per-detection truth, several gigabytes; streamed, the run holds the world, the estimator's window and map,
the per-scan truth and the columns. `bench/scale.py` measures its time per scan and peak memory against the
drive's length.

Same scenario, seed and duration -> the same scans as `Scenario.simulate` and so the same estimates, bit for bit.

Checked by: tests/validation/test_stream.py
"""

from __future__ import annotations

from rodo.estimator.config import OdometryConfig
from rodo.estimator.errors import InputError
from rodo.sim.faults import Faults
from rodo.sim.stream import StreamedSimulation, stream

from .driver import RunResult, run_scans


def stream_scenario(name: str, seed: int, duration: float | None = None, faults: Faults | None = None,
                    **params) -> StreamedSimulation:
    """Scenario `name` with `seed`, streamed: what `scenarios.get(name).simulate(seed, duration, faults=faults,
    **params)` gives, scan by scan (the same parts, radar config and radar generator; the scenario's
    `extra_truth` added to the truth). Faults that change the recorded scans are refused (`sim.stream`)."""
    from rodo import scenarios

    scenario = scenarios.get(name)
    faults = Faults() if faults is None else faults
    if faults.changes_scans:
        raise InputError("faults: ghosts, dropped scans, jitter and outages are drawn over the whole sequence and "
                         "cannot be streamed; simulate the sequence instead (only clutter streams)")
    parts = scenario.build(seed, duration, **params)
    config = faults.radar(parts.radar)
    rng_radar = scenario._rngs(seed)[2]  # the radar's stream, as Scenario.simulate draws it
    sim = stream(parts.world, parts.profile, config, rng_radar, parts.duration)
    if scenario.extra_truth is not None:
        sim.truth.update(scenario.extra_truth(parts.profile))
    return sim


def run_streamed(sim: StreamedSimulation, config: OdometryConfig, progress=None) -> RunResult:
    """Run the estimator over a streamed simulation, scan by scan, keeping only `RunResult.columns`."""
    return run_scans(sim.sensor, ((scan.t, scan) for scan in sim.scans()), config, progress)
