"""Where two hands meet (lisa_hand.fitting.pair.contact), on the shipped model's mean hand: the
mirrored mesh, a hand's SDF as the joint fit evaluates it (against the inference's own
:class:`lisa_hand.inference.hand_field.HandField`, for a right and a left hand; far points with
no network call), and the penetration depths against exact distances to the meshes
(:func:`lisa_hand.geometry.mesh_distance.mesh_distance`)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
import torch

from lisa_hand.fitting.pair.contact import HandBody, penetration_depths
from lisa_hand.geometry.mesh_distance import mesh_distance
from lisa_hand.geometry.meshing import Mesh
from lisa_hand.inference import mesh_hand
from lisa_hand.inference.hand_field import hand_field

from .scene import BACK_M, mean_right_hand, mirrored_left

RESOLUTION = 64


@pytest.fixture(scope="module")
def hands(model):
    """{side: (params, mesh)}: the mean right hand (palm to the camera) and the left hand that
    is its mirror image through z = BACK_M - 2.5 mm (the two overlap back to back)."""
    right = mean_right_hand(model)
    left = mirrored_left(right, BACK_M - 0.0025)
    return {side: (hand, mesh_hand(model, hand, RESOLUTION))
            for side, hand in (("right", right), ("left", left))}


def near_points(mesh: Mesh, seed: int) -> torch.Tensor:
    """[600, 3] world points within about 1 cm of the hand's surface (inside and out)."""
    rng = np.random.default_rng(seed)
    rows = rng.choice(len(mesh.vertices), 600, replace=False)
    points = mesh.vertices[rows].astype(np.float64) + rng.normal(0.0, 0.004, (600, 3))
    return torch.from_numpy(points).float()


@pytest.mark.parametrize("side", ["right", "left"])
def test_body_sdf_is_the_hand_field_near_the_hand(model, hands, side):
    """At points near the hand the body's SDF is the inference's HandField (which mirrors a
    left hand itself); on the hand's own mesh it is about zero."""
    params, mesh = hands[side]
    body = HandBody.of(model, params, mesh, 500, 0)
    assert body.flip == (side == "left") and body.right.side == "right"
    points = near_points(mesh, 1)
    reference = hand_field(model, params).sdf_fn()
    with torch.no_grad():
        got = body.sdf(model, body.right.pose, body.right.translation, body.right.shape_code,
                       points)
        expected = reference(points)
    assert (got < -0.002).sum() > 50 and (got > 0.002).sum() > 50  # inside and outside
    torch.testing.assert_close(got, expected, rtol=0, atol=1e-6)
    with torch.no_grad():
        on_mesh = body.sdf(model, body.right.pose, body.right.translation,
                           body.right.shape_code, torch.from_numpy(mesh.vertices))
    assert float(on_mesh.abs().median()) < 0.0005  # metres; voxels of about 4 mm


@pytest.mark.parametrize("side", ["right", "left"])
def test_body_sdf_moves_with_its_translation(model, hands, side):
    """The field moves with the hand: d sdf / d translation (of the right hand the body holds)
    is minus the SDF's gradient at the point in the right hand's frame (mirrored for a left
    hand)."""
    params, mesh = hands[side]
    body = HandBody.of(model, params, mesh, 500, 0)
    points = near_points(mesh, 2)[:50].clone().requires_grad_(True)
    translation = body.right.translation.clone().requires_grad_(True)
    sdf = body.sdf(model, body.right.pose, translation, body.right.shape_code, points)
    by_translation = torch.stack([
        torch.autograd.grad(value, translation, retain_graph=True)[0] for value in sdf])
    by_points = torch.autograd.grad(sdf.sum(), points)[0]
    expected = -by_points * torch.tensor([-1.0, 1.0, 1.0]) if side == "left" else -by_points
    assert float(by_points.norm(dim=-1).min()) > 0.1
    torch.testing.assert_close(by_translation, expected, rtol=1e-3, atol=1e-4)


@pytest.mark.parametrize("side", ["right", "left"])
def test_body_sdf_far_away_needs_no_network(model, hands, side, monkeypatch):
    """Beyond 1 cm of the bone regions' box: the distance to that box plus the margin, a
    lower bound of the distance to the hand's surface, with the network never called."""
    from lisa_hand.model.frame import region_bounds

    params, mesh = hands[side]
    body = HandBody.of(model, params, mesh, 500, 0)
    state = model.field.prepare(**body.right.batch())
    low, high = (bound[0].double() for bound in region_bounds(state, model.field))
    rng = np.random.default_rng(3)
    directions = rng.normal(size=(200, 3))
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    centre = mesh.vertices.astype(np.float64).mean(0)
    points = torch.from_numpy(centre + rng.uniform(0.2, 1.0, (200, 1)) * directions)

    def refuse(*args, **kwargs):
        raise AssertionError("the network was called for far points")

    monkeypatch.setattr(model.field, "field", refuse)
    with torch.no_grad():
        got = body.sdf(model, body.right.pose, body.right.translation, body.right.shape_code,
                       points).double()
    local = points * torch.tensor([-1.0, 1.0, 1.0], dtype=torch.float64) \
        if side == "left" else points
    margin = 0.01
    outside = (low - margin - local).clamp_min(0) + (local - high - margin).clamp_min(0)
    torch.testing.assert_close(got, outside.norm(dim=-1) + margin, rtol=0, atol=1e-6)
    exact = mesh_distance(points.numpy(), mesh.vertices, mesh.faces).sdf
    assert (got.numpy() > 0).all()
    assert (got.numpy() <= exact + 1e-6).all()  # never further than the surface


