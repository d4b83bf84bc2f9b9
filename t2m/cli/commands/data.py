"""`t2m data build`: turn Bandai-Namco's BVH clips or the captioned CMU trials into a HumanML3D-layout training
dataset; `t2m data merge`: put built datasets together (ids prefixed by source) for training on all of them."""
from __future__ import annotations

import argparse
import time


def register(subparsers: argparse._SubParsersAction) -> None:
    data = subparsers.add_parser("data", help="build training datasets")
    commands = data.add_subparsers(dest="data_command", metavar="SUBCOMMAND")
    build = commands.add_parser(
        "build", help="Bandai-Namco BVH or captioned CMU trials (.tar.xz or extracted dir) -> HumanML3D layout")
    build.add_argument("--source", required=True,
                       help="bandai-namco-motion.tar.xz or cmu-captioned-motion.tar.xz, or the directory either "
                            "unpacks to (the kind is recognised from the contents)")
    build.add_argument("--out", required=True, help="output directory (HumanML3D layout)")
    build.add_argument("--index", default=None,
                       help="CMU only: index.json with the sentences (default: beside the archive)")
    build.add_argument("--workers", type=int, default=2, help="Bandai-Namco: worker processes (default 2)")
    build.add_argument("--no-mirror", action="store_true", help="do not add mirrored copies (M<id>)")
    build.add_argument("--limit", type=int, default=None,
                       help="use only N clips (Bandai-Namco) or trials (CMU) for quick runs")
    build.add_argument("--overwrite", action="store_true", help="replace a dataset already in --out")
    build.add_argument("--quiet", action="store_true", help="no progress bar")
    build.set_defaults(func=_build)
    merge = commands.add_parser("merge", help="merge built datasets into one (ids prefixed by source)")
    merge.add_argument("--input", action="append", required=True, metavar="PREFIX=DIR",
                       help="a built dataset and the prefix of its ids, e.g. bn-=data/bandai (repeat)")
    merge.add_argument("--out", required=True, help="output directory (HumanML3D layout)")
    merge.add_argument("--overwrite", action="store_true", help="replace a dataset already in --out")
    merge.set_defaults(func=_merge)
    data.set_defaults(func=lambda args: data.print_help() or 2)


def _build(args: argparse.Namespace) -> int:
    from t2m.cli.main import CliError
    from t2m.model.data.cmu_source import is_cmu_source

    if args.workers < 1:
        raise CliError(f"--workers must be at least 1, got {args.workers}")
    if args.limit is not None and args.limit < 1:
        raise CliError(f"--limit must be at least 1, got {args.limit}")
    started = time.time()
    if is_cmu_source(args.source):
        from t2m.model.data.cmu_builder import CmuBuildOptions, build_cmu_dataset, format_cmu_summary
        summary = build_cmu_dataset(args.source, args.out, CmuBuildOptions(
            index=args.index, mirror=not args.no_mirror, limit=args.limit, overwrite=args.overwrite,
            progress=not args.quiet))
        print(format_cmu_summary(summary))
    else:
        from t2m.model.data.dataset_builder import BuildOptions, build_dataset, format_summary
        if args.index is not None:
            raise CliError(f"--index is for the CMU trials; {args.source} is not the CMU archive")
        options = BuildOptions(workers=args.workers, mirror=not args.no_mirror, limit=args.limit,
                               overwrite=args.overwrite, progress=not args.quiet)
        print(format_summary(build_dataset(args.source, args.out, options)))
    print(f"wrote {args.out} in {time.time() - started:.1f} s (log: {args.out}/build.log)")
    return 0


def _merge(args: argparse.Namespace) -> int:
    from t2m.cli.main import CliError
    from t2m.model.data.merge import merge_datasets

    sources = []
    for text in args.input:
        prefix, sep, directory = text.partition("=")
        if not sep or not directory:
            raise CliError(f"--input expects PREFIX=DIR (e.g. cmu-=data/cmu), got {text!r}")
        sources.append((prefix, directory))
    summary = merge_datasets(sources, args.out, overwrite=args.overwrite)
    for split, s in summary["splits"].items():
        print(f"  {split:5s} {s['items']:6d} items {s['hours']:6.2f} h  " +
              " ".join(f"{k}={v}" for k, v in s.items() if k.startswith("items_")))
    print(f"merged {len(sources)} datasets into {args.out} (licence {summary['license']})")
    return 0
