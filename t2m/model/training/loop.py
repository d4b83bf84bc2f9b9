"""Pieces shared by the training loops: seeding, optimiser and schedule, logging, checkpoints, resume.

:func:`run_training` drives any model given a ``step_fn(model, batch) -> (loss, metrics, samples)``:
AdamW with linear warm-up then step decay, tqdm progress, a CSV log (log.csv), a text log
(train.log), periodic validation, checkpoints (model.safetensors + config.json) and
curves.png, and resume from resume.pt (optimiser, schedule, RNG states and every buffer,
including the quantiser's non-persistent EMA statistics).
"""
from __future__ import annotations

import csv
import logging
import math
import random
import time
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, TypeVar

import numpy as np
import torch
from torch import nn

from t2m.model.training.checkpoint import save_checkpoint

RESUME_FILE = "resume.pt"
LOG_CSV = "log.csv"
TRAIN_LOG = "train.log"
CURVES = "curves.png"

ModelT = TypeVar("ModelT", bound=nn.Module)
# (model, batch) -> (loss, metrics, samples in the batch); model -> validation metrics
StepFn = Callable[[ModelT, Any], tuple[torch.Tensor, dict[str, float], int]]
ValFn = Callable[[ModelT], dict[str, float]]


@dataclass
class LoopSettings:
    steps: int = 10_000
    lr: float = 2e-4
    weight_decay: float = 0.0
    betas: tuple[float, float] = (0.9, 0.99)
    warmup_steps: int = 500
    lr_milestones: tuple[float, ...] = (0.7,)  # fractions of `steps` where the LR is multiplied by lr_gamma
    lr_gamma: float = 0.1
    grad_clip: float | None = 1.0
    log_every: int = 50
    val_every: int = 1000
    save_every: int = 1000
    seed: int = 0
    extra: dict[str, Any] = field(default_factory=dict)


def set_seed(seed: int) -> None:
    random.seed(seed)
    np.random.seed(seed % 2**32)
    torch.manual_seed(seed)


def set_threads(threads: int | None) -> None:
    if threads:
        torch.set_num_threads(threads)


def make_optimizer(model: nn.Module, settings: LoopSettings) -> torch.optim.AdamW:
    """AdamW; weight decay only on matrices of Linear/Conv layers (not biases, norms, embeddings, codebooks)."""
    decay: list[nn.Parameter] = []
    no_decay: list[nn.Parameter] = []
    for name, parameter in model.named_parameters():
        if not parameter.requires_grad:
            continue
        plain_matrix = parameter.dim() >= 2 and not any(k in name for k in ("emb", "codebook", "pos"))
        (decay if plain_matrix else no_decay).append(parameter)
    groups = [{"params": decay, "weight_decay": settings.weight_decay}, {"params": no_decay, "weight_decay": 0.0}]
    return torch.optim.AdamW(groups, lr=settings.lr, betas=settings.betas)


def lr_factor(step: int, settings: LoopSettings) -> float:
    """Linear warm-up to 1 over warmup_steps, then x lr_gamma at each milestone fraction of the run."""
    if settings.warmup_steps and step < settings.warmup_steps:
        return (step + 1) / settings.warmup_steps
    passed = sum(1 for m in settings.lr_milestones if step >= int(m * settings.steps))
    return settings.lr_gamma**passed


def infinite(loader: Iterable) -> Iterator:
    """Cycle a DataLoader forever (a new shuffle each pass)."""
    while True:
        yielded = False
        for batch in loader:
            yielded = True
            yield batch
        if not yielded:
            raise ValueError("the training data loader is empty")


def all_buffers(model: nn.Module) -> dict[str, torch.Tensor]:
    """Every buffer, persistent or not (the EMA statistics of a quantiser are not in state_dict)."""
    return {name: buffer.detach().clone() for name, buffer in model.named_buffers()}


def save_resume(run_dir: Path, model: nn.Module, optimizer: torch.optim.Optimizer, step: int) -> None:
    state = {
        "step": step,
        "model": model.state_dict(),
        "buffers": all_buffers(model),
        "optimizer": optimizer.state_dict(),
        "rng": {
            "torch": torch.get_rng_state(),
            "numpy": np.random.get_state(),
            "python": random.getstate(),
        },
    }
    tmp = run_dir / (RESUME_FILE + ".tmp")
    torch.save(state, tmp)
    tmp.replace(run_dir / RESUME_FILE)


