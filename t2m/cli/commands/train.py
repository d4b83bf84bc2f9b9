"""`t2m train vq|gpt|evaluator`: the training entry points (torch is imported only when one runs).

Each trainer module (t2m.model.training.train_vq, t2m.model.training.train_gpt,
t2m.model.training.train_evaluator) exposes `add_arguments(parser)` and `main(args)`; this command only wires them
to sub-commands.
"""
from __future__ import annotations

import argparse
import importlib

TRAINERS = {
    "vq": ("t2m.model.training.train_vq", "train the motion VQ-VAE on feature windows"),
    "gpt": ("t2m.model.training.train_gpt", "train the text-to-code GPT on a trained VQ's codes"),
    "evaluator": ("t2m.model.training.train_evaluator", "train the text-motion evaluator used by `t2m eval`"),
}


def _handler(module_name: str):
    def run(args: argparse.Namespace) -> int:
        module = importlib.import_module(module_name)
        return int(module.main(args) or 0)

    return run


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser("train", help="train the VQ-VAE, the GPT or the evaluator")
    kinds = parser.add_subparsers(dest="train_kind", metavar="KIND")
    parser.set_defaults(func=lambda args: parser.print_help() or 2)
    for kind, (module_name, help_text) in TRAINERS.items():
        try:
            # The trainer modules import torch only inside main(); add_arguments is cheap.
            module = importlib.import_module(module_name)
        except ModuleNotFoundError as error:
            if error.name == module_name:
                continue  # that trainer is not written (yet)
            raise
        sub = kinds.add_parser(kind, help=help_text, description=(module.__doc__ or help_text).strip().splitlines()[0])
        module.add_arguments(sub)
        sub.set_defaults(func=_handler(module_name))
