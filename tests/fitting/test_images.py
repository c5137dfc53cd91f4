"""Fitting LISA to calibrated views: the reader's validation and fallbacks, the closed-form
pieces (translation, triangulation, bilinear lookup, mirrored cameras) and self-consistency:
views rendered from a tiny model at a known pose and codes are fitted from scratch."""

from __future__ import annotations

import dataclasses
import json
import math
import shutil

import numpy as np
import pytest
import torch

from lisa_hand.data.layout import FramePaths, write_image, write_mask
from lisa_hand.fields.config import FieldConfig
from lisa_hand.fitting.images import (
    FitImagesConfig,
    ImageView,
    PoseFit,
    _background_colour,
    _sample_map,
    _solve_translation,
    _triangulate,
    _ViewData,
    cpu_threads,
    fit_color,
    fit_images,
    fit_keypoints,
    input_notes,
    keypoint_errors,
    mirror_view,
    read_views,
    render_fitted_views,
    view_psnrs,
)
from lisa_hand.geometry import axis_angle_to_matrix
from lisa_hand.geometry.cameras import Camera, make_rig, save_cameras
from lisa_hand.handmodel.poses import sample_pose
from lisa_hand.model.lisa import LisaModel
from lisa_hand.model.trained import TrainedModel
from lisa_hand.render import RenderConfig
from lisa_hand.skeleton import KEYPOINT_NAMES, mirror_points
from lisa_hand.skeleton.params import HandParams
from lisa_hand.utils.io import write_json

TINY_FIELD = dict(sdf_hidden=32, sdf_depth=2, skinning_hidden=32, skinning_depth=1,
                  color_hidden=16, color_depth=1, pe_frequencies=4, shape_dim=8, color_dim=8)
WIDTH, HEIGHT = 48, 36
FAST_RENDER = RenderConfig(sampler="sphere_traced", num_samples=8, num_samples_extra=4,
                           sphere_num_steps=16, stratified=True)


@pytest.fixture(scope="module", autouse=True)
def _one_thread():
    previous = torch.get_num_threads()
    torch.set_num_threads(1)  # the CPU is shared: one thread per test process
    yield
    torch.set_num_threads(previous)


def load_float_template():
    from lisa_hand.handmodel.template import load_template

    return load_template().to(dtype=torch.float32)


def tiny_model(seed: int = 0) -> TrainedModel:
    """A tiny LISA with colour at its geometric initialisation on the template's skeleton."""
    template = load_float_template()
    torch.manual_seed(seed)
    rest = template.rest_joints(torch.zeros(1, template.num_betas))[0]
    generator = torch.Generator().manual_seed(seed)
    return TrainedModel(
        field=LisaModel(FieldConfig(**TINY_FIELD), init_rest_joints=rest).eval(),
        shape_codes=0.1 * torch.randn(3, 8, generator=generator),
        color_codes=torch.randn(3, 8, generator=generator), subject_ids=["s0", "s1", "s2"],
        beta=0.002, gain=torch.tensor([1.1, 1.0, 0.9]), bias=torch.tensor([0.02, 0.0, -0.02]),
        source="tiny",
    )  # fmt: skip


def true_hand(model: TrainedModel, seed: int = 1) -> HandParams:
    """A natural pose with a random global rotation, a larger-than-mean hand (betas[0] = 1),
    the first subject's shape code and a colour code far from the mean."""
    template = load_float_template()
    generator = torch.Generator().manual_seed(seed)
    betas = torch.zeros(template.num_betas)
    betas[0] = 1.0
    return HandParams(
        pose=sample_pose(generator, 1, global_orient=True)[0],
        translation=torch.tensor([0.05, 0.02, -0.01]),
        rest_joints=template.rest_joints(betas[None])[0], shape_code=model.shape_codes[0],
        color_code=model.color_codes[1], betas=betas, model="tiny",
    )  # fmt: skip


