"""A campaign's worker processes do not share its lock: forked, they inherited the flock (it belongs to the open
file) and, orphaned when the campaign was killed, held it, so `--resume` was refused until they were killed by
hand. Spawned, they hold no descriptor of it."""

import os

from rodo.validation.campaign import make_executor
from rodo.validation.campaign_dir import LOCK_NAME, campaign_lock


def open_files() -> list[str]:
    """The paths this process holds open (Linux: /proc/self/fd)."""
    out = []
    for fd in os.listdir("/proc/self/fd"):
        try:
            out.append(os.readlink(f"/proc/self/fd/{fd}"))
        except OSError:
            pass
    return out


def test_a_workers_descriptors_do_not_include_the_campaigns_lock(tmp_path):
    with campaign_lock(tmp_path / "campaign") as out:
        lock = os.path.realpath(out / LOCK_NAME)
        assert lock in open_files()  # the campaign holds it
        with make_executor(1) as ex:
            held = ex.submit(open_files).result()
        assert held and lock not in held, held


def test_a_worker_leaves_when_its_parent_is_gone():
    """The initializer's watch: a process whose parent has gone (here a fake parent pid that is not its parent)
    ends within a few watch intervals. Run in a child process so that os._exit ends the child, not pytest."""
    import multiprocessing

    from rodo.validation.workers import exit_with_parent

    ctx = multiprocessing.get_context("spawn")
    child = ctx.Process(target=_orphan_then_wait, args=(exit_with_parent,))
    child.start()
    child.join(timeout=60)  # generous: it leaves after one interval (1 s); a hung child would fail here
    alive = child.is_alive()
    if alive:
        child.kill()
    assert not alive and child.exitcode == 1


def _orphan_then_wait(start_watch) -> None:
    """Watch a 'parent' that is not ours (as after re-parenting), then wait as a worker blocked on a pipe would."""
    import time

    start_watch(os.getppid() + 1_000_000)
    time.sleep(600)
