"""`t2m train KIND`: the training entry points (torch is imported only when one runs).

Each trainer module (t2m.model.training.train_vq, train_vq_decoder, train_gpt, train_evaluator, train_joint_vq,
train_masked, train_residual, train_length, train_hifigpt) exposes `add_arguments(parser)` and `main(args)`; this
command only wires them to sub-commands.
"""
from __future__ import annotations

import argparse
import importlib

TRAINERS = {
    "vq": ("t2m.model.training.train_vq", "train the motion VQ-VAE on feature windows"),
    "vq-decoder": ("t2m.model.training.train_vq_decoder",
                   "train a new decoder (e.g. a short-lookahead one) for a trained VQ on its frozen codes"),
    "gpt": ("t2m.model.training.train_gpt", "train the text-to-code GPT on a trained VQ's codes"),
    "evaluator": ("t2m.model.training.train_evaluator", "train the text-motion evaluator used by `t2m eval`"),
    # the masked family (MoGenTS / MoMask)
    "joint-vq": ("t2m.model.training.train_joint_vq", "train the 2D joint VQ-VAE (time x joint token maps)"),
    "masked": ("t2m.model.training.train_masked", "train the masked transformer on a VQ's first-layer codes"),
    "residual": ("t2m.model.training.train_residual", "train the residual transformer on a VQ's later layers"),
    "length": ("t2m.model.training.train_length", "train the length estimator (free length for masked models)"),
    # T2M-HiFiGPT (issue 16)
    "hifigpt": ("t2m.model.training.train_hifigpt", "train T2M-HiFiGPT's double-tier GPT on a residual VQ's codes"),
}


def _handler(module_name: str):
    def run(args: argparse.Namespace) -> int:
        module = importlib.import_module(module_name)
        return int(module.main(args) or 0)

    return run


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser("train", help="train the VQ-VAE, the GPT, the evaluator or the masked family")
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
