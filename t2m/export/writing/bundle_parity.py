"""A quantised bundle against its float32 original, as served: the same seeded requests through the service's engine
on both bundles, for any family.

Two figures, because they answer two questions:

- token agreement: the share of token positions where the quantised bundle draws the same token as the float32
  one for the same request and seed (sampling as served, the family's default settings). It is what a user sees
  change: once a draw differs, the rest of that motion may follow another path, so this is a lower bound on how
  close the logits are and 1.0 means "the same motions";
- max |logit diff|: each quantised graph run on exactly the feeds its float32 twin saw during those requests (the
  float32 trajectory, teacher-forced), outputs whose name says logit compared; with the largest float32 logit
  beside it as the scale to read it against.

Only onnxruntime and numpy: `t2m quantize` measures a bundle without PyTorch.
"""
from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

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
    max_abs_logit: float = 0.0       # the float32 logits' scale


@dataclass
class BundleParity:
    """What a quantisation costs a bundle, measured over `runs` seeded requests of `seconds` each."""

    runs: int
    seconds: float
    tokens: int = 0                  # token positions compared (the longer of the two runs' sequences)
    agreeing: int = 0
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
                "graphs": {name: vars(g) for name, g in self.graphs.items()}}


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
            if "logit" not in name:
                continue
            if not np.isfinite(b).all():
                raise ValueError(f"{self._record.file}: the quantised graph gave non-finite {name}")
            self._record.max_abs_logit_diff = max(self._record.max_abs_logit_diff, float(np.abs(a - b).max()))
            self._record.max_abs_logit = max(self._record.max_abs_logit, float(np.abs(a).max()))
        self._record.calls += 1
        return outputs

    def __getattr__(self, name: str) -> Any:
        return getattr(self._fp32, name)


def compare_bundles(fp32_dir: str | Path, quantised_dir: str | Path, graphs: Sequence[str],
                    runs: int = PARITY_RUNS, seconds: float = PARITY_SECONDS, threads: int = 0) -> BundleParity:
    """Serve the same `runs` seeded one-sentence requests on both bundles; compare their tokens and, for each file
    in `graphs`, the quantised graph's logits with the float32 one's on the float32 trajectory."""
    from t2m.service.engine.bundle import load_bundle
    from t2m.service.engine.engine import OnnxEngine
    from t2m.service.engine.types import GenerationRequest, SegmentRequest

    fp32 = load_bundle(Path(fp32_dir), intra_op_threads=threads)
    quantised = load_bundle(Path(quantised_dir), intra_op_threads=threads)
    seconds = min(seconds, fp32.manifest.max_tokens * fp32.manifest.frames_per_token / fp32.manifest.fps)
    report = BundleParity(runs=runs, seconds=seconds)
    for name in graphs:
        report.graphs[name] = GraphParity(name)
        fp32.sessions[name] = _ComparingSession(fp32.sessions[name], quantised.sessions[name], report.graphs[name])
    engines = [OnnxEngine(bundle) for bundle in (fp32, quantised)]
    guidance = engines[0].limits.default_guidance
    requests = [GenerationRequest(segments=[SegmentRequest(TEXTS[run % len(TEXTS)], seconds)], seed=run,
                                  guidance=guidance) for run in range(runs)]
    for a, b in zip(*(_served_codes(engine, requests) for engine in engines)):
        common = min(a.size, b.size)
        report.tokens += max(a.size, b.size)
        report.agreeing += int((a[:common] == b[:common]).sum())
    return report


def _served_codes(engine: Any, requests: Sequence[Any]) -> list[np.ndarray]:
    """The codes each request's motion was decoded from, flattened (the decoder's input, caught on the way)."""
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
            engine.generate(request)
            result.append(np.concatenate(seen) if seen else np.zeros(0, np.int64))
    finally:
        engine.decoder.decode = decode
    return result
