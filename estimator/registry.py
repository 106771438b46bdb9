"""A registry of named definitions (scenarios, sensor profiles): registration order kept, a name registered
once unless replaced on purpose (`register(entry, replace=True)`, e.g. a notebook cell run again), the built-in
definitions never replaced (`seal`), and an unknown name answered with an InputError that lists the known ones.

Checked by: tests/estimator/test_registry.py
"""

from __future__ import annotations

from typing import Generic, TypeVar

from .errors import InputError

T = TypeVar("T")
# the scenarios' and sensor profiles' hint (`Registry(hint=...)`): where an entry of one's own comes from
USER_ENTRIES = ('yours: a module that registers them, imported by `rodo --plugin MODULE` or RODO_PLUGINS; '
                'docs/simulator.md, "Custom scenarios and sensor profiles"')


class Registry(Generic[T]):
    """Named entries of one kind (`kind` names it in messages, e.g. "scenario", `plural` the known ones,
    default kind + "s", `hint` how to add one's own); each entry has a `name`. The entries registered before
    `seal()` are built in."""

    def __init__(self, kind: str, plural: str | None = None, hint: str = ""):
        self.kind = kind
        self.plural = kind + "s" if plural is None else plural
        self.hint = hint  # appended to the unknown-name message: how to add an entry of one's own
        self._entries: dict[str, T] = {}
        self._builtin: frozenset[str] | None = None  # None until sealed

    def register(self, entry: T, replace: bool = False) -> T:
        """Add `entry` under entry.name, after the others. A name already taken is a ValueError (a programming
        error) unless `replace`: then `entry` takes the place of the one of that name, in its position. A
        built-in entry (`seal`) is never replaced: its name means the same everywhere (it is versioned), so
        another definition needs another name."""
        name = entry.name
        if self.is_builtin(name):
            subject = f"{self.kind} {name!r}" + ("" if replace else " registered twice; it")
            raise ValueError(f"{subject} is a built-in, versioned {self.kind} and cannot be replaced; register yours "
                             f"under another name, e.g. 'my_{name}'")
        if name in self._entries and not replace:
            raise ValueError(f"{self.kind} {name!r} registered twice (to replace it, e.g. when a notebook cell "
                             "runs again, register it with replace=True)")
        self._entries[name] = entry
        return entry

    def seal(self) -> None:
        """Mark the entries registered so far as built in (`register` refuses to replace them). Called once,
        after the built-in definitions; a second call is a ValueError."""
        if self._builtin is not None:
            raise ValueError(f"the {self.kind} registry is already sealed (its built-in entries are fixed)")
        self._builtin = frozenset(self._entries)

    def is_builtin(self, name: str) -> bool:
        """True for an entry registered before `seal()`."""
        return self._builtin is not None and name in self._builtin

    def names(self) -> list[str]:
        """The registered names, in registration order."""
        return list(self._entries)

    def get(self, name: str) -> T:
        """The entry called `name`; InputError listing the known names otherwise."""
        try:
            return self._entries[name]
        except (KeyError, TypeError):
            hint = f" ({self.hint})" if self.hint else ""
            raise InputError(f"unknown {self.kind} {name!r}; known {self.plural}: {', '.join(self.names())}{hint}") \
                from None
