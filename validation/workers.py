"""The process pools of campaigns and verdicts: spawned workers that exit with their parent.

- Spawned, not forked: a forked worker inherits every open file of its parent, the campaign's lock among them
  (flock belongs to the open file), and held it after the campaign was killed, so `--resume` was refused.
- Exiting with their parent: a worker whose campaign was killed (SIGKILL, a closed terminal) blocked for ever
  writing its result into a queue nobody reads (it holds that pipe's read end too). Each worker watches its
  parent and leaves when it is gone.
- Importing the plugins: a spawned worker starts from a fresh interpreter, so the scenarios and sensor profiles
  that `rodo --plugin` or RODO_PLUGINS registered in the parent are imported again (`validation.plugins`; the
  parent's `load` left their names in the RODO_PLUGINS the worker inherits).

Checked by: tests/validation/test_campaign_workers.py, tests/cli/test_plugins.py
"""

from __future__ import annotations

import os
import threading
import time
from concurrent.futures import ProcessPoolExecutor
from multiprocessing import get_context

from .plugins import load as load_plugins

WATCH_INTERVAL = 1.0  # s between a worker's looks at its parent


def spawn_pool(workers: int) -> ProcessPoolExecutor:
    """A ProcessPoolExecutor of `workers` spawned processes, each leaving when this process is gone and importing
    the plugins of RODO_PLUGINS first (`start_worker`)."""
    return ProcessPoolExecutor(int(workers), mp_context=get_context("spawn"), initializer=start_worker,
                               initargs=(os.getpid(),))


def start_worker(parent: int) -> None:
    """A worker's initializer: watch the parent (pid `parent`, `exit_with_parent`), then import the plugins named
    in RODO_PLUGINS (`validation.plugins.load`), so the worker knows the parent's scenarios and profiles."""
    exit_with_parent(parent)
    load_plugins()


def exit_with_parent(parent: int) -> None:
    """A worker's initializer: a daemon thread that ends the worker once its parent (pid `parent`) has gone
    (orphaned, it is re-parented and os.getppid() changes)."""
    def watch():
        while os.getppid() == parent:
            time.sleep(WATCH_INTERVAL)
        os._exit(1)

    threading.Thread(target=watch, name="exit-with-parent", daemon=True).start()
