"""The image fit over views of several moments (a video's keyframes): one shape, skeleton and
colour, a pose and translation a moment. Views rendered from a tiny model at two known poses."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import torch

from lisa_hand.fitting.images.color_stage import _Renderer, fit_color, with_mean_codes
from lisa_hand.fitting.images.config import FitImagesConfig
from lisa_hand.fitting.images.fit import fit_images
from lisa_hand.fitting.images.keypoint_stage import fit_keypoints
from lisa_hand.fitting.images.views import check_moments
from lisa_hand.fitting.stages import history_columns
from lisa_hand.handmodel.poses import sample_pose
from lisa_hand.render import RenderConfig
from tests.fitting.image_scene import (
    FAST_RENDER,
    load_float_template,
    make_scene,
    render_frame,
    rotation_error_deg,
)

pytestmark = pytest.mark.usefixtures("one_thread_per_module")  # the CPU is shared


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    """The image-fit scene (moment 0: 3 views) and a second moment: the same hand in another
    pose and place, 2 views."""
    scene = make_scene(tmp_path_factory)
    truth = scene["truth"]
    second = dataclasses.replace(
        truth, pose=sample_pose(torch.Generator().manual_seed(5), 1, global_orient=True)[0],
        translation=truth.translation + torch.tensor([-0.02, 0.01, 0.015]))
    scene["second"] = second
    scene["second_views"] = render_frame(scene["model"], second, num_views=2)
    return scene


def test_check_moments():
    assert check_moments(None, 3) == (0, 0, 0)
    assert check_moments([0, 1, np.int64(1)], 3) == (0, 1, 1)
    with pytest.raises(ValueError, match="2 entries for 3 views"):
        check_moments([0, 1], 3)
    with pytest.raises(ValueError, match=r"moments \[1\] have no view"):
        check_moments([0, 2, 2], 3)
    with pytest.raises(ValueError, match="integers >= 0"):
        check_moments([0, -1, 0], 3)


def _terms(scene, views, moments, starts):
    config = FitImagesConfig(num_rays=256, render=RenderConfig(
        sampler="sphere_traced", num_samples=8, num_samples_extra=4, sphere_num_steps=16,
        stratified=False))
    template = load_float_template()
    starts = [with_mean_codes(hand, scene["model"]) for hand in starts]
    renderer = _Renderer(scene["model"], views, template, config, starts, moments)
    unknowns = {"pose": torch.stack([hand.pose for hand in starts]),
                "translation": torch.stack([hand.translation for hand in starts]),
                "betas": starts[0].betas, "shape_code": starts[0].shape_code,
                "color_code": starts[0].color_code}
    with torch.no_grad():
        return renderer.terms(unknowns)


def test_each_ray_and_keypoint_goes_through_its_moments_hand(scene):
    truth, second = scene["truth"], scene["second"]
    views = scene["views"] + scene["second_views"]
    # Two moments at one pose are one moment: the same rays give the same losses.
    one, pixels_one = _terms(scene, views, (0,) * 5, [truth])
    two, pixels_two = _terms(scene, views, (0, 0, 0, 1, 1), [truth, truth])
    for name in ("col", "joints", "mask"):
        assert float(two[name]) == pytest.approx(float(one[name]), rel=1e-5, abs=1e-7)
    assert torch.allclose(pixels_one, pixels_two, atol=1e-4)
    # Each moment at its true pose: every view's keypoints fit (noiseless), where one pose
    # for all views leaves the second moment's views 10+ pixels off.
    right, pixels = _terms(scene, views, (0, 0, 0, 1, 1), [truth, second])
    keypoints = torch.stack([view.keypoints for view in views])
    assert float((pixels[0] - keypoints).norm(dim=-1).mean()) < 0.01
    assert float((pixels_one[0, 3:] - keypoints[3:]).norm(dim=-1).mean()) > 10.0
    assert float(right["col"]) < float(one["col"])


def test_color_stage_fits_one_hand_to_two_moments(scene):
    truth, second, model = scene["truth"], scene["second"], scene["model"]
    views = scene["views"] + scene["second_views"]
    starts = [with_mean_codes(truth, model), with_mean_codes(second, model)]
    config = FitImagesConfig(color_iters=40, num_rays=512, render=FAST_RENDER, code_lr=0.05)
    fitted, report = fit_color(model, views, starts, config, load_float_template(),
                               moments=[0, 0, 0, 1, 1])
    history = history_columns(report.history, "color")
    assert np.mean(history["col"][-5:]) < 0.85 * np.mean(history["col"][:5])
    mean_code = model.mean_color_code()
    assert (fitted.color_code - truth.color_code).norm() < 0.8 * (
        mean_code - truth.color_code).norm()
    assert report.keypoint_error_px < 1.0  # over both moments' views
    assert rotation_error_deg(fitted.pose[:3], truth.pose[:3]) < 2.0
    (other,) = fitted.extra["moments"]
    assert rotation_error_deg(torch.tensor(other["pose"][:3]), second.pose[:3]) < 2.0
    assert np.linalg.norm(np.subtract(other["translation"], second.translation.numpy())) < 0.003
    with pytest.raises(ValueError, match=r"1 start hand\(s\) for 2 moment\(s\)"):
        fit_color(model, views, starts[:1], config, moments=[0, 0, 0, 1, 1])


def test_fit_images_fits_each_moments_keypoints_with_one_skeleton(scene):
    model = scene["model"]
    views = scene["views"] + scene["second_views"]
    config = FitImagesConfig(keypoint_iters=30, color_iters=3, num_rays=64, render=FAST_RENDER,
                             restarts=3, rotation_pool=64)
    result = fit_images(model, views, config, moments=[0, 0, 0, 1, 1])
    first, _ = fit_keypoints(scene["views"], config)
    other, _ = fit_keypoints(scene["second_views"], config)
    # The first moment's keypoint stage is its views' own; the skeleton the moments' mean.
    assert torch.equal(result.start.pose, first.pose)
    assert torch.allclose(result.params.betas, (first.betas + other.betas) / 2, atol=1e-6)
    assert set(result.keypoint_error_px) == {"keypoints", "color"}
    assert result.params.extra["views"] == [view.name for view in scene["views"]]
    with pytest.raises(ValueError, match="one hand a moment"):
        fit_images(model, views, config, moments=[0, 0, 0, 1, 1], start=[first])
