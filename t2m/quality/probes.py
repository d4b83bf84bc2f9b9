"""Does the model follow the text? Kinematic probes (t2m.model.evaluation.probes) run on a bundle's onnxruntime engine.

Every probe x phrasing x seed is generated as a `--duration` s motion (3 s by default) and measured; a paired probe
(run vs walk) generates its reference sentence with the same seed. The three-sentence stream of
t2m.model.evaluation.probes.STREAM is generated per seed too: each segment is probed against its own sentence and the
pelvis velocity jump at each join is compared with the changes inside the segments. Prints markdown tables;
`--json-out` keeps every trial.

    t2m eval probes                                  # t2m/bundles/default, 5 seeds, the model's guidance
    t2m eval probes --bundle DIR --seeds 5 --guidance 3 --json-out artifacts/probes.json
    t2m eval probes --real-clips DATASET_DIR --per-content 20   # on motion capture (the archive's dataset/)
    t2m eval probes --probes jump,invert,get_up       # the CMU actions' probes on a model
    t2m eval probes --cmu-clips data/cmu              # ... and on the captioned CMU clips (t2m data build)
"""
from __future__ import annotations

import argparse
import json
import logging
import sys
import time
from collections.abc import Iterable, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from t2m.bundles import DEFAULT_BUNDLE
from t2m.model.evaluation.action_probes import ACTION_PROBES
from t2m.model.evaluation.probes import PROBES, STREAM, ProbeSpec, join_smoothness, probe_by_name
from t2m.runtime.types import GenerationRequest, Motion, SegmentRequest

if TYPE_CHECKING:
    from t2m.runtime.engine import OnnxEngine

__all__ = [
    "ProbeReport",
    "ProbeSummary",
    "StreamSummary",
    "Trial",
    "calibrate_on_clips",
    "calibrate_on_cmu",
    "format_calibration",
    "format_report",
    "generate",
    "main",
    "run_probes",
    "run_stream",
]

log = logging.getLogger("t2m.quality.probes")

BATCH = 16          # requests sampled in lockstep per engine call


@dataclass(frozen=True)
class Trial:
    phrasing: str
    seed: int
    value: float
    passed: bool
    details: dict[str, float] = field(default_factory=dict)


@dataclass(frozen=True)
class ProbeSummary:
    probe: str
    rule: str
    unit: str
    trials: list[Trial]

    @property
    def pass_rate(self) -> float:
        return float(np.mean([t.passed for t in self.trials]))

    @property
    def mean_value(self) -> float:
        return float(np.mean([t.value for t in self.trials]))

    def pass_rate_of(self, phrasing: str) -> float:
        return float(np.mean([t.passed for t in self.trials if t.phrasing == phrasing]))


@dataclass(frozen=True)
class StreamSummary:
    """The three-sentence stream over seeds: per-segment probe verdicts and the join smoothness."""

    sentences: list[tuple[str, float, str]]
    segment_pass_rates: dict[str, float]           # "index:probe" -> pass rate
    join_ratios: list[list[float]]                  # per seed: join change / median change inside segments
    join_p95_ratios: list[list[float]]              # per seed: join change / 95th percentile change inside segments
    join_changes: list[list[float]]                 # m/s per frame
    within_median: list[float]
    within_p95: list[float]


@dataclass(frozen=True)
class ProbeReport:
    bundle: str
    model: str
    seeds: list[int]
    guidance: float
    duration: float
    probes: list[ProbeSummary]
    stream: StreamSummary | None
    seconds: float

    def probe(self, name: str) -> ProbeSummary:
        for summary in self.probes:
            if summary.probe == name:
                return summary
        raise KeyError(name)

    def to_json(self) -> dict:
        data = asdict(self)
        for summary, row in zip(self.probes, data["probes"]):
            row["pass_rate"], row["mean_value"] = summary.pass_rate, summary.mean_value
        return data


