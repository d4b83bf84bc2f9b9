"""`t2m bench`: ms per generated token and ms for a 10 s motion, onnxruntime + KV cache vs PyTorch eager.

Prints a markdown table (default model size and the T2M-GPT release size) with the machine's CPU, cores,
library versions and thread counts; the last line is `speedup_vs_eager_recompute=<N>x` for the default size.
With `--bundle DIR` (repeatable) it times whole requests on those bundles instead, every model family side by side
(a 10 s motion and a 3-sentence stream, per stage), through the service's own engine.
"""
from __future__ import annotations

import argparse
from pathlib import Path


def register(subparsers: argparse._SubParsersAction) -> None:
    from t2m.cli.subjects import subjects_help

    parser = subparsers.add_parser("bench", help="generation speed: onnxruntime + KV cache vs PyTorch eager",
                                   description=(__doc__ or "").strip().splitlines()[0],
                                   epilog=subjects_help("bench"), formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--quick", action="store_true",
                        help="one repeat, and only 10 tokens at the T2M-GPT release size "
                             "(under ~40 s once the graphs are cached)")
    parser.add_argument("--threads", type=int, default=None,
                        help="threads for torch and onnxruntime (default: all cores)")
    parser.add_argument("--cache-dir", type=Path, default=None, metavar="DIR",
                        help="where exported benchmark graphs are kept between runs (default ~/.cache/t2m/bench)")
    parser.add_argument("--no-cache", action="store_true", help="export the graphs afresh into a temporary directory")
    parser.add_argument("--no-release", action="store_true", help="skip the 228M-parameter T2M-GPT release size")
    parser.add_argument("--bundle", type=Path, action="append", default=None, metavar="DIR",
                        help="time whole requests on this bundle (repeat to compare models in one run; "
                             "an embedded bundle by its name: default, masked)")
    parser.add_argument("--repeats", type=int, default=5, help="--bundle: requests timed per case (default 5)")
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from t2m.cli.main import CliError

    if args.threads is not None and args.threads < 1:
        raise CliError("--threads must be >= 1")
    if args.bundle:
        return run_bundles(args)
    from t2m.bench.models import default_cache_dir, run_bench

    cache_dir = None if args.no_cache else (args.cache_dir or default_cache_dir())
    run_bench(quick=args.quick, threads=args.threads, include_release=not args.no_release, cache_dir=cache_dir)
    return 0


def run_bundles(args: argparse.Namespace) -> int:
    from t2m.bench.bundles import run_bundle_bench
    from t2m.bundle import BundleError
    from t2m.bundles import resolve_bundle
    from t2m.cli.main import CliError

    if args.repeats < 1:
        raise CliError("--repeats must be >= 1")
    paths = [resolve_bundle(path) for path in args.bundle]
    for path in paths:
        if not (path / "manifest.json").is_file():
            raise CliError(f"--bundle {path}: no manifest.json there (not a bundle directory)")
    try:
        run_bundle_bench(paths, repeats=args.repeats, threads=args.threads)
    except BundleError as error:
        raise CliError(f"--bundle: {error}") from error
    return 0
