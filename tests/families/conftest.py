"""Fixtures of the family tests: the tiny random bundles and the app client of the service tests, the training data
of the model tests, one torch thread and offline transformers as in the export tests (imported, so each is defined
once)."""
from __future__ import annotations

import os

import pytest

from tests.model.conftest import data_dir
from tests.service.conftest import (
    hifigpt_build,
    hifigpt_bundle,
    make_client,
    masked_build,
    masked_bundle,
    random_bundle,
)

os.environ.setdefault("HF_HUB_OFFLINE", "1")
os.environ.setdefault("TRANSFORMERS_OFFLINE", "1")

__all__ = ["data_dir", "hifigpt_build", "hifigpt_bundle", "make_client", "masked_build", "masked_bundle",
           "random_bundle"]


@pytest.fixture(autouse=True, scope="session")
def _one_torch_thread():
    import torch

    torch.set_num_threads(1)
