"""Background coarse-to-fine remeshing (lisa_hand.viewer.meshing)."""

from __future__ import annotations

import numpy as np
import pytest

from lisa_hand.inference import MeshConfig, hand_field, mesh_hand, mesh_hand_with_stats
from lisa_hand.viewer.meshing import CancellableHandField, MeshCancelled, RemeshConfig, Remesher

from .conftest import PADDING

CONFIG = RemeshConfig(coarse_resolution=16, fine_resolution=32, padding=PADDING)


def test_coarse_then_fine_equal_direct_meshing(model, hands):
    updates = []
    remesher = Remesher(model, updates.append, CONFIG)
    try:
        generation = remesher.request(hands[0].params)
        assert remesher.wait_idle(60.0)
    finally:
        remesher.close()
    assert [(u.generation, u.level, u.resolution) for u in updates] == [
        (generation, "coarse", 16), (generation, "fine", 32)]
    config = MeshConfig(padding=PADDING, chunk_size=CONFIG.chunk_size)
    for update in updates:
        reference = mesh_hand(model, hands[0].params, update.resolution, config)
        assert np.array_equal(update.mesh.vertices, reference.vertices)
        assert np.array_equal(update.mesh.colors, reference.colors)
        assert update.mesh.skin_weights.shape == (reference.num_vertices, 16)
    assert updates[0].mesh.num_vertices < updates[1].mesh.num_vertices


def test_a_newer_request_cancels_the_older_fine_mesh(model, hands):
    updates = []
    remesher = Remesher(model, lambda u: (updates.append(u), u.generation == 1
                                          and remesher.request(hands[1].params)), CONFIG)
    try:
        remesher.request(hands[0].params)  # its coarse mesh asks for hand B
        assert remesher.wait_idle(60.0)
    finally:
        remesher.close()
    assert [(u.generation, u.level) for u in updates] == [
        (1, "coarse"), (2, "coarse"), (2, "fine")]
    assert remesher.cancelled == 1


def test_cancellation_stops_an_extraction_between_chunks(model, hands):
    calls = []

    def cancelled() -> bool:
        calls.append(1)
        return len(calls) > 3

    hand = CancellableHandField.of(hand_field(model, hands[0].params), cancelled)
    with pytest.raises(MeshCancelled):
        mesh_hand_with_stats(model, hands[0].params, 64, MeshConfig(padding=PADDING,
                                                                    chunk_size=512), hand=hand)
    assert len(calls) == 4


def test_errors_reach_the_viewer(model, hands):
    errors = []
    remesher = Remesher(model, lambda u: None, CONFIG, on_error=errors.append)
    try:
        remesher.request("not a hand")
        remesher.wait_idle(30.0)
        remesher.request(hands[0].params)  # the worker lives on
        assert remesher.wait_idle(60.0)
    finally:
        remesher.close()
    assert len(errors) == 1 and isinstance(errors[0], TypeError)


def test_config_is_checked():
    with pytest.raises(ValueError, match="resolution"):
        RemeshConfig(coarse_resolution=4)
    with pytest.raises(ValueError, match="padding"):
        RemeshConfig(padding=-1.0)
    assert RemeshConfig(coarse_resolution=40, fine_resolution=0).levels() == [("coarse", 40)]
