"""A quantised bundle against its float32 original, as served: the same seeded requests through the service's engine
on both bundles, for any family.

Three figures, because they answer three questions:

- token agreement: the share of token positions where the quantised bundle draws the same token as the float32
  one for the same request and seed (sampling as served, the family's default settings). It is what a user sees
  change: once a draw differs, the rest of that motion may follow another path, so this is a lower bound on how
  close the logits are and 1.0 means "the same motions". A family without tokens (diffusion: the decoder reads
  float features) has none;
- max |logit diff| (the diffusion denoiser: max |x0 diff|): each quantised graph run on exactly the feeds its
  float32 twin saw during those requests (the float32 trajectory, teacher-forced), outputs whose name says logit
  (or x0) compared; with the largest float32 value beside it as the scale to read it against;
- the largest joint difference: how far apart, in metres, the two bundles put any joint of the served motions
  for the same request and seed (frames both have). For a diffusion model it is the whole run's drift.

A family's captured graphs (the GPT's gpt_step_fixed.onnx, which T2M_CUDA_GRAPHS serves) are measured the same way
with `captured=True`: both bundles served with CUDA graphs asked for, which on the CPU provider steps those graphs
without capturing anything. They keep their cache in their own buffers, so the quantised twin is fed the float32
trajectory's inputs (cond, token, position, length) and keeps a cache of its own, as it would when served.

Only onnxruntime and numpy: `t2m quantize` measures a bundle without PyTorch.
"""
from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from t2m.decoding.lockstep import keep_rows
from t2m.export.writing.quantize import REPORT_TEXTS as TEXTS  # the motion captions int8 reports use

__all__ = ["PARITY_RUNS", "BundleParity", "GraphParity", "compare_bundles"]

PARITY_RUNS = 8   # seeded requests per comparison (one sentence each, the bundle's longest segment up to 10 s)
PARITY_SECONDS = 10.0


@dataclass
class GraphParity:
    """One quantised graph against its float32 twin on the float32 trajectory."""

    file: str
    calls: int = 0
    max_abs_logit_diff: float = 0.0
    max_abs_logit: float = 0.0       # the float32 outputs' scale
    output: str = "logit"            # what was compared: logit outputs, or the denoiser's x0

    def compare(self, name: str, fp32: np.ndarray, quantised: np.ndarray) -> None:
        """One call's output `name` of both graphs: kept when it is a logit output (or a denoiser's x0);
        non-finite twins refused."""
        if "logit" not in name and name != "x0":
            return
        self.output = "x0" if name == "x0" else "logit"
        if not np.isfinite(quantised).all():
            raise ValueError(f"{self.file}: the quantised graph gave non-finite {name}")
        self.max_abs_logit_diff = max(self.max_abs_logit_diff, float(np.abs(fp32 - quantised).max()))
        self.max_abs_logit = max(self.max_abs_logit, float(np.abs(fp32).max()))


@dataclass
class BundleParity:
    """What a quantisation costs a bundle, measured over `runs` seeded requests of `seconds` each."""

    runs: int
    seconds: float
    tokens: int = 0                  # token positions compared (the longer of the two runs' sequences; 0: none)
    agreeing: int = 0
    max_joint_diff_m: float = 0.0    # the served motions' largest joint difference, over frames both have
    graphs: dict[str, GraphParity] = field(default_factory=dict)

    @property
    def agreement(self) -> float:
        return self.agreeing / self.tokens if self.tokens else 1.0

    @property
    def max_abs_logit_diff(self) -> float:
        return max((g.max_abs_logit_diff for g in self.graphs.values()), default=0.0)

    def as_dict(self) -> dict[str, Any]:
        return {"runs": self.runs, "seconds": self.seconds, "tokens": self.tokens, "agreeing": self.agreeing,
                "agreement": self.agreement, "max_abs_logit_diff": self.max_abs_logit_diff,
                "max_joint_diff_m": self.max_joint_diff_m, "graphs": {name: vars(g) for name, g in self.graphs.items()}}


class _ComparingSession:
    """A float32 session that also runs the quantised twin on every call's feeds and keeps the largest logit
    difference; the served loop sees only the float32 outputs."""

    def __init__(self, fp32: Any, quantised: Any, record: GraphParity) -> None:
        self._fp32, self._quantised, self._record = fp32, quantised, record

    def run(self, output_names: Sequence[str] | None, feeds: Mapping[str, np.ndarray], *args: Any) -> list:
        outputs = self._fp32.run(output_names, feeds, *args)
        names = list(output_names) if output_names else [o.name for o in self._fp32.get_outputs()]
        twins = self._quantised.run(names, feeds, *args)
        for name, a, b in zip(names, outputs, twins):
            self._record.compare(name, a, b)
        self._record.calls += 1
        return outputs

    def __getattr__(self, name: str) -> Any:
        return getattr(self._fp32, name)


