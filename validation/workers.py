"""The executors of campaigns and verdicts (`make_executor`): a pool of spawned workers that exit with their
parent, or Dask's workers.

- Spawned, not forked: a forked worker inherits every open file of its parent, the campaign's lock among them
  (flock belongs to the open file), and held it after the campaign was killed, so `--resume` was refused.
- Exiting with their parent: a worker whose campaign was killed (SIGKILL, a closed terminal) blocked for ever
  writing its result into a queue nobody reads (it holds that pipe's read end too). Each worker watches its
  parent and leaves when it is gone.
- Importing the plugins: a spawned worker starts from a fresh interpreter, so the scenarios and sensor profiles
  that `rodo --plugin` or RODO_PLUGINS registered in the parent are imported again (`validation.plugins`; the
  parent's `load` left their names in the RODO_PLUGINS the worker inherits). Dask's workers, which rodo does not
  start, import them by a setup callback that `make_executor` registers on its client (`import_plugins_on`).

Checked by: tests/validation/test_campaign_workers.py, tests/validation/test_campaign.py, tests/cli/test_plugins.py
"""

from __future__ import annotations

import contextlib
import functools
import importlib.util
import os
import threading
import time
from concurrent.futures import ProcessPoolExecutor
from multiprocessing import get_context

from rodo.estimator.errors import InputError

from .plugins import load as load_plugins
from .plugins import names as plugin_names

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


@contextlib.contextmanager
def make_executor(jobs: int, dask: str | None = None, processes: bool = True, dashboard: str | None = None,
                  on_dashboard=None):
    """A concurrent.futures Executor: ProcessPoolExecutor(jobs), or Dask (`dask="local"`: a LocalCluster of
    `jobs` workers with one thread each, processes unless processes=False; `dask="tcp://host:port"`: connect).

    `dashboard` (LocalCluster only) is the address its dashboard serves on ("localhost:8787"; ":8787" listens
    on every interface; None: no dashboard); `on_dashboard(link)` is then called with the dashboard's URL.
    Dask moves tasks and results by pickle: connect only to a scheduler you trust (docs/evaluation.md)."""
    if int(jobs) < 1:
        raise InputError(f"jobs: must be >= 1, got {jobs!r}")
    if dashboard is not None and dask != "local":
        raise InputError("dashboard: only with dask='local' (a remote scheduler serves its own dashboard: "
                         "`dask scheduler --dashboard-address :8787`)")
    if dask is None:  # spawned workers that leave with this process (`spawn_pool`)
        with spawn_pool(int(jobs)) as ex:
            yield ex
        return
    from distributed import Client, LocalCluster

    if dask == "local":
        if dashboard is not None and importlib.util.find_spec("bokeh") is None:
            raise InputError("dashboard: Dask's dashboard needs bokeh: pip install 'dask[diagnostics]'")
        with LocalCluster(n_workers=int(jobs), threads_per_worker=1, processes=processes,
                          dashboard_address=dashboard, silence_logs=40) as cluster, Client(cluster) as client:
            if dashboard is not None and on_dashboard is not None:
                on_dashboard(cluster.dashboard_link)
            import_plugins_on(client)
            yield client.get_executor()
    else:
        if "://" not in dask:
            raise InputError(f"dask: expected 'local' or a scheduler address like tcp://host:8786, got {dask!r}")
        try:
            client = Client(dask, timeout=10)
        except OSError as exc:
            raise InputError(f"dask: cannot connect to scheduler {dask!r}: {exc}") from None
        with client:
            import_plugins_on(client)
            yield client.get_executor()


def import_plugins_on(client) -> None:
    """Dask's workers are not spawned by rodo: the plugins this process imported (RODO_PLUGINS) are imported on
    each of `client`'s workers, those that join later too, by a worker setup callback."""
    names = plugin_names()
    if not names:
        return
    try:
        client.register_worker_callbacks(setup=functools.partial(load_plugins, names, {}))
    except Exception as exc:  # noqa: BLE001 - whatever failed on a worker, the message names the plugins
        raise InputError(f"dask: the workers cannot import the plugins {', '.join(names)}: {exc}") from None
