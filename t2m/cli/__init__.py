"""The `t2m` command. Each subcommand lives in cli/commands/<name>.py and imports its package lazily,
so that `t2m serve` and `t2m generate` never import torch."""
