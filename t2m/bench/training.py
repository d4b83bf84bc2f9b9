"""Training throughput (samples/s) of the VQ-VAE and the GPT on this machine, to size real runs.

Times full training steps (forward, loss, backward, AdamW update) on random batches of the real shapes:
VQ windows [B, 64, 263]; GPT sequences of 50 codes + condition. Prints one line per configuration.

    t2m bench training --threads 2 --steps 8
"""
from __future__ import annotations

import argparse
import os
import time

import torch


def time_steps(step, steps: int, warmup: int = 2) -> tuple[float, float]:
    """(wall seconds, CPU seconds of this process) per step. On a shared machine the CPU time tells what the
    step costs; wall time tells what this run got."""
    for _ in range(warmup):
        step()
    wall, cpu = time.perf_counter(), time.process_time()
    for _ in range(steps):
        step()
    return (time.perf_counter() - wall) / steps, (time.process_time() - cpu) / steps


def bench_vq(width: int, batch: int, window: int, steps: int) -> tuple[float, float, int]:
    from t2m.model.networks.vqvae import MotionVQVAE, VQConfig
    from t2m.model.training.train_vq import vq_loss

    model = MotionVQVAE(VQConfig(width=width, code_dim=width, nb_code=512)).train()
    optimizer = torch.optim.AdamW(model.parameters(), lr=2e-4)
    x = torch.randn(batch, window, 263)

    def step() -> None:
        loss, _ = vq_loss(model, x)
        optimizer.zero_grad(set_to_none=True)
        loss.backward()
        optimizer.step()

    wall, cpu = time_steps(step, steps)
    return batch / wall, batch / cpu, sum(p.numel() for p in model.parameters())


def bench_gpt(embed: int, layers: int, heads: int, batch: int, steps: int) -> tuple[float, float, int]:
    from t2m.families.gpt.network import GPTConfig, MotionGPT
    from t2m.families.gpt.training import next_token_loss

    config = GPTConfig(codebook_size=512, embed=embed, n_head=heads, n_layer_base=layers - layers // 2,
                       n_layer_head=layers // 2, block_size=51, text_dim=384)
    model = MotionGPT(config).train()
    optimizer = torch.optim.AdamW(model.parameters(), lr=2e-4)
    cond = torch.randn(batch, 384)
    tokens = torch.randint(0, 514, (batch, 51))
    length = torch.randint(0, 51, (batch,))

    def step() -> None:
        loss, _ = next_token_loss(model, cond, tokens[:, :-1], tokens, length)
        optimizer.zero_grad(set_to_none=True)
        loss.backward()
        torch.nn.utils.clip_grad_norm_(model.parameters(), 1.0)
        optimizer.step()

    wall, cpu = time_steps(step, steps)
    return batch / wall, batch / cpu, model.num_parameters()


def report(label: str, params: int, rate: float, per_cpu: float, batch: int) -> None:
    print(f"{label} params={params / 1e6:5.2f}M  {rate:7.1f} samples/s wall ({rate / batch * 3600:6.0f} steps/h)  "
          f"{per_cpu:7.1f} samples per CPU-second", flush=True)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--steps", type=int, default=8)
    parser.add_argument("--batch-size", type=int, default=64)
    parser.add_argument("--only", choices=("vq", "gpt"), default=None)
    args = parser.parse_args(argv)
    torch.set_num_threads(args.threads)
    torch.manual_seed(0)
    print(f"torch {torch.__version__}, threads {torch.get_num_threads()}, batch {args.batch_size}, "
          f"load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} cpus")
    if args.only in (None, "vq"):
        for width in (128, 256):
            rate, per_cpu, params = bench_vq(width, args.batch_size, 64, args.steps)
            report(f"vq  width={width:<4} code_dim={width:<4} window=64", params, rate, per_cpu, args.batch_size)
    if args.only in (None, "gpt"):
        for embed, layers, heads in ((256, 4, 4), (256, 6, 4), (384, 4, 6), (384, 6, 6)):
            rate, per_cpu, params = bench_gpt(embed, layers, heads, args.batch_size, args.steps)
            report(f"gpt embed={embed:<4} layers={layers} heads={heads}  ", params, rate, per_cpu, args.batch_size)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
