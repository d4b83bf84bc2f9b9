"""The masked transformer (MoMask / MoGenTS): predicts the first-layer codes of a token map from a partly masked one.

Vocabulary: codes 0..K-1, ``mask_id`` = K (a token still to be predicted), ``pad_id`` = K + 1 (beyond the motion's
length; rows past ``length`` are set to it here, so callers may leave anything there, -1 included). Logits cover
the K codes only. The text feature enters as one condition row (``cond_emb``; zeros = the null condition that
classifier-free guidance subtracts). Training masks tokens on the cosine schedule (t2m.families.masked.masking);
sampling
starts from a map of mask tokens and fills it in a few confident steps.

Key names follow MoMask's ``t2m_transformer`` / MoGenTS's ``t2m_transformer_ts``: ``token_emb`` [K + 2, code_dim],
``input_process.poseEmbedding``, ``position_enc.pe`` or ``position2d_enc.pe``, ``cond_emb``,
``seqTransEncoder{,2,3}.layers.{i}.*``, ``output_process.{dense, LayerNorm, poseFinal}``.
"""
from __future__ import annotations

import torch
from torch import nn

from t2m.model.networks.token_transformer import OutputProcess, TokenMapEncoder, TokenTransformerConfig


class MaskedTransformer(TokenMapEncoder):
    """(tokens [B, T, C], cond [B, Dt], length [B]) -> logits [B, T, C, K]."""

    def __init__(self, config: TokenTransformerConfig | None = None) -> None:
        config = config or TokenTransformerConfig()
        super().__init__(config, prefix_rows=1, spatial_adds=False)
        self.token_emb = nn.Embedding(config.codebook_size + 2, config.code_dim)
        self.output_process = OutputProcess(config.latent, config.codebook_size)
        self._init_weights()

    def forward(self, tokens: torch.Tensor, cond: torch.Tensor, length: torch.Tensor) -> torch.Tensor:
        self.check_shapes(tokens, cond, length)
        c = self.config
        valid = self.valid_rows(length, tokens.shape[1])[:, :, None]
        tokens = torch.where(valid, tokens.clamp(0, c.pad_id), torch.full_like(tokens, c.pad_id))
        motion = self.input_process(self.token_emb(tokens))  # [B, T, C, latent]
        prefix = self.cond_emb(cond)[:, None, :]  # [B, 1, latent]
        return self.output_process(self.encode(motion, prefix, length))
