"""Fitting LISA to calibrated views, self-consistency: views rendered from a tiny model at a known
pose and codes are fitted from scratch, stage by stage (keypoint stage, colour stage) and
composed (:func:`fit_images`), right and left hands."""

from __future__ import annotations

import dataclasses
import json
import math

import numpy as np
import pytest
import torch

from lisa_hand.fitting.images import keypoint_stage
from lisa_hand.fitting.images.color_stage import fit_color, with_mean_codes
from lisa_hand.fitting.images.config import FitImagesConfig
from lisa_hand.fitting.images.fit import fit_images
from lisa_hand.fitting.images.folder import render_fitted_views, view_psnrs
from lisa_hand.fitting.images.keypoint_stage import (
    fit_keypoints,
    keypoint_errors,
    mean_keypoint_error,
)
from lisa_hand.fitting.images.views import mirror_view
from lisa_hand.fitting.sides import mirror_hand
from lisa_hand.fitting.stages import history_columns
from lisa_hand.utils.threads import cpu_threads
from tests.fitting.image_scene import (
    FAST_RENDER,
    load_float_template,
    make_scene,
    render_frame,
    rotation_error_deg,
    tiny_model,
)

pytestmark = pytest.mark.usefixtures("one_thread_per_module")  # the CPU is shared


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    return make_scene(tmp_path_factory)


def test_rendered_truth_reproduces_the_views(scene):
    scores = view_psnrs(render_fitted_views(scene["model"], scene["truth"], scene["views"],
                                            samples=24))
    assert scores["psnr_db"] == math.inf or scores["psnr_db"] > 60.0
    other = dataclasses.replace(scene["truth"], color_code=scene["model"].color_codes[2])
    worse = view_psnrs(render_fitted_views(scene["model"], other, scene["views"], samples=24))
    assert worse["psnr_mask_db"] < 40.0


@pytest.mark.parametrize("which, max_rotation_deg, max_translation_m", [
    ((0, 1, 2), 2.0, 0.003),
    ((1,), 5.0, 0.02),  # one view: the depth is barely constrained
])  # fmt: skip
def test_keypoint_stage_recovers_the_pose_from_scratch(scene, which, max_rotation_deg,
                                                       max_translation_m):
    views = [scene["views"][index] for index in which]
    config = FitImagesConfig(keypoint_iters=150, restarts=6, rotation_pool=512)
    hand, report = fit_keypoints(views, config, load_float_template())
    truth = scene["truth"]
    assert report.stage == "keypoints" and report.candidate is not None
    depth = round(config.depth_restart_fraction * 150) if len(views) == 1 else 0
    assert [record["stage"] for record in report.history] == ["keypoints"] * (150 + depth)
    assert history_columns(report.history)["kp_px"][0] > 5.0 * report.keypoint_error_px
    assert report.energies == [report.loss]
    assert report.keypoint_error_px < 0.5  # pixels, noiseless keypoints
    assert rotation_error_deg(hand.pose[:3], truth.pose[:3]) < max_rotation_deg
    assert (hand.translation - truth.translation).norm() < max_translation_m
    assert hand.side == "right" and hand.shape_code.numel() == 0 and hand.color_code is None
    template = load_float_template()
    assert torch.allclose(hand.rest_joints, template.rest_joints(hand.betas[None])[0])
    errors = keypoint_errors(template, views, hand)
    assert set(errors) == {view.name for view in views}
    assert abs(np.mean(list(errors.values())) - report.keypoint_error_px) < 1e-4
    assert abs(mean_keypoint_error(template, views, hand) - report.keypoint_error_px) < 1e-4


def _one_view_optimiser(scene, config):
    from lisa_hand.fitting.images.terms import ViewData
    from lisa_hand.fitting.priors import prior_mean_fingers

    data = ViewData(scene["views"][1:2], config.coverage_pixels, torch.Generator().manual_seed(0))
    return keypoint_stage._Optimiser(load_float_template(), data, config,
                                     prior_mean_fingers(config.prior_pose, data.device), None)


def _candidates(hand, translation):
    return keypoint_stage._Candidates(hand.pose[None, :3].clone(), hand.pose[None, 3:].clone(),
                                      translation[None].clone(), hand.betas[None].clone())


def test_depth_copies_move_the_hand_along_its_ray(scene):
    """Each copy's keypoint centre on the ray from the camera centre through the hand's, at the
    factor times its distance; pose and betas unchanged."""
    optimiser = _one_view_optimiser(scene, FitImagesConfig())
    truth, template = scene["truth"], optimiser.template
    camera = scene["views"][1].camera
    centre = -(camera.R.T @ camera.t)
    factors = (0.5, 0.9, 1.3)
    copies = keypoint_stage._depth_copies(template, _candidates(truth, truth.translation),
                                          optimiser.data, factors)
    keypoints = template.forward(copies.pose(), copies.betas, copies.translation).keypoints
    rays = keypoints.mean(1) - centre  # [4, 3]
    assert torch.allclose(copies.translation[0], truth.translation)
    for index, factor in enumerate(factors, start=1):
        assert torch.allclose(rays[index], factor * rays[0], atol=1e-6)
    assert torch.equal(copies.fingers, truth.pose[3:].expand(4, -1))
    assert torch.equal(copies.betas, truth.betas.expand(4, -1))