def render_frame(model: TrainedModel, truth: HandParams, num_views: int = 3,
                 width: int = WIDTH, height: int = HEIGHT) -> list[ImageView]:
    """Views of ``truth``: images rendered with the model, masks (opacity > 0.5) and the
    template's keypoints projected (noiseless)."""
    template = load_float_template()
    posed = template.forward(truth.pose[None], truth.betas[None], truth.translation[None])
    cameras = make_rig(num_views, target=posed.vertices[0].mean(0).tolist(), radius=0.5,
                       width=width, height=height, fov_deg=40.0, seed=0)
    blank = [ImageView(name=c.name, camera=c, rgb=torch.zeros(height, width, 3))
             for c in cameras]
    views = []
    for camera, render in zip(cameras, render_fitted_views(model, truth, blank, samples=24),
                              strict=True):
        pixels, _ = camera.project(posed.keypoints[0])
        views.append(ImageView(name=camera.name, camera=camera, rgb=render.rgb,
                               mask=render.opacity > 0.5, keypoints=pixels))
    return views


def write_frame(folder, views: list[ImageView]):
    """Write views in the frame-folder layout (cameras.json, images/, masks/, keypoints.json)."""
    paths = FramePaths(folder)
    save_cameras(paths.cameras, [view.camera for view in views])
    for view in views:
        write_image(paths.image(view.name), view.rgb.numpy())
        if view.mask is not None:
            write_mask(paths.mask(view.name), view.mask.numpy())
    entries = {view.name: {"keypoints": view.keypoints.tolist(),
                           "visible": [True] * len(KEYPOINT_NAMES)}
               for view in views if view.keypoints is not None}
    write_json(paths.keypoints, {"names": list(KEYPOINT_NAMES), "views": entries})
    return folder


def rotation_error_deg(first: torch.Tensor, second: torch.Tensor) -> float:
    relative = axis_angle_to_matrix(first).T @ axis_angle_to_matrix(second)
    return math.degrees(math.acos(float(((relative.trace() - 1) / 2).clamp(-1, 1))))


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    model = tiny_model()
    truth = true_hand(model)
    views = render_frame(model, truth)
    folder = write_frame(tmp_path_factory.mktemp("frame") / "f000", views)
    return {"model": model, "truth": truth, "views": views, "folder": folder}


# ------------------------------------------------------------------------------------------------
# Reading views


def test_read_views_round_trip(scene):
    views = read_views(scene["folder"])
    assert [v.name for v in views] == [v.name for v in scene["views"]]
    for read, written in zip(views, scene["views"], strict=True):
        assert read.rgb.shape == (HEIGHT, WIDTH, 3) and read.rgb.dtype == torch.float32
        assert torch.equal(read.mask, written.mask)
        assert (read.rgb - written.rgb).abs().max() <= 0.5 / 255 + 1e-6  # 8-bit PNG
        assert torch.allclose(read.keypoints, written.keypoints, atol=1e-4)
        assert bool(read.visible.all()) and torch.allclose(read.camera.K, written.camera.K)
    subset = read_views(scene["folder"], ["cam002", "cam000"])
    assert [v.name for v in subset] == ["cam002", "cam000"]
    assert input_notes(views) == []


def _copy(scene, tmp_path):
    folder = tmp_path / "frame"
    shutil.copytree(scene["folder"], folder)
    return folder


def _drop_camera_field(folder):
    cameras = json.loads((folder / "cameras.json").read_text())
    del cameras[1]["K"]
    (folder / "cameras.json").write_text(json.dumps(cameras))


def _small_image(folder):
    write_image(folder / "images" / "cam001.png", np.zeros((30, 40, 3), np.uint8))


def _small_mask(folder):
    write_mask(folder / "masks" / "cam001.png", np.ones((30, 40), bool))


def _empty_mask(folder):
    write_mask(folder / "masks" / "cam002.png", np.zeros((HEIGHT, WIDTH), bool))


def _bad_keypoints(folder):
    data = json.loads((folder / "keypoints.json").read_text())
    data["views"]["cam000"]["keypoints"] = data["views"]["cam000"]["keypoints"][:20]
    (folder / "keypoints.json").write_text(json.dumps(data))


def _nothing_to_locate(folder):
    shutil.rmtree(folder / "masks")
    (folder / "keypoints.json").unlink()


