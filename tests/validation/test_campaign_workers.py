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
