"""Train a small DiP (the diffusion family's autoregressive model, ../shared/docs/diffusion-models.md §5) on this
project's data: `t2m train dip`.

Per batch (the official trainer's recipe for DiP, at a CPU's size):
- windows of context_len + pred_len frames (20 + 40) of normalised features from the training split, one random
  window of a clip drawn uniformly (or action-balanced, --balance-power) and one of its captions; a clip shorter
  than the window (but with at least --min-pred-frames after the prefix) gives a padded window whose real frames
  are its length (the model masks the rest out of attention: mask_frames, and out of the loss);
- the text: the caption's MiniLM token states (cached once per caption: --text-cache), dropped to the null condition
  (zero states, the real mask kept: what the sampler's guidance feeds) with probability --cond-mask-prob (0.1);
- t uniform over the trained steps (10), x_t = sqrt(abar_t) x0 + sqrt(1 - abar_t) noise on the cosine schedule's
  tables (t2m.families.diffusion.loop.cosine_schedule: the sampler's own), the first context_len frames clean (the
  prefix), the model predicting x0 of the pred_len frames;
- loss = MSE between the predicted and the true x0 over the real predicted frames (the official default: its
  geometric terms, lambda_vel / lambda_rcxyz / lambda_fc, are 0 for HumanML3D and DiP, so none here);
- AdamW, an EMA copy of the weights (model_avg, --ema-decay) updated after every step, saved beside the model in
  the checkpoint (kind "dip": t2m.families.diffusion.network.AveragedMDM); the export takes model_avg.
Validation (fixed windows, captions, t and noise of the val split): the same MSE for the EMA weights and the
trained ones, and the EMA's MSE at the noisiest step (what the first sampling step faces).
Every random draw of a batch comes from torch's global generator, which resume.pt restores, so a resumed run repeats
the uninterrupted one's losses exactly. The run directory gets mean.npy / std.npy (the training statistics).
"""
from __future__ import annotations

import argparse
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from t2m.model.data.balancing import BALANCE_POWER_HELP
from t2m.model.training import run_options

if TYPE_CHECKING:
    import torch

    from t2m.families.diffusion.network import MDM, AveragedMDM
    from t2m.families.diffusion.text_encoders import TokenStateCache, TokenStateEncoder
    from t2m.model.data.datasets import MotionReader

VAL_WINDOWS = 256


def add_arguments(parser: argparse.ArgumentParser) -> None:
    run_options.add_schedule_arguments(parser, steps=16_000, batch_size=64, lr=2e-4, warmup_steps=500)
    parser.add_argument("--text-cache", default=None,
                        help="caption token-state cache (default <out>/text_tokens.npz; shareable between runs)")
    parser.add_argument("--latent", type=int, default=128, help="transformer width (DiP: 512)")
    parser.add_argument("--layers", type=int, default=4, help="decoder layers (DiP: 8)")
    parser.add_argument("--heads", type=int, default=4)
    parser.add_argument("--ff-size", type=int, default=256, help="feed-forward width (DiP: 1024)")
    parser.add_argument("--dropout", type=float, default=0.0,
                        help="dropout (DiP: 0.1; 0 here: it costs a fifth of a CPU step)")
    parser.add_argument("--context-len", type=int, default=20, help="clean prefix frames per call")
    parser.add_argument("--pred-len", type=int, default=40, help="new frames per call")
    parser.add_argument("--diffusion-steps", type=int, default=10, help="trained (and sampled) diffusion steps")
    parser.add_argument("--cond-mask-prob", type=float, default=0.1,
                        help="probability of the null condition (zero text states; guidance needs it > 0)")
    parser.add_argument("--ema-decay", type=float, default=0.999,
                        help="EMA of the weights per step (DiP: 0.9999 over 600k steps)")
    parser.add_argument("--min-pred-frames", type=int, default=10,
                        help="clips need context-len + this many frames (shorter windows are padded and masked)")
    parser.add_argument("--balance-power", type=float, default=1.0, help=BALANCE_POWER_HELP)
    run_options.add_bookkeeping_arguments(parser)