@pytest.mark.parametrize("damage, names, message", [
    (lambda f: (f / "cameras.json").unlink(), None, r"cameras\.json: no such file"),
    (_drop_camera_field, None, r"cameras\.json: camera 1: missing camera field\(s\): K"),
    (lambda f: (f / "images" / "cam001.png").unlink(), None, r"images/cam001\.png: no such"),
    (_small_image, None, r"images/cam001\.png: image is 40x30 but camera 'cam001'"),
    (_small_mask, None, r"masks/cam001\.png: mask is 40x30 but camera 'cam001'"),
    (_empty_mask, None, r"masks/cam002\.png: the mask is empty"),
    (_bad_keypoints, None, r"keypoints\.json: view 'cam000': 'keypoints' must be \[21, 2\]"),
    (_nothing_to_locate, None, r"no view has a mask .* or keypoints"),
    (lambda f: None, ["cam000", "cam9"], r"cameras\.json: no camera named 'cam9'"),
])  # fmt: skip
def test_read_views_errors_name_the_file(scene, tmp_path, damage, names, message):
    folder = _copy(scene, tmp_path)
    damage(folder)
    with pytest.raises((ValueError, FileNotFoundError), match=message):
        read_views(folder, names)


def test_missing_masks_and_keypoints_are_documented_fallbacks(scene, tmp_path):
    folder = _copy(scene, tmp_path)
    (folder / "masks" / "cam001.png").unlink()
    views = read_views(folder)
    assert views[1].mask is None and views[0].mask is not None
    assert any("no mask for view(s) cam001" in note for note in input_notes(views))
    (folder / "keypoints.json").unlink()
    views = read_views(folder)
    assert all(v.keypoints is None for v in views)
    assert any(note.startswith("no keypoints: the pose comes from the masks alone")
               for note in input_notes(views))
    # Background of a view without a mask: the median colour of the image border.
    rgb = torch.full((HEIGHT, WIDTH, 3), 0.25)
    rgb[10:20, 10:20] = torch.tensor([0.9, 0.1, 0.1])
    rgb[0, :5] = 1.0  # a few outliers on the border do not move the median
    view = ImageView(name="v", camera=scene["views"][0].camera, rgb=rgb)
    assert torch.allclose(_background_colour(view), torch.full((3,), 0.25))
    masked = ImageView(name="v", camera=view.camera, rgb=rgb, mask=rgb[..., 0] > 0.5)
    assert torch.equal(_background_colour(masked), torch.zeros(3))


# ------------------------------------------------------------------------------------------------
# Closed-form pieces


def test_sample_map_is_bilinear_with_distance_outside():
    rows, cols = torch.meshgrid(torch.arange(6.0), torch.arange(8.0), indexing="ij")
    ramp = (2.0 * cols + 3.0 * rows + 1.0)[None, None]  # value at pixel centre (c + .5, r + .5)
    inside = torch.tensor([[[1.2, 2.7], [4.5, 0.5], [7.5, 5.5], [3.3, 3.9]]])
    expected = 2.0 * (inside[..., 0] - 0.5) + 3.0 * (inside[..., 1] - 0.5) + 1.0
    assert torch.allclose(_sample_map(ramp, inside), expected, atol=1e-5)
    # Beyond the image: the border value plus the distance to the image (pixels).
    outside = torch.tensor([[[-2.0, 0.5], [8.0 + 3.0, 5.5]]])
    border = torch.tensor([[0.0 + 0.0 + 1.0, 2 * 7 + 3 * 5 + 1.0]])
    assert torch.allclose(_sample_map(ramp, outside), border + torch.tensor([[2.0, 3.0]]))


def test_translation_and_triangulation_are_exact_on_noiseless_keypoints(scene):
    views = scene["views"]
    config = FitImagesConfig()
    data = _ViewData(views, config, torch.Generator().manual_seed(0))
    template = load_float_template()
    truth = scene["truth"]
    posed = template.forward(truth.pose[None], truth.betas[None], None)
    shift = _solve_translation(posed.keypoints, data)
    assert torch.allclose(shift[0], truth.translation, atol=2e-5)
    shift = _solve_translation(posed.keypoints, data, palm_only=True)
    assert torch.allclose(shift[0], truth.translation, atol=2e-5)
    points, valid = _triangulate(data)
    assert bool(valid.all())
    expected = posed.keypoints[0] + truth.translation
    assert (points - expected).abs().max() < 1e-4  # metres


