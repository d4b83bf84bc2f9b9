"""The model-family seam: one `ModelFamily` object per family, found by the manifest's `family` name.

A family is declared once (t2m/families/<name>.py for the built-in ones, or any module of a plug-in package): its
manifest block and checks, the graphs it needs, the served decoding object and what it can do, its exporter and CLI
flags, its training kinds, its evaluation loader and its benchmark line. The rest of t2m asks the registry
(`get_family(manifest.family)`) instead of branching on the name.

This module is the bundle contract's part of the seam (json + stdlib only). The hooks that need onnxruntime or torch
(`serve`, `export`, `load_eval_models`) import their code inside the method, so the service never imports torch by
looking a family up. Built-in families are the modules of t2m/families/, imported on the first lookup; plug-in
packages declare theirs under the entry-point group `t2m.families` (each entry point names a `ModelFamily`
instance), and a test or an application may call `register_family` directly.
"""
from __future__ import annotations

import argparse
import importlib
import pkgutil
import threading
from collections.abc import Callable, Iterator, Mapping
from dataclasses import dataclass
from importlib.metadata import entry_points
from typing import Any, ClassVar

from t2m.bundle.errors import BundleError

__all__ = [
    "BUILTIN_FAMILY_PACKAGE",
    "EDIT_KINDS",
    "ENTRY_POINT_GROUP",
    "SEGMENT_EDITS",
    "Capabilities",
    "FieldRule",
    "ModelFamily",
    "family_names",
    "get_family",
    "iter_families",
    "register_family",
    "unregister_family",
]

FieldRule = tuple[Callable[[Any], bool], str]
"""(check, what the value must be) for one manifest field; the message reads "field 'x' must be <what>"."""

# the families t2m ships: every module of this package holds one ModelFamily instance named FAMILY
BUILTIN_FAMILY_PACKAGE = "t2m.families"
ENTRY_POINT_GROUP = "t2m.families"

# edit kinds a family may declare (Capabilities.edits): POST /edit serves the segment edits (the first three) for a
# family that declares them, and in_between and body_part for a family whose loop inpaints (Capabilities.inpaints)
EDIT_KINDS = ("regenerate", "append", "prepend", "in_between", "body_part")
# what a family of independent per-segment token sequences does by sampling only the edited segments (GPT, HiFiGPT)
SEGMENT_EDITS = frozenset({"regenerate", "append", "prepend"})


@dataclass(frozen=True)
class Capabilities:
    """What a family's served decoding can do; the engine, the batcher and /health read these, not the name.

    `continuous_batching`: requests join running work at a step boundary (the served object has `cohort`);
    `early_frames`: frames stream while codes are still sampled (the job has a `progress` hook and the decoder's
    reach is probed); `code_depth`: the decoder reads [steps, R] code rows (T2M-HiFiGPT) instead of [steps] or
    [steps, C, R] maps, for the reach probe; `edits`: the edit kinds it supports (of EDIT_KINDS: "regenerate" a
    segment with a new text, seed or duration, "append" / "prepend" segments, "in_between", "body_part"); POST /edit
    answers 422 for a kind the model's family does not declare; `inpaints`: an edit's tokens are filled by the
    family's own loop with the kept tokens around them as context (a request's `inpaint` maps: the masked family),
    not sampled alone; `devices`: where its graphs may run."""

    continuous_batching: bool = False
    early_frames: bool = False
    code_depth: bool = False
    edits: frozenset[str] = frozenset()
    inpaints: bool = False
    devices: tuple[str, ...] = ("cpu",)
    why_not_early: str = "the whole token map exists only at the end"


