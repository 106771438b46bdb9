"""Plugins: modules of your own that register scenarios and sensor profiles when imported
(`rodo.scenarios.register`, `rodo.sim.profiles.register`), imported by name before a command runs so that every
command sees them (docs/simulator.md, "Custom scenarios and sensor profiles").

The names come from the environment variable RODO_PLUGINS (comma-separated module names) and from `rodo --plugin
MODULE`. `load` imports them and writes all of them back into RODO_PLUGINS, so that the processes started
afterwards inherit the list: the campaigns' spawned workers (`validation.workers`) import the same modules before
their first trial. A plugin is found like any module: installed, or its folder on PYTHONPATH. Only the CLI and the
workers' initializer call `load` (read the variable); the rest of the library does not.

Checked by: tests/cli/test_plugins.py
"""

from __future__ import annotations

import importlib
import os
from collections.abc import Iterable, MutableMapping

from rodo.estimator.errors import InputError

ENV = "RODO_PLUGINS"


def names_in(text: str | None) -> list[str]:
    """The module names of a comma-separated list (RODO_PLUGINS, a --plugin value); blanks ignored."""
    return [name.strip() for name in (text or "").split(",") if name.strip()]


def names() -> list[str]:
    """The plugins named in this process's RODO_PLUGINS (after `load`: every plugin it imported)."""
    return names_in(os.environ.get(ENV))


def load(modules: Iterable[str] = (), environ: MutableMapping[str, str] | None = None) -> list[str]:
    """Import the plugins named in RODO_PLUGINS and then `modules` (each a name or a comma-separated list),
    each once, and set RODO_PLUGINS to all of them (`environ`, default os.environ). Returns their names.

    A module that cannot be imported is an InputError naming it and its error (before RODO_PLUGINS is changed).
    """
    environ = os.environ if environ is None else environ
    names = list(dict.fromkeys(names_in(environ.get(ENV)) + names_in(",".join(modules))))
    for name in names:
        import_plugin(name)
    if names:
        environ[ENV] = ",".join(names)
    return names


def import_plugin(name: str):
    """Import plugin module `name` (imported once per process, as any module); InputError naming it otherwise."""
    if not all(part.isidentifier() for part in name.split(".")):
        raise InputError(f"plugin {name!r}: not a module name (expected e.g. my_scenarios or mypackage.radars)")
    try:
        return importlib.import_module(name)
    except InputError as exc:  # e.g. a Scenario that refuses its arguments
        raise InputError(f"plugin {name!r}: {exc}") from None
    except Exception as exc:  # noqa: BLE001 - whatever a plugin's import raises, the message names the plugin
        hint = ""
        if isinstance(exc, ModuleNotFoundError) and exc.name is not None and (name + ".").startswith(exc.name + "."):
            hint = " (install it, or put its folder on PYTHONPATH)"
        raise InputError(f"plugin {name!r}: {type(exc).__name__}: {exc}{hint}") from exc
