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
- Deaf to Ctrl-C, stopped by their parent: a terminal's Ctrl-C reaches the whole process group, and every worker
  printed a KeyboardInterrupt traceback (while importing, idle or running). Workers are born with SIGINT ignored
  (`_QuietSpawnContext`); the parent, interrupted, stops them (`WorkerPool.stop`): the queued tasks are cancelled
  and a SIGTERM ends the running ones (`StopTask`), so the campaign exits at once instead of waiting for its running
  trials, whose results it would not keep (the review of session 56, finding 4).

Checked by: tests/validation/test_campaign_workers.py, tests/validation/test_worker_signals.py, tests/validation/test_campaign.py, tests/cli/test_plugins.py
"""

from __future__ import annotations

import contextlib
import functools
import importlib.util
import os
import signal
import threading
import time
from concurrent.futures import ProcessPoolExecutor
from multiprocessing.context import SpawnContext, SpawnProcess

from rodo.estimator.errors import InputError, is_environment_error

from .plugins import load as load_plugins
from .plugins import names as plugin_names

WATCH_INTERVAL = 1.0  # s between a worker's looks at its parent
STOP_RESEND = 0.2  # s between a stopped pool's SIGTERMs to its workers still alive (`WorkerPool.stop`)


def spawn_pool(workers: int) -> WorkerPool:
    """A `WorkerPool` of `workers` spawned processes, each leaving when this process is gone, deaf to Ctrl-C and
    importing the plugins of RODO_PLUGINS first (`start_worker`)."""
    return WorkerPool(int(workers))


class WorkerPool(ProcessPoolExecutor):
    """A ProcessPoolExecutor of spawned workers (`start_worker`) that a with-block ended by an exception (Ctrl-C
    in the parent) stops at once (`stop`) instead of waiting for the tasks it submitted."""

    def __init__(self, workers: int):
        self._context = _QuietSpawnContext()
        self._stopped = self._context.Event()
        _events_in_use.add(self._stopped)
        super().__init__(int(workers), mp_context=self._context, initializer=start_worker,
                         initargs=(os.getpid(), self._stopped))

    @property
    def workers(self) -> list:
        """The worker processes started so far (multiprocessing Process objects)."""
        return list(self._context.started)

    def submit(self, fn, /, *args, **kwargs):
        return super().submit(_task, fn, *args, **kwargs)

    def shutdown(self, wait=True, *, cancel_futures=False):
        super().shutdown(wait, cancel_futures=cancel_futures)
        if wait:  # every worker has exited: none will read the stop event any more
            _events_in_use.discard(self._stopped)

    def stop(self) -> None:
        """Cancel the tasks not started and end the others: a task that a worker has taken ends with `StopTask`
        before it starts (the pool's stop event), and one running on SIGTERM (`_on_stop`); each worker then exits as
        the shut-down pool tells it. Returns without waiting. No worker is killed: a worker killed breaks the pool,
        whose manager then fails on the futures cancelled here (CPython 3.11: InvalidStateError). A thread sends
        SIGTERM again every STOP_RESEND s until the workers have exited: an exception raised by a signal handler
        is lost where it lands in a finalizer (`__del__`: "Exception ignored in ..."), and the task runs on."""
        self._stopped.set()
        self.shutdown(wait=False, cancel_futures=True)
        workers = self.workers

        def terminate_until_gone():
            while any(p.is_alive() for p in workers):
                for p in workers:
                    with contextlib.suppress(OSError, ValueError):  # exited meanwhile
                        if p.is_alive():
                            p.terminate()
                time.sleep(STOP_RESEND)

        threading.Thread(target=terminate_until_gone, name="stop-workers", daemon=True).start()

    def __exit__(self, exc_type, exc, tb):
        if exc_type is None:
            return super().__exit__(exc_type, exc, tb)
        self.stop()
        return False


# The stop events of the pools not shut down with wait: a spawned worker opens its pool's event by name when it
# starts, and the event's semaphore is unlinked when the event is collected, so a pool stopped and dropped while
# its workers still started left them a traceback (FileNotFoundError) instead of their StopTask.
_events_in_use: set = set()


class StopTask(BaseException):
    """Raised in a worker's task when its pool stops (`WorkerPool.stop`); a BaseException, so that no task's
    `except Exception` books it as the task's own failure."""


_stopped = None  # a worker's: its pool's stop event (`start_worker`); set, every task it takes ends at once
_running = False  # a worker's: a task is running (`_task`)


def _task(fn, *args, **kwargs):
    """A task in a worker, which its pool's stop ends (`_on_stop`)."""
    global _running
    if _stopped is not None and _stopped.is_set():
        raise StopTask("the pool stopped")
    _running = True
    try:
        return fn(*args, **kwargs)
    finally:
        _running = False


def _on_stop(signum, frame) -> None:
    """A worker's SIGTERM: its pool stopped. A running task ends here; an idle worker waits for the shut-down
    pool's word to exit (an exit of its own would break the pool)."""
    if _running:
        raise StopTask("the pool stopped")


class _QuietProcess(SpawnProcess):
    """A spawned process born with SIGINT and SIGTERM ignored: a child inherits an ignored signal through exec,
    and Python keeps it ignored, so a Ctrl-C during its imports prints nothing, and its pool's stop does not kill
    it before `start_worker` handles SIGTERM. (Only the main thread can set a handler; elsewhere `start_worker`
    ignores SIGINT once the imports are done.)"""

    def start(self):
        if threading.current_thread() is not threading.main_thread():
            return super().start()
        previous = {}
        try:  # a Ctrl-C between the two settings must still restore the first
            for s in (signal.SIGINT, signal.SIGTERM):
                previous[s] = signal.signal(s, signal.SIG_IGN)
            return super().start()
        finally:
            for s, handler in previous.items():
                signal.signal(s, handler)


class _QuietSpawnContext(SpawnContext):
    """The spawn context of a `WorkerPool`: its processes are `_QuietProcess`es, remembered for `stop`."""

    def __init__(self):
        super().__init__()
        self.started: list[_QuietProcess] = []

    def Process(self, *args, **kwargs):  # noqa: N802 - the name multiprocessing's contexts give it
        process = _QuietProcess(*args, **kwargs)
        self.started.append(process)
        return process


def start_worker(parent: int, stopped=None) -> None:
    """A worker's initializer: ignore SIGINT (the parent stops its workers), end the running task on SIGTERM
    (`_on_stop`) and the tasks taken once the event `stopped` is set (`_task`), watch the parent (pid `parent`,
    `exit_with_parent`), then import the plugins named in RODO_PLUGINS (`validation.plugins.load`), so the worker
    knows the parent's scenarios and profiles."""
    global _stopped
    _stopped = stopped
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, _on_stop)
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
        try:
            cluster = LocalCluster(n_workers=int(jobs), threads_per_worker=1, processes=processes,
                                   dashboard_address=dashboard, silence_logs=40)
        except RuntimeError as exc:  # "Cluster failed to start": a full disk under its scratch space is the machine's
            if is_environment_error(exc.__cause__):
                raise exc.__cause__ from None
            raise
        with cluster, Client(cluster) as client:
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