class DipWindows:
    """A split's clips in memory (normalised) with their captions' rows in the token-state cache; ``draw`` makes a
    batch of windows from torch's global generator (so a restored generator repeats it)."""

    def __init__(self, reader: MotionReader, cache: TokenStateCache, context_len: int, pred_len: int,
                 min_pred: int) -> None:
        from t2m.model.data.datasets import normalized_features

        self.context_len, self.pred_len = context_len, pred_len
        self.window = context_len + pred_len
        self.clips: list[np.ndarray] = []
        self.captions: list[list[int]] = []
        self.ids: list[str] = []
        self.captions_of = reader.captions
        for clip_id in reader.ids:
            captions = reader.captions(clip_id)
            features = normalized_features(reader, clip_id)
            if features.shape[0] >= context_len + min_pred and captions:
                self.clips.append(features)
                self.captions.append([cache.index[c] for c in captions])
                self.ids.append(clip_id)
        if not self.clips:
            raise ValueError(f"no clip has {context_len} + {min_pred} frames and a caption "
                             f"(of {len(reader.ids)} clips)")
        self.cache = cache
        self.features = int(self.clips[0].shape[1])

    def __len__(self) -> int:
        return len(self.clips)

    def batch(self, clips: list[int], offsets: list[int], captions: list[int]) -> dict[str, torch.Tensor]:
        """{"motion" [B, window, F] (zero padded), "length" [B] real predicted frames, "text", "text_mask"}."""
        import torch

        motion = torch.zeros(len(clips), self.window, self.features)
        length = torch.zeros(len(clips), dtype=torch.long)
        for b, (clip, offset) in enumerate(zip(clips, offsets)):
            window = self.clips[clip][offset:offset + self.window]
            motion[b, :len(window)] = torch.from_numpy(window)
            length[b] = len(window) - self.context_len
        text, text_mask = self.cache.batch(captions)
        return {"motion": motion, "length": length, "text": text, "text_mask": text_mask}

    def draw(self, batch_size: int, weights: torch.Tensor | None = None,
             generator: torch.Generator | None = None) -> dict[str, torch.Tensor]:
        import torch

        if weights is None:
            clips = torch.randint(0, len(self.clips), (batch_size,), generator=generator).tolist()
        else:
            clips = torch.multinomial(weights, batch_size, replacement=True, generator=generator).tolist()
        offsets, captions = [], []
        for clip in clips:
            spare = max(self.clips[clip].shape[0] - self.window, 0)
            offsets.append(int(torch.randint(0, spare + 1, (), generator=generator)))
            choices = self.captions[clip]
            captions.append(choices[int(torch.randint(0, len(choices), (), generator=generator))])
        return self.batch(clips, offsets, captions)


def noise_tables(steps: int) -> tuple[torch.Tensor, torch.Tensor]:
    """(sqrt(abar_t), sqrt(1 - abar_t)) float32 [steps] of the cosine schedule the sampler uses."""
    import torch

    from t2m.families.diffusion.loop import cosine_schedule

    alphas_cumprod = cosine_schedule(steps).alphas_cumprod
    return (torch.from_numpy(np.sqrt(alphas_cumprod)).float(), torch.from_numpy(np.sqrt(1.0 - alphas_cumprod)).float())


def dip_loss(model: MDM, batch: dict[str, torch.Tensor], cond_mask_prob: float,
             generator: torch.Generator | None = None, t: torch.Tensor | None = None
             ) -> tuple[torch.Tensor, dict[str, float]]:
    """x0 MSE over the real predicted frames of a batch; t (uniform when not given), noise and the null condition
    drawn from ``generator`` (torch's global one when None)."""
    import torch

    c = model.config
    motion, length = batch["motion"], batch["length"]
    prefix, x0 = motion[:, :c.context_len], motion[:, c.context_len:]
    rows = len(motion)
    if t is None:
        t = torch.randint(0, c.diffusion_steps, (rows,), generator=generator)
    noise = torch.randn(x0.shape, generator=generator)
    keep_scale, noise_scale = noise_tables(c.diffusion_steps)
    x_t = keep_scale[t][:, None, None] * x0 + noise_scale[t][:, None, None] * noise
    dropped = torch.rand(rows, generator=generator) < cond_mask_prob
    text = batch["text"] * (~dropped).float()[:, None, None]
    predicted = model(x_t, t, text, batch["text_mask"], length, prefix)
    real = (torch.arange(x0.shape[1])[None, :] < length[:, None]).float()[..., None]
    mse = (((predicted - x0) ** 2) * real).sum() / (real.sum() * x0.shape[-1])
    return mse, {"mse": float(mse.detach())}


def validate(net: AveragedMDM, batches: list[dict[str, torch.Tensor]], seed: int = 0) -> dict[str, float]:
    """The x0 MSE of the EMA and of the trained weights on fixed batches (true condition; t and noise from a fixed
    generator), and the EMA's at the noisiest step."""
    import torch

    net.eval()
    results: dict[str, float] = {}
    with torch.no_grad():
        for key, model, last in (("mse", net.model_avg, False), ("mse_raw", net.model, False),
                                 ("mse_t_max", net.model_avg, True)):
            generator = torch.Generator().manual_seed(seed)
            total, weight = 0.0, 0
            for batch in batches:
                t = torch.full((len(batch["motion"]),), model.config.diffusion_steps - 1) if last else None
                _, metrics = dip_loss(model, batch, 0.0, generator, t)
                total += metrics["mse"] * len(batch["motion"])
                weight += len(batch["motion"])
            results[key] = total / max(weight, 1)
    return results


