"""Model checkpoints as docs/contracts.md fixes them.

``<run_dir>/model.safetensors`` holds the module's state dict (persistent tensors only);
``<run_dir>/config.json`` = ``{"kind": "vq"|"gpt"|<a family's kind>, "config": {...}, "step": N, "data": {...}}``
is enough to rebuild the module: :func:`load_model` does that.
The training resume state (optimizer, schedule, RNG, quantiser EMA statistics) lives apart in resume.pt.
"""
from __future__ import annotations

import json
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal, TypeVar, overload

from torch import nn

if TYPE_CHECKING:
    from t2m.model.networks.evaluator import MotionEvaluator
    from t2m.model.networks.vqvae import MotionVQVAE

ModelT = TypeVar("ModelT")

CONFIG_FILE = "config.json"
WEIGHTS_FILE = "model.safetensors"
# the kinds written here by name; every model family adds the kinds of its own modules (ModelFamily.checkpoint_kinds)
BUILT_IN_KINDS = ("vq", "evaluator")


def table_kinds() -> dict[str, tuple[str, str, str]]:
    """kind -> (module, model class, config class) of every family's modules built from a table."""
    from t2m.bundle import iter_families

    return {kind: entry for family in iter_families() for kind, entry in family.checkpoint_kinds.items()}


def kinds() -> tuple[str, ...]:
    return (*BUILT_IN_KINDS, *table_kinds())


def model_kind(model: nn.Module) -> str:
    from t2m.model.networks.vqvae import MotionVQVAE

    if isinstance(model, MotionVQVAE):
        return "vq"
    if type(model).__name__ == "MotionEvaluator":
        return "evaluator"
    for kind, (module, class_name, _) in table_kinds().items():
        if type(model).__module__ == module and type(model).__name__ == class_name:
            return kind
    raise ValueError(f"no checkpoint kind for {type(model).__name__}")


def _config_dict(model: nn.Module) -> dict[str, Any]:
    config: Any = model.config  # the model class's own config dataclass
    return config.to_dict() if hasattr(config, "to_dict") else dict(vars(config))


def save_checkpoint(run_dir: str | Path, model: nn.Module, step: int, data: dict[str, Any] | None = None) -> Path:
    """Write model.safetensors and config.json (atomically: a crash never leaves half a checkpoint)."""
    from safetensors.torch import save_file

    run_dir = Path(run_dir)
    run_dir.mkdir(parents=True, exist_ok=True)
    state: dict[str, Any] = {}
    seen: set[int] = set()
    for name, tensor in model.state_dict().items():
        value = tensor.detach().cpu().contiguous()
        if value.data_ptr() in seen:   # one tensor under two names (MDM's pe table): safetensors wants copies
            value = value.clone()
        seen.add(value.data_ptr())
        state[name] = value
    tmp_weights = run_dir / (WEIGHTS_FILE + ".tmp")
    save_file(state, str(tmp_weights), metadata={"kind": model_kind(model), "step": str(step)})
    tmp_weights.replace(run_dir / WEIGHTS_FILE)
    record = {"kind": model_kind(model), "config": _config_dict(model), "step": int(step), "data": data or {}}
    tmp_config = run_dir / (CONFIG_FILE + ".tmp")
    tmp_config.write_text(json.dumps(record, indent=2) + "\n")
    tmp_config.replace(run_dir / CONFIG_FILE)
    return run_dir


def read_run_config(run_dir: str | Path) -> dict[str, Any]:
    """config.json of a run, checked for the fields load_model needs."""
    path = Path(run_dir) / CONFIG_FILE
    if not path.is_file():
        raise FileNotFoundError(str(path))
    try:
        record = json.loads(path.read_text())
    except json.JSONDecodeError as error:
        raise ValueError(f"{path}: not valid JSON ({error})") from error
    for field in ("kind", "config"):
        if field not in record:
            raise ValueError(f"{path}: missing field {field!r}")
    if record["kind"] not in kinds():
        raise ValueError(f"{path}: kind must be one of {', '.join(kinds())}, got {record['kind']!r}")
    return record


