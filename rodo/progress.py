"""Progress bars on stderr through tqdm: shown only when the stream is a terminal (so logs, CI and captured
output stay clean: no carriage returns, nothing at all).

`Progress` keeps rodo's small interface (`with Progress(total, label) as bar: ... bar.update(n)`) so the
library code takes any object with `update(n)` and never imports tqdm.

Checked by: tests/cli/test_progress.py
"""

from __future__ import annotations

import sys

from tqdm import tqdm


class _Bar(tqdm):
    """tqdm without its monitor thread: a campaign forks worker processes after the bar starts, and forking a
    process that runs extra threads may deadlock."""

    monitor_interval = 0


def is_terminal(stream) -> bool:
    """True when `stream` says it is a terminal (`isatty()`); False for files, pipes and StringIO."""
    isatty = getattr(stream, "isatty", None)
    try:
        return bool(isatty()) if callable(isatty) else False
    except ValueError:  # a closed stream
        return False


class Progress:
    """`with Progress(total, "label") as bar: ... bar.update()`; shows count, rate and ETA on a terminal.

    Args:
        total: number of steps expected (>= 0; a resumed campaign with nothing left passes 0), or None when
            unknown (count and rate only, e.g. the messages of a bag).
        label: shown before the bar.
        stream: where the bar goes (default sys.stderr).
        enabled: force the bar on or off; default: on only when `stream` is a terminal.
        unit: the name of one step ("scan", "run", "figure").
    """

    def __init__(self, total: int | None, label: str, stream=None, enabled: bool | None = None, unit: str = "it"):
        self.stream = stream if stream is not None else sys.stderr
        self.enabled = is_terminal(self.stream) if enabled is None else bool(enabled)
        self.total = None if total is None else max(int(total), 0)
        self.label = label
        self.done = 0
        self._bar = _Bar(total=self.total, desc=label, file=self.stream, disable=not self.enabled, unit=unit,
                         mininterval=0.1, dynamic_ncols=True, leave=True)

    def update(self, n: int = 1) -> None:
        self.done += n
        self._bar.update(n)

    def print(self, text: str, file=None) -> None:
        """Print a line (default on stdout) without breaking the bar: tqdm clears it, prints, redraws."""
        file = file if file is not None else sys.stdout
        if self.enabled:
            tqdm.write(text, file=file)
            file.flush()
        else:
            print(text, file=file, flush=True)

    def close(self) -> None:
        self._bar.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