class ModelFamily:
    """Base of every family: subclass it, fill in the class attributes, override the hooks, register an instance.

    The manifest's common fields (t2m.bundle.manifest.COMMON_FIELDS) are checked for every family; `fields` adds the
    family's own (its block, dotted paths), `optional_fields` the ones that may be absent or null."""

    name: ClassVar[str]                         # the manifest's `family` value
    title: ClassVar[str]                        # one line for people: "T2M-GPT: one code per step, ..."
    fields: ClassVar[Mapping[str, FieldRule]] = {}
    optional_fields: ClassVar[Mapping[str, FieldRule]] = {}
    capabilities: ClassVar[Capabilities] = Capabilities()
    training_kinds: ClassVar[Mapping[str, tuple[str, str]]] = {}   # `t2m train KIND` -> (module, help)
    # `t2m bench SUBJECT` / `t2m eval SUBJECT` of its own -> (module with main(argv) -> int, help)
    bench_subjects: ClassVar[Mapping[str, tuple[str, str]]] = {}
    eval_subjects: ClassVar[Mapping[str, tuple[str, str]]] = {}
    # checkpoint kinds of its PyTorch modules built from a table: kind -> (module, model class, config class)
    checkpoint_kinds: ClassVar[Mapping[str, tuple[str, str, str]]] = {}
    eval_run_option: ClassVar[str | None] = None                  # `t2m eval --NAME RUN` picks this family
    evaluates_bundle: ClassVar[bool] = False                      # `t2m eval --bundle` takes its bundles
    # "module:function" that builds its `t2m eval --bundle` Models (the lockstep families' by default; a string, as
    # training_kinds, so that t2m.bundle imports no training or export code)
    bundle_evaluation: ClassVar[str] = "t2m.export.evaluation:lockstep_bundle_models"
    encodes: ClassVar[bool] = False     # its decoder reads codes, so a bundle may hold encoder.onnx (bundle.graphs)

    # ------------------------------------------------------------------ manifest and graphs (json only)

    def field_table(self, common: Mapping[str, FieldRule]) -> dict[str, FieldRule]:
        """Every required field of this family's manifests, in the order they are checked (common then own)."""
        return {**{path: rule for path, rule in common.items() if path != "files"}, **self.fields,
                "files": common["files"]}

    def check_consistency(self, manifest: Mapping[str, Any]) -> None:
        """Rules between fields (e.g. block sizes against max_tokens); raise BundleError naming the field."""

    def required_files(self, manifest: Mapping[str, Any]) -> tuple[str, ...]:
        """Every file a bundle of this manifest must hold."""
        raise NotImplementedError

    def graphs(self, manifest: Mapping[str, Any]) -> dict[str, Any]:
        """{file: t2m.bundle.graphs.GraphSpec} of the family's graphs and its decoder (the text graph is common)."""
        raise NotImplementedError

    def settings(self, manifest: Mapping[str, Any]) -> Any:
        """The typed view of the family's block; must have `unconditional_branch`, `default_guidance` and
        `length_conditioning`."""
        raise NotImplementedError

    def describe(self, manifest: Any, guidance: float) -> str:
        """One line about how it decodes (t2m bench, /health)."""
        return f"{self.name}, guidance {guidance:g}"

    # ------------------------------------------------------------------ service (onnxruntime, no torch)

    def serve(self, bundle: Any) -> Any:
        """The served decoding object for a loaded bundle (t2m.runtime.family_codes.FamilyCodes)."""
        raise NotImplementedError

    def capabilities_of(self, manifest: Any) -> Capabilities:
        """What a loaded bundle's served decoding can do (the engine asks this): the family's `capabilities`, unless
        its bundles differ (the diffusion family: a DiP bundle streams call by call, an MDM one makes whole
        motions)."""
        return self.capabilities

    def check_servable(self, manifest: Any) -> None:
        """Refuse, at load, a manifest that passes the contract but that the served loop cannot run."""

    # ------------------------------------------------------------------ export, evaluation (torch, lazily)

    def add_export_arguments(self, group: argparse._ArgumentGroup) -> None:
        """`t2m export --family NAME`'s own options (their dests must not collide with another family's)."""

    int8_graphs: ClassVar[frozenset[str]] = frozenset()               # what `t2m export --int8` may name
    # the seeded requests (how many, seconds each) a quantised copy is served on beside its original by default
    # (t2m.export.writing.bundle_parity); a family whose requests cost many network calls asks for fewer
    quantize_parity: ClassVar[tuple[int, float]] = (8, 10.0)

    def quantizable_graphs(self, manifest: Mapping[str, Any]) -> tuple[str, ...]:
        """The graph files of a bundle that `t2m quantize` and `t2m import --quantize` rewrite (int8, int4, fp16):
        the graphs called at every step (token graphs, a diffusion denoiser), whose MatMul weights carry the
        per-step cost; each one's manifest key is `quantization.<file stem>`. The text encoder (run once per
        request; `t2m export --int8 text` is its option), the decoder and the length graph are not among them.
        None: the family has nothing to quantise."""
        return ()

    def captured_graphs(self, manifest: Mapping[str, Any]) -> dict[str, Any]:
        """Optional graphs a bundle may carry (listed in its `files`) only for T2M_CUDA_GRAPHS: a step over fixed
        device buffers that the family's own step class captures and replays (engine/graphed_step.py). Opened only
        with that setting. None by default."""
        return {}

    def replayable_graphs(self, manifest: Mapping[str, Any]) -> tuple[str, ...]:
        """The graph files the engine may replay as CUDA graphs (T2M_CUDA_GRAPHS, engine/graphed_step.py): graphs
        without a cache, called through `session.run` by the family's steps, whose shapes repeat over a request's
        passes. None by default: a family with a growing cache changes its shapes every step."""
        return ()
    export_needs_vq: ClassVar[bool] = False                           # `t2m export` refuses it without --vq RUN

    def export(self, args: argparse.Namespace, int8: Any) -> tuple[dict, dict]:
        """Run `t2m export --family NAME`: (written manifest, checks) or raise ValueError naming what is wrong."""
        raise NotImplementedError(f"family {self.name!r} has no exporter")

    def check_export_arguments(self, args: argparse.Namespace) -> None:
        """Refuse bad `t2m export` options of this family (ValueError with the option's name)."""

    def add_eval_arguments(self, parser: argparse.ArgumentParser) -> None:
        """`t2m eval`'s options of this family besides its run option."""

    def check_eval_arguments(self, args: argparse.Namespace) -> None:
        """Refuse bad `t2m eval` options of this family (ValueError with the option's name)."""

    def load_eval_models(self, args: argparse.Namespace, mean: Any, std: Any) -> Any:
        """t2m.model.evaluation.evaluate.Models for `t2m eval --<eval_run_option> RUN`."""
        raise NotImplementedError(f"family {self.name!r} cannot be evaluated from training runs")

    def load_bundle_eval_models(self, evaluator: Any, evaluator_run: str, bundle: Any) -> Any:
        """t2m.model.evaluation.evaluate.Models for `t2m eval --bundle DIR` (families with `evaluates_bundle`): the
        function named by `bundle_evaluation` called with the evaluator, its run and the bundle's served object."""
        import importlib

        module, _, function = self.bundle_evaluation.partition(":")
        build = getattr(importlib.import_module(module), function)
        return build(evaluator, evaluator_run, bundle, self.serve(bundle))

    default_eval_guidance: ClassVar[tuple[float, ...]] = (1.0, 3.0)

    def __repr__(self) -> str:
        return f"<model family {self.name!r}>"


