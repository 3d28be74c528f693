"""Shared test fixtures: keep torch to one thread so that two cores are not oversubscribed."""

from __future__ import annotations

import pytest
import torch


@pytest.fixture(autouse=True)
def _single_torch_thread() -> None:
    torch.set_num_threads(1)
