"""T2M-GPT's parity checks: its step graph against its PyTorch module on a guided greedy rollout through the
service's own loop (export and import), the bundle's motions against the modules', and an int8 or int4 step graph
against its float32 original."""
from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch

from t2m.export.kit.parity import decoder_parity, text_parity
from t2m.families.gpt.network import MotionGPT
from t2m.model.networks.vqvae import MotionVQVAE


@dataclass
class Rollout:
    codes: np.ndarray  # [B, steps] guided greedy choices
    logits: list[np.ndarray]  # per step, the raw logits of every row [rows, K + 1]
    seconds: float


def guidance_rows(cond: np.ndarray, length: np.ndarray, guidance: float) -> tuple[np.ndarray, np.ndarray]:
    """The service's batch layout: conditional rows, then (when guidance != 1) the same rows with a zero condition."""
    if guidance == 1.0:
        return cond, length
    return np.concatenate([cond, np.zeros_like(cond)]), np.concatenate([length, length])


class _RecordingStep:
    """A GPT step (t2m.families.gpt.loop.GptStep) that records each call's logits and feeds the rollout's own length
    input (a row may read 0, free length, while the loop holds it to exactly `steps` codes)."""

    def __init__(self, step: Any, length: np.ndarray) -> None:
        self.step, self.length = step, length
        self.logits: list[np.ndarray] = []

    def empty_cache(self, batch: int) -> np.ndarray:
        return self.step.empty_cache(batch)

    def __call__(self, cond: np.ndarray, token: np.ndarray, position: int, length: np.ndarray,
                 past: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        logits, present = self.step(cond, token, position, self.length, past)
        self.logits.append(np.asarray(logits))
        return logits, present


def greedy_rollout(step: Any, cond: np.ndarray, length: np.ndarray, steps: int, end_id: int,
                   guidance: float = 1.0) -> Rollout:
    """`steps` guided argmax codes per row through the service's own GPT loop (t2m.families.gpt.loop, End masked until
    the target) over any step: the exported graph or the PyTorch module, each feeding back its own choices."""
    from t2m.families.gpt.loop import SamplingJob, sample_codes

    cond = np.asarray(cond, np.float32)
    recorder = _RecordingStep(step, guidance_rows(cond, np.asarray(length, np.int64), guidance)[1])
    job = SamplingJob.of(cond, [steps] * len(cond), max_tokens=steps, guidance=guidance, temperature=0)
    start = time.perf_counter()
    (codes,) = sample_codes(recorder, [job], steps, end_id)
    assert codes is not None  # a job without a cancel callback is never cancelled
    return Rollout(np.stack(codes), recorder.logits, time.perf_counter() - start)


def ort_greedy_rollout(session: Any, cond: np.ndarray, length: np.ndarray, kv_shape: Sequence[int], steps: int,
                       end_id: int, guidance: float = 1.0) -> Rollout:
    """greedy_rollout through a gpt_step onnxruntime session; kv_shape = (n_layer, n_head, head_dim)."""
    from t2m.runtime.onnx_step import OnnxGptStep

    has_length = "length" in {tensor.name for tensor in session.get_inputs()}
    n_layer, n_head, head_dim = kv_shape
    return greedy_rollout(OnnxGptStep(session, n_layer, n_head, head_dim, has_length), cond, length, steps, end_id,
                          guidance)


@torch.no_grad()
def recompute_logits(gpt: MotionGPT, cond: np.ndarray, length: np.ndarray, codes: np.ndarray,
                     guidance: float) -> list[np.ndarray]:
    """Per-step logits by full-prefix recomputation (``forward`` on the whole prefix, as T2M-GPT samples)."""
    rows_cond, rows_len = guidance_rows(cond.astype(np.float32), length.astype(np.int64), guidance)
    rows_codes = np.concatenate([codes, codes]) if guidance != 1.0 else codes
    len_t = torch.from_numpy(rows_len) if gpt.config.length_conditioning else None
    full = gpt(torch.from_numpy(rows_cond), torch.from_numpy(rows_codes[:, :-1]), len_t)  # [rows, steps, K+1]
    return [full[:, step].numpy() for step in range(codes.shape[1])]


@dataclass
class GptParity:
    steps: int
    rows: int
    max_abs_logit_diff: float
    codes_identical: bool
    max_abs_diff_vs_recompute: float


def gpt_parity(gpt: MotionGPT, onnx_path: str | Path, steps: int = 50, guidance: float = 3.0, batch: int = 1,
               seed: int = 0) -> GptParity:
    """Compare the exported step graph with the PyTorch model on a ``steps``-long greedy rollout."""
    from t2m.export.graphs.export import ort_session
    from t2m.families.gpt.sampling import TorchGptStep, evaluating

    c = gpt.config
    steps = min(steps, c.max_tokens)
    rng = np.random.default_rng(seed)
    cond = rng.normal(size=(batch, c.text_dim)).astype(np.float32)
    cond /= np.linalg.norm(cond, axis=1, keepdims=True)
    length = np.full(batch, steps, np.int64)
    with evaluating(gpt):
        reference = greedy_rollout(TorchGptStep(gpt), cond, length, steps, c.end_id, guidance)
    exported = ort_greedy_rollout(ort_session(onnx_path), cond, length, (c.n_layer, c.n_head, c.head_dim), steps,
                                  c.end_id, guidance)
    recomputed = recompute_logits(gpt, cond, length, reference.codes, guidance)
    return GptParity(
        steps=steps,
        rows=reference.logits[0].shape[0],
        max_abs_logit_diff=max(float(np.abs(a - b).max()) for a, b in zip(reference.logits, exported.logits)),
        codes_identical=bool(np.array_equal(reference.codes, exported.codes)),
        max_abs_diff_vs_recompute=max(float(np.abs(a - b).max()) for a, b in zip(recomputed, exported.logits)),
    )


def bundle_parity(bundle_dir: str | Path, vq: MotionVQVAE, gpt: MotionGPT, text_encoder: Any | None,
                  guidance: float, steps: int = 50) -> dict[str, Any]:
    """All three comparisons for the float32 graphs in a (possibly not yet finished) bundle directory.

    Returns a JSON-friendly dict; ``t2m export`` prints it and records it in the model card.
    """
    bundle_dir = Path(bundle_dir)
    report: dict[str, Any] = {
        "gpt_step": asdict(gpt_parity(gpt, bundle_dir / "gpt_step.onnx", steps=steps, guidance=guidance)),
        "decoder": asdict(decoder_parity(vq, np.load(bundle_dir / "mean.npy"), np.load(bundle_dir / "std.npy"),
                                         bundle_dir / "decoder.onnx")),
    }
    report["gpt_step"]["guidance"] = guidance
    if text_encoder is not None:
        report["text_encoder"] = asdict(text_parity(text_encoder, bundle_dir / "text_encoder.onnx",
                                                    bundle_dir / "tokenizer.json"))
    return report


@dataclass
class GptInt8Report:
    max_abs_logit_diff: float
    greedy_codes_match: bool
    steps: int
    fp32_ms_per_step: float
    int8_ms_per_step: float
    fp32_bytes: int
    int8_bytes: int
    agree_steps: int = 0            # greedy steps before the first code that differs (= steps when all match)


def gpt_int8_report(fp32_path: str | Path, int8_path: str | Path, manifest: dict, steps: int = 50,
                    seed: int = 0, threads: int = 1) -> GptInt8Report:
    """Compare the float32 and int8 GPT step graphs on the same greedy rollout from random conditions."""
    from t2m.export.graphs.export import ort_session

    gpt = manifest["gpt"]
    steps = min(steps, manifest["max_tokens"])
    rng = np.random.default_rng(seed)
    cond = rng.normal(size=(2, manifest["text_encoder"]["dim"])).astype(np.float32)
    if manifest["text_encoder"]["normalize"]:
        cond /= np.linalg.norm(cond, axis=1, keepdims=True)
    length = np.array([steps, 0], np.int64)
    shape = (gpt["n_layer"], gpt["n_head"], gpt["head_dim"])
    guidance = gpt["default_guidance"]
    results = []
    for path in (fp32_path, int8_path):
        session = ort_session(path, threads=threads)
        ort_greedy_rollout(session, cond, length, shape, 2, manifest["end_id"], guidance)  # warm-up
        results.append(ort_greedy_rollout(session, cond, length, shape, steps, manifest["end_id"], guidance))
    codes32, logits32, t32 = results[0].codes, results[0].logits, results[0].seconds
    codes8, logits8, t8 = results[1].codes, results[1].logits, results[1].seconds
    # Logit differences are compared along the float32 trajectory only while the codes agree.
    agree = int(np.argmax(np.any(codes32 != codes8, axis=0))) if np.any(codes32 != codes8) else steps
    diffs = [float(np.abs(a - b).max()) for a, b in zip(logits32[: agree + 1], logits8[: agree + 1])]
    return GptInt8Report(
        max_abs_logit_diff=max(diffs), greedy_codes_match=bool(np.array_equal(codes32, codes8)), steps=steps,
        fp32_ms_per_step=1000 * t32 / steps, int8_ms_per_step=1000 * t8 / steps,
        fp32_bytes=Path(fp32_path).stat().st_size, int8_bytes=Path(int8_path).stat().st_size, agree_steps=agree,
    )
