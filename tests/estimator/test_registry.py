"""The shared registry of named definitions (scenarios and sensor profiles use it)."""

from dataclasses import dataclass

import pytest

from rodo.estimator.errors import InputError
from rodo.estimator.registry import Registry


@dataclass(frozen=True)
class Entry:
    name: str
    value: int = 0


def test_registration_order_lookup_and_errors():
    reg = Registry("widget")
    a, b = reg.register(Entry("b", 1)), reg.register(Entry("a", 2))
    assert reg.names() == ["b", "a"] and reg.get("a") is b and reg.get("b") is a
    with pytest.raises(ValueError, match="widget 'a' registered twice"):
        reg.register(Entry("a", 3))
    assert reg.get("a").value == 2  # the first registration stands
    with pytest.raises(InputError, match=r"unknown widget 'c'; known widgets: b, a"):
        reg.get("c")
    with pytest.raises(InputError, match="unknown widget"):
        reg.get(["not", "hashable"])


def test_the_plural_names_the_known_entries():
    with pytest.raises(InputError, match="known profiles: $"):
        Registry("sensor profile", "profiles").get("x")


def test_scenarios_and_profiles_share_it():
    from rodo import scenarios
    from rodo.sim import profiles

    with pytest.raises(InputError, match="unknown scenario 'nope'; known scenarios: city"):
        scenarios.get("nope")
    with pytest.raises(InputError, match="unknown sensor profile 'nope'; known profiles: generic"):
        profiles.get("nope")