def generate(engine: OnnxEngine, requests: Sequence[GenerationRequest]) -> list[Motion]:
    """All requests through the engine, BATCH at a time; any failed request is raised."""
    motions: list[Motion] = []
    for start in range(0, len(requests), BATCH):
        for result in engine.generate_batch(requests[start:start + BATCH]):
            if isinstance(result, BaseException):
                raise result
            motions.append(result)
    return motions


def _request(text: str, duration: float, seed: int, guidance: float) -> GenerationRequest:
    return GenerationRequest(segments=[SegmentRequest(text, duration)], seed=seed, guidance=guidance)


def run_probe(engine: OnnxEngine, spec: ProbeSpec, seeds: Sequence[int], guidance: float,
              duration: float = 3.0) -> ProbeSummary:
    """One probe: every phrasing with every seed (plus, for a paired probe, its reference with the same seed)."""
    if not seeds:
        raise ValueError("seeds: at least one seed is needed")
    cases = [(k, phrasing, seed) for k, phrasing in enumerate(spec.phrasings) for seed in seeds]
    requests = [_request(phrasing, duration, seed, guidance) for _, phrasing, seed in cases]
    if spec.reference_phrasings:
        references = spec.reference_phrasings
        requests += [_request(references[k % len(references)], duration, seed, guidance) for k, _, seed in cases]
    motions = generate(engine, requests)
    trials = []
    for index, (_, phrasing, seed) in enumerate(cases):
        args = [motions[index].joints]
        if spec.reference_phrasings:
            args.append(motions[len(cases) + index].joints)
        result = spec.check(*args)
        trials.append(Trial(phrasing, seed, result.value, bool(result.passed), dict(result.details)))
    return ProbeSummary(spec.name, result.rule, result.unit, trials)


def run_stream(engine: OnnxEngine, seeds: Sequence[int], guidance: float,
               sentences: Sequence[tuple[str, float, str]] = STREAM) -> StreamSummary:
    """The multi-sentence stream per seed: each segment's own probe, and the velocity jump at each join."""
    requests = [GenerationRequest(segments=[SegmentRequest(text, seconds) for text, seconds, _ in sentences],
                                  seed=seed, guidance=guidance) for seed in seeds]
    passes: dict[str, list[bool]] = {f"{i}:{probe}": [] for i, (_, _, probe) in enumerate(sentences)}
    ratios, p95_ratios, changes, medians, p95s = [], [], [], [], []
    for motion in generate(engine, requests):
        for i, (span, (_, _, probe)) in enumerate(zip(motion.segments, sentences)):
            passes[f"{i}:{probe}"].append(bool(probe_by_name(probe).check(
                motion.joints[span.start_frame:span.end_frame]).passed))
        joins = join_smoothness(motion.joints, [span.start_frame for span in motion.segments[1:]], motion.fps)
        ratios.append(list(joins.ratios))
        p95_ratios.append(list(joins.p95_ratios))
        changes.append(list(joins.join_changes))
        medians.append(joins.within_median)
        p95s.append(joins.within_p95)
    return StreamSummary([(text, seconds, probe) for text, seconds, probe in sentences],
                         {k: float(np.mean(v)) for k, v in passes.items()},
                         ratios, p95_ratios, changes, medians, p95s)


def with_progress(items: list[ProbeSpec], **options: object) -> Iterable[ProbeSpec]:
    """tqdm's bar where it is installed (the train extra); the bare items on a runtime-only install."""
    try:
        from tqdm import tqdm
    except ImportError:
        return items
    return tqdm(items, **options)  # type: ignore[call-overload]


def run_probes(engine: OnnxEngine, seeds: Sequence[int], guidance: float, duration: float = 3.0,
               probes: Iterable[ProbeSpec] = PROBES, stream: bool = True, bundle: str = "",
               progress: bool = True) -> ProbeReport:
    """Every probe (and the stream) on this engine; a report with every trial."""
    started = time.perf_counter()
    specs = list(probes)
    summaries = []
    for spec in with_progress(specs, desc="probes", unit="probe", disable=not progress):
        summaries.append(run_probe(engine, spec, seeds, guidance, duration))
        log.info("%s: pass rate %.2f, mean %.3f", spec.name, summaries[-1].pass_rate, summaries[-1].mean_value)
    stream_summary = run_stream(engine, seeds, guidance) if stream else None
    limits = engine.limits
    return ProbeReport(bundle=bundle, model=f"{limits.name} {limits.version}", seeds=list(seeds), guidance=guidance,
                       duration=duration, probes=summaries, stream=stream_summary,
                       seconds=time.perf_counter() - started)


