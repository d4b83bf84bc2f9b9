"""`t2m eval`: the papers' evaluation of a VQ-VAE + token model on a test split, with our own evaluator.

The token model is a family (t2m.model.evaluation.family.CodeFamily): the GPT (gpt_family), the masked
transformers (masked_family) or T2M-HiFiGPT's double-tier GPT (hifigpt_family). A family only makes codes for texts
and token counts; the VQ decodes them, and everything else below is shared, so the families are measured on the same
draws with the same evaluator.

Table 1 follows Guo et al. / T2M-GPT: rows Real motion, VQ reconstruction and Generation at each guidance scale;
columns R-precision top-1/2/3 (32-way), FID, MM-Dist, Diversity, MModality, plus MPJPE for the reconstruction.
Every number is the mean over `repeats` evaluations with ± the 95% interval (1.96 std / sqrt(repeats)).

One repeat:
- draw A: each test clip gets a random caption and a random crop (at most the evaluator's 196 frames, a multiple of
  the VQ's frames per code, 4 or 8, so a generated motion can have exactly its length). Draw A is the FID reference,
  the generation prompts (caption + the crop's token count) and the reconstruction input.
- draw B: another caption/crop draw of the same clips: the Real motion row (its FID is the noise floor).
- MModality: `mm_texts` prompts of draw A, each generated `mm_repeats` times; 10 pairs per prompt.

Table 2 follows T2LM's multi-sentence evaluation: draw A is shuffled into streams of 3 prompts; each sentence is
generated for its own duration, the streams' codes are concatenated and decoded once (as the service does).
Sliding-scope FID compares 80-frame windows (stride 40) of the streams with 80-frame windows of the real test clips;
transition-scope FID compares the 80-frame windows centred on the joins with the same real windows. The pelvis
velocity jump is the change of the pelvis velocity between consecutive frames at the joins versus inside segments
(and inside real clips, for reference). Two reference rows use the same streams of real crops instead of generated
ones, so that "transition-scope FID close to sliding-scope FID" has a scale: the crops pasted with hard cuts (what
joins cost with no transition at all) and the crops' own VQ codes concatenated and decoded once (what the decoder's
receptive field makes of those cuts without the GPT).
"""
from __future__ import annotations

import json
import math
from collections.abc import Sequence, Sized
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import torch

from t2m.model.evaluation import metrics
from t2m.model.evaluation.family import StreamFamily
from t2m.model.networks.evaluator import MotionEvaluator, embed_motions, embed_texts
from t2m.motion.constants import FPS, FRAMES_PER_TOKEN

if TYPE_CHECKING:
    from t2m.model.evaluation.family import CodeDecoder, CodeFamily, TextFeatureSource
    from t2m.model.networks.joint_vqvae import JointVQVAE
    from t2m.model.networks.vqvae import MotionVQVAE


@dataclass
class EvalOptions:
    split: str = "test"
    repeats: int = 20                       # the papers' 20 evaluations
    guidance: tuple[float, ...] = (1.0, 3.0)
    seed: int = 0
    limit: int | None = None                # use only N clips of the split (quick runs)
    temperature: float = 1.0
    top_k: int | None = None
    mm_texts: int = 100                     # Guo et al.: 100 texts x 30 motions, 10 pairs each
    mm_repeats: int = 30
    mm_pairs: int = 10
    diversity_pairs: int = 300
    r_precision_pool: int = 32
    stream_sentences: int = 3
    streams: int | None = None              # default: every clip of draw A used once
    window: int = 80
    stride: int = 40
    batch_size: int = 128
    multi_sentence: bool = True
    progress: bool = True

    def check(self) -> None:
        if self.repeats < 1:
            raise ValueError(f"repeats must be at least 1, got {self.repeats}")
        if not self.guidance:
            raise ValueError("give at least one guidance scale")
        if self.limit is not None and self.limit < 2:
            raise ValueError(f"limit must be at least 2 clips, got {self.limit}")
        if self.temperature < 0:
            raise ValueError(f"temperature must be >= 0, got {self.temperature}")
        if self.mm_repeats < 2 or self.mm_texts < 1:
            raise ValueError(
                f"MModality needs mm_texts >= 1 and mm_repeats >= 2, got {self.mm_texts}/{self.mm_repeats}"
            )
        if self.stream_sentences < 2:
            raise ValueError(
                f"stream_sentences must be at least 2 (a stream needs a join), got {self.stream_sentences}"
            )
        if not 0 < self.stride <= self.window:
            raise ValueError(f"need 0 < stride <= window, got stride {self.stride}, window {self.window}")
        if self.batch_size < 1:
            raise ValueError(f"batch_size must be at least 1, got {self.batch_size}")