def test_hands_far_apart_do_not_penetrate_and_need_no_network(model, hands, monkeypatch):
    right, right_mesh = hands["right"]
    left, left_mesh = hands["left"]
    away = np.array([0.4, 0.0, 0.0], np.float32)
    far_left = replace(left, translation=left.translation + torch.from_numpy(away))
    far_mesh = replace(left_mesh, vertices=left_mesh.vertices + away)
    bodies = [HandBody.of(model, right, right_mesh, 1, 0),
              HandBody.of(model, far_left, far_mesh, 1, 0)]

    def refuse(*args, **kwargs):
        raise AssertionError("the network was called for hands 40 cm apart")

    monkeypatch.setattr(model.field, "field", refuse)
    np.testing.assert_array_equal(penetration_depths(model, bodies), np.zeros((2, 2)))


def mesh_depth_mm(mesh: Mesh, other: Mesh) -> float:
    """The deepest vertex of ``mesh`` inside ``other``, mm, by exact distances to its faces."""
    return 1000.0 * max(0.0, -float(mesh_distance(mesh.vertices, other.vertices,
                                                  other.faces).sdf.min()))


@pytest.mark.parametrize("shift_mm", [0.0, 3.0, 6.0, 10.0])
def test_a_hand_and_its_copy_moved_through_its_back(model, hands, shift_mm):
    """The same hand twice, the second moved ``shift_mm`` along its palm's normal: the depths
    are within 1.5 mm of the exact depths in the other mesh (the field is a learned SDF: its
    gradient norm is 0.4-1.4 near the surface), and coinciding hands (shift 0) measure under
    0.6 mm: the samples are moved onto the field's zero level (marching cubes' vertices lie up
    to 1 mm inside it: 1.05 mm measured at the raw vertices)."""
    params, mesh = hands["right"]
    shift = np.array([0.0, 0.0, shift_mm / 1000.0], np.float32)
    copy = replace(params, translation=params.translation + torch.from_numpy(shift))
    copy_mesh = replace(mesh, vertices=mesh.vertices + shift)
    depths = penetration_depths(model, [HandBody.of(model, params, mesh, 1, 0),
                                        HandBody.of(model, copy, copy_mesh, 1, 0)])
    assert depths[0, 0] == 0.0 and depths[1, 1] == 0.0
    if shift_mm == 0.0:
        assert depths.max() < 0.6
    exact = mesh_depth_mm(mesh, copy_mesh)
    assert exact == pytest.approx(shift_mm, abs=0.05)  # a flat back: the shift itself
    assert abs(depths[0, 1] - exact) < 1.5 and abs(depths[1, 0] - exact) < 1.5


def test_a_right_hand_and_its_mirror_image_overlapping_back_to_back(model, hands):
    """The left hand is the right one's mirror image through a plane 2.5 mm inside the right
    hand's back: both depths are equal (the left hand's mirroring is right), about 5 mm, and
    near the exact depths in the meshes (measured 4.95 mm by the fields, 5.70 by the meshes)."""
    right, right_mesh = hands["right"]
    left, left_mesh = hands["left"]
    depths = penetration_depths(model, [HandBody.of(model, right, right_mesh, 1, 0),
                                        HandBody.of(model, left, left_mesh, 1, 0)])
    assert depths[0, 1] == pytest.approx(depths[1, 0], abs=0.01)
    exact = mesh_depth_mm(right_mesh, left_mesh)
    assert exact == pytest.approx(mesh_depth_mm(left_mesh, right_mesh), abs=0.01)
    assert 4.0 < depths[0, 1] < 7.0 and 4.0 < exact < 7.0
    assert abs(depths[0, 1] - exact) < 1.5
    # Moved 1 cm apart along the mirror's normal they are clear of each other.
    apart = mirrored_left(right, BACK_M + 0.005)
    apart_mesh = replace(left_mesh, vertices=left_mesh.vertices + np.float32([0.0, 0.0, 0.015]))
    clear = penetration_depths(model, [HandBody.of(model, right, right_mesh, 1, 0),
                                       HandBody.of(model, apart, apart_mesh, 1, 0)])
    np.testing.assert_array_equal(clear, np.zeros((2, 2)))
