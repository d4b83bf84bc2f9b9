"""`t2m generate`: sentences -> motion file (.json, .bvh or .glb) on this machine, no server needed.

    t2m generate "a person walks forward" --duration 3 --then "a person waves" --duration 2 -o wave.bvh

A --duration belongs to the sentence written before it (the first sentence or the latest --then); a sentence
without one gets a free length (the model ends it). The request goes through the API's own pydantic schema, so the
limits and messages are the same as over HTTP.
"""
from __future__ import annotations

import argparse
import secrets
import sys
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

FORMATS = {".json": "json", ".bvh": "bvh", ".glb": "glb"}
FREE_WORDS = ("free", "none", "null", "auto")


def _duration(text: str) -> float | None:
    if text.strip().lower() in FREE_WORDS:
        return None
    try:
        return float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected seconds or one of {', '.join(FREE_WORDS)}, got {text!r}") from None


class _SegmentEvent(argparse.Action):
    """Records --then and --duration in command-line order, so each duration can find its sentence."""

    def __call__(self, parser: argparse.ArgumentParser, namespace: argparse.Namespace, values: Any,
                 option_string: str | None = None) -> None:
        events = list(getattr(namespace, "segment_events", None) or [])
        events.append((option_string, values))
        namespace.segment_events = events


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "generate", help="sentences -> motion file (.json/.bvh/.glb) without a server",
        description="Generate one continuous motion from one or more sentences. A --duration belongs to the "
                    "sentence before it; leave it out (or write 'free') to let the model end that sentence.")
    parser.add_argument("text", help="the first sentence")
    parser.add_argument("--duration", dest="segment_events", action=_SegmentEvent, type=_duration, metavar="SECONDS",
                        help="seconds of the sentence written before it (0.5-10; 'free' = model decides)")
    parser.add_argument("--then", dest="segment_events", action=_SegmentEvent, metavar="TEXT",
                        help="a following sentence (repeatable)")
    parser.add_argument("--seed", type=int, default=None, help="same seed + same input = same motion")
    parser.add_argument("--guidance", type=float, default=None, help="classifier-free guidance (default: model's)")
    parser.add_argument("--temperature", type=float, default=1.0, help="sampling temperature (default 1)")
    parser.add_argument("--top-k", dest="top_k", type=int, default=None, help="sample among the k likeliest codes")
    parser.add_argument("--model", type=Path, default=None,
                        help="model bundle directory (default: T2M_MODEL_DIR, else the embedded t2m/bundles/default)")
    parser.add_argument("-o", "--output", type=Path, required=True, help="output file: .json, .bvh or .glb")
    parser.set_defaults(func=_generate, segment_events=[])


def segments_from_args(text: str, events: list[tuple[str, Any]]) -> list[dict[str, Any]]:
    """[{'text', 'duration'}] from the first sentence and the ordered --then/--duration events."""
    from t2m.cli.main import CliError

    segments: list[dict[str, Any]] = [{"text": text}]
    for option, value in events:
        if option == "--then":
            segments.append({"text": value})
        elif "duration" in segments[-1]:
            raise CliError(f"sentence {len(segments)} ({segments[-1]['text']!r}) has two --duration values")
        else:
            segments[-1]["duration"] = value
    for segment in segments:
        segment.setdefault("duration", None)
    return segments


def _field_name(loc: tuple[Any, ...]) -> str:
    """A pydantic error location in the words of the command line."""
    if len(loc) >= 3 and loc[0] == "segments" and isinstance(loc[1], int):
        return f"sentence {loc[1] + 1} {'--duration' if loc[2] == 'duration' else loc[2]}"
    if loc and loc[0] == "segments":
        return "sentences"
    return "--" + str(loc[0]).replace("_", "-") if loc else "request"


def one_line(errors: Sequence[Mapping[str, Any]]) -> str:
    return "; ".join(f"{_field_name(tuple(e['loc']))}: {e['msg']}" for e in errors)


def _generate(args: argparse.Namespace) -> int:
    from pydantic import ValidationError

    from t2m.api import GenerateRequest, model_limit_errors, to_generation_request
    from t2m.cli.main import CliError

    fmt = FORMATS.get(args.output.suffix.lower())
    if fmt is None:
        raise CliError(f"{args.output}: the suffix must be one of {', '.join(FORMATS)} (it picks the format)")
    body = {"segments": segments_from_args(args.text, args.segment_events), "format": fmt, "seed": args.seed,
            "guidance": args.guidance, "temperature": args.temperature, "top_k": args.top_k}
    try:
        request = GenerateRequest.model_validate(body)
    except ValidationError as error:
        raise CliError(one_line(error.errors())) from None
    if not args.output.parent.exists():
        raise CliError(f"{args.output.parent}: output directory does not exist")

    from t2m.bundles import configured_default_bundle
    from t2m.runtime.engine import OnnxEngine
    from t2m.runtime.formats import render
    from t2m.runtime.handles import answer_handle

    bundle = args.model if args.model is not None else configured_default_bundle()
    engine = OnnxEngine.load(bundle)
    errors = model_limit_errors(request, engine.limits)
    if errors:
        raise CliError(one_line([{**e, "loc": e["loc"][1:]} for e in errors]))
    seed = request.seed if request.seed is not None else secrets.randbits(31)
    generation = to_generation_request(request, engine.limits, seed)
    motion = engine.generate(generation)
    handle = answer_handle(engine.limits, generation, motion) if fmt == "json" else None   # `t2m edit` takes it
    rendered = render(motion, fmt, engine.limits, handle)
    args.output.write_bytes(rendered.body)
    frames = len(motion.joints)
    print(f"wrote {args.output}: {frames} frames ({frames / motion.fps:.1f} s), {len(motion.segments)} segments, "
          f"seed {seed}", file=sys.stderr)
    for warning in motion.warnings:
        print(f"warning: {warning}", file=sys.stderr)
    return 0
