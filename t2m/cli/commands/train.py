"""`t2m train KIND`: the training entry points (torch is imported only when one runs).

Each trainer module (the shared t2m.model.training.train_vq, train_vq_decoder, train_evaluator, and the ones each
model family lists in its `training_kinds`) exposes `add_arguments(parser)` and `main(args)`; this command only
wires them to sub-commands.
"""
from __future__ import annotations

import argparse
import importlib

# kinds every family may use; each family adds its own (ModelFamily.training_kinds)
SHARED_TRAINERS = {
    "vq": ("t2m.model.training.train_vq", "train the motion VQ-VAE on feature windows"),
    "vq-decoder": ("t2m.model.training.train_vq_decoder",
                   "train a new decoder (e.g. a short-lookahead one) for a trained VQ on its frozen codes"),
    "evaluator": ("t2m.model.training.train_evaluator", "train the text-motion evaluator used by `t2m eval`"),
}


def trainers() -> dict[str, tuple[str, str]]:
    """Every `t2m train` kind -> (module, help): the shared ones, then each family's."""
    from t2m.bundle import iter_families

    kinds = dict(SHARED_TRAINERS)
    for family in iter_families():
        for kind, entry in family.training_kinds.items():
            if kind in kinds:
                raise ValueError(f"training kind {kind!r} of family {family.name!r} is taken")
            kinds[kind] = entry
    return kinds


def _handler(module_name: str):
    def run(args: argparse.Namespace) -> int:
        module = importlib.import_module(module_name)
        return int(module.main(args) or 0)

    return run


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser("train", help="train a VQ-VAE, a token model of a family, or the evaluator")
    kinds = parser.add_subparsers(dest="train_kind", metavar="KIND")
    parser.set_defaults(func=lambda args: parser.print_help() or 2)
    for kind, (module_name, help_text) in trainers().items():
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
