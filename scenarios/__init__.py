"""Named, versioned simulation scenarios: `scenarios.get(name)`, `scenarios.names()`,
`scenarios.simulate_to(name, seed, out_dir, duration=None)`. Definitions: scenarios/definitions.py."""

from . import definitions  # noqa: F401  (registers the scenarios, explicitly)
from .registry import Parts, Scenario, get, names, register, simulate_to

__all__ = ["Parts", "Scenario", "get", "names", "register", "simulate_to"]