def test_mirror_view_sees_the_mirrored_world():
    camera = make_rig(1, width=40, height=30, seed=3)[0]
    camera = Camera(K=torch.tensor([[50.0, 2.0, 18.0], [0.0, 55.0, 16.0], [0.0, 0.0, 1.0]]),
                    R=camera.R, t=camera.t, width=40, height=30, name="c")
    points = torch.randn(10, 3, generator=torch.Generator().manual_seed(0)) * 0.05
    pixels, depth = camera.project(points)
    rgb = torch.rand(30, 40, 3, generator=torch.Generator().manual_seed(1))
    keypoints = torch.rand(21, 2, generator=torch.Generator().manual_seed(2)) * 30.0
    view = ImageView(name="c", camera=camera, rgb=rgb, mask=rgb[..., 0] > 0.5,
                     keypoints=keypoints)
    mirrored = mirror_view(view)
    mirrored_pixels, mirrored_depth = mirrored.camera.project(mirror_points(points))
    assert torch.allclose(mirrored_pixels[:, 0], 40.0 - pixels[:, 0], atol=1e-4)
    assert torch.allclose(mirrored_pixels[:, 1], pixels[:, 1], atol=1e-4)
    assert torch.allclose(mirrored_depth, depth, atol=1e-6)
    assert torch.equal(mirrored.rgb[:, 0], rgb[:, -1]) and torch.equal(mirrored.mask,
                                                                        view.mask.flip(1))
    assert torch.allclose(mirrored.keypoints[:, 0], 40.0 - view.keypoints[:, 0])
    assert torch.allclose(mirror_view(mirrored).camera.K, camera.K)


# ------------------------------------------------------------------------------------------------
# Self-consistency


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
    fit = fit_keypoints(views, config, load_float_template())
    truth = scene["truth"]
    assert fit.history["kp_px"][0] > 5.0 * fit.keypoint_error_px
    assert fit.keypoint_error_px < 0.5  # pixels, noiseless keypoints
    assert rotation_error_deg(fit.pose[:3], truth.pose[:3]) < max_rotation_deg
    assert (fit.translation - truth.translation).norm() < max_translation_m
    errors = keypoint_errors(load_float_template(), views, fit.pose, fit.translation,
                             fit.betas)
    assert set(errors) == {view.name for view in views}
    assert abs(np.mean(list(errors.values())) - fit.keypoint_error_px) < 1e-4


def test_color_stage_lowers_the_color_loss(scene):
    truth, model = scene["truth"], scene["model"]
    start = PoseFit(pose=truth.pose, translation=truth.translation, betas=truth.betas,
                    keypoint_error_px=0.0, loss=0.0, candidate=0)
    config = FitImagesConfig(color_iters=40, num_rays=128, render=FAST_RENDER,
                             latent_lr=0.05)
    fitted, history = fit_color(model, scene["views"], start, config, load_float_template())
    early, late = np.mean(history["col"][:5]), np.mean(history["col"][-5:])
    assert late < 0.7 * early
    mean_code = model.mean_color_code()
    assert (fitted["color_code"] - truth.color_code).norm() < 0.8 * (
        mean_code - truth.color_code).norm()
    assert max(history["kp_px"]) < 1.0  # the joint loss keeps the keypoints in place


def test_fit_images_geometry_only_model_needs_color_iters_zero(scene):
    geometry = tiny_model()
    geometry.color_codes = None
    with pytest.raises(ValueError, match="has no colour"):
        fit_images(geometry, scene["views"], FitImagesConfig(keypoint_iters=1, color_iters=1))
    result = fit_images(geometry, scene["views"], FitImagesConfig(
        keypoint_iters=2, color_iters=0, restarts=2, rotation_pool=16))
    assert result.params.color_code is None and result.params.betas.shape == (10,)
    assert set(result.stage_seconds) == {"keypoints", "color"}


def test_config_validation_and_thread_setting():
    with pytest.raises(ValueError, match="side must be 'right' or 'left'"):
        FitImagesConfig(side="middle")
    with pytest.raises(ValueError, match="rigid_fraction \\+ finger_restart_fraction"):
        FitImagesConfig(rigid_fraction=0.8, finger_restart_fraction=0.3)
    with pytest.raises(ValueError, match="num_rays must be an int >= 1"):
        FitImagesConfig(num_rays=0)
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
    assert [p.name for p in written] == ["params.json", "mesh.ply", "metrics.json"]
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