CODES_OF = "decoder_trained_on_the_codes_of"   # a `t2m train vq-decoder` run: whose encoder and codebooks it kept


def codes_source(vq_run: str | Path) -> Path:
    """The VQ run whose codes `vq_run` gives: itself, or for a run of `t2m train vq-decoder` (a new decoder on
    frozen codes) the run it kept the encoder and codebooks of, followed back to the first."""
    run = Path(vq_run).resolve()
    seen = {run}
    while (source := read_run_config(run).get("data", {}).get(CODES_OF)) and Path(source).exists():
        run = Path(source).resolve()
        if run in seen:
            break
        seen.add(run)
    return run


def check_trained_on(token_run: str | Path, vq_run: str | Path) -> None:
    """A token model (GPT, masked, residual, HiFiGPT) learned one VQ's codes: refuse a VQ that gives other codes
    (when the recorded VQ run still exists); a new decoder on the same codes is accepted, whichever of the two the
    token model was trained with."""
    recorded = read_run_config(token_run).get("data", {}).get("vq_run")
    if recorded and Path(recorded).exists() and codes_source(recorded) != codes_source(vq_run):
        raise ValueError(f"{token_run}: trained on the codes of {recorded}, not of --vq {vq_run}")


def build_model(kind: str, config: dict[str, Any]) -> nn.Module:
    """An untrained module of the given kind from its config dict."""
    if kind == "vq":
        from t2m.model.networks.vqvae import MotionVQVAE, VQConfig

        return MotionVQVAE(VQConfig.from_dict(config))
    if kind == "evaluator":
        from t2m.model.networks.evaluator import EvaluatorConfig, MotionEvaluator

        return MotionEvaluator(EvaluatorConfig(**config))
    table = table_kinds()
    if kind in table:
        import importlib

        module_name, class_name, config_name = table[kind]
        module = importlib.import_module(module_name)
        return getattr(module, class_name)(getattr(module, config_name).from_dict(config))
    raise ValueError(f"unknown checkpoint kind {kind!r}")


@overload
def load_model(run_dir: str | Path, expect_kind: Literal["vq"]) -> MotionVQVAE: ...
@overload
def load_model(run_dir: str | Path, expect_kind: Literal["evaluator"]) -> MotionEvaluator: ...
@overload
def load_model(run_dir: str | Path, expect_kind: str | None = None) -> nn.Module: ...


def load_model(run_dir: str | Path, expect_kind: str | None = None) -> nn.Module:
    """Rebuild the module described by run_dir/config.json and load model.safetensors into it (strict), eval mode."""
    from safetensors.torch import load_file

    run_dir = Path(run_dir)
    record = read_run_config(run_dir)
    if expect_kind is not None and record["kind"] != expect_kind:
        raise ValueError(f"{run_dir / CONFIG_FILE}: expected a {expect_kind} checkpoint, found {record['kind']!r}")
    weights = run_dir / WEIGHTS_FILE
    if not weights.is_file():
        raise FileNotFoundError(str(weights))
    model = build_model(record["kind"], record["config"])
    try:
        model.load_state_dict(load_file(str(weights)), strict=True)
    except RuntimeError as error:
        raise ValueError(f"{weights}: weights do not match config.json ({error})") from error
    return model.eval()


def load_run(run: str | Path, kind: str, model_type: type[ModelT]) -> ModelT:
    """load_model(run, kind), typed: the module a run of that kind rebuilds."""
    model = load_model(run, expect_kind=kind)
    if not isinstance(model, model_type):  # pragma: no cover - load_model builds the kind's class
        raise ValueError(f"{run}: a {kind} run rebuilt a {type(model).__name__}, not a {model_type.__name__}")
    return model


def text_kind(run: str | Path) -> str:
    """The text encoder a token model's run was trained with ("minilm", "clip"), from its config.json."""
    text = read_run_config(run).get("data", {}).get("text_encoder", "minilm")
    return str(text.get("kind", "minilm") if isinstance(text, dict) else text)