def load_resume(run_dir: Path, model: nn.Module, optimizer: torch.optim.Optimizer) -> int:
    """Restore the state saved by save_resume; returns the step to continue from."""
    path = run_dir / RESUME_FILE
    if not path.is_file():
        raise FileNotFoundError(str(path))
    state = torch.load(path, map_location="cpu", weights_only=False)
    model.load_state_dict(state["model"])
    buffers = dict(model.named_buffers())
    with torch.no_grad():
        for name, value in state["buffers"].items():
            if name in buffers:
                buffers[name].copy_(value)
    optimizer.load_state_dict(state["optimizer"])
    torch.set_rng_state(state["rng"]["torch"])
    np.random.set_state(state["rng"]["numpy"])
    random.setstate(state["rng"]["python"])
    return int(state["step"])


def make_logger(run_dir: Path, name: str) -> logging.Logger:
    """Logger writing to <run_dir>/train.log (and to stderr through tqdm.write)."""
    from tqdm import tqdm

    class TqdmHandler(logging.Handler):
        def emit(self, record: logging.LogRecord) -> None:
            tqdm.write(self.format(record))

    logger = logging.getLogger(f"t2m.train.{name}.{run_dir.resolve()}")
    logger.setLevel(logging.INFO)
    logger.propagate = False
    logger.handlers.clear()
    formatter = logging.Formatter("%(asctime)s %(message)s", "%Y-%m-%d %H:%M:%S")
    file_handler = logging.FileHandler(run_dir / TRAIN_LOG)
    console = TqdmHandler()
    for handler in (file_handler, console):
        handler.setFormatter(formatter)
        logger.addHandler(handler)
    return logger


class CsvLog:
    """Rows of metrics by step in log.csv; columns grow as new metrics appear (the file is rewritten then)."""

    def __init__(self, path: Path, resume_step: int | None = None) -> None:
        self.path = path
        self.rows: list[dict[str, Any]] = []
        if resume_step is not None and path.is_file():
            with path.open(newline="") as handle:
                self.rows = [r for r in csv.DictReader(handle) if int(float(r["step"])) <= resume_step]
        self.columns: list[str] = list(self.rows[0].keys()) if self.rows else ["step"]
        for row in self.rows:
            for key in row:
                if key not in self.columns:
                    self.columns.append(key)
        self._rewrite()

    def _rewrite(self) -> None:
        with self.path.open("w", newline="") as handle:
            writer = csv.DictWriter(handle, fieldnames=self.columns)
            writer.writeheader()
            writer.writerows(self.rows)

    def append(self, row: dict[str, Any]) -> None:
        self.rows.append(row)
        new = [k for k in row if k not in self.columns]
        if new:
            self.columns += new
            self._rewrite()
        else:
            with self.path.open("a", newline="") as handle:
                csv.DictWriter(handle, fieldnames=self.columns).writerow(row)

    def plot(self, path: Path) -> None:
        """curves.png: one panel per metric, train and val values against the step."""
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        skip = {"step", "lr", "samples_per_s", "step_s", "elapsed_s"}
        names = sorted({c.removeprefix("val_") for c in self.columns if c not in skip})
        if not names:
            return
        columns = min(3, len(names))
        rows = math.ceil(len(names) / columns)
        figure, axes = plt.subplots(rows, columns, figsize=(4.5 * columns, 3.2 * rows), squeeze=False)
        for axis, name in zip(axes.flat, names):
            for column, style in ((name, "-"), (f"val_{name}", "o-")):
                points = [
                    (float(r["step"]), float(r[column]))
                    for r in self.rows
                    if r.get(column) not in (None, "")
                ]
                if points:
                    axis.plot(*zip(*points), style, label=column, markersize=3)
            axis.set_title(name)
            axis.set_xlabel("step")
            axis.legend(fontsize=7)
        for axis in list(axes.flat)[len(names):]:
            axis.axis("off")
        figure.tight_layout()
        figure.savefig(path, dpi=90)
        plt.close(figure)


