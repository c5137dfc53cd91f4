"""A tiny scene for the image-fit tests: a tiny LISA model with colour, a true hand, views of it
rendered with the model (48 x 36 pixels) and a frame folder written from them."""

from __future__ import annotations

import math

import torch

from lisa_hand.data.keypoints import write_keypoints
from lisa_hand.data.layout import FramePaths, write_image, write_mask
from lisa_hand.fields.config import FieldConfig
from lisa_hand.fitting.images.folder import render_fitted_views
from lisa_hand.fitting.images.views import ImageView
from lisa_hand.geometry import axis_angle_to_matrix
from lisa_hand.geometry.cameras import make_rig, save_cameras
from lisa_hand.handmodel.poses import sample_pose
from lisa_hand.model.lisa import LisaModel
from lisa_hand.model.trained import TrainedModel
from lisa_hand.render import RenderConfig
from lisa_hand.skeleton import KEYPOINT_NAMES
from lisa_hand.skeleton.params import HandParams

TINY_FIELD = dict(sdf_hidden=32, sdf_depth=2, skinning_hidden=32, skinning_depth=1,
                  color_hidden=16, color_depth=1, pe_frequencies=4, shape_dim=8, color_dim=8)
WIDTH, HEIGHT = 48, 36
FAST_RENDER = RenderConfig(sampler="sphere_traced", num_samples=8, num_samples_extra=4,
                           sphere_num_steps=16, stratified=True)


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
    write_keypoints(paths.keypoints, {
        view.name: {"keypoints": view.keypoints, "visible": [True] * len(KEYPOINT_NAMES)}
        for view in views if view.keypoints is not None})
    return folder


def rotation_error_deg(first: torch.Tensor, second: torch.Tensor) -> float:
    relative = axis_angle_to_matrix(first).T @ axis_angle_to_matrix(second)
    return math.degrees(math.acos(float(((relative.trace() - 1) / 2).clamp(-1, 1))))


def make_scene(tmp_path_factory) -> dict:
    """{"model", "truth", "views", "folder"}: the tiny model, the true hand, 3 rendered views
    and their frame folder."""
    model = tiny_model()
    truth = true_hand(model)
    views = render_frame(model, truth)
    folder = write_frame(tmp_path_factory.mktemp("frame") / "f000", views)
    return {"model": model, "truth": truth, "views": views, "folder": folder}
