"""Importers of released checkpoints (T2M-GPT, MoMask, MoGenTS): strict readers that name the key or shape they
expected, the mapping onto our modules, parity, and honest model cards."""