def run_training(
    model: ModelT,
    batches: Iterator,
    step_fn: StepFn[ModelT],
    settings: LoopSettings,
    run_dir: str | Path,
    val_fn: ValFn[ModelT] | None = None,
    data_info: dict[str, Any] | None = None,
    resume: bool = False,
    name: str = "train",
    after_update: Callable[[ModelT], None] | None = None,
) -> int:
    """Train until settings.steps; returns the last step. Checkpoints at save_every and at the end.
    ``after_update(model)`` runs after each optimiser step (e.g. an EMA copy of the weights following them)."""
    from tqdm import tqdm

    run_dir = Path(run_dir)
    run_dir.mkdir(parents=True, exist_ok=True)
    optimizer = make_optimizer(model, settings)
    start = 0
    if resume:
        start = load_resume(run_dir, model, optimizer)
    logger = make_logger(run_dir, name)
    log = CsvLog(run_dir / LOG_CSV, resume_step=start if resume else None)
    parameters = sum(p.numel() for p in model.parameters())
    trained = sum(p.numel() for p in model.parameters() if p.requires_grad)
    counted = f"{parameters / 1e6:.2f}M parameters" + (
        f" ({trained:,} trained)" if trained != parameters else "")   # e.g. an EMA copy is not trained
    logger.info(
        f"{name}: {'resuming at' if resume else 'starting at'} step {start} of {settings.steps}; "
        f"{counted}; threads {torch.get_num_threads()}; run dir {run_dir}"
    )

    def checkpoint(step: int) -> None:
        save_checkpoint(run_dir, model, step, data_info)
        save_resume(run_dir, model, optimizer, step)
        log.plot(run_dir / CURVES)

    model.train()
    sums: dict[str, float] = {}
    count, samples, train_seconds = 0, 0, 0.0
    run_start = time.perf_counter()
    progress = tqdm(total=settings.steps, initial=start, desc=name, unit="step", dynamic_ncols=True)
    step = start
    while step < settings.steps:
        factor = lr_factor(step, settings)
        for group in optimizer.param_groups:
            group["lr"] = settings.lr * factor
        step_start = time.perf_counter()  # throughput counts data + forward + backward + update, not validation
        loss, metrics, batch_samples = step_fn(model, next(batches))
        if not torch.isfinite(loss):
            raise FloatingPointError(f"{name}: loss became {loss.item()} at step {step}")
        optimizer.zero_grad(set_to_none=True)
        loss.backward()
        if settings.grad_clip:
            torch.nn.utils.clip_grad_norm_(model.parameters(), settings.grad_clip)
        optimizer.step()
        if after_update is not None:
            after_update(model)
        train_seconds += time.perf_counter() - step_start
        step += 1
        progress.update(1)
        count += 1
        samples += batch_samples
        sums["loss"] = sums.get("loss", 0.0) + float(loss.detach())
        for key, value in metrics.items():
            sums[key] = sums.get(key, 0.0) + float(value)

        row: dict[str, Any] = {}
        if step % settings.log_every == 0 or step == settings.steps:
            row.update({k: round(v / count, 6) for k, v in sums.items()})
            row["samples_per_s"] = round(samples / max(train_seconds, 1e-9), 1)
            row["step_s"] = round(train_seconds / count, 4)
            progress.set_postfix(loss=f"{row['loss']:.4f}", sps=row["samples_per_s"])
            sums, count, samples, train_seconds = {}, 0, 0, 0.0
        if val_fn is not None and (step % settings.val_every == 0 or step == settings.steps):
            values = val_fn(model)
            model.train()
            row.update({f"val_{k}": round(float(v), 6) for k, v in values.items()})
        if row:
            elapsed_s = round(time.perf_counter() - run_start, 1)
            row = {"step": step, "lr": settings.lr * factor, **row, "elapsed_s": elapsed_s}
            log.append(row)
            logger.info(" ".join(f"{k}={v}" for k, v in row.items()))
        if step % settings.save_every == 0 or step == settings.steps:
            checkpoint(step)
    progress.close()
    if start >= settings.steps:
        logger.info(f"{name}: already at step {start} >= {settings.steps}; nothing to do")
    logger.info(f"{name}: done at step {step}; checkpoint in {run_dir}")
    for handler in list(logger.handlers):
        handler.close()
        logger.removeHandler(handler)
    return step