def format_report(report: ProbeReport) -> str:
    """Markdown: the probe table (pass rate, mean measured value, per phrasing), then the stream's figures."""
    n = len(report.seeds)
    lines = [f"### Kinematic probes: {report.model}, {report.duration:g} s motions, {n} seed(s) per phrasing, "
             f"guidance {report.guidance:g}", "",
             "| probe | passes when | pass rate | trials | mean value | pass rate per phrasing |",
             "| --- | --- | ---: | ---: | ---: | --- |"]
    for summary in report.probes:
        phrasings = list(dict.fromkeys(t.phrasing for t in summary.trials))
        per = "; ".join(f'"{p}" {summary.pass_rate_of(p):.2f}' for p in phrasings)
        lines.append(f"| {summary.probe} | {summary.rule} | {summary.pass_rate:.2f} | {len(summary.trials)} | "
                     f"{summary.mean_value:+.2f} {summary.unit} | {per} |")
    stream = report.stream
    if stream is not None:
        sentence_list = " -> ".join(f'"{text}" {seconds:g} s' for text, seconds, _ in stream.sentences)
        lines += ["", f"### Three-sentence stream ({n} seed(s)): {sentence_list}", "",
                  "| segment | probe | pass rate |", "| ---: | --- | ---: |"]
        for key, rate in stream.segment_pass_rates.items():
            index, probe = key.split(":")
            lines.append(f"| {int(index) + 1} | {probe} | {rate:.2f} |")
        ratios, p95_ratios = np.asarray(stream.join_ratios), np.asarray(stream.join_p95_ratios)
        changes = np.asarray(stream.join_changes)
        lines += ["", "Pelvis velocity change from one frame to the next (m/s per frame), at each join vs inside the "
                  f"segments (median {np.mean(stream.within_median):.3f}, p95 {np.mean(stream.within_p95):.3f}); "
                  "mean and max over seeds:", "",
                  "| join | change at the join | join / median | join / p95 |", "| ---: | ---: | ---: | ---: |"]
        for j in range(ratios.shape[1]):
            lines.append(f"| {j + 1} | {changes[:, j].mean():.3f} | {ratios[:, j].mean():.1f} (max "
                         f"{ratios[:, j].max():.1f}) | {p95_ratios[:, j].mean():.2f} "
                         f"(max {p95_ratios[:, j].max():.2f}) |")
    lines += ["", f"({report.seconds:.1f} s)"]
    return "\n".join(lines)


# Bandai-Namco content labels whose clips each single-motion probe should pass on (the rest it should fail on)
PROBE_CONTENTS: dict[str, tuple[str, ...]] = {
    "walk_forward": ("walk",), "walk_backward": ("walk-back",), "turn_left": ("walk-turn-left",),
    "turn_right": ("walk-turn-right",), "raise_right": ("raise-up-right-hand", "wave-right-hand"),
    "raise_left": ("raise-up-left-hand", "wave-left-hand"), "raise_both": ("raise-up-both-hands", "wave-both-hands"),
    "bow": ("bow",), "kick": ("kick",),
}
CALIBRATION_CONTENTS = ("walk", "walk-back", "run", "dash", "walk-turn-left", "walk-turn-right", "raise-up-right-hand",
                        "wave-right-hand", "raise-up-left-hand", "wave-left-hand", "raise-up-both-hands",
                        "wave-both-hands", "bow", "bye", "kick")


