"""Fixtures of the inference tests: one thread, the tiny model and its right hand's mesh (made
once for the whole folder)."""

from __future__ import annotations

import pytest

from lisa_hand import inference
from lisa_hand.model.trained import TrainedModel
from lisa_hand.utils.threads import cpu_threads

from .helpers import BIAS, GAIN, PADDING, hand_params, tiny_model


@pytest.fixture(scope="package", autouse=True)
def _one_thread():
    with cpu_threads(1):  # the CPU is shared
        yield


@pytest.fixture(scope="package")
def model() -> TrainedModel:
    return tiny_model(gain=GAIN, bias=BIAS)


@pytest.fixture(scope="package")
def right_mesh(model) -> inference.HandMesh:
    return inference.mesh_hand_with_stats(model, hand_params(model), 40,
                                          inference.MeshConfig(padding=PADDING))
