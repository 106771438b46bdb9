"""`rodo config dump [--model MODEL] [--markdown]`: the complete default configuration of the estimator as
commented TOML that `rodo run --config` accepts (or, with --markdown, docs/configuration.md). The keys, their
defaults, units and descriptions come from `rodo.config_schema`, which reads estimator/config.py's dataclasses.
"""

from __future__ import annotations

import argparse

from rodo.estimator.config import MODELS


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("config", help="print the estimator's default configuration (commented TOML)",
                       description="Estimator configuration. `rodo config dump` prints every key with its default, "
                                   "unit and description as TOML that `rodo run --config FILE` accepts.")
    actions = p.add_subparsers(dest="action", required=True, metavar="ACTION")
    d = actions.add_parser("dump", help="print the complete default configuration as commented TOML",
                           description="Print every key of the estimator's configuration with its default for "
                                       "MODEL, as commented TOML: save it, edit it, pass it to `rodo run --config`.")
    d.add_argument("--model", choices=MODELS, default="ca-polar", metavar="MODEL",
                   help=f"the model whose defaults to print: {', '.join(MODELS)} (default ca-polar)")
    d.add_argument("--markdown", action="store_true",
                   help="print the reference of every key as Markdown instead (docs/configuration.md)")
    d.set_defaults(func=main)


def main(args: argparse.Namespace) -> int:
    from rodo.config_schema import render_markdown, render_toml

    print(render_markdown() if args.markdown else render_toml(args.model), end="")
    return 0
