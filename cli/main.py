"""Entry point of the `t2m` command: builds the parser from the subcommand modules and runs one."""
from __future__ import annotations

import argparse
import importlib
import sys
from typing import Sequence

# Each module in cli/commands exposes `register(subparsers)`; the handler it sets via
# `parser.set_defaults(func=...)` receives the parsed namespace and returns an exit code.
COMMAND_MODULES = [
    "motion",     # t2m motion joints|features|from-bvh
    "data",       # t2m data build
    "train",      # t2m train vq|gpt|evaluator
    "evaluate",   # t2m eval
    "export",     # t2m export
    "importer",   # t2m import t2m-gpt
    "bench",      # t2m bench
    "serve",      # t2m serve
    "generate",   # t2m generate
]


class CliError(Exception):
    """A user error: printed as one line on stderr, exit code 2. Never a traceback."""


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="t2m", description="Text-to-motion: data, training, export and serving.")
    subparsers = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name in COMMAND_MODULES:
        try:
            module = importlib.import_module(f"cli.commands.{name}")
        except ModuleNotFoundError as error:
            if error.name == f"cli.commands.{name}":
                continue  # a subcommand not written yet
            raise
        module.register(subparsers)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if not getattr(args, "func", None):
        parser.print_help()
        return 2
    try:
        return int(args.func(args) or 0)
    except CliError as error:
        print(f"t2m {args.command}: error: {error}", file=sys.stderr)
        return 2
    except FileNotFoundError as error:
        print(f"t2m {args.command}: error: file not found: {error.filename or error}", file=sys.stderr)
        return 2
    except ValueError as error:  # motion-core and bundle checks raise ValueError with a user-facing message
        print(f"t2m {args.command}: error: {error}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        return 130


if __name__ == "__main__":
    sys.exit(main())
