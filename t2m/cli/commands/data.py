"""`t2m data build`: turn the Bandai-Namco BVH clips into a HumanML3D-layout training dataset."""
from __future__ import annotations

import argparse
import time


def register(subparsers: argparse._SubParsersAction) -> None:
    data = subparsers.add_parser("data", help="build training datasets")
    commands = data.add_subparsers(dest="data_command", metavar="SUBCOMMAND")
    build = commands.add_parser(
        "build", help="Bandai-Namco BVH (.tar.xz or extracted dir) -> HumanML3D layout (joints, features, texts)")
    build.add_argument("--source", required=True,
                       help="bandai-namco-motion.tar.xz or the directory it unpacks to")
    build.add_argument("--out", required=True, help="output directory (HumanML3D layout)")
    build.add_argument("--workers", type=int, default=2, help="worker processes (default 2)")
    build.add_argument("--no-mirror", action="store_true", help="do not add mirrored copies (M<id>)")
    build.add_argument("--limit", type=int, default=None, help="use only N clips spread over the dataset (quick runs)")
    build.add_argument("--overwrite", action="store_true", help="replace a dataset already in --out")
    build.add_argument("--quiet", action="store_true", help="no progress bar")
    build.set_defaults(func=_build)
    data.set_defaults(func=lambda args: data.print_help() or 2)


def _build(args: argparse.Namespace) -> int:
    from t2m.cli.main import CliError
    from t2m.model.data.dataset_builder import BuildOptions, build_dataset, format_summary

    if args.workers < 1:
        raise CliError(f"--workers must be at least 1, got {args.workers}")
    if args.limit is not None and args.limit < 1:
        raise CliError(f"--limit must be at least 1, got {args.limit}")
    started = time.time()
    options = BuildOptions(workers=args.workers, mirror=not args.no_mirror, limit=args.limit,
                           overwrite=args.overwrite, progress=not args.quiet)
    summary = build_dataset(args.source, args.out, options)
    print(format_summary(summary))
    print(f"wrote {args.out} in {time.time() - started:.1f} s (log: {args.out}/build.log)")
    return 0
