"""`t2m eval`: the papers' Table 1 (and T2LM's multi-sentence metrics) for a VQ-VAE + GPT, or for the masked family
(joint VQ + masked + residual transformer), or for T2M-HiFiGPT (residual VQ + double-tier GPT), on a test split. The
family is the token run given: --gpt, --masked or --hifigpt; or a served GPT, T2M-HiFiGPT or diffusion (MDM, DiP)
bundle (--bundle DIR: its own ONNX graphs, no training runs)."""
from __future__ import annotations

import argparse
import time
from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from t2m.bundle import ModelFamily


def register(subparsers: argparse._SubParsersAction) -> None:
    from t2m.bundle import iter_families
    from t2m.cli.subjects import subjects_help

    parser = subparsers.add_parser(
        "eval", epilog=subjects_help("eval"), formatter_class=argparse.RawDescriptionHelpFormatter,
        help="evaluate a VQ-VAE + GPT (or masked family) with a trained evaluator (R-precision, FID, ...)",
        description="Reports on a split, laid out like the papers' Table 1: Real motion, VQ reconstruction and "
                    "generation at each guidance scale, mean ± 95% interval over repeats; plus T2LM's sliding- and "
                    "transition-scope FID on streams of sentences. Writes markdown (--out) and JSON (raw numbers). "
                    "GPT family: --vq VQ_RUN --gpt RUN. Masked family: --vq JOINT_VQ_RUN --masked RUN --residual RUN "
                    "[--length RUN], decoded by the service's loop (t2m.families.masked.loop). T2M-HiFiGPT: --vq "
                    "RESIDUAL_VQ_RUN --hifigpt RUN (t2m.families.hifigpt.loop). A served GPT, T2M-HiFiGPT or diffusion "
                    "bundle: --bundle DIR (its text, step or denoiser and decoder graphs in onnxruntime through the "
                    "service's loop; no VQ-reconstruction row; a diffusion bundle's streams are one request each, "
                    "joined as served).")
    parser.add_argument("--data", required=True, help="dataset directory in HumanML3D layout")
    parser.add_argument("--evaluator", required=True, help="evaluator run directory (t2m train evaluator)")
    parser.add_argument("--vq", default=None, help="VQ-VAE run directory (the joint VQ for the masked family)")
    parser.add_argument("--bundle", default=None,
                        help="a served GPT, T2M-HiFiGPT or diffusion bundle instead of runs (no --vq): evaluates "
                             "what the service runs")
    owners: dict[str, list[argparse.Action]] = {}
    for family in iter_families():
        if family.eval_run_option is None:
            continue
        before = len(parser._actions)
        parser.add_argument(f"--{family.eval_run_option}", default=None, metavar="RUN",
                            help=f"token model run directory: {family.title}")
        family.add_eval_arguments(parser)
        owners[family.name] = parser._actions[before + 1:]
    parser.add_argument("--split", default="test", help="split to evaluate on (default test)")
    parser.add_argument("--repeats", type=int, default=20, help="evaluations averaged, as the papers do (default 20)")
    parser.add_argument("--guidance", type=float, nargs="+", default=None,
                        help="classifier-free guidance scales (the masked family: of its masked stage), one table "
                             "row each (default 1 3 for the GPT, 1 4 for the masked family: MoMask's scale)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--limit", type=int, default=None, help="use only N clips of the split (quick runs)")
    parser.add_argument("--out", default="eval_report.md", help="markdown report (default eval_report.md)")
    parser.add_argument("--json", default=None, help="raw numbers (default: --out with .json)")
    parser.add_argument("--temperature", type=float, default=1.0, help="sampling temperature (default 1)")
    parser.add_argument("--top-k", type=int, default=None,
                        help="sample from the k likeliest codes (masked family: its masked stage; default: all)")
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
    parser.set_defaults(func=_evaluate, family_options=owners)


def _family(args: argparse.Namespace) -> ModelFamily | None:
    """The family whose run option was given (None: --bundle DIR); another family's options are refused."""
    from t2m.bundle import get_family, iter_families
    from t2m.cli.main import CliError

    families = [family for family in iter_families() if family.eval_run_option is not None]
    given = [family for family in families if getattr(args, str(family.eval_run_option)) is not None]
    runs = "/".join(f"--{family.eval_run_option}" for family in families)
    chosen = given[0] if len(given) == 1 else None
    for name, actions in args.family_options.items():
        for action in actions:
            if getattr(args, action.dest) is not None and (chosen is None or chosen.name != name):
                what = "--bundle" if args.bundle is not None else f"--{chosen.eval_run_option}" if chosen else None
                if what is not None:
                    owner = get_family(name)
                    raise CliError(f"{action.option_strings[0]} applies to the {owner.name} family "
                                   f"(--{owner.eval_run_option}), not to {what}")
    if args.bundle is not None:
        if given or args.vq is not None:
            raise CliError(f"--bundle replaces --vq and the token runs: give either --bundle DIR or --vq with one of "
                           f"{runs}")
        return None
    if args.vq is None:
        raise CliError("give --vq VQ_RUN with the token run (or --bundle DIR)")
    if chosen is None:
        raise CliError("give exactly one of " + ", ".join(f"--{family.eval_run_option} RUN ({family.name} family)"
                                                          for family in families))
    try:
        chosen.check_eval_arguments(args)
    except ValueError as error:
        raise CliError(str(error)) from None
    return chosen


def _evaluate(args: argparse.Namespace) -> int:
    from t2m.cli.main import CliError

    if args.threads < 1:
        raise CliError(f"--threads must be at least 1, got {args.threads}")
    if args.top_k is not None and args.top_k < 1:
        raise CliError(f"--top-k must be at least 1, got {args.top_k}")
    if args.streams is not None and args.streams < 1:
        raise CliError(f"--streams must be at least 1, got {args.streams}")
    family = _family(args)

    import torch

    from t2m.model.data.motion_data import MotionDirectory
    from t2m.model.evaluation.evaluate import EvalOptions, evaluate, write_report

    torch.set_num_threads(args.threads)
    guidance = args.guidance or (family.default_eval_guidance if family is not None else (1.0, 3.0))
    options = EvalOptions(split=args.split, repeats=args.repeats, guidance=tuple(guidance), seed=args.seed,
                          limit=args.limit, temperature=args.temperature, top_k=args.top_k, mm_texts=args.mm_texts,
                          mm_repeats=args.mm_repeats, streams=args.streams, batch_size=args.batch_size,
                          multi_sentence=not args.no_multi_sentence, progress=not args.quiet)
    options.check()
    started = time.time()
    reader = MotionDirectory(args.data, args.split)
    if family is None:
        from t2m.export.evaluation import load_bundle_models

        models = load_bundle_models(args.evaluator, args.bundle, threads=args.threads)
    else:
        models = family.load_eval_models(args, reader.mean, reader.std)
    encoder_kwargs = {"clip": {"weights": args.clip_weights}} if args.clip_weights else None
    result = evaluate(models, reader, options, text_cache=args.text_cache, encoder_kwargs=encoder_kwargs)
    result["data"] = str(args.data)
    result["seconds"] = round(time.time() - started, 1)
    json_path = args.json or str(Path(args.out).with_suffix(".json"))
    text = write_report(result, args.out, json_path, title=f"Evaluation on {args.data} ({args.split})")
    print(text, end="")
    print(f"wrote {args.out} and {json_path} in {result['seconds']:.0f} s")
    return 0
