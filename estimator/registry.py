"""A registry of named definitions (scenarios, sensor profiles): registration order kept, a name registered
once, and an unknown name answered with an InputError that lists the known ones.

Checked by: tests/estimator/test_registry.py
"""

from __future__ import annotations

from typing import Generic, TypeVar

from .errors import InputError

T = TypeVar("T")


class Registry(Generic[T]):
    """Named entries of one kind (`kind` names it in messages, e.g. "scenario", `plural` the known ones,
    default kind + "s"); each entry has a `name`."""

    def __init__(self, kind: str, plural: str | None = None):
        self.kind = kind
        self.plural = kind + "s" if plural is None else plural
        self._entries: dict[str, T] = {}

    def register(self, entry: T) -> T:
        """Add `entry` under entry.name; ValueError if that name is taken (a programming error)."""
        name = entry.name
        if name in self._entries:
            raise ValueError(f"{self.kind} {name!r} registered twice")
        self._entries[name] = entry
        return entry

    def names(self) -> list[str]:
        """The registered names, in registration order."""
        return list(self._entries)

    def get(self, name: str) -> T:
        """The entry called `name`; InputError listing the known names otherwise."""
        try:
            return self._entries[name]
        except (KeyError, TypeError):
            raise InputError(f"unknown {self.kind} {name!r}; known {self.plural}: {', '.join(self.names())}") \
                from None
