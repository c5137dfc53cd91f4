"""The shipped model, loaded once for the pair package's tests (one CPU thread)."""

from __future__ import annotations

import pytest
import torch


@pytest.fixture(scope="package")
def model():
    from lisa_hand.model.trained import load_trained
    from lisa_hand.utils.threads import cpu_threads

    with cpu_threads(1):
        yield load_trained(None, torch.device("cpu"))