def calibrate_on_clips(dataset_dir: str | Path, per_content: int = 20, seconds: float = 3.0, seed: int = 0,
                       progress: bool = True) -> tuple[dict[str, dict[str, float]], dict[str, int]]:
    """Pass rate of every single-motion probe on real Bandai-Namco clips of each content label (first `seconds`).

    The probes' ceiling (their own action) and false alarms (the others) on motion capture; run_vs_walk pairs each
    run clip with a random walk clip. Returns ({probe: {content: pass rate}}, {content: clips used}).
    """
    import random

    from tqdm import tqdm

    from t2m.model.evaluation.probes import probe_run_vs_walk
    from t2m.motion.bvh import read_bvh
    from t2m.motion.retarget import bvh_to_smpl22

    root = Path(dataset_dir)
    files = sorted(root.glob("Bandai-Namco-Research-Motiondataset-*/data/*.bvh"))
    if not files:
        raise FileNotFoundError(f"no Bandai-Namco BVH files under {root}/Bandai-Namco-Research-Motiondataset-*/data")
    by_content: dict[str, list[Path]] = {}
    for path in files:
        by_content.setdefault(path.stem.split("_")[1], []).append(path)
    rng = random.Random(seed)
    frames = round(seconds * 20)
    joints: dict[str, list[np.ndarray]] = {}
    for content in tqdm(CALIBRATION_CONTENTS, desc="clips", unit="content", disable=not progress):
        chosen = rng.sample(by_content.get(content, []), min(per_content, len(by_content.get(content, []))))
        joints[content] = [bvh_to_smpl22(read_bvh(path))[:frames] for path in chosen]
    rates: dict[str, dict[str, float]] = {}
    for name in PROBE_CONTENTS:
        check = probe_by_name(name).check
        rates[name] = {content: float(np.mean([check(j).passed for j in clips]))
                       for content, clips in joints.items() if clips}
    walks = joints.get("walk", [])
    rates["run_vs_walk"] = {content: float(np.mean([probe_run_vs_walk(j, walks[rng.randrange(len(walks))]).passed
                                                    for j in clips]))
                            for content, clips in joints.items() if clips and walks}
    return rates, {content: len(clips) for content, clips in joints.items()}


# which CMU sentences ask for each action probe's action (the calibration's "own" clips)
CMU_ACTIONS = {"jump": r"\bjump|\bhop", "invert": r"cartwheel|handstand|flip|somersault",
               "get_up": r"gets? up|stands? up|pushes himself up|rises? from"}


def calibrate_on_cmu(data_dir: str | Path) -> dict[str, dict[str, float | int]]:
    """Each action probe on every clip of a CMU build (t2m data build; whole clips as cut by their sentences): its
    pass rate on the clips whose sentences ask for its action, and on all the others."""
    import re

    root = Path(data_dir)
    names = sorted(path.stem for path in (root / "new_joints").glob("*.npy"))
    if not names:
        raise FileNotFoundError(f"no clips under {root}/new_joints (build it: t2m data build --source "
                                "<cmu-captioned-motion.tar.xz> --out DIR)")
    clips = [(np.load(root / "new_joints" / f"{name}.npy"), (root / "texts" / f"{name}.txt").read_text().lower())
             for name in names]
    out: dict[str, dict[str, float | int]] = {}
    for spec in ACTION_PROBES:
        own = [bool(spec.check(joints).passed) for joints, text in clips if re.search(CMU_ACTIONS[spec.name], text)]
        other = [bool(spec.check(joints).passed) for joints, text in clips
                 if not re.search(CMU_ACTIONS[spec.name], text)]
        out[spec.name] = {"own_rate": float(np.mean(own)) if own else float("nan"), "own_clips": len(own),
                          "other_rate": float(np.mean(other)) if other else float("nan"), "other_clips": len(other)}
    return out


