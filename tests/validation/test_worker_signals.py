"""A campaign's workers and a Ctrl-C (validation.workers): a terminal's Ctrl-C reaches the whole process group,
and every worker printed a KeyboardInterrupt traceback while importing, idle or running; the interrupted campaign
then waited for its running trials, whose results it threw away. Workers are now born deaf to SIGINT, and the
interrupted parent stops them at once."""

import os
import signal
import time

import pytest

from rodo.validation.workers import StopTask, WorkerPool, _QuietSpawnContext, spawn_pool


def _disposition():
    return signal.getsignal(signal.SIGINT)


def _report(queue):
    queue.put(signal.getsignal(signal.SIGINT))


def test_a_worker_is_born_deaf_to_ctrl_c():
    """Ignored from birth (before the pool's initializer, which runs after the imports a Ctrl-C would interrupt),
    and so while it waits and works."""
    before = signal.getsignal(signal.SIGINT)  # Python's handler, or ignored where pytest runs in the background
    context = _QuietSpawnContext()
    queue = context.SimpleQueue()
    child = context.Process(target=_report, args=(queue,))
    child.start()
    child.join(timeout=120)
    assert queue.get() == signal.SIG_IGN
    assert signal.getsignal(signal.SIGINT) == before  # the parent's is as it was
    with spawn_pool(1) as pool:
        assert pool.submit(_disposition).result() == signal.SIG_IGN


def test_a_ctrl_c_to_the_group_leaves_the_pool_working():
    with spawn_pool(1) as pool:
        pid = pool.submit(os.getpid).result()
        os.kill(pid, signal.SIGINT)  # what a terminal's Ctrl-C sends to every process of the group
        assert pool.submit(sum, [1, 2]).result() == 3


def test_an_interrupted_pool_ends_its_running_and_queued_tasks_at_once():
    """A KeyboardInterrupt in the with-block: the task running (10 min) and the ones queued behind it end with
    StopTask, and the workers exit, instead of the block's end waiting for all of them."""
    with pytest.raises(KeyboardInterrupt):
        with WorkerPool(1) as pool:
            futures = [pool.submit(time.sleep, 600) for _ in range(4)]
            while not futures[0].running():
                time.sleep(0.05)
            time.sleep(0.5)  # the worker has taken the task from the queue
            raise KeyboardInterrupt
    processes = pool.workers
    deadline = time.monotonic() + 120  # generous: they leave within a second; a worker still sleeping fails here
    while any(p.is_alive() for p in processes) and time.monotonic() < deadline:
        time.sleep(0.05)  # (the pool's own thread reaps them too: a join here can return before it has noted one)
    assert processes and not any(p.is_alive() for p in processes)
    for fut in futures:
        assert fut.cancelled() or isinstance(fut.exception(timeout=120), StopTask)
