"""The image fit's 2D terms: the bilinear lookup of a distance map, the keypoint losses and the
priors (the shared ones of :mod:`lisa_hand.fitting.priors`)."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from lisa_hand.fitting.images.config import FitImagesConfig
from lisa_hand.fitting.images.terms import (
    ViewData,
    keypoint_l1,
    keypoint_px,
    sample_map,
)
from lisa_hand.fitting.images.views import ImageView
from lisa_hand.fitting.priors import joint_limit_excess, prior_mean_fingers
from lisa_hand.fitting.terms import HandTerms, hand_prior
from lisa_hand.geometry.cameras import make_rig


def test_sample_map_is_bilinear_with_distance_outside():
    rows, cols = torch.meshgrid(torch.arange(6.0), torch.arange(8.0), indexing="ij")
    ramp = (2.0 * cols + 3.0 * rows + 1.0)[None, None]  # value at pixel centre (c + .5, r + .5)
    inside = torch.tensor([[[1.2, 2.7], [4.5, 0.5], [7.5, 5.5], [3.3, 3.9]]])
    expected = 2.0 * (inside[..., 0] - 0.5) + 3.0 * (inside[..., 1] - 0.5) + 1.0
    assert torch.allclose(sample_map(ramp, inside), expected, atol=1e-5)
    # Beyond the image: the border value plus the distance to the image (pixels).
    outside = torch.tensor([[[-2.0, 0.5], [8.0 + 3.0, 5.5]]])
    border = torch.tensor([[0.0 + 0.0 + 1.0, 2 * 7 + 3 * 5 + 1.0]])
    assert torch.allclose(sample_map(ramp, outside), border + torch.tensor([[2.0, 3.0]]))


def test_keypoint_losses_count_the_visible_keypoints_only():
    camera = make_rig(1, width=40, height=30, seed=3)[0]
    keypoints = torch.full((21, 2), 10.0)
    visible = torch.zeros(21, dtype=torch.bool)
    visible[:4] = True
    view = ImageView(name="c", camera=camera, rgb=torch.zeros(30, 40, 3), keypoints=keypoints,
                     visible=visible)
    data = ViewData([view], coverage_pixels=0, generator=torch.Generator().manual_seed(0))
    pixels = keypoints.clone()[None, None]
    pixels[..., :4, :] += torch.tensor([3.0, 4.0])  # 7 px L1, 5 px Euclidean
    pixels[..., 4:, :] += 100.0  # not visible: ignored
    assert torch.allclose(keypoint_l1(pixels, data), torch.tensor([7.0]))
    assert torch.allclose(keypoint_px(pixels, data), torch.tensor([5.0]))
    no_keypoints = ViewData([ImageView(name="c", camera=camera, rgb=torch.zeros(30, 40, 3),
                                       mask=torch.ones(30, 40, dtype=torch.bool))], 0,
                            torch.Generator())
    assert keypoint_l1(pixels, no_keypoints).item() == 0.0
    assert math.isnan(keypoint_px(pixels, no_keypoints).item())


@pytest.mark.parametrize("prior_pose", ["relaxed", "flat"])
def test_the_image_prior_is_the_shared_prior_terms(prior_pose):
    config = FitImagesConfig(prior_pose=prior_pose)
    mean = prior_mean_fingers(prior_pose)
    pose = torch.zeros(2, 48)
    pose[1, 3:] = mean + 0.1
    pose[1, 5] = 3.0  # far beyond a joint limit
    betas = torch.tensor([[0.0, 0.0], [1.0, 3.0]])
    expected = (config.pose_weight * ((pose[:, 3:] - mean) ** 2).mean(-1)
                + config.betas_weight * torch.tensor([0.0, 5.0])
                + config.limit_weight * joint_limit_excess(pose))
    got = hand_prior(config, mean)(HandTerms(pose=pose, betas=betas))
    assert torch.allclose(got, expected)
    assert joint_limit_excess(pose)[1] > 1.0


def _hinged_reference(points: np.ndarray, directions: np.ndarray, margin: float) -> float:
    """direction_misfit in float64 numpy, loop by loop."""
    parents = (-1, 0, 1, 2, 3, 0, 5, 6, 7, 0, 9, 10, 11, 0, 13, 14, 15, 0, 17, 18, 19)
    total = 0.0
    for child in range(1, 21):
        start = points[parents[child]]
        bone = (points[child] - start) / np.linalg.norm(points[child] - start)
        ray = start / np.linalg.norm(start)
        total += max(0.0, abs(float((bone - directions[child - 1]) @ ray)) - margin) ** 2
    return total / 20


def test_direction_misfit_counts_the_lean_along_the_rays_beyond_the_margin():
    """A numpy float64 reference on a random hand; the detector's landmarks scaled, moved and
    turned about the camera's axis (across the rays) as the misfit's own hand gives 0 only
    where they keep each bone's lean along its ray."""
    from lisa_hand.fitting.images.terms import DIRECTION_MARGIN, bone_directions, direction_misfit

    rng = np.random.default_rng(4)
    points = rng.normal(0.0, 0.05, size=(21, 3)) + [0.02, -0.01, 0.5]
    landmarks = rng.normal(0.0, 0.05, size=(21, 3))
    directions = bone_directions(torch.from_numpy(landmarks))
    parents = [0, 1, 2, 3, 0, 5, 6, 7, 0, 9, 10, 11, 0, 13, 14, 15, 0, 17, 18, 19]
    bones = landmarks[1:] - landmarks[parents]
    np.testing.assert_allclose(directions.numpy(),
                               bones / np.linalg.norm(bones, axis=-1, keepdims=True), rtol=1e-12)
    for margin in (0.0, DIRECTION_MARGIN, 0.4):
        value = float(direction_misfit(torch.from_numpy(points), directions, margin))
        assert value == pytest.approx(_hinged_reference(points, directions.numpy(), margin),
                                      rel=1e-10)
        assert value > 0.0 if margin < 0.4 else value >= 0.0
    # The hand itself, at another size and origin (an average hand's landmarks): no misfit.
    own = bone_directions(torch.from_numpy(1.3 * points + [0.1, 0.2, -0.3]))
    assert float(direction_misfit(torch.from_numpy(points), own, 0.0)) == pytest.approx(0.0,
                                                                                       abs=1e-20)
    # The index's last bone leaning toward the camera, then as far away from it (its tip
    # mirrored through the plane across its ray): it costs (2 x 0.02 / 0.0224 along the ray,
    # one bone of 20), the other bones nothing.
    ray = points[7] / np.linalg.norm(points[7])
    across = np.cross(ray, [0.0, 1.0, 0.0])
    toward = points.copy()
    toward[8] = points[7] - 0.02 * ray + 0.01 * across / np.linalg.norm(across)
    away = toward.copy()
    away[8] = points[7] + 0.02 * ray + 0.01 * across / np.linalg.norm(across)
    leaning = bone_directions(torch.from_numpy(toward))
    assert float(direction_misfit(torch.from_numpy(away), leaning, 0.0)) == pytest.approx(
        (0.04 / math.hypot(0.02, 0.01)) ** 2 / 20, rel=1e-9)


def test_view_data_direction_misfit_is_the_mean_over_views_with_landmarks():
    from lisa_hand.fitting.images.terms import bone_directions, direction_misfit

    cameras = make_rig(2, width=40, height=30, seed=3)
    rng = np.random.default_rng(5)
    landmarks = torch.from_numpy(rng.normal(0.0, 0.05, size=(21, 3))).float()
    views = [ImageView(name=c.name, camera=c, rgb=torch.zeros(30, 40, 3),
                       landmarks_3d=landmarks if index == 0 else None)
             for index, c in enumerate(cameras)]
    data = ViewData(views, 0, torch.Generator().manual_seed(0))
    assert data.num_directions == 1.0
    keypoints = torch.from_numpy(rng.normal(0.0, 0.04, size=(2, 21, 3))).float()
    in_camera = keypoints @ cameras[0].R.T.float() + cameras[0].t.float()
    expected = direction_misfit(in_camera, bone_directions(landmarks))
    torch.testing.assert_close(data.direction_misfit(keypoints), expected)
    none = ViewData(views[1:], 0, torch.Generator().manual_seed(0))
    assert none.num_directions == 0.0 and torch.equal(none.direction_misfit(keypoints),
                                                       torch.zeros(2))