@dataclass
class Models:
    """The evaluator, the VQ-VAE (with the statistics its outputs are de-normalised with) and the family that makes
    its codes. A served bundle has no VQ module: `vq` is None, its `decoder` (decoder.onnx) decodes, and its
    `family_text` (text_encoder.onnx) makes the family's text features, so the evaluation measures what is served."""

    evaluator: MotionEvaluator
    vq: MotionVQVAE | JointVQVAE | None
    family: CodeFamily
    vq_mean: np.ndarray
    vq_std: np.ndarray
    evaluator_text: str = "minilm"
    paths: dict[str, str] = field(default_factory=dict)
    decoder: CodeDecoder | None = None
    family_text: TextFeatureSource | None = None

    @property
    def frames_per_token(self) -> int:
        """Frames per code row of the VQ (4; 8 for T2M-HiFiGPT's RVQ-VAE): crops are cut to multiples of it."""
        if self.decoder is not None:
            return int(self.decoder.frames_per_token)
        assert self.vq is not None, "Models needs a VQ or a decoder"
        return int(self.vq.frames_per_token)


def load_evaluator_and_vq(evaluator_run: str | Path, vq_run: str | Path, vq_kinds: Sequence[str],
                           data_mean: np.ndarray, data_std: np.ndarray
                           ) -> tuple[MotionEvaluator, MotionVQVAE | JointVQVAE, np.ndarray, np.ndarray]:
    """The evaluator and a VQ of one of `vq_kinds`; the VQ statistics come from its run (mean.npy/std.npy) or else
    the dataset."""
    from t2m.model.networks.joint_vqvae import JointVQVAE
    from t2m.model.networks.vqvae import MotionVQVAE
    from t2m.model.training.checkpoint import load_model, load_run, read_run_config

    evaluator = load_model(evaluator_run, expect_kind="evaluator")
    kind = read_run_config(vq_run)["kind"]
    kind = kind if kind in vq_kinds else vq_kinds[0]     # another kind: load_model names what it expected
    vq: MotionVQVAE | JointVQVAE = (load_run(vq_run, kind, JointVQVAE) if kind == "joint_vq"
                                    else load_run(vq_run, kind, MotionVQVAE))
    mean, std = data_mean, data_std
    if (Path(vq_run) / "mean.npy").is_file() and (Path(vq_run) / "std.npy").is_file():
        mean, std = np.load(Path(vq_run) / "mean.npy"), np.load(Path(vq_run) / "std.npy")
    return evaluator, vq, np.asarray(mean, np.float32), np.asarray(std, np.float32)


def code_family_models(evaluator: MotionEvaluator, vq: MotionVQVAE | JointVQVAE, family: CodeFamily, mean: np.ndarray,
            std: np.ndarray, evaluator_run: str | Path, vq_run: str | Path) -> Models:
    if evaluator.config.feature_dim != vq.config.feat_dim or len(mean) != vq.config.feat_dim:
        raise ValueError(f"feature dims differ: evaluator {evaluator.config.feature_dim}, VQ {vq.config.feat_dim}, "
                         f"statistics {len(mean)}")
    return Models(evaluator, vq, family, mean, std, evaluator_text=evaluator.config.text_encoder,
                  paths={"evaluator": str(evaluator_run), "vq": str(vq_run), **family.paths})


# ----------------------------------------------------------------------------------------- data and draws


@dataclass
class Clips:
    ids: list[str]
    features: list[np.ndarray]     # raw [T, D]
    captions: list[list[str]]