def _check(args: argparse.Namespace) -> Path:
    out = run_options.check_arguments(args, ("latent", "layers", "heads", "ff_size", "context_len", "pred_len",
                                             "min_pred_frames"), ("dropout", "cond_mask_prob", "balance_power"))
    if args.diffusion_steps < 2:
        raise ValueError(f"--diffusion-steps must be >= 2, got {args.diffusion_steps}")
    if not 0.0 <= args.ema_decay < 1.0:
        raise ValueError(f"--ema-decay must be in [0, 1), got {args.ema_decay}")
    if args.min_pred_frames > args.pred_len:
        raise ValueError(f"--min-pred-frames ({args.min_pred_frames}) must be <= --pred-len ({args.pred_len})")
    if args.latent % args.heads:
        raise ValueError(f"--latent ({args.latent}) must be divisible by --heads ({args.heads})")
    return out


def train(args: argparse.Namespace, encoder: TokenStateEncoder | None = None) -> int:
    """The whole of `t2m train dip`; ``encoder`` replaces MiniLM's token states (tests)."""
    import torch

    from t2m.families.diffusion.network import AveragedMDM, DiffusionConfig
    from t2m.families.diffusion.text_encoders import cache_token_states, minilm_token_encoder
    from t2m.model.data.balancing import run_sampling_weights
    from t2m.model.data.datasets import open_split
    from t2m.model.training.loop import run_training, set_seed, set_threads

    out = _check(args)
    set_threads(args.threads)
    set_seed(args.seed)
    train_reader, val_reader = open_split(args.data, "train"), open_split(args.data, "val")
    out.mkdir(parents=True, exist_ok=True)
    encoder = encoder or minilm_token_encoder()
    cache = cache_token_states([train_reader, val_reader], encoder,
                               Path(args.text_cache) if args.text_cache else out / "text_tokens.npz")
    train_set = DipWindows(train_reader, cache, args.context_len, args.pred_len, args.min_pred_frames)
    val_set = DipWindows(val_reader, cache, args.context_len, args.pred_len, args.min_pred_frames)
    mean, std = np.asarray(train_reader.mean, np.float32), np.asarray(train_reader.std, np.float32)
    np.save(out / "mean.npy", mean)
    np.save(out / "std.npy", std)

    val_generator = torch.Generator().manual_seed(args.seed + 1)   # the same windows and captions every time
    val_batches = [val_set.draw(min(args.batch_size, VAL_WINDOWS - start), generator=val_generator)
                   for start in range(0, VAL_WINDOWS, args.batch_size)]
    weights = run_sampling_weights(train_set.ids, args.balance_power, out, train_set.captions_of)
    weight_tensor = None if weights is None else torch.as_tensor(weights, dtype=torch.float64)

    def batches() -> Any:
        while True:
            yield train_set.draw(args.batch_size, weight_tensor)

    config = DiffusionConfig(
        arch="trans_dec", features=train_set.features, latent_dim=args.latent, layers=args.layers,
        ff_size=args.ff_size, heads=args.heads, dropout=args.dropout, text_dim=cache.dim, text_tokens=True,
        mask_frames=True, pos_embed_max_len=max(args.context_len + args.pred_len, args.diffusion_steps),
        diffusion_steps=args.diffusion_steps, context_len=args.context_len, pred_len=args.pred_len,
        cond_mask_prob=args.cond_mask_prob)
    model = AveragedMDM(config)

    def step_fn(net: AveragedMDM, batch: dict) -> tuple[torch.Tensor, dict[str, float], int]:
        loss, metrics = dip_loss(net.model, batch, args.cond_mask_prob)
        return loss, metrics, len(batch["motion"])

    data_info: dict[str, Any] = {
        "data_dir": str(Path(args.data).resolve()), "train_clips": len(train_set), "val_clips": len(val_set),
        "val_windows": VAL_WINDOWS, "batch_size": args.batch_size, "seed": args.seed,
        "window": {"context_len": args.context_len, "pred_len": args.pred_len,
                   "min_pred_frames": args.min_pred_frames},
        "text_encoder": {"kind": encoder.name, "dim": cache.dim, "max_length": int(encoder.max_length),
                         "pooling": "tokens", "normalize": False, "null_condition": "zeros",
                         "cache_dtype": "float16"},
        "training": {"cond_mask_prob": args.cond_mask_prob, "ema_decay": args.ema_decay,
                     "balance_power": args.balance_power, "loss": "x0 MSE over the real predicted frames",
                     "timesteps": "uniform over the trained steps", "schedule": "cosine"},
        "normalization": {"mean": "mean.npy", "std": "std.npy"},
        "weights_exported": "model_avg",
    }
    run_training(model, batches(), step_fn, run_options.loop_settings(args, grad_clip=1.0), out,
                 val_fn=lambda net: validate(net, val_batches), data_info=data_info, resume=args.resume,
                 name="dip", after_update=lambda net: net.update_average(args.ema_decay))
    return 0


def main(args: argparse.Namespace) -> int:
    return train(args)
