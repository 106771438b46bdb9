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

    with pytest.raises(InputError, match="unknown scenario 'nope'; known scenarios: city") as scenario:
        scenarios.get("nope")
    with pytest.raises(InputError, match="unknown sensor profile 'nope'; known profiles: generic") as profile:
        profiles.get("nope")
    for said in (scenario, profile):  # and where one of the user's own comes from
        assert str(said.value).endswith("(yours: a module that registers them, imported by `rodo --plugin MODULE` "
                                        'or RODO_PLUGINS; docs/simulator.md, "Custom scenarios and sensor profiles")')


def test_replace_swaps_a_users_entry_in_its_place():
    reg = Registry("widget")
    for name in "abc":
        reg.register(Entry(name, 1))
    new = reg.register(Entry("b", 2), replace=True)
    assert reg.names() == ["a", "b", "c"] and reg.get("b") is new and new.value == 2
    assert reg.register(Entry("d", 3), replace=True).value == 3 and reg.names() == ["a", "b", "c", "d"]  # new name


def test_registering_a_name_twice_says_how_to_replace_it():
    reg = Registry("widget")
    reg.register(Entry("a", 1))
    with pytest.raises(ValueError, match=r"widget 'a' registered twice \(.*replace=True\)"):
        reg.register(Entry("a", 2))
    assert reg.get("a").value == 1


def test_sealed_entries_are_never_replaced():
    reg = Registry("widget")
    reg.register(Entry("a", 1))
    reg.seal()
    reg.register(Entry("b", 1))  # registered after seal: a user's, replaceable
    for replace in (False, True):
        with pytest.raises(ValueError, match=r"widget 'a'.* a built-in, versioned widget and cannot be replaced; "
                                             r"register yours under another name, e.g. 'my_a'"):
            reg.register(Entry("a", 2), replace=replace)
    assert reg.get("a").value == 1 and reg.is_builtin("a") and not reg.is_builtin("b")
    assert reg.register(Entry("b", 2), replace=True).value == 2 and reg.names() == ["a", "b"]
    with pytest.raises(ValueError, match="already sealed"):
        reg.seal()


def test_the_built_in_scenarios_and_profiles_are_sealed():
    """A notebook cannot change what `city` or `lrr30f` means: every definition of scenarios/definitions.py and
    sim/profiles.py is refused, with replace=True too, and stays registered."""
    from rodo import scenarios
    from rodo.scenarios import definitions
    from rodo.sim import profiles

    built_in = [v for v in vars(definitions).values() if isinstance(v, scenarios.Scenario)]
    assert len(built_in) == 10
    for registry, entries in ((scenarios, built_in), (profiles, [profiles.GENERIC, profiles.LRR30F,
                                                                  profiles.IWR6843AOP, profiles.CORNER2D])):
        for entry in entries:
            with pytest.raises(ValueError, match=f"'{entry.name}' is a built-in, versioned .* another name"):
                registry.register(entry, replace=True)
            assert registry.get(entry.name) is entry
