"""Fixtures of the viewer tests: one thread, the tiny model of the inference tests and two of its
hands (A: subject 0, B: subject 1 on a 5 % larger skeleton, another pose)."""

from __future__ import annotations

import socket
from dataclasses import replace

import pytest
import torch

from lisa_hand.utils.threads import cpu_threads
from tests.inference.helpers import PADDING, hand_params, tiny_model

__all__ = ["PADDING", "free_port"]


def free_port() -> int:
    """A TCP port nobody listens on now (for a viewer started in-process)."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as probe:
        probe.bind(("127.0.0.1", 0))
        return int(probe.getsockname()[1])


@pytest.fixture(scope="package", autouse=True)
def _one_thread():
    with cpu_threads(1):  # the CPU is shared
        yield


@pytest.fixture(scope="package")
def model():
    return tiny_model(gain=(1.1, 0.9, 1.0), bias=(0.05, -0.02, 0.0))


@pytest.fixture(scope="package")
def hands(model):
    """Two NamedHands of the tiny model: A (row 0) and B (row 1, larger, flexed)."""
    from lisa_hand.viewer.state import NamedHand

    a = replace(hand_params(model, 0), model="tiny")
    b_pose = a.pose.clone()
    b_pose[3:] = 0.25
    b = replace(hand_params(model, 1), rest_joints=a.rest_joints * 1.05, pose=b_pose,
                translation=torch.tensor([0.05, 0.02, 0.38]), model="tiny")
    return [NamedHand("A", a, "test"), NamedHand("B", b, "test")]