@dataclass
class Draw:
    """One caption and one crop per clip."""

    captions: list[str]
    motions: list[np.ndarray]      # raw [T', D], T' a multiple of frames_per_token
    frames_per_token: int = FRAMES_PER_TOKEN

    @property
    def tokens(self) -> list[int]:
        return [len(m) // self.frames_per_token for m in self.motions]


def read_clips(reader, limit: int | None, min_frames: int = FRAMES_PER_TOKEN) -> Clips:
    """The split's clips (evenly spaced ones with a limit, so that every label region stays represented)."""
    ids = list(reader.ids)
    if limit is not None and limit < len(ids):
        ids = [ids[i] for i in np.linspace(0, len(ids) - 1, limit).round().astype(int)]
    kept = Clips([], [], [])
    for clip_id in ids:
        features = reader.features(clip_id)
        if len(features) < min_frames:
            continue
        kept.ids.append(clip_id)
        kept.features.append(features)
        kept.captions.append(reader.captions(clip_id))
    if len(kept.ids) < 2:
        raise ValueError(f"{getattr(reader, 'root', 'dataset')}: the split has fewer than 2 usable clips")
    return kept


def draw(clips: Clips, max_frames: int, rng: np.random.Generator, frames_per_token: int = FRAMES_PER_TOKEN) -> Draw:
    captions, motions = [], []
    for features, clip_captions in zip(clips.features, clips.captions):
        captions.append(clip_captions[int(rng.integers(len(clip_captions)))])
        length = min(len(features), max_frames)
        length -= length % frames_per_token
        start = int(rng.integers(0, len(features) - length + 1))
        motions.append(features[start:start + length])
    return Draw(captions, motions, frames_per_token)


def windows(motion: np.ndarray, window: int, stride: int) -> list[np.ndarray]:
    return [motion[s:s + window] for s in range(0, len(motion) - window + 1, stride)]


def windows_at_joins(motion: np.ndarray, joins: Sequence[int], window: int) -> list[np.ndarray]:
    """Windows of `window` frames centred on each join that fit inside the motion."""
    half = window // 2
    return [motion[j - half:j - half + window] for j in joins if j - half >= 0 and j - half + window <= len(motion)]


def pelvis_velocity_jumps(joints: np.ndarray, joins: Sequence[int] = (), margin: int = 2,
                          fps: int = FPS) -> tuple[np.ndarray, np.ndarray]:
    """Change of the pelvis velocity (m/s) across each frame boundary, at the joins and elsewhere.

    Boundary b lies between frames b-1 and b; its jump is the larger of |v(b-1→b) - v(b-2→b-1)| and
    |v(b→b+1) - v(b-1→b)|, so a step in position at a join shows in full. Boundaries within `margin` frames of a
    join count for neither set. Returns (jumps at the joins [len(joins)], jumps inside segments)."""
    pelvis = np.asarray(joints, np.float64)[:, 0, :]
    velocity = np.diff(pelvis, axis=0) * fps                   # v[k]: frame k -> k+1
    change = np.linalg.norm(np.diff(velocity, axis=0), axis=1)  # change[k]: v[k] -> v[k+1]
    frames = len(pelvis)

    def jump(boundary: int) -> float:
        return float(max(change[boundary - 2], change[boundary - 1]))

    valid = range(2, frames - 1)  # boundaries with both neighbouring velocity changes
    at_joins = np.array([jump(j) for j in joins if j in valid])
    near = {b for j in joins for b in range(j - margin, j + margin + 1)}
    inside = np.array([jump(b) for b in valid if b not in near])
    return at_joins, inside


# ------------------------------------------------------------------------------------------- generation


def _groups_by_length(sequences: Sequence[Sized]) -> dict[int, list[int]]:
    groups: dict[int, list[int]] = {}
    for index, sequence in enumerate(sequences):
        groups.setdefault(len(sequence), []).append(index)
    return groups


@torch.no_grad()
def decode(models: Models, codes: Sequence[Sequence[int]] | Sequence[np.ndarray],
           batch_size: int = 128) -> list[np.ndarray]:
    """Code sequences -> raw features [4T, D] (batched by equal length: the convolutions see no padding)."""
    out: list[np.ndarray] = [np.zeros(0)] * len(codes)
    for indices in _groups_by_length(codes).values():
        for start in range(0, len(indices), batch_size):
            chunk = indices[start:start + batch_size]
            dtype = getattr(models.decoder, "code_dtype", np.int64)   # float frames for the diffusion family
            stacked = np.stack([np.asarray(codes[i], dtype=dtype) for i in chunk])
            if models.decoder is not None:
                features = models.decoder.decode_batch(stacked)
            else:
                assert models.vq is not None, "Models needs a VQ or a decoder"
                features = models.vq.decode(torch.as_tensor(stacked)).numpy() * models.vq_std + models.vq_mean
            for row, index in enumerate(chunk):
                out[index] = features[row].astype(np.float32)
    return out


@torch.no_grad()
def reconstruct_codes(models: Models, motions: Sequence[np.ndarray], batch_size: int = 128) -> list[np.ndarray]:
    """Raw motions -> their VQ code sequences."""
    if models.vq is None:
        raise ValueError("reconstruction needs a VQ encoder (a served bundle has only the decoder)")
    codes: list[np.ndarray] = [np.zeros(0)] * len(motions)
    for indices in _groups_by_length(motions).values():
        for start in range(0, len(indices), batch_size):
            chunk = indices[start:start + batch_size]
            normalised = (np.stack([motions[i] for i in chunk]) - models.vq_mean) / models.vq_std
            batch_codes = models.vq.encode(torch.from_numpy(normalised.astype(np.float32))).numpy()
            for row, index in enumerate(chunk):
                codes[index] = batch_codes[row]
    return codes



def sample(models: Models, cond: np.ndarray, tokens: Sequence[int] | np.ndarray, guidance: float, options: EvalOptions,
           generator: np.random.Generator, desc: str) -> list[Any]:
    """The family's codes of exactly `tokens[i]` time steps for each condition row, in batches (of similar lengths
    when the family asks for it), returned in the rows' order."""
    from tqdm import tqdm

    order = (np.argsort(np.asarray(tokens), kind="stable") if models.family.batch_by_length
             else np.arange(len(tokens)))
    codes: list[Any] = [None] * len(tokens)
    starts = range(0, len(tokens), options.batch_size)
    for start in tqdm(starts, desc=desc, unit="batch", leave=False, disable=not options.progress):
        rows = order[start:start + options.batch_size]
        batch = models.family.codes(np.asarray(cond, np.float32)[rows], [int(tokens[i]) for i in rows], guidance,
                                    options.temperature, options.top_k, generator)
        for row, row_codes in zip(rows, batch):
            codes[row] = row_codes
    return codes


# ------------------------------------------------------------------------------------------- the metrics


def single_motion_metrics(text_emb: np.ndarray, motion_emb: np.ndarray, reference_emb: np.ndarray,
                          options: EvalOptions, seed: int) -> dict[str, float]:
    top = metrics.r_precision(text_emb, motion_emb, top_k=3, pool=options.r_precision_pool, seed=seed)
    return {"top1": float(top[0]), "top2": float(top[1]), "top3": float(top[2]),
            "fid": metrics.fid(reference_emb, motion_emb),
            "mm_dist": metrics.matching_score(text_emb, motion_emb),
            "diversity": metrics.diversity(motion_emb, options.diversity_pairs, seed=seed)}


def mpjpe_mm(real: Sequence[np.ndarray], recon: Sequence[np.ndarray], root_relative: bool = False) -> float:
    """Mean per-joint position error (mm) between the joints recovered from real and reconstructed features.

    Global positions integrate the root velocity channels, so small velocity errors add up to a drift over a clip;
    `root_relative=True` measures the pose alone (every frame's joints minus its pelvis)."""
    from t2m.motion.features import features_to_joints

    def joints(features: np.ndarray) -> np.ndarray:
        positions = features_to_joints(features)
        return positions - positions[:, :1] if root_relative else positions

    errors = [metrics.mpjpe(joints(a), joints(b)) for a, b in zip(real, recon)]
    frames = [len(a) for a in real]
    return 1000.0 * float(np.average(errors, weights=frames))


class TextFeatures:
    """Caption -> frozen text feature, per encoder, encoded once (optionally cached in an .npz)."""

    def __init__(self, captions: Sequence[str], encoders: Sequence[str], cache: str | Path | None = None,
                 encoder_kwargs: dict[str, dict[str, Any]] | None = None,
                 own: dict[str, TextFeatureSource] | None = None):
        """`own`: encoders given as objects (a bundle's text graph), used as they are and never cached."""
        from t2m.model.networks.text_encoders import cache_text_features, get_text_encoder

        unique = list(dict.fromkeys(captions))
        self.table: dict[str, dict[str, np.ndarray]] = {}
        own = own or {}
        for name, source in own.items():
            features = np.concatenate([source.encode(unique[i:i + 256]) for i in range(0, len(unique), 256)])
            self.table[name] = dict(zip(unique, features))
        cached = [name for name in dict.fromkeys(encoders) if name not in own]
        for name in cached:
            encoder = get_text_encoder(name, **(encoder_kwargs or {}).get(name, {}))
            if cache is not None:
                path = Path(cache)
                path = path if len(cached) == 1 else path.with_name(f"{path.stem}_{name}{path.suffix}")
                self.table[name] = cache_text_features(unique, encoder, path)
            else:
                self.table[name] = dict(zip(unique, encoder.encode(unique)))

    def __call__(self, encoder: str, captions: Sequence[str]) -> np.ndarray:
        return np.stack([self.table[encoder][c] for c in captions]).astype(np.float32)


def evaluate(models: Models, reader, options: EvalOptions, text_cache: str | Path | None = None,
             encoder_kwargs: dict[str, dict[str, Any]] | None = None) -> dict[str, Any]:
    """Run `options.repeats` evaluations; returns {"repeats": [per-repeat rows], "summary": mean and CI, ...}."""
    from tqdm import tqdm

    from t2m.motion.features import features_to_joints

    options.check()
    per_token = models.frames_per_token
    clips = read_clips(reader, options.limit, min_frames=per_token)
    max_frames = min(models.evaluator.config.max_frames, per_token * models.family.max_tokens)
    own = {models.family.text_encoder: models.family_text} if models.family_text is not None else None
    texts = TextFeatures([c for cs in clips.captions for c in cs], [models.evaluator_text, models.family.text_encoder],
                         text_cache, encoder_kwargs, own)
    evaluator = models.evaluator

    real_windows = [w for f in clips.features for w in windows(f, options.window, options.stride)]
    real_window_emb = embed_motions(evaluator, real_windows, normalized=False) if len(real_windows) >= 2 else None
    real_within = np.concatenate([pelvis_velocity_jumps(features_to_joints(f))[1] for f in clips.features
                                  if len(f) >= 4])

    n_streams = len(clips.ids) // options.stream_sentences
    if options.streams is not None:
        n_streams = min(n_streams, options.streams)
    runs: list[dict[str, dict[str, float]]] = []
    for repeat in tqdm(range(options.repeats), desc="evaluation repeats", unit="repeat", disable=not options.progress):
        seed = options.seed * 1000 + repeat
        rng = np.random.default_rng(seed)
        generator = np.random.default_rng([seed, 1])   # the sampling stream, apart from the crop draws
        reference, real = draw(clips, max_frames, rng, per_token), draw(clips, max_frames, rng, per_token)
        reference_emb = embed_motions(evaluator, reference.motions, normalized=False)
        text_emb_a = embed_texts(evaluator, texts(models.evaluator_text, reference.captions))
        text_emb_b = embed_texts(evaluator, texts(models.evaluator_text, real.captions))
        row: dict[str, dict[str, float]] = {}
        row["real"] = single_motion_metrics(text_emb_b, embed_motions(evaluator, real.motions, normalized=False),
                                            reference_emb, options, seed)
        row["real"]["pelvis_jump_within"] = float(real_within.mean())

        reference_codes = None
        if models.vq is not None:  # a served bundle has no VQ encoder: no reconstruction row
            reference_codes = reconstruct_codes(models, reference.motions, options.batch_size)
            recon = decode(models, reference_codes, options.batch_size)
            row["recon"] = single_motion_metrics(text_emb_a, embed_motions(evaluator, recon, normalized=False),
                                                 reference_emb, options, seed)
            row["recon"]["mpjpe_mm"] = mpjpe_mm(reference.motions, recon)
            row["recon"]["mpjpe_root_mm"] = mpjpe_mm(reference.motions, recon, root_relative=True)

        cond = texts(models.family.text_encoder, reference.captions)
        tokens = reference.tokens
        mm_index = rng.choice(len(clips.ids), min(options.mm_texts, len(clips.ids)), replace=False)
        stream_order = rng.permutation(len(clips.ids))
        streams = stream_order[:n_streams * options.stream_sentences].reshape(n_streams, options.stream_sentences)
        estimated = models.family.estimate_tokens(cond, generator)
        for guidance in options.guidance:
            name = f"gen_g{guidance:g}"
            codes = sample(models, cond, tokens, guidance, options, generator, f"generate g={guidance:g}")
            generated = decode(models, codes, options.batch_size)
            gen_emb = embed_motions(evaluator, generated, normalized=False)
            row[name] = single_motion_metrics(text_emb_a, gen_emb, reference_emb, options, seed)

            mm_cond = np.repeat(cond[mm_index], options.mm_repeats, axis=0)
            mm_tokens = np.repeat(np.asarray(tokens)[mm_index], options.mm_repeats)
            mm_codes = sample(models, mm_cond, mm_tokens, guidance, options, generator, f"MModality g={guidance:g}")
            mm_emb = embed_motions(evaluator, decode(models, mm_codes, options.batch_size), normalized=False)
            row[name]["mmodality"] = metrics.multimodality(mm_emb.reshape(len(mm_index), options.mm_repeats, -1),
                                                           options.mm_pairs, seed=seed)
            if estimated is not None:
                row[f"free_g{guidance:g}"] = estimated_length_metrics(models, cond, estimated, tokens, guidance,
                                                                      options, generator, text_emb_a, reference_emb,
                                                                      seed)
            if options.multi_sentence and n_streams > 0:
                row[f"multi_g{guidance:g}"] = multi_sentence(models, cond, tokens, streams, guidance, options,
                                                             generator, real_window_emb)
        if options.multi_sentence and n_streams > 0:
            row.update(real_stream_references(models, reference.motions, reference_codes, streams, options,
                                              real_window_emb))
        runs.append(row)
    result: dict[str, Any] = {"options": asdict(options), "models": models.paths,
              "counts": {"clips": len(clips.ids), "real_windows": len(real_windows), "streams_per_repeat": n_streams,
                         "max_frames": max_frames},
              "repeats": runs, "summary": summarise(runs)}
    if models.family.settings:
        result["family"], result["decoding"] = models.family.name, models.family.settings
    result["report"] = {"labels": {**MODEL_LABELS, **models.family.labels}, "joined": models.family.joined,
                        "decoding": models.family.report_note()}
    return result


def estimated_length_metrics(models: Models, cond: np.ndarray, estimated: Sequence[int], tokens: Sequence[int],
                             guidance: float, options: EvalOptions, generator: np.random.Generator,
                             text_emb: np.ndarray, reference_emb: np.ndarray, seed: int) -> dict[str, float]:
    """Generation at the lengths the family's own estimator drew (a null duration in the service), plus how far
    those lengths are from the crops' (mean absolute error in tokens)."""
    codes = sample(models, cond, estimated, guidance, options, generator, f"estimated lengths g={guidance:g}")
    motions = decode(models, codes, options.batch_size)
    result = single_motion_metrics(text_emb, embed_motions(models.evaluator, motions, normalized=False),
                                   reference_emb, options, seed)
    result["length_mae_tokens"] = float(np.mean(np.abs(np.asarray(estimated) - np.asarray(tokens))))
    return result


def multi_sentence(models: Models, cond: np.ndarray, tokens: Sequence[int], streams: np.ndarray, guidance: float,
                   options: EvalOptions, generator: np.random.Generator,
                   real_window_emb: np.ndarray | None) -> dict[str, float]:
    """T2LM's streams: per-sentence codes, concatenated, decoded once; sliding/transition FID and pelvis jumps. A
    family that samples whole streams itself (`sample_streams`: the diffusion family's chained calls and joins) gets
    each stream as one request."""
    flat = streams.reshape(-1)
    if isinstance(models.family, StreamFamily):
        per_stream = []
        for start in range(0, len(streams), options.batch_size):
            chunk = streams[start:start + options.batch_size]
            per_stream += models.family.sample_streams([cond[stream] for stream in chunk],
                                                       [[int(tokens[i]) for i in stream] for stream in chunk],
                                                       guidance, generator)
    else:
        codes = sample(models, cond[flat], np.asarray(tokens)[flat], guidance, options, generator,
                       f"streams g={guidance:g}")
        per_stream = [codes[i:i + streams.shape[1]] for i in range(0, len(codes), streams.shape[1])]
    motions = decode(models, [np.concatenate([np.asarray(segment) for segment in stream]) for stream in per_stream],
                     options.batch_size)
    lengths = [[models.frames_per_token * len(segment) for segment in stream] for stream in per_stream]
    return stream_metrics(models.evaluator, motions, lengths, options, real_window_emb)


def real_stream_references(models: Models, motions: Sequence[np.ndarray], codes: Sequence[np.ndarray] | None,
                           streams: np.ndarray, options: EvalOptions,
                           real_window_emb: np.ndarray | None) -> dict[str, dict[str, float]]:
    """The streams' own real crops (`motions`, with their VQ `codes`), pasted with hard cuts ("pasted") and as their
    codes concatenated and decoded once ("pasted_codes", only with a VQ encoder): the scale against which the
    generated streams' joins are read."""
    lengths = [[len(motions[i]) for i in stream] for stream in streams]
    pasted = [np.concatenate([motions[i] for i in stream]) for stream in streams]
    result = {"pasted": stream_metrics(models.evaluator, pasted, lengths, options, real_window_emb)}
    if codes is not None:
        decoded = decode(models, [np.concatenate([codes[i] for i in stream]) for stream in streams],
                         options.batch_size)
        result["pasted_codes"] = stream_metrics(models.evaluator, decoded, lengths, options, real_window_emb)
    return result


def stream_metrics(evaluator: MotionEvaluator | None, motions: Sequence[np.ndarray],
                   segment_frames: Sequence[Sequence[int]], options: EvalOptions,
                   real_window_emb: np.ndarray | None) -> dict[str, float]:
    """Sliding/transition-scope FID and pelvis jumps of raw stream motions whose segments have the given lengths."""
    from t2m.motion.features import features_to_joints

    sliding, transition, at_joins, inside = [], [], [], []
    for motion, frames in zip(motions, segment_frames):
        joins = [int(j) for j in np.cumsum(frames)[:-1]]
        sliding += windows(motion, options.window, options.stride)
        transition += windows_at_joins(motion, joins, options.window)
        jumps_at, jumps_in = pelvis_velocity_jumps(features_to_joints(motion), joins)
        at_joins.append(jumps_at)
        inside.append(jumps_in)
    result = {"pelvis_jump_joins": float(np.concatenate(at_joins).mean()),
              "pelvis_jump_within": float(np.concatenate(inside).mean())}
    if real_window_emb is None:
        return result
    if evaluator is None:
        raise ValueError("real_window_emb needs the evaluator to embed the stream windows with")
    if len(sliding) >= 2:
        result["sliding_fid"] = metrics.fid(real_window_emb, embed_motions(evaluator, sliding, normalized=False))
    if len(transition) >= 2:
        result["transition_fid"] = metrics.fid(real_window_emb, embed_motions(evaluator, transition, normalized=False))
    return result


def summarise(runs: Sequence[dict[str, dict[str, float]]]) -> dict[str, dict[str, list[float]]]:
    """{row: {metric: [mean, 95% half-width]}} over the repeats."""
    summary: dict[str, dict[str, list[float]]] = {}
    for row in runs[0]:
        summary[row] = {}
        for metric in runs[0][row]:
            values = [run[row][metric] for run in runs if metric in run.get(row, {})]
            summary[row][metric] = list(metrics.mean_confidence_interval(values))
    return summary


# ------------------------------------------------------------------------------------------- the report

TABLE1_COLUMNS = [("top1", "Top-1 ↑", 3), ("top2", "Top-2 ↑", 3), ("top3", "Top-3 ↑", 3), ("fid", "FID ↓", 4),
                  ("mm_dist", "MM-Dist ↓", 3), ("diversity", "Diversity →", 3), ("mmodality", "MModality ↑", 3),
                  ("mpjpe_mm", "MPJPE (mm) ↓", 1), ("mpjpe_root_mm", "MPJPE root-rel. (mm) ↓", 1)]
TABLE2_COLUMNS = [("sliding_fid", "Sliding-scope FID ↓", 4), ("transition_fid", "Transition-scope FID ↓", 4),
                  ("pelvis_jump_joins", "Pelvis Δv at joins (m/s) ↓", 3),
                  ("pelvis_jump_within", "Pelvis Δv within segments (m/s)", 3)]


def _row_label(row: str) -> str:
    if row == "real":
        return "Real motion"
    if row == "recon":
        return "VQ reconstruction"
    if row == "pasted":
        return "Real crops pasted (hard cuts)"
    if row == "pasted_codes":
        return "Real crops' VQ codes, decoded once"
    kind, guidance = row.split("_g")
    if kind == "free":
        return f"Generation, estimated lengths (guidance={guidance})"
    return f"Generation (guidance={guidance})" if kind == "gen" else f"Streams (guidance={guidance})"


def _cell(values: list[float] | None, digits: int) -> str:
    if values is None:
        return "-"
    mean, half = values
    if not math.isfinite(mean):
        return "nan"
    return f"{mean:.{digits}f}±{half:.{digits}f}"


def _table(summary: dict[str, dict[str, list[float]]], rows: list[str], columns) -> list[str]:
    lines = ["| Method | " + " | ".join(title for _, title, _ in columns) + " |",
             "| --- | " + " | ".join("---:" for _ in columns) + " |"]
    for row in rows:
        cells = [_cell(summary[row].get(key), digits) for key, _, digits in columns]
        lines.append(f"| {_row_label(row)} | " + " | ".join(cells) + " |")
    return lines


MODEL_LABELS = {"evaluator": "evaluator", "vq": "VQ"}   # the family adds its runs' labels (CodeFamily.labels)


def _models_line(result: dict[str, Any]) -> str:
    """The runs evaluated, and the family's note on its decoding settings."""
    report = result.get("report", {})
    labels = report.get("labels", MODEL_LABELS)
    runs = ", ".join(f"{labels.get(name, name)} `{path}`" for name, path in result["models"].items())
    note = report.get("decoding")
    return f"Models: {runs}." + (f" {note}" if note else "")


def format_report(result: dict[str, Any], title: str = "Evaluation") -> str:
    """The markdown report: Table 1 (single sentences) and Table 2 (streams of sentences)."""
    summary, options, counts = result["summary"], result["options"], result["counts"]
    single = ["real"] + [r for r in summary if r == "recon" or r.startswith(("gen_", "free_"))]
    lines = [f"# {title}", "",
             f"Split `{options['split']}`: {counts['clips']} clips; {options['repeats']} repeats "
             f"(mean ± 95% interval); seed {options['seed']}; sampling temperature {options['temperature']:g}, "
             f"top-k {options['top_k'] or 'off'}.",
             _models_line(result),
             "Embeddings come from our own contrastive evaluator (t2m/model/evaluator.py), not Guo et al.'s: the "
             "numbers compare our models with each other, not with published tables.", "",
             "## Table 1: text-to-motion (one sentence per motion)", "",
             f"R-precision is {min(options['r_precision_pool'], counts['clips'])}-way; Diversity over "
             f"{min(options['diversity_pairs'], counts['clips'])} pairs; MModality over "
             f"{min(options['mm_texts'], counts['clips'])} texts x {options['mm_repeats']} motions "
             f"({min(options['mm_pairs'], options['mm_repeats'])} pairs each); MPJPE on joints recovered from the "
             f"features, in mm: global positions (the root trajectory is integrated from velocities, so its drift "
             f"counts) and root-relative (each frame's pose around its pelvis).", ""]
    if "recon" not in summary:
        lines[-1:] = ["No VQ reconstruction row: a served bundle has the VQ's decoder but not its encoder.", ""]
    lines += _table(summary, single, TABLE1_COLUMNS)
    free = [r for r in single if r.startswith("free_")]
    if free:  # the same draws for every guidance scale
        error = _cell(summary[free[0]]["length_mae_tokens"], 2)
        lines += ["", f"Estimated lengths: the length estimator's draws are {error} tokens (mean absolute error) "
                      f"from the crops' lengths."]
    multi = [r for r in summary if r.startswith("multi_")] + [r for r in ("pasted", "pasted_codes") if r in summary]
    if multi:
        joined = result.get("report", {}).get("joined", "codes concatenated")
        lines += ["", f"## Table 2: streams of {options['stream_sentences']} sentences (T2LM's multi-sentence metrics)",
                  "",
                  f"{counts['streams_per_repeat']} streams per repeat; each sentence generated for its own duration, "
                  f"{joined} and decoded once. FIDs against {counts['real_windows']} real "
                  f"{options['window']}-frame windows (stride {options['stride']}); transition windows are centred on "
                  f"the joins. Pelvis Δv: change of the pelvis velocity between consecutive frames (the Real motion "
                  f"row: inside real clips). " + (
                      "The last two rows put the same streams' real crops together instead of generating them: with "
                      "hard cuts, and as their VQ codes decoded once." if "pasted_codes" in summary else
                      "The last row puts the same streams' real crops together with hard cuts instead of generating "
                      "them."), ""]
        lines += _table(summary, ["real"] + multi, TABLE2_COLUMNS)
    return "\n".join(lines) + "\n"


def write_report(result: dict[str, Any], markdown_path: str | Path, json_path: str | Path | None = None,
                 title: str = "Evaluation") -> str:
    text = format_report(result, title)
    markdown_path = Path(markdown_path)
    markdown_path.parent.mkdir(parents=True, exist_ok=True)
    markdown_path.write_text(text, encoding="utf-8")
    json_path = Path(json_path) if json_path else markdown_path.with_suffix(".json")
    json_path.write_text(json.dumps(result, indent=2) + "\n", encoding="utf-8")
    return text
