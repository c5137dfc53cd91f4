"""Two hands refined together (lisa_hand.fitting.pair.joint.fit_hands_together), on the shipped
model's mean hand: a right hand and its mirror image (a left hand) overlapping back to back by
about 5 mm, each with its own keypoints projected into the camera (what a fit alone would leave:
zero keypoint error), are pushed apart by the penetration term and only by it; no steps give
the hands back; the depth order of two hands seen overlapping in the image, apart in depth,
from masks that say which is in front (the term's value against a second implementation
here)."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from lisa_hand.fitting.outputs import hand_keypoints_3d
from lisa_hand.fitting.pair.config import JointConfig
from lisa_hand.fitting.pair.contact import HandBody, penetration_depths
from lisa_hand.fitting.pair.joint import HandView, JointHand, fit_hands_together
from lisa_hand.geometry.mesh_distance import mesh_distance
from lisa_hand.inference import mesh_hand

from .scene import BACK_M, K, mean_right_hand, mirrored_left, project, silhouette

RESOLUTION = 48


@pytest.fixture(scope="module")
def template():
    from lisa_hand.handmodel.template import load_template

    return load_template()


def keypoints_px(hand) -> np.ndarray:
    return project(hand_keypoints_3d(hand))


def joint_hands(hands, meshes, masks=(None, None)) -> list[JointHand]:
    """Each hand with its own keypoints projected (all visible) in the one view."""
    return [JointHand(params=hand, mesh=mesh,
                      views=(HandView(K=K, keypoints=keypoints_px(hand),
                                      visible=np.ones(21, bool), mask=mask),))
            for hand, mesh, mask in zip(hands, meshes, masks, strict=True)]


@pytest.fixture(scope="module")
def overlapping(model):
    """The mean right hand, palm to the camera, and its mirror image through a plane 2.7 mm
    inside its back: (hands, meshes), the two overlapping by about 5 mm."""
    right = mean_right_hand(model)
    left = mirrored_left(right, BACK_M - 0.0027)
    hands = [right, left]
    return hands, [mesh_hand(model, hand, RESOLUTION) for hand in hands]


def exact_depth_mm(meshes) -> float:
    """The deepest vertex of either mesh inside the other, mm (exact distances to faces)."""
    first, second = meshes
    depths = [mesh_distance(a.vertices, b.vertices, b.faces).sdf.min()
              for a, b in ((first, second), (second, first))]
    return 1000.0 * max(0.0, -min(depths))


def keypoint_error_px(hands, targets) -> list[float]:
    return [float(np.linalg.norm(keypoints_px(hand) - target, axis=1).mean())
            for hand, target in zip(hands, targets, strict=True)]


def test_the_joint_fit_pushes_overlapping_hands_apart(model, template, overlapping):
    hands, meshes = overlapping
    targets = [keypoints_px(hand) for hand in hands]
    start_exact = exact_depth_mm(meshes)
    fitted, report = fit_hands_together(model, joint_hands(hands, meshes), template)
    assert report.iters == JointConfig().iters
    assert [hand.side for hand in fitted] == ["right", "left"]
    assert 4.0 < report.penetration_start_mm.max() < 6.0 and 4.0 < start_exact < 7.0
    assert report.keypoint_error_start_px == pytest.approx([0.0, 0.0], abs=1e-6)
    assert report.penetration_end_mm.max() < 1.5
    assert report.energy_end["penetration"] < 0.05 * report.energy_start["penetration"]
    # The fitted hands meshed again: clear of each other by their fields and by their meshes.
    again = [mesh_hand(model, hand, RESOLUTION) for hand in fitted]
    bodies = [HandBody.of(model, hand, mesh, 1, 0)
              for hand, mesh in zip(fitted, again, strict=True)]
    assert penetration_depths(model, bodies).max() < 1.5
    assert exact_depth_mm(again) < 1.5
    # The keypoints barely moved (the report's errors and the fitted hands' keypoints, here).
    errors = keypoint_error_px(fitted, targets)
    assert max(errors) < 3.0
    assert report.keypoint_error_end_px == pytest.approx(errors, abs=0.01)
    # The hands moved apart along the overlap's normal (the camera's z): right towards it.
    shift = [float(f.translation[2] - h.translation[2]) for f, h in zip(fitted, hands,
                                                                          strict=True)]
    assert shift[0] < -0.001 and shift[1] > 0.001


def test_without_the_penetration_term_the_overlap_stays(model, template, overlapping):
    hands, meshes = overlapping
    config = JointConfig(penetration_weight=0.0, order_weight=0.0)
    fitted, report = fit_hands_together(model, joint_hands(hands, meshes), template, config)
    assert report.penetration_end_mm.max() > 4.0
    assert report.penetration_end_mm.max() == pytest.approx(report.penetration_start_mm.max(),
                                                            abs=0.2)
    for hand, start in zip(fitted, hands, strict=True):
        assert float((hand.translation - start.translation).abs().max()) < 1e-4  # metres


def test_no_steps_give_the_hands_back(model, template, overlapping):
    hands, meshes = overlapping
    fitted, report = fit_hands_together(model, joint_hands(hands, meshes), template,
                                        JointConfig(iters=0))
    for hand, start in zip(fitted, hands, strict=True):
        assert hand.side == start.side
        for name in ("pose", "translation", "rest_joints", "shape_code", "color_code",
                     "betas"):
            torch.testing.assert_close(getattr(hand, name), getattr(start, name), rtol=0,
                                       atol=0)
    np.testing.assert_array_equal(report.penetration_end_mm, report.penetration_start_mm)
    assert report.energy_end == report.energy_start
    assert report.to_dict()["iters"] == 0


def test_hands_that_do_not_meet_stay_as_fitted_alone(model, template, crossing):
    """Apart in depth, masks in the true order, keypoints 2 px off: nothing to resolve, so the
    hands come back as they are (the keypoint term would only refit them), no step taken."""
    hands, meshes, shapes = crossing
    joint = joint_hands(hands, meshes, [shapes[0], shapes[1] & ~shapes[0]])
    joint = [JointHand(params=hand.params, mesh=hand.mesh, views=tuple(
        HandView(K=view.K, keypoints=view.keypoints + 2.0, visible=view.visible, mask=view.mask)
        for view in hand.views)) for hand in joint]
    fitted, report = fit_hands_together(model, joint, template, JointConfig())
    assert report.iters == 0 and report.energy_start["keypoints"] > 0.0
    assert report.energy_start["penetration"] == 0.0 and report.energy_start["order"] == 0.0
    assert all(hand is start for hand, start in zip(fitted, hands, strict=True))


# ------------------------------------------------------------------------------------------------
# Depth order from the masks.


@pytest.fixture(scope="module")
def crossing(model):
    """The mean right hand at 0.45 m and its mirror image 3 cm behind it, moved 4 cm to the
    right: they overlap in the image, apart in depth. -> (hands, meshes, silhouettes)."""
    right = mean_right_hand(model)
    left = mirrored_left(right, BACK_M + 0.015, shift=(0.04, 0.0, 0.0))
    hands = [right, left]
    meshes = [mesh_hand(model, hand, RESOLUTION) for hand in hands]
    shapes = [silhouette(mesh) for mesh in meshes]
    assert (shapes[0] & shapes[1]).sum() > 0.3 * shapes[1].sum()
    return hands, meshes, shapes


def _right(hand):
    from lisa_hand.fitting.sides import mirror_hand

    return mirror_hand(hand) if hand.side == "left" else hand


def order_reference(samples, masks, config) -> float:
    """The order term with every surface sample (``samples``: each hand's [S, 3]), computed
    here: for each ordered pair (a, b), a's samples projecting at least ``order_margin_px``
    inside b's mask (scipy's erosion) and not into a's own must lie no nearer the camera than
    b's nearest sample projecting within ``order_radius_px``; how many mm they are ahead of it,
    pseudo-Huber, summed, over a's sample count."""
    from scipy import ndimage

    radius_px, scale = config.order_radius_px, config.order_scale_mm

    def in_mask(mask, pixels):
        column, row = np.floor(pixels).astype(int).T
        inside = (column >= 0) & (column < mask.shape[1]) & (row >= 0) & (row < mask.shape[0])
        hits = np.zeros(len(pixels), bool)
        hits[inside] = mask[row[inside], column[inside]]
        return hits

    total = 0.0
    for a in range(2):
        b = 1 - a
        points, front = samples[a], samples[b]
        pixels, front_pixels = project(points), project(front)
        inner = ndimage.binary_erosion(masks[b], iterations=int(config.order_margin_px))
        rows = in_mask(inner, pixels) & ~in_mask(masks[a], pixels)
        gaps = np.linalg.norm(pixels[rows][:, None] - front_pixels[None], axis=-1)
        depth_front = np.where(gaps < radius_px, front[None, :, 2], np.inf).min(axis=1)
        seen = np.isfinite(depth_front)
        ahead = np.maximum(1000.0 * (depth_front[seen] - points[rows][seen, 2]), 0.0)
        total += (scale ** 2 * (np.sqrt(1.0 + (ahead / scale) ** 2) - 1.0)).sum() / len(points)
    return total