def format_calibration(rates: dict[str, dict[str, float]], counts: dict[str, int], seconds: float) -> str:
    contents = [content for content in CALIBRATION_CONTENTS if counts.get(content)]
    lines = [f"### Probes on real Bandai-Namco clips (first {seconds:g} s; clips per label: "
             f"{', '.join(f'{c} {counts[c]}' for c in contents)}): pass rate; its own labels in bold", "",
             "| probe | " + " | ".join(contents) + " |", "| --- |" + " ---: |" * len(contents)]
    own = dict(PROBE_CONTENTS, run_vs_walk=("run", "dash"))
    for name, row in rates.items():
        cells = [f"**{row[c]:.2f}**" if c in own[name] else f"{row[c]:.2f}" for c in contents]
        lines.append(f"| {name} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def _spec(name: str) -> ProbeSpec:
    """A probe of the default set or of the CMU actions' set, by name."""
    for spec in ACTION_PROBES:
        if spec.name == name:
            return spec
    try:
        return probe_by_name(name)
    except ValueError:
        raise ValueError(f"probe: unknown probe {name!r}; known: "
                         f"{', '.join(spec.name for spec in (*PROBES, *ACTION_PROBES))}") from None


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--bundle", default=str(DEFAULT_BUNDLE), help="bundle directory (default t2m/bundles/default)")
    parser.add_argument("--seeds", type=int, default=5, help="seeds per phrasing (0..N-1)")
    parser.add_argument("--guidance", type=float, default=None,
                        help="classifier-free guidance (default: the manifest's, or 1 without an unconditional branch)")
    parser.add_argument("--duration", type=float, default=3.0, help="seconds per probe motion")
    parser.add_argument("--probes", default=None, help="comma-separated probe names (default: all)")
    parser.add_argument("--no-stream", action="store_true", help="skip the three-sentence stream")
    parser.add_argument("--json-out", default=None, help="write the report with every trial here")
    parser.add_argument("--real-clips", default=None, metavar="DATASET_DIR",
                        help="instead of a model: the probes on real Bandai-Namco clips under DATASET_DIR (the "
                             "unpacked archive's dataset/), per content label")
    parser.add_argument("--per-content", type=int, default=20, help="with --real-clips: clips per content label")
    parser.add_argument("--cmu-clips", default=None, metavar="DATA_DIR",
                        help="instead of a model: the CMU actions' probes (jump, invert, get_up) on a CMU build")
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(name)s %(message)s")
    if args.cmu_clips:
        try:
            rates = calibrate_on_cmu(args.cmu_clips)
        except FileNotFoundError as error:
            print(f"error: {error}", file=sys.stderr)
            return 2
        print("| probe | its own clips: pass rate (clips) | the other clips: pass rate (clips) |")
        print("| --- | ---: | ---: |")
        for name, row in rates.items():
            print(f"| {name} | {row['own_rate']:.2f} ({row['own_clips']}) | {row['other_rate']:.2f} "
                  f"({row['other_clips']}) |")
        return 0
    if args.real_clips:
        try:
            rates, counts = calibrate_on_clips(args.real_clips, args.per_content, args.duration)
        except (ValueError, FileNotFoundError) as error:
            print(f"error: {error}", file=sys.stderr)
            return 2
        print(format_calibration(rates, counts, args.duration))
        if args.json_out:
            Path(args.json_out).parent.mkdir(parents=True, exist_ok=True)
            Path(args.json_out).write_text(json.dumps({"rates": rates, "clips": counts}, indent=1))
        return 0
    if not 1 <= args.seeds <= 100:
        parser.error(f"--seeds: {args.seeds} is outside 1..100")
    if not 0.2 <= args.duration <= 10.0:
        parser.error(f"--duration: {args.duration} is outside 0.2..10 s")
    try:
        specs = PROBES if args.probes is None else [_spec(name.strip()) for name in args.probes.split(",")]
        from t2m.runtime.engine import OnnxEngine

        engine = OnnxEngine.load(args.bundle)
    except (ValueError, FileNotFoundError) as error:
        print(f"error: {error}", file=sys.stderr)
        return 2
    limits = engine.limits
    guidance = limits.guidance(args.guidance)
    report = run_probes(engine, range(args.seeds), guidance, args.duration, specs, not args.no_stream,
                        bundle=str(Path(args.bundle).resolve()))
    print(format_report(report))
    if args.json_out:
        Path(args.json_out).parent.mkdir(parents=True, exist_ok=True)
        Path(args.json_out).write_text(json.dumps(report.to_json(), indent=1))
        print(f"wrote {args.json_out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
