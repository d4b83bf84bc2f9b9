"""The residual transformer (MoMask's design): predicts RVQ layer q of a token map from layers 0..q-1, in one pass.

Given the text and layer 0 (from the masked transformer), layers 1..R-1 follow one pass each (q = 1, 2, ...).
The input is the sum over the known layers k < q of the layer's token embedding, E_k[ids_k]; a second prefix
row says which layer is asked for (``quant_emb`` of one_hot(q)). The output features go through ``output_process``
to code_dim and are scored against layer q's classifier table W_q: logits over K codes + ``pad_id`` = K (MoMask's
vocabulary; a sampled pad means "this layer unused" = code -1).

With ``share_weight`` (MoMask's released setting) the embedding table of layer k and the classifier of layer k are
one matrix for k = 1..R-2, which halves those parameters:

    token_embed_weight_ [1, K+1, code_dim]          E_0
    embed_proj_shared_weight [R-2, K+1, code_dim]   E_k = W_k, k = 1..R-2
    output_proj_weight_ [1, K+1, code_dim]          W_{R-1}

Without it: ``token_embed_weight`` [R-1, ...] (E_0..E_{R-2}) and ``output_proj_weight`` [R-1, ...] (W_1..W_{R-1}).
"""
from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn

from t2m.model.networks.token_transformer import OutputProcess, TokenMapEncoder, TokenTransformerConfig, index_range


class ResidualTransformer(TokenMapEncoder):
    """(codes [B, T, C, R'], layer q [B], cond [B, Dt], length [B]) -> logits [B, T, C, K + 1] for layer q
    ([B, T, C, K + 2] with ``residual_mask_class``)."""

    def __init__(self, config: TokenTransformerConfig | None = None) -> None:
        config = config or TokenTransformerConfig()
        if config.residual_layers < 2:
            raise ValueError(f"a residual transformer needs residual_layers >= 2, got {config.residual_layers}")
        super().__init__(config, prefix_rows=2, spatial_adds=True)
        vocab, layers = self.vocabulary, config.residual_layers

        def table(count: int) -> nn.Parameter:
            return nn.Parameter(torch.randn(count, vocab, config.code_dim) * 0.02)

        if config.share_weight:
            self.token_embed_weight_ = table(1)
            self.embed_proj_shared_weight = table(layers - 2)
            self.output_proj_weight_ = table(1)
        else:
            self.token_embed_weight = table(layers - 1)
            self.output_proj_weight = table(layers - 1)
        self.quant_emb = nn.Linear(layers, config.latent)
        self.output_process = OutputProcess(config.latent, config.code_dim)
        self._init_weights()

    @property
    def pad_id(self) -> int:
        """K (MoMask), or K + 1 when the mask id K is a class too (MoGenTS's 2D residual model)."""
        return self.config.codebook_size + int(self.config.residual_mask_class)

    @property
    def mask_id(self) -> int | None:
        """The drawable mask class (K) of MoGenTS's 2D residual model; None when there is none."""
        return self.config.codebook_size if self.config.residual_mask_class else None

    @property
    def vocabulary(self) -> int:
        return self.pad_id + 1

    def input_tables(self) -> torch.Tensor:
        """[R-1, K+1, code_dim]: E_0..E_{R-2}, the embeddings of layers 0..R-2."""
        if self.config.share_weight:
            return torch.cat([self.token_embed_weight_, self.embed_proj_shared_weight], dim=0)
        return self.token_embed_weight

    def output_tables(self) -> torch.Tensor:
        """[R-1, K+1, code_dim]: W_1..W_{R-1}, the classifiers of layers 1..R-1."""
        if self.config.share_weight:
            return torch.cat([self.embed_proj_shared_weight, self.output_proj_weight_], dim=0)
        return self.output_proj_weight

    def history(self, codes: torch.Tensor, layer: torch.Tensor) -> torch.Tensor:
        """sum_{k < q} E_k[codes[..., k]]: codes [B, T, C, R'] (-1 = unused, embedded as pad), q [B] -> [B, T, C, d]."""
        known = min(codes.shape[-1], self.config.residual_layers - 1)
        codes = codes[..., :known]
        codes = torch.where(codes < 0, torch.full_like(codes, self.pad_id), codes.clamp(max=self.pad_id))
        tables = self.input_tables()[:known]  # [k, K+1, d]
        depths = index_range(known, codes)  # [k]
        embedded = F.embedding(codes + depths * tables.shape[1], tables.reshape(-1, tables.shape[-1]))  # [B,T,C,k,d]
        used = (depths[None, :] < layer[:, None]).to(embedded.dtype)  # [B, k]
        return (embedded * used[:, None, None, :, None]).sum(dim=3)

    def forward(
        self, codes: torch.Tensor, layer: torch.Tensor, cond: torch.Tensor, length: torch.Tensor
    ) -> torch.Tensor:
        self.check_shapes(codes, cond, length)
        c = self.config
        motion = self.input_process(self.history(codes, layer))
        quant = self.quant_emb(F.one_hot(layer, c.residual_layers).to(motion.dtype))
        prefix = torch.stack([self.cond_emb(cond), quant], dim=1)  # [B, 2, latent]
        features = self.output_process(self.encode(motion, prefix, length))  # [B, T, C, code_dim]
        classifier = self.output_tables().index_select(0, (layer - 1).clamp(min=0))  # [B, K+1, code_dim]
        return torch.einsum("btcd,bkd->btck", features, classifier)