def test_the_depth_order_term_is_zero_in_the_masks_order_and_positive_against_it(
        model, template, crossing):
    hands, meshes, shapes = crossing
    right_in_front = [shapes[0], shapes[1] & ~shapes[0]]  # the truth
    left_in_front = [shapes[0] & ~shapes[1], shapes[1]]
    config = JointConfig(iters=0, samples=10 ** 6)  # every vertex a sample
    samples = [HandBody.of(model, hand, mesh, 1, 0).surface_points(
        mirrored.pose, mirrored.translation, every=True).numpy()
        for hand, mesh, mirrored in ((hand, mesh, _right(hand)) for hand, mesh in zip(
            hands, meshes, strict=True))]
    energies = {}
    for name, masks in (("right", right_in_front), ("left", left_in_front)):
        _, report = fit_hands_together(model, joint_hands(hands, meshes, masks), template,
                                       config)
        assert report.energy_start["penetration"] == 0.0
        energies[name] = report.energy_start["order"]
        assert energies[name] == pytest.approx(
            order_reference(samples, masks, config), rel=1e-6, abs=1e-9)
    assert energies["right"] == 0.0
    assert energies["left"] > 5.0  # samples some 3 cm ahead of the hand said in front
    # Without masks there is no order to keep.
    _, report = fit_hands_together(model, joint_hands(hands, meshes), template, config)
    assert report.energy_start["order"] == 0.0


def test_the_depth_order_term_moves_the_hands_into_the_masks_order(model, template, crossing):
    """Masks that put the left hand in front: a few steps bring the left hand nearer the
    camera and the right one further, and the term falls."""
    hands, meshes, shapes = crossing
    left_in_front = [shapes[0] & ~shapes[1], shapes[1]]
    fitted, report = fit_hands_together(model, joint_hands(hands, meshes, left_in_front),
                                        template, JointConfig(iters=40))
    assert report.energy_end["order"] < 0.5 * report.energy_start["order"]
    assert float(fitted[0].translation[2] - hands[0].translation[2]) > 0.002
    assert float(fitted[1].translation[2] - hands[1].translation[2]) < -0.002
