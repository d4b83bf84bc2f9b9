"""Vector quantisers for the motion VQ-VAE.

All quantisers take latents laid out time-major, ``[B, T, D]``, and return
``(quantized [B, T, D], codes, loss, perplexity)`` where ``quantized`` carries
straight-through gradients to the encoder, ``codes`` are int64 (``[B, T]``, or
``[B, T, R]`` for the residual quantiser), ``loss`` is the quantiser's own loss
(commitment, plus the codebook loss for the plain quantiser) and ``perplexity``
measures codebook usage in the batch (exp of the code distribution's entropy).

``codes_to_latent(codes)`` is the decoding path (also what the ONNX decoder runs).

Key names follow T2M-GPT / MoMask so released weights load 1:1:
``codebook`` [K, D] for one quantiser, ``layers.{i}.codebook`` for the residual one.
"""
from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn

QuantizerOutput = tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]


def nearest_codes(x: torch.Tensor, codebook: torch.Tensor) -> torch.Tensor:
    """Index of the nearest codebook row (squared L2) for each row of ``x`` [N, D]."""
    distances = (
        x.pow(2).sum(dim=1, keepdim=True)
        - 2.0 * x @ codebook.t()
        + codebook.pow(2).sum(dim=1)[None, :]
    )
    return distances.argmin(dim=1)


def code_perplexity(codes: torch.Tensor, nb_code: int) -> torch.Tensor:
    """exp(entropy) of the batch's code histogram: nb_code when all codes are used equally, 1 when one is."""
    counts = torch.bincount(codes.reshape(-1), minlength=nb_code).float()
    probs = counts / counts.sum().clamp(min=1.0)
    return torch.exp(-(probs * torch.log(probs + 1e-10)).sum())


