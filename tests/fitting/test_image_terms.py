"""The image fit's 2D terms: the bilinear lookup of a distance map, the keypoint losses and the
priors (the shared ones of :mod:`lisa_hand.fitting.priors`)."""

from __future__ import annotations

import math

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
