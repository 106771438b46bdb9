"""The `rodo` command's entry point: the command line (`rodo.cli`) imports numba, its kernels and the commands,
about a second and a half in which a Ctrl-C would end in a traceback before `rodo.cli.main`'s own handler exists.
Here that import is interrupted quietly: `rodo: interrupted`, exit 130, as `rodo.cli.main` says it later. It is
also what a campaign's spawned workers import as their main module (the `rodo` script), which costs nothing.

Checked by: tests/cli/test_entry.py
"""

from __future__ import annotations

import sys

INTERRUPTED = 130  # 128 + SIGINT, as a shell reports a command ended by Ctrl-C


def main() -> int:
    try:
        from rodo.cli import main as cli_main
    except KeyboardInterrupt:
        print("rodo: interrupted", file=sys.stderr)
        return INTERRUPTED
    return cli_main()


if __name__ == "__main__":
    sys.exit(main())