class EMAResetQuantizer(nn.Module):
    """T2M-GPT's quantiser: codebook updated by exponential moving averages, dead codes reset to batch vectors.

    The codebook is a buffer (no gradients). In training mode each forward pass
    (1) initialises the codebook from the first batch, (2) moves every code to the
    EMA of the latents assigned to it, and (3) replaces codes whose EMA usage count
    fell below ``reset_threshold`` by random latents of the current batch, which keeps
    the whole codebook alive. The loss is the commitment term ||x - sg(q)||^2.
    """

    codebook: torch.Tensor
    code_sum: torch.Tensor
    code_count: torch.Tensor
    initialized: torch.Tensor

    def __init__(self, nb_code: int, code_dim: int, mu: float = 0.99, reset_threshold: float = 1.0) -> None:
        super().__init__()
        self.nb_code = nb_code
        self.code_dim = code_dim
        self.mu = mu
        self.reset_threshold = reset_threshold
        self.register_buffer("codebook", torch.randn(nb_code, code_dim) / code_dim**0.5)
        # EMA statistics are training state only: not part of the released key set (resume.pt keeps them).
        self.register_buffer("code_sum", torch.zeros(nb_code, code_dim), persistent=False)
        self.register_buffer("code_count", torch.zeros(nb_code), persistent=False)
        self.register_buffer("initialized", torch.tensor(False), persistent=False)
        self._register_load_state_dict_pre_hook(self._mark_loaded_codebook)

    def _mark_loaded_codebook(self, state_dict, prefix, *args, **kwargs) -> None:
        """A loaded codebook is a trained one: seed the EMA from it instead of re-initialising from a batch."""
        codebook = state_dict.get(prefix + "codebook")
        if codebook is not None and codebook.shape == self.codebook.shape:
            with torch.no_grad():
                self.code_sum.copy_(codebook)
                self.code_count.fill_(1.0)
                self.initialized.fill_(True)

    def _random_batch_vectors(self, flat: torch.Tensor) -> torch.Tensor:
        """nb_code random rows of the batch; a small batch is tiled with a little noise (as T2M-GPT does)."""
        n = flat.shape[0]
        if n < self.nb_code:
            repeats = (self.nb_code + n - 1) // n
            std = 0.01 / self.code_dim**0.5
            flat = flat.repeat(repeats, 1)
            flat = flat + torch.randn_like(flat) * std
        return flat[torch.randperm(flat.shape[0], device=flat.device)[: self.nb_code]]

    def update(self, flat: torch.Tensor, codes: torch.Tensor) -> None:
        """The EMA update (and dead-code reset) from latents [N, D] assigned to codes [N] (training only)."""
        self._ema_update(flat.detach(), codes)

    @torch.no_grad()
    def _ema_update(self, flat: torch.Tensor, codes: torch.Tensor) -> None:
        if not bool(self.initialized):
            self.codebook.copy_(self._random_batch_vectors(flat))
            self.code_sum.copy_(self.codebook)
            self.code_count.fill_(1.0)
            self.initialized.fill_(True)
            return
        onehot = F.one_hot(codes, self.nb_code).type_as(flat)  # [N, K]
        self.code_sum.mul_(self.mu).add_(onehot.t() @ flat, alpha=1.0 - self.mu)
        self.code_count.mul_(self.mu).add_(onehot.sum(dim=0), alpha=1.0 - self.mu)
        alive = (self.code_count >= self.reset_threshold).unsqueeze(1).type_as(flat)
        updated = self.code_sum / self.code_count.clamp(min=1e-6).unsqueeze(1)
        self.codebook.copy_(alive * updated + (1.0 - alive) * self._random_batch_vectors(flat))

    def initialize_from(self, flat: torch.Tensor) -> None:
        """In training, the first batch's latents [N, D] become the codebook (no-op once initialised)."""
        if self.training and not bool(self.initialized):
            self._ema_update(flat.detach(), torch.zeros(0, dtype=torch.long, device=flat.device))

    def assign(self, flat: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Nearest codes of latents [N, D] and their vectors (a copy: a later EMA update does not change them)."""
        codes = nearest_codes(flat.detach(), self.codebook)
        return codes, F.embedding(codes, self.codebook).clone()

    def forward(self, x: torch.Tensor) -> QuantizerOutput:
        batch, time, dim = x.shape
        flat = x.reshape(-1, dim)
        self.initialize_from(flat)
        codes, vectors = self.assign(flat)
        quantized = vectors.view(batch, time, dim)  # the codebook before this step
        if self.training:
            self._ema_update(flat.detach(), codes)
        perplexity = code_perplexity(codes, self.nb_code)
        loss = F.mse_loss(x, quantized.detach())
        quantized = x + (quantized - x).detach()  # straight-through estimator
        return quantized, codes.view(batch, time), loss, perplexity

    def codes_to_latent(self, codes: torch.Tensor) -> torch.Tensor:
        """[B, T] int64 -> [B, T, D]."""
        return F.embedding(codes, self.codebook)


class PlainQuantizer(nn.Module):
    """VQ-VAE's original quantiser: the codebook is a parameter learned by the codebook loss ||sg(x) - q||^2.

    loss = codebook loss + beta * commitment loss (van den Oord et al.: beta = 0.25); train it with a
    quantiser-loss weight of 1 (train_vq picks that for 'plain'). The codebook starts as random latents of
    the first training batch: a random init far from the encoder's scale leaves most codes unused.
    """

    initialized: torch.Tensor

    def __init__(self, nb_code: int, code_dim: int, beta: float = 0.25) -> None:
        super().__init__()
        self.nb_code = nb_code
        self.code_dim = code_dim
        self.beta = beta
        self.codebook = nn.Parameter(torch.empty(nb_code, code_dim).uniform_(-1.0 / nb_code, 1.0 / nb_code))
        self.register_buffer("initialized", torch.tensor(False), persistent=False)
        self._register_load_state_dict_pre_hook(self._mark_loaded_codebook)

    def _mark_loaded_codebook(self, state_dict, prefix, *args, **kwargs) -> None:
        if prefix + "codebook" in state_dict:
            self.initialized.fill_(True)

    def forward(self, x: torch.Tensor) -> QuantizerOutput:
        batch, time, dim = x.shape
        flat = x.reshape(-1, dim)
        if self.training and not bool(self.initialized):
            with torch.no_grad():
                rows = flat.detach()
                rows = rows.repeat((self.nb_code + len(rows) - 1) // len(rows), 1)
                rows = rows + 0.01 / dim**0.5 * torch.randn_like(rows)
                self.codebook.copy_(rows[torch.randperm(len(rows), device=x.device)[: self.nb_code]])
                self.initialized.fill_(True)
        codes = nearest_codes(flat.detach(), self.codebook.detach())
        quantized = F.embedding(codes, self.codebook).view(batch, time, dim)
        codebook_loss = F.mse_loss(quantized, x.detach())
        commitment = F.mse_loss(x, quantized.detach())
        quantized = x + (quantized - x).detach()
        loss = codebook_loss + self.beta * commitment
        return quantized, codes.view(batch, time), loss, code_perplexity(codes, self.nb_code)

    def codes_to_latent(self, codes: torch.Tensor) -> torch.Tensor:
        """[B, T] int64 -> [B, T, D]."""
        return F.embedding(codes, self.codebook)


class ResidualQuantizer(nn.Module):
    """R EMA-reset quantisers in a chain, each quantising what the previous ones left over (MoMask's RVQ).

    Quantiser dropout (training only): with probability ``dropout`` only the first
    r ~ U{1..R} layers are used, so the first layers learn to carry a coarse motion
    on their own. Codes of unused layers are -1. The latent is the sum of the layers'
    codebook vectors; ``perplexity`` is the first layer's.

    ``shared=True`` is T2M-HiFiGPT's variant: one codebook serves every depth (its key is ``layers.0.codebook``),
    so the greedy search picks R codes of one dictionary whose sum approximates the latent. Its EMA update pools the
    residuals of all depths of a batch into one update (R separate updates would drag the codes towards whichever
    depth came last), and dead codes are reset to residuals of any depth.
    """

    def __init__(
        self, nb_code: int, code_dim: int, num_layers: int = 6, dropout: float = 0.2, mu: float = 0.99,
        shared: bool = False,
    ) -> None:
        super().__init__()
        if num_layers < 1:
            raise ValueError(f"residual_layers must be >= 1, got {num_layers}")
        self.nb_code = nb_code
        self.code_dim = code_dim
        self.num_layers = num_layers
        self.dropout = dropout
        self.shared = shared
        books = 1 if shared else num_layers
        self.layers = nn.ModuleList(EMAResetQuantizer(nb_code, code_dim, mu=mu) for _ in range(books))
        self.last_active_layers = num_layers  # for tests and logging

    def layer(self, depth: int) -> EMAResetQuantizer:
        """The quantiser (codebook) of a depth: its own, or the shared one."""
        layer = self.layers[0 if self.shared else depth]
        assert isinstance(layer, EMAResetQuantizer)
        return layer

    def codebooks(self) -> torch.Tensor:
        """The codebooks [books, K, D] (books = 1 when shared, else R), in depth order."""
        return torch.stack([self.layer(index).codebook for index in range(len(self.layers))])

    def _active_layers(self) -> int:
        if self.training and self.num_layers > 1 and torch.rand(()).item() < self.dropout:
            return int(torch.randint(1, self.num_layers + 1, ()).item())
        return self.num_layers

    def forward(self, x: torch.Tensor) -> QuantizerOutput:
        active = self._active_layers()
        self.last_active_layers = active
        if self.shared:
            quantized_sum, codes, loss = self._shared_chain(x, active)
        else:
            quantized_sum, codes, loss = self._chain(x, active)
        perplexity = code_perplexity(codes[..., 0], self.nb_code)
        # Straight-through for the whole chain; each depth's commitment loss already pulls the encoder.
        quantized = x + (quantized_sum - x).detach()
        return quantized, codes, loss, perplexity

    def _chain(self, x: torch.Tensor, active: int) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """One quantiser per depth, each updating its own codebook."""
        residual = x
        quantized_sum = torch.zeros_like(x)
        codes = torch.full((*x.shape[:2], self.num_layers), -1, dtype=torch.long, device=x.device)
        loss = x.new_zeros(())
        for index in range(active):
            quantized, layer_codes, layer_loss, _ = self.layer(index)(residual)
            residual = residual - quantized.detach()
            quantized_sum = quantized_sum + quantized.detach()
            codes[:, :, index] = layer_codes
            loss = loss + layer_loss
        return quantized_sum, codes, loss

    def _shared_chain(self, x: torch.Tensor, active: int) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """The greedy search of eq. (1) over one codebook, then one pooled EMA update."""
        layer = self.layer(0)
        batch, time, dim = x.shape
        residual = x.reshape(-1, dim).detach()
        layer.initialize_from(residual)
        quantized_sum = torch.zeros_like(residual)
        codes = torch.full((batch, time, self.num_layers), -1, dtype=torch.long, device=x.device)
        loss = x.new_zeros(())
        seen, chosen = [], []
        for index in range(active):
            depth_codes, vectors = layer.assign(residual)
            loss = loss + F.mse_loss(x.reshape(-1, dim) - quantized_sum, vectors)
            seen.append(residual)
            chosen.append(depth_codes)
            residual = residual - vectors
            quantized_sum = quantized_sum + vectors
            codes[:, :, index] = depth_codes.view(batch, time)
        if self.training:
            layer.update(torch.cat(seen), torch.cat(chosen))
        return quantized_sum.view(batch, time, dim), codes, loss

    def codes_to_latent(self, codes: torch.Tensor) -> torch.Tensor:
        """[B, T, R'] (R' <= R, first R' layers) or [B, T] (first layer only) -> [B, T, D], layers summed;
        -1 = unused."""
        if codes.dim() == 2:
            codes = codes.unsqueeze(-1)
        latent = self._layer_latent(0, codes[..., 0])
        for index in range(1, codes.shape[-1]):
            latent = latent + self._layer_latent(index, codes[..., index])
        return latent

    def _layer_latent(self, index: int, codes: torch.Tensor) -> torch.Tensor:
        """One layer's vectors; a code of -1 (layer unused, as quantiser dropout writes) contributes zeros."""
        layer = self.layer(index)
        used = (codes >= 0).unsqueeze(-1).to(layer.codebook.dtype)
        return layer.codes_to_latent(codes.clamp(min=0)) * used
