"""Named, versioned simulation scenarios: `scenarios.get(name)`, `scenarios.names()`,
`scenarios.simulate_to(name, seed, out_dir, duration=None)`; a scenario of your own:
`scenarios.register(Scenario(...), replace=False)` (the built-in ones are never replaced; the CLI sees yours
through a plugin module: docs/simulator.md, "Custom scenarios and sensor profiles").

The package, file by file:
    registry.py     `Scenario` (name, version, builder of `Parts`, estimator defaults, default extent),
                    `Parts` (profile, world, radar config), the explicit registry (`register`, `get`, `names`; `seal`)
                    and `simulate_to` (scenario -> simulated sequence on disk), `simulate_rig_to` (several
                    radars on one drive -> a rig directory); `MARGIN`.
    definitions.py  the built-in scenario definitions, each registered explicitly at import (then sealed):
                    `CITY`, `HIGHWAY`, `HILLS`, `STOP_AND_GO`, `BLOCKAGE` (with its `BLOCKAGE_*` timings), `YAW_ACCEL`,
                    `PRIOR_CA`, `PRIOR_CV` (motion drawn from the prior's SDE, parameter `qc`), `PRIOR_CA_POINTS`,
                    `PRIOR_CV_POINTS` (the same motion among persistent point scatterers only);
                    `MOVER_ID` (first id of moving objects).

Checked by: tests/scenarios/test_registry.py
"""

from .definitions import (BLOCKAGE, BLOCKAGE_BLACKOUT, BLOCKAGE_DELTA, BLOCKAGE_SLOW, CITY, HIGHWAY, HILLS, MOVER_ID,
                          PRIOR_CA, PRIOR_CA_POINTS, PRIOR_CV, PRIOR_CV_POINTS, STOP_AND_GO, YAW_ACCEL)
from .registry import MARGIN, Parts, Scenario, get, names, register, simulate_rig_to, simulate_to

__all__ = [
    # registry.py
    "MARGIN", "Parts", "Scenario", "get", "names", "register", "simulate_rig_to", "simulate_to",
    # definitions.py
    "BLOCKAGE", "BLOCKAGE_BLACKOUT", "BLOCKAGE_DELTA", "BLOCKAGE_SLOW", "CITY", "HIGHWAY", "HILLS", "MOVER_ID",
    "PRIOR_CA", "PRIOR_CA_POINTS", "PRIOR_CV", "PRIOR_CV_POINTS", "STOP_AND_GO", "YAW_ACCEL",
]
