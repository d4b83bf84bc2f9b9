"""`t2m edit`: a json motion saved from /generate, /edit or `t2m generate` with some segments changed, on this
machine, no server needed (POST /edit's path: t2m.runtime.editing.edit_in_process).

    t2m edit walk_wave_bow.json --segment 1 --text "a person raises the left hand" -o edited.json
    t2m edit walk_wave_bow.json --segment 2 --seed 7 -o bow7.bvh
    t2m edit walk_wave_bow.json --edits '[{"op": "append", "segments": [{"text": "a person sits", "duration": 3}]}]' \\
        -o longer.glb

The answer's `handle` names its model (name and version): --model must be a bundle of that model (default:
T2M_MODEL_DIR, else the embedded default model). A json motion without a handle (its `frames`, `fps` and
`segments`) or a .bvh file this service wrote is uploaded instead: encoded by the model's encoder.onnx as POST /edit
encodes a `motion` (a bundle without one cannot). --edits takes POST /edit's `edits` list as JSON; --segment with
--text / --seed / --duration is one regenerate edit; both may be given (the --segment edit comes last).
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

from t2m.cli.commands.generate import FORMATS


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "edit", help="edit a saved json motion (its handle) without a server",
        description="Regenerate segments of a saved json motion (new text, seed or duration) or add segments, "
                    "keeping the other segments' codes, and write the result as .json, .bvh or .glb.")
    parser.add_argument("motion", type=Path, help="a json answer (its `handle`, else its frames) or a .bvh file")
    parser.add_argument("--segment", type=int, default=None, help="index of the segment to regenerate (0 = first)")
    parser.add_argument("--text", default=None, help="its new text (default: its own)")
    parser.add_argument("--seed", type=int, default=None, help="its seed (default: derived from the motion's)")
    parser.add_argument("--duration", type=float, default=None, help="its new duration in seconds")
    parser.add_argument("--edits", default=None, help="POST /edit's `edits` list as JSON")
    parser.add_argument("--model", type=Path, default=None,
                        help="model bundle directory (default: T2M_MODEL_DIR, else the embedded t2m/bundles/default)")
    parser.add_argument("-o", "--output", type=Path, required=True, help="output file: .json, .bvh or .glb")
    parser.set_defaults(func=_edit)


def _edits(args: argparse.Namespace) -> list[Any]:
    from t2m.cli.main import CliError

    edits: list[Any] = []
    if args.edits is not None:
        try:
            edits = json.loads(args.edits)
        except ValueError as error:
            raise CliError(f"--edits: not JSON ({error})") from None
        if not isinstance(edits, list):
            raise CliError("--edits: must be a JSON list of edits")
    if args.segment is not None:
        edit = {"segment": args.segment, "text": args.text, "seed": args.seed, "duration": args.duration}
        edits.append({key: value for key, value in edit.items() if value is not None})
    elif any(value is not None for value in (args.text, args.seed, args.duration)):
        raise CliError("--text, --seed and --duration belong to a --segment")
    return edits


def _source(path: Path) -> dict[str, Any]:
    """POST /edit's `handle` of a saved json answer, else its `motion`: a json answer's frames (with its segments'
    texts and frame counts) or a .bvh file's text."""
    from t2m.cli.main import CliError

    try:
        text = path.read_text(encoding="utf-8")
        saved = text if path.suffix.lower() == ".bvh" else json.loads(text)
    except (OSError, ValueError) as error:
        raise CliError(f"{path}: not a readable json or BVH motion ({error})") from None
    if isinstance(saved, str):
        return {"motion": {"bvh": saved}}
    if isinstance(saved, dict) and isinstance(saved.get("handle"), str):
        return {"handle": saved["handle"]}
    if not isinstance(saved, dict) or "frames" not in saved:
        raise CliError(f"{path}: holds neither a handle nor frames (a json answer of /generate, /edit or t2m "
                       "generate has both)")
    spans = saved.get("segments")
    segments = ([{"text": s["text"], "frames": s["end_frame"] - s["start_frame"]} for s in spans]
                if isinstance(spans, list) and spans
                and all(isinstance(s, dict) and {"text", "start_frame", "end_frame"} <= s.keys() for s in spans)
                else None)
    return {"motion": {"joints": saved["frames"], "fps": saved.get("fps"), "segments": segments}}


def _edit(args: argparse.Namespace) -> int:
    from pydantic import ValidationError

    from t2m.api import EditRequest
    from t2m.cli.commands.generate import one_line
    from t2m.cli.main import CliError

    fmt = FORMATS.get(args.output.suffix.lower())
    if fmt is None:
        raise CliError(f"{args.output}: the suffix must be one of {', '.join(FORMATS)} (it picks the format)")
    try:
        body = EditRequest.model_validate({**_source(args.motion), "edits": _edits(args), "format": fmt})
    except ValidationError as error:
        raise CliError(one_line(error.errors())) from None
    if not args.output.parent.exists():
        raise CliError(f"{args.output.parent}: output directory does not exist")

    from t2m.bundles import configured_default_bundle
    from t2m.runtime.edit_runner import edit_with_engine
    from t2m.runtime.editing import EditError
    from t2m.runtime.engine import OnnxEngine
    from t2m.runtime.formats import render
    from t2m.runtime.handles import HandleError
    from t2m.runtime.types import RequestLimitError
    from t2m.runtime.uploads import uploaded_handle

    engine = OnnxEngine.load(args.model if args.model is not None else configured_default_bundle())
    try:
        handle = body.handle if body.motion is None else uploaded_handle(body.motion, engine.limits, engine.encode)
        assert handle is not None
        result = edit_with_engine(engine, handle, body.edits)
    except EditError as error:               # its field, as POST /edit's 422 names it
        raise CliError(f"{'.'.join(str(part) for part in error.loc[1:])}: {error}") from None
    except (HandleError, RequestLimitError) as error:
        raise CliError(str(error)) from None
    extra = {"edited": [{"segment": index, "seed": seed} for index, seed in result.edited]}
    args.output.write_bytes(render(result.motion, fmt, engine.limits, result.handle, extra).body)
    frames = len(result.motion.joints)
    sampled = ", ".join(f"segment {index} seed {seed}" for index, seed in result.edited) or "nothing"
    print(f"wrote {args.output}: {frames} frames ({frames / result.motion.fps:.1f} s), "
          f"{len(result.motion.segments)} segments; sampled {sampled}", file=sys.stderr)
    for warning in result.motion.warnings:
        print(f"warning: {warning}", file=sys.stderr)
    return 0
