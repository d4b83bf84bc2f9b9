"""`t2m eval`: the papers' Table 1 (and T2LM's multi-sentence metrics) for a VQ-VAE + GPT on a test split."""
from __future__ import annotations

import argparse
import time
from pathlib import Path


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "eval", help="evaluate a VQ-VAE + GPT with a trained evaluator (R-precision, FID, MM-Dist, ...)",
        description="Reports on a split, laid out like the papers' Table 1: Real motion, VQ reconstruction and "
                    "generation at each guidance scale, mean ± 95% interval over repeats; plus T2LM's sliding- and "
                    "transition-scope FID on streams of sentences. Writes markdown (--out) and JSON (raw numbers).")
    parser.add_argument("--data", required=True, help="dataset directory in HumanML3D layout")
    parser.add_argument("--evaluator", required=True, help="evaluator run directory (t2m train evaluator)")
    parser.add_argument("--vq", required=True, help="VQ-VAE run directory")
    parser.add_argument("--gpt", required=True, help="GPT run directory")
    parser.add_argument("--split", default="test", help="split to evaluate on (default test)")
    parser.add_argument("--repeats", type=int, default=20, help="evaluations averaged, as the papers do (default 20)")
    parser.add_argument("--guidance", type=float, nargs="+", default=[1.0, 3.0],
                        help="classifier-free guidance scales, one table row each (default 1 3)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--limit", type=int, default=None, help="use only N clips of the split (quick runs)")
    parser.add_argument("--out", default="eval_report.md", help="markdown report (default eval_report.md)")
    parser.add_argument("--json", default=None, help="raw numbers (default: --out with .json)")
    parser.add_argument("--temperature", type=float, default=1.0, help="sampling temperature (default 1)")
    parser.add_argument("--top-k", type=int, default=None, help="sample from the k likeliest codes (default: all)")
    parser.add_argument("--mm-texts", type=int, default=100, help="texts for MModality (default 100)")
    parser.add_argument("--mm-repeats", type=int, default=30, help="motions per MModality text (default 30)")
    parser.add_argument("--streams", type=int, default=None,
                        help="multi-sentence streams per repeat (default: every clip used once, in threes)")
    parser.add_argument("--no-multi-sentence", action="store_true", help="skip the T2LM stream metrics")
    parser.add_argument("--batch-size", type=int, default=128, help="rows generated in lockstep (default 128)")
    parser.add_argument("--text-cache", default=None, help="npz cache of caption features (reused across runs)")
    parser.add_argument("--clip-weights", default=None,
                        help="local CLIP ViT-B/32 weights, for a GPT trained on the clip text encoder")
    parser.add_argument("--threads", type=int, default=1,
                        help="torch CPU threads (default 1: on shared cores more threads mostly wait for each other)")
    parser.add_argument("--quiet", action="store_true", help="no progress bars")
    parser.set_defaults(func=_evaluate)


def _evaluate(args: argparse.Namespace) -> int:
    from t2m.cli.main import CliError

    if args.threads < 1:
        raise CliError(f"--threads must be at least 1, got {args.threads}")
    if args.top_k is not None and args.top_k < 1:
        raise CliError(f"--top-k must be at least 1, got {args.top_k}")
    if args.streams is not None and args.streams < 1:
        raise CliError(f"--streams must be at least 1, got {args.streams}")

    import torch

    from t2m.model.data.motion_data import MotionDirectory
    from t2m.model.evaluation.evaluate import EvalOptions, evaluate, load_models, write_report

    torch.set_num_threads(args.threads)
    options = EvalOptions(split=args.split, repeats=args.repeats, guidance=tuple(args.guidance), seed=args.seed,
                          limit=args.limit, temperature=args.temperature, top_k=args.top_k, mm_texts=args.mm_texts,
                          mm_repeats=args.mm_repeats, streams=args.streams, batch_size=args.batch_size,
                          multi_sentence=not args.no_multi_sentence, progress=not args.quiet)
    options.check()
    started = time.time()
    reader = MotionDirectory(args.data, args.split)
    models = load_models(args.evaluator, args.vq, args.gpt, reader.mean, reader.std)
    encoder_kwargs = {"clip": {"weights": args.clip_weights}} if args.clip_weights else None
    result = evaluate(models, reader, options, text_cache=args.text_cache, encoder_kwargs=encoder_kwargs)
    result["data"] = str(args.data)
    result["seconds"] = round(time.time() - started, 1)
    json_path = args.json or str(Path(args.out).with_suffix(".json"))
    text = write_report(result, args.out, json_path, title=f"Evaluation on {args.data} ({args.split})")
    print(text, end="")
    print(f"wrote {args.out} and {json_path} in {result['seconds']:.0f} s")
    return 0