_registry: dict[str, ModelFamily] = {}
_lock = threading.Lock()
_discovered = False


def register_family(family: ModelFamily, *, replace: bool = False) -> ModelFamily:
    """Add a family; a second family of the same name is refused unless `replace`."""
    _discover()
    with _lock:
        if family.name in _registry and not replace and _registry[family.name] is not family:
            raise ValueError(f"a model family named {family.name!r} is already registered")
        _registry[family.name] = family
    return family


def unregister_family(name: str) -> None:
    """Remove a family (tests that register one of their own)."""
    with _lock:
        _registry.pop(name, None)


def _discover() -> None:
    """Import the built-in families, then the plug-ins' entry points, once."""
    global _discovered
    if _discovered:
        return
    with _lock:
        if _discovered:
            return
        package = importlib.import_module(BUILTIN_FAMILY_PACKAGE)
        modules = sorted(info.name for info in pkgutil.iter_modules(package.__path__))
        found = [importlib.import_module(f"{BUILTIN_FAMILY_PACKAGE}.{name}").FAMILY for name in modules]
        found += [point.load() for point in entry_points(group=ENTRY_POINT_GROUP)]
        for family in found:
            _registry.setdefault(family.name, family)
        _discovered = True


def iter_families() -> Iterator[ModelFamily]:
    """The registered families: the built-in ones (by module name), then plug-ins, then registered ones."""
    _discover()
    return iter(list(_registry.values()))


def family_names() -> tuple[str, ...]:
    return tuple(family.name for family in iter_families())


def get_family(name: str) -> ModelFamily:
    """The family of that name; an unknown one is a BundleError naming the manifest field and the known ones."""
    _discover()
    family = _registry.get(name)
    if family is None:
        raise BundleError(f"manifest.json: field 'family' must be one of {list(_registry)}, got {name!r}")
    return family
