"""Entry point of the `t2m` command: builds the parser from the subcommand modules and runs one."""
from __future__ import annotations

import argparse
import functools
import importlib
import sys
from collections.abc import Sequence
from importlib.metadata import entry_points

from t2m import DISTRIBUTION, __version__
from t2m.cli.subjects import run_subject, subject_of

# Each module in cli/commands exposes `register(subparsers)`, adding the command named here; the handler it sets via
# `parser.set_defaults(func=...)` receives the parsed namespace and returns an exit code. Only the module of the
# command being run is imported, so `t2m serve` and `t2m generate` never pay for (or need) torch. Packages that are
# not the CLI's add their commands as entry points of the group PLUGGED_COMMANDS, each naming such a module whose
# HELP is its one line: the HTTP service adds `t2m serve` that way, so the CLI never imports the service.
PLUGGED_COMMANDS = "t2m_commands"
BUILTIN_COMMANDS: dict[str, tuple[str, str]] = {
    "motion": ("t2m.cli.commands.motion", "convert between features, joints and BVH"),
    "data": ("t2m.cli.commands.data", "build a training set in HumanML3D's layout"),
    "train": ("t2m.cli.commands.train", "train the VQ-VAE, the GPT or the evaluator"),
    "eval": ("t2m.cli.commands.evaluate", "evaluate trained models (FID, R-precision, ...)"),
    "export": ("t2m.cli.commands.export", "export trained models to an ONNX bundle"),
    "import": ("t2m.cli.commands.importer", "import released checkpoints (T2M-GPT, MoMask, MoGenTS, MDM, DiP)"),
    "index-captions": ("t2m.cli.commands.index_captions", "index a bundle's training captions (unknown-text warnings)"),
    "quantize": ("t2m.cli.commands.quantize", "quantise a GPT bundle's step graph (int8 or int4 weights)"),
    "bench": ("t2m.cli.commands.bench", "benchmark generation speed"),
    "generate": ("t2m.cli.commands.generate", "generate a motion file without a server"),
    "edit": ("t2m.cli.commands.edit", "edit a saved json motion (its handle) without a server"),
}




def _commands() -> dict[str, tuple[str, str]]:
    """The built-in commands, then the plugged ones (a plugged command never replaces a built-in one)."""
    plugged = {point.name: (point.value, importlib.import_module(point.value).HELP)
               for point in entry_points(group=PLUGGED_COMMANDS) if point.name not in BUILTIN_COMMANDS}
    return {**BUILTIN_COMMANDS, **dict(sorted(plugged.items()))}


COMMANDS = _commands()


class CliError(Exception):
    """A user error: printed as one line on stderr, exit code 2. Never a traceback."""


def _selected_command(argv: Sequence[str]) -> str | None:
    """The command named on the command line (the first word that is not an option), if any."""
    for word in argv:
        if not word.startswith("-"):
            return word if word in COMMANDS else None
    return None


def build_parser(selected: str | None = None) -> argparse.ArgumentParser:
    """The parser with the selected command fully registered and the others as one-line entries for --help.

    `selected=None` registers every command (used by tests and documentation tools)."""
    parser = argparse.ArgumentParser(prog="t2m", description="Text-to-motion: data, training, export and serving.")
    parser.add_argument("--version", action="version", version=f"{DISTRIBUTION} {__version__}")
    subparsers = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name, (module_name, help_text) in COMMANDS.items():
        if selected is None or name == selected:
            importlib.import_module(module_name).register(subparsers)
        else:
            subparsers.add_parser(name, help=help_text)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    subject = subject_of(argv)
    if subject is not None:
        command = subject[0]
        run = functools.partial(run_subject, *subject, argv[2:])
    else:
        parser = build_parser(_selected_command(argv) or "")
        args = parser.parse_args(argv)
        if not getattr(args, "func", None):
            parser.print_help()
            return 2
        command = args.command
        run = functools.partial(args.func, args)
    try:
        return int(run() or 0)
    except CliError as error:
        print(f"t2m {command}: error: {error}", file=sys.stderr)
        return 2
    except FileNotFoundError as error:
        print(f"t2m {command}: error: file not found: {error.filename or error}", file=sys.stderr)
        return 2
    except ValueError as error:  # motion-core and bundle checks raise ValueError with a user-facing message
        print(f"t2m {command}: error: {error}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        return 130


if __name__ == "__main__":
    sys.exit(main())
