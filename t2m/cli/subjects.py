"""`t2m bench SUBJECT ...` and `t2m eval SUBJECT ...`: every speed and quality figure the docs quote has one command.

A subject is a module with `main(argv) -> int` (its own options, its own --help); the shared ones are listed here,
a family's own come from its declaration (`ModelFamily.bench_subjects`, `eval_subjects`). Only the module of the
subject being run is imported."""
from __future__ import annotations

import importlib
import sys
from collections.abc import Sequence

from t2m.bundle import iter_families

BENCH_SUBJECTS: dict[str, tuple[str, str]] = {
    "host-loop": ("t2m.bench.host_loop", "the decoding loops' host cost alone, over steps that answer instantly"),
    "released": ("t2m.bench.released_models",
                 "the released models at their released sizes (random weights), float32 / int8 / int4 / fp16"),
    "quantized-release": ("t2m.bench.quantized_release",
                          "T2M-GPT's release-size step: float32 vs int8 graphs vs the reference sampler"),
    "clip-text": ("t2m.bench.clip_text", "CLIP ViT-B/32's text tower: load, export, onnxruntime vs PyTorch"),
    "compute-floor": ("t2m.bench.compute_floor", "a masked-family model against this CPU's arithmetic limit"),
    "training": ("t2m.bench.training", "training throughput of the VQ-VAE and the GPT (samples/s)"),
    "edits": ("t2m.bench.edit_latency", "editing one segment vs generating the whole motion again"),
    "scheduler": ("t2m.bench.scheduler", "short requests first, the batcher in process (no HTTP)"),
}
EVAL_SUBJECTS: dict[str, tuple[str, str]] = {
    "probes": ("t2m.quality.probes", "kinematic probes: does the motion do what the sentence says"),
    "edits": ("t2m.quality.edits", "does an edited span follow its new text, and are its borders smooth"),
    "joins": ("t2m.quality.joins", "the pelvis-velocity change at the joins, decoded and fitted to exact durations"),
    "int8-agreement": ("t2m.quality.int8_agreement", "an int8 GPT step's greedy codes against float32's"),
}
COMMANDS_WITH_SUBJECTS = ("bench", "eval")


def subjects(command: str) -> dict[str, tuple[str, str]]:
    """The subjects of `t2m bench` or `t2m eval`: the shared ones, then each registered family's."""
    table = dict(BENCH_SUBJECTS if command == "bench" else EVAL_SUBJECTS)
    for family in iter_families():
        own = family.bench_subjects if command == "bench" else family.eval_subjects
        table.update({name: entry for name, entry in own.items() if name not in table})
    return table


def subject_of(argv: Sequence[str]) -> tuple[str, str] | None:
    """(command, subject) when argv is `bench|eval SUBJECT ...`, else None."""
    if len(argv) >= 2 and argv[0] in COMMANDS_WITH_SUBJECTS and argv[1] in subjects(argv[0]):
        return argv[0], argv[1]
    return None


def run_subject(command: str, subject: str, argv: Sequence[str]) -> int:
    """The subject's main(argv), its usage and errors named `t2m COMMAND SUBJECT` (argparse's prog is argv[0])."""
    module, _ = subjects(command)[subject]
    main = importlib.import_module(module).main
    program, sys.argv[0] = sys.argv[0], f"t2m {command} {subject}"
    try:
        return int(main(list(argv)) or 0)
    finally:
        sys.argv[0] = program


def subjects_help(command: str) -> str:
    """The subject list for the command's --help."""
    lines = [f"subjects (t2m {command} SUBJECT --help for their options):"]
    lines += [f"  {name:<18} {text}" for name, (_, text) in subjects(command).items()]
    return "\n".join(lines)
