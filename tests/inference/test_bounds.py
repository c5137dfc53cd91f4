"""Where the hand is (lisa_hand.inference.bounds): bounding sphere, skeleton box, union sphere."""

from __future__ import annotations

import numpy as np
import pytest
import torch
import trimesh

from lisa_hand import inference
from lisa_hand.skeleton import forward_kinematics

from .helpers import PADDING, REST, hand_params


def test_bounds_hold_the_surface(model, right_mesh):
    params = hand_params(model)
    center, radius = inference.hand_bounds(params, model.config)
    vertices = right_mesh.mesh.vertices
    assert np.linalg.norm(vertices - center.numpy(), axis=1).max() < radius
    assert not right_mesh.grown
    low, high = inference.skeleton_box(params, model.config, padding=PADDING)
    assert (vertices > low).all() and (vertices < high).all()
    # The skeleton box holds every posed joint, PADDING inside its sides.
    joints = forward_kinematics(params.pose[None], REST[None], params.translation[None]).joints[0]
    assert (joints.numpy() >= low + PADDING - 1e-6).all()
    assert (joints.numpy() <= high - PADDING + 1e-6).all()
    # Without padding the surface reaches the box: the grid grows instead of cutting it (dense
    # evaluation: the untrained field jumps at region edges, beyond any Lipschitz bound).
    grown = inference.mesh_hand_with_stats(
        model, params, 24, inference.MeshConfig(padding=0.0, coarse_to_fine=False, colors=False,
                                                skin_weights=False))
    assert grown.grown
    assert trimesh.Trimesh(grown.mesh.vertices, grown.mesh.faces, process=True).is_watertight
    assert np.linalg.norm(grown.mesh.vertices - center.numpy(), axis=1).max() < radius


def test_posed_segments_follow_the_skeleton(model):
    params = hand_params(model)
    start, end = inference.posed_segments(params, model.config)
    assert start.shape == end.shape == (20, 3) and start.dtype == torch.float64
    # Every segment starts at a posed joint (the wrist bone's five at the wrist).
    joints = forward_kinematics(params.pose[None].double(), REST[None].double(),
                                params.translation[None].double()).joints[0]
    assert float(torch.cdist(start, joints).amin(dim=1).max()) < 1e-9
    # ... and ends at the next one, but for the five fingertips (extended past the last joint).
    at_joint = torch.cdist(end, joints).amin(dim=1) < 1e-9
    assert int(at_joint.sum()) == 15


def test_union_sphere_by_hand():
    center, radius = inference.union_sphere(
        [(torch.tensor([0.0, 0.0, 0.0]), 1.0), (torch.tensor([4.0, 0.0, 0.0]), 1.0)])
    torch.testing.assert_close(center, torch.tensor([2.0, 0.0, 0.0], dtype=torch.float64))
    assert radius == pytest.approx(3.0)
    one = inference.union_sphere([(torch.tensor([1.0, 2.0, 3.0]), 0.5)])
    torch.testing.assert_close(one[0], torch.tensor([1.0, 2.0, 3.0], dtype=torch.float64))
    assert one[1] == pytest.approx(0.5)
    with pytest.raises(ValueError, match="spheres must not be empty"):
        inference.union_sphere([])


def test_bad_margins(model):
    params = hand_params(model)
    with pytest.raises(ValueError, match="margin must be >= 0"):
        inference.hand_bounds(params, model.config, margin=-1.0)
    with pytest.raises(ValueError, match="padding must be >= 0"):
        inference.skeleton_box(params, model.config, padding=float("nan"))