def test_depth_restarts_find_the_depth_and_keep_a_right_one(scene):
    """One view, the true hand pushed to 1/0.84 of its distance: the copy at 0.84 brings it
    back (9.5 cm off at the start, within about 6 mm after; a 48 x 36 view); the true hand
    itself is kept exactly as it was."""
    config = FitImagesConfig()
    optimiser = _one_view_optimiser(scene, config)
    truth, template = scene["truth"], optimiser.template
    camera = scene["views"][1].camera
    centre = -(camera.R.T @ camera.t)
    middle = template.forward(truth.pose[None], truth.betas[None],
                              truth.translation[None]).keypoints[0].mean(0)
    far = truth.translation + (1 / 0.84 - 1.0) * (middle - centre)
    for translation, moved in ((far, True), (truth.translation, False)):
        state = _candidates(truth, translation)
        with torch.no_grad():
            loss, error = optimiser.objective(state, rigid=False)
        state, loss, error, best = keypoint_stage._restart_depth(optimiser, state, loss, error,
                                                                 0, 60)
        found = state.translation[best]
        if moved:
            assert (translation - truth.translation).norm() > 0.09
            assert best > 0 and (found - truth.translation).norm() < 0.008
        else:
            assert best == 0 and torch.equal(found, truth.translation)
            assert torch.equal(state.fingers[0], truth.pose[3:])


def test_color_stage_lowers_the_color_loss(scene):
    truth, model = scene["truth"], scene["model"]
    start = with_mean_codes(truth, model)  # the true pose, the mean codes
    assert torch.equal(start.color_code, model.mean_color_code())
    config = FitImagesConfig(color_iters=40, num_rays=512, render=FAST_RENDER,
                             code_lr=0.05)
    fitted, report = fit_color(model, scene["views"], start, config, load_float_template())
    assert [record["iteration"] for record in report.history] == list(range(40))
    history = history_columns(report.history, "color")
    early, late = np.mean(history["col"][:5]), np.mean(history["col"][-5:])
    # Measured over seeds 0-3 (512 rays): late / early 0.72-0.77 with the shape code in the
    # training codes' space, 0.65-0.83 with the paper's free code (means 0.747 and 0.745; the
    # former bound 0.7 at 128 rays held for seed 0 of the free code only). With the views'
    # responses fitted too (view_calibration, issue 15): 0.74-0.81 over seeds 0-2 (0.72-0.77
    # without), the colour code as close to the truth (0.556-0.561 of the mean code's distance,
    # 0.535-0.561 without).
    assert late < 0.85 * early
    mean_code = model.mean_color_code()
    assert (fitted.color_code - truth.color_code).norm() < 0.8 * (
        mean_code - truth.color_code).norm()
    assert max(history["kp_px"]) < 1.0  # the joint loss keeps the keypoints in place
    assert report.keypoint_error_px < 1.0 and report.loss == history["energy"][-1]
    assert fitted.model == "tiny" and fitted.side == "right"
    with pytest.raises(ValueError, match=r"start.shape_code has 0 values, but model tiny's "
                                         r"codes have 8: start from with_mean_codes"):
        fit_color(model, scene["views"], dataclasses.replace(truth, shape_code=torch.zeros(0)),
                  config)


def test_fit_images_geometry_only_model_needs_color_iters_zero(scene):
    geometry = tiny_model()
    geometry.color_codes = None
    with pytest.raises(ValueError, match="has no colour"):
        fit_images(geometry, scene["views"], FitImagesConfig(keypoint_iters=1, color_iters=1))
    result = fit_images(geometry, scene["views"], FitImagesConfig(
        keypoint_iters=2, color_iters=0, restarts=2, rotation_pool=16))
    assert result.params.color_code is None and result.params.betas.shape == (10,)
    assert set(result.stage_seconds) == {"keypoints", "color"}
    assert set(result.reports) == {"keypoints"}


def test_fit_images_reuses_a_keypoint_stage_hand(scene):
    model, views = scene["model"], scene["views"]
    config = FitImagesConfig(keypoint_iters=30, color_iters=3, num_rays=64, render=FAST_RENDER,
                             restarts=3, rotation_pool=64)
    whole = fit_images(model, views, config)
    hand, report = fit_keypoints(views, config)
    reused = fit_images(model, views, config, start=hand)
    assert torch.equal(reused.params.pose, whole.params.pose)
    assert torch.equal(reused.params.color_code, whole.params.color_code)
    assert reused.keypoint_error_px["keypoints"] == pytest.approx(report.keypoint_error_px,
                                                                  abs=1e-4)
    with pytest.raises(ValueError, match="start is a right hand but side is 'left'"):
        fit_images(model, views, config, side="left", start=hand)


