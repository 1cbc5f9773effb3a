"""The ``towerpipe`` command line.

Each sub-command lives in the module that owns the concept; a module joins the
command line by exposing ``register(subparsers)`` which adds its parser and sets
``func`` (called with the parsed namespace, returns an exit code).
"""

from __future__ import annotations

import argparse
import importlib
import logging
import sys

from towerpipe import __version__
from towerpipe.errors import TowerpipeError

#: Modules that add sub-commands, in --help order.
COMMAND_MODULES = [
    "towerpipe.jobs.run",
    "towerpipe.config",
    "towerpipe.synth.cli",
    "towerpipe.training.cli",
    "towerpipe.evaluation.evaluate",
    "towerpipe.evaluation.calibrate",
    "towerpipe.evaluation.realshape",
    "towerpipe.evaluation.trace",
    "towerpipe.jobs.lines",
    "towerpipe.bench",
]


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="towerpipe", description=__doc__.splitlines()[0])
    parser.add_argument("--version", action="version", version=f"towerpipe {__version__}")
    parser.add_argument("-v", "--verbose", action="store_true", help="debug logging")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name in COMMAND_MODULES:
        importlib.import_module(name).register(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    logging.basicConfig(
        level=logging.DEBUG if args.verbose else logging.INFO, format="%(asctime)s %(levelname)s %(name)s: %(message)s"
    )
    if not getattr(args, "func", None):
        parser.print_help()
        return 2
    try:
        return int(args.func(args) or 0)
    except TowerpipeError as exc:
        print(f"towerpipe: error: {type(exc).__name__}: {exc}", file=sys.stderr)
        return 1


if __name__ == "__main__":
    sys.exit(main())