class _ComparingStep:
    """A GPT-loop step (t2m.families.gpt.loop.GptStep) over a captured graph that also steps its quantised twin on the
    same inputs, the twin with a cache of its own; the served loop sees only the float32 logits and cache."""

    def __init__(self, fp32: Any, quantised: Any, record: GraphParity) -> None:
        self._fp32, self._quantised, self._record = fp32, quantised, record

    def empty_cache(self, batch: int) -> tuple[Any, Any]:
        return self._fp32.empty_cache(batch), self._quantised.empty_cache(batch)

    def keep_rows(self, past: tuple[Any, Any], keep: np.ndarray) -> tuple[Any, Any]:
        return keep_rows(self._fp32, past[0], keep), keep_rows(self._quantised, past[1], keep)

    def __call__(self, cond: np.ndarray, token: np.ndarray, position: int, length: np.ndarray,
                 past: tuple[Any, Any]) -> tuple[np.ndarray, tuple[Any, Any]]:
        logits, fp32_past = self._fp32(cond, token, position, length, past[0])
        twin, quantised_past = self._quantised(cond, token, position, length, past[1])
        self._record.compare("logits", logits, twin)
        self._record.calls += 1
        return logits, (fp32_past, quantised_past)


def compare_bundles(fp32_dir: str | Path, quantised_dir: str | Path, graphs: Sequence[str],
                    runs: int = PARITY_RUNS, seconds: float = PARITY_SECONDS, threads: int = 0,
                    captured: bool = False) -> BundleParity:
    """Serve the same `runs` seeded one-sentence requests on both bundles; compare their tokens and, for each file
    in `graphs`, the quantised graph's logits with the float32 one's on the float32 trajectory. `captured`: `graphs`
    is the GPT step the service replays as CUDA graphs (gpt_step_fixed.onnx), served here on the CPU provider."""
    from t2m.runtime.bundle_loader import load_bundle
    from t2m.runtime.engine import OnnxEngine
    from t2m.runtime.execution import Execution
    from t2m.runtime.types import GenerationRequest, SegmentRequest

    execution = Execution(cuda_graphs=True) if captured else None
    fp32 = load_bundle(Path(fp32_dir), intra_op_threads=threads, execution=execution)
    quantised = load_bundle(Path(quantised_dir), intra_op_threads=threads, execution=execution)
    seconds = min(seconds, fp32.manifest.max_tokens * fp32.manifest.frames_per_token / fp32.manifest.fps)
    report = BundleParity(runs=runs, seconds=seconds)
    for name in graphs:
        report.graphs[name] = GraphParity(name)
        if not captured:
            fp32.sessions[name] = _ComparingSession(fp32.sessions[name], quantised.sessions[name],
                                                    report.graphs[name])
    engines = [OnnxEngine(bundle) for bundle in (fp32, quantised)]
    if captured:
        from t2m.runtime.family_codes import StepsOneGraph

        (name,) = graphs   # the one captured graph a family has: the GPT's, served through its step
        fp32_codes, quantised_codes = (engine.codes for engine in engines)
        if name not in fp32.sessions or name not in quantised.sessions:
            raise ValueError(f"{name}: not opened for CUDA-graph serving in both bundles")
        if not isinstance(fp32_codes, StepsOneGraph) or not isinstance(quantised_codes, StepsOneGraph):
            raise ValueError(f"{name}: only the GPT family serves a captured step graph")
        fp32_codes.step = _ComparingStep(fp32_codes.step, quantised_codes.step, report.graphs[name])
    guidance = engines[0].limits.default_guidance
    requests = [GenerationRequest(segments=[SegmentRequest(TEXTS[run % len(TEXTS)], seconds)], seed=run,
                                  guidance=guidance) for run in range(runs)]
    for (a, joints_a), (b, joints_b) in zip(*(_served(engine, requests) for engine in engines)):
        if np.issubdtype(a.dtype, np.integer):       # tokens; a diffusion decoder reads float features
            common = min(a.size, b.size)
            report.tokens += max(a.size, b.size)
            report.agreeing += int((a[:common] == b[:common]).sum())
        frames = min(len(joints_a), len(joints_b))
        if frames:
            distance = np.linalg.norm(joints_a[:frames] - joints_b[:frames], axis=-1).max()
            report.max_joint_diff_m = max(report.max_joint_diff_m, float(distance))
    return report


def _served(engine: Any, requests: Sequence[Any]) -> list[tuple[np.ndarray, np.ndarray]]:
    """Per request, what its motion was decoded from, flattened (the decoder's input, caught on the way: codes,
    or a diffusion model's features), and the served joints [frames, J, 3]."""
    seen: list[np.ndarray] = []
    decode = engine.decoder.decode

    def catching(codes: np.ndarray) -> np.ndarray:
        seen.append(np.asarray(codes).reshape(-1).copy())
        return decode(codes)

    engine.decoder.decode = catching
    result = []
    try:
        for request in requests:
            seen.clear()
            joints = engine.generate(request).joints
            result.append((np.concatenate(seen) if seen else np.zeros(0, np.int64), joints))
    finally:
        engine.decoder.decode = decode
    return result