def test_fit_images_left_hand_is_the_mirrored_right_hand(scene):
    model = scene["model"]
    mirrored = [mirror_view(view) for view in scene["views"]]  # views of a left hand
    config = FitImagesConfig(keypoint_iters=30, color_iters=3, num_rays=64, render=FAST_RENDER,
                             restarts=3, rotation_pool=64)
    left = fit_images(model, mirrored, config, side="left")
    right = fit_images(model, scene["views"], config)
    assert left.params.side == "left"
    back = mirror_hand(left.params)
    assert torch.allclose(back.pose, right.params.pose, atol=1e-3)
    assert torch.allclose(back.translation, right.params.translation, atol=1e-4)
    assert left.keypoint_error_px["color"] == pytest.approx(right.keypoint_error_px["color"],
                                                            abs=1e-3)


def test_config_validation_and_thread_setting(scene):
    with pytest.raises(ValueError, match="side must be 'right' or 'left'"):
        fit_images(scene["model"], scene["views"], side="middle")
    with pytest.raises(ValueError, match="rigid_fraction \\+ finger_restart_fraction"):
        FitImagesConfig(rigid_fraction=0.8, finger_restart_fraction=0.3)
    with pytest.raises(ValueError, match="depth_factors must be a tuple of positive numbers"):
        FitImagesConfig(depth_factors=(0.8, -1.2))
    with pytest.raises(ValueError, match="depth_factors must be a tuple of positive numbers"):
        FitImagesConfig(depth_factors=[0.8])
    with pytest.raises(ValueError, match="depth_restart_fraction must be in"):
        FitImagesConfig(depth_restart_fraction=1.5)
    with pytest.raises(ValueError, match="num_rays must be an int >= 1"):
        FitImagesConfig(num_rays=0)
    with pytest.raises(ValueError, match="prior_pose must be one of relaxed, flat"):
        FitImagesConfig(prior_pose="fist")
    with pytest.raises(TypeError, match="views\\[0\\] must be an ImageView"):
        fit_keypoints(["cam000"])
    before = torch.get_num_threads()
    with cpu_threads(2):
        assert torch.get_num_threads() == 2
    assert torch.get_num_threads() == before


def test_outputs_are_written_all_or_nothing(scene, tmp_path):
    from lisa_hand.fitting.outputs import json_safe, write_fit_outputs
    from lisa_hand.geometry.meshing import Mesh

    assert json_safe({"a": math.nan, "b": [1.0, math.inf], "c": "x"}) == {
        "a": None, "b": [1.0, None], "c": "x"}
    mesh = Mesh(vertices=np.eye(3), faces=np.array([[0, 1, 2]]))
    written = write_fit_outputs(tmp_path / "out", scene["truth"], mesh, {"psnr_db": math.nan})
    assert [p.name for p in written] == ["params.json", "mesh.ply", "keypoints.json",
                                         "metrics.json"]
    assert json.loads((tmp_path / "out" / "metrics.json").read_text()) == {"psnr_db": None}
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out"]  # no staging folder left
    with pytest.raises(NotADirectoryError, match="must be a folder"):
        write_fit_outputs(tmp_path / "out" / "params.json", scene["truth"], mesh)


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs CUDA")
def test_fit_images_runs_on_cuda(scene):
    model = tiny_model().to("cuda")
    result = fit_images(model, scene["views"], FitImagesConfig(
        keypoint_iters=20, color_iters=3, num_rays=64, render=FAST_RENDER, restarts=2,
        rotation_pool=64))
    assert result.params.pose.device.type == "cpu"
    assert result.keypoint_error_px["color"] < 5.0
    on_device = fit_images(tiny_model(), scene["views"], FitImagesConfig(
        keypoint_iters=20, color_iters=3, num_rays=64, render=FAST_RENDER, restarts=2,
        rotation_pool=64, device="cuda"))
    assert on_device.keypoint_error_px["color"] < 5.0



@pytest.mark.parametrize("light", [None, (0.3, -0.5, -1.0)])
def test_color_stage_shades_the_rays_like_the_renderer(scene, light):
    # A model trained with headlight shading: the colour stage lights its rays as the image
    # renderer lit the views (at the true hand the colour loss is small), and an unshaded copy
    # of the same model does not explain those views.
    from lisa_hand.render.shading import HeadlightShading

    shading = HeadlightShading.from_values(0.7, light).eval()
    shaded = dataclasses.replace(scene["model"], shading=shading)
    views = render_frame(shaded, scene["truth"])
    config = FitImagesConfig(color_iters=1, num_rays=512, render=FAST_RENDER,
                             view_calibration=False, guard=False)
    first = {}
    for name, model in (("shaded", shaded), ("plain", scene["model"])):
        _, report = fit_color(model, views, scene["truth"], config, load_float_template())
        first[name] = history_columns(report.history, "color")["col"][0]
    assert first["shaded"] < 0.3 * first["plain"], first
