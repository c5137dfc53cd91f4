"""A fitted hand's mesh rendered into a camera: :func:`render_mesh`, the fast picture.

Ray casting (Embree, :func:`lisa_hand.data.images.render_views`) of the mesh :func:`mesh_hand`
made, with its vertex colours (calibrated with the model's mean gain and bias) shaded by the
model's own learned shading (:class:`lisa_hand.render.shading.HeadlightShading`, as the volume
renderer applies it), at ``supersample x supersample`` rays a pixel averaged into colour and
coverage. Milliseconds where the volume renderer (:func:`prepare_render`) takes seconds on a CPU:
for overlays and previews of a surface already meshed; the volume render stays the measure of
a model's images (PSNR). Runs under ``torch.no_grad``. :func:`render_meshes_over` lays
several hands over a photo or a video frame (the overlays of the fits).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from ..geometry.cameras import Camera, pixel_rays
from ..geometry.meshing import Mesh
from ..model.trained import TrainedModel
from .render import scale_camera

__all__ = ["MeshRender", "render_mesh", "render_meshes_over"]


@dataclass(eq=False)
class MeshRender:
    """One view of a mesh (numpy; pixel ``(u, v)`` is ``array[v, u]``)."""

    rgb: np.ndarray
    """[H, W, 3] float32 in [0, 1]: the shaded surface over black (the mean over the pixel's
    sub-pixels: colour times ``alpha``, as the volume renderer's over a black background)."""
    alpha: np.ndarray
    """[H, W] float32 in [0, 1]: the fraction of the pixel's sub-pixels that hit the surface."""


@torch.no_grad()
def render_mesh(model: TrainedModel, mesh: Mesh, camera: Camera, supersample: int = 2
                ) -> MeshRender:
    """Render ``mesh`` (a hand of ``model``: world frame metres, outward faces, uint8 colours
    [V, 3]) into ``camera`` with the model's shading; a mesh without colours, or of a model
    without colour (a geometric prior), in grey lit by a light at the camera (ambient 0.3,
    diffuse 0.7: :class:`lisa_hand.data.shading.ShadingConfig`), so that its shape shows.

    supersample: rays a pixel side (>= 1). -> :class:`MeshRender` of ``camera``'s size.
    """
    from ..data.images import render_views
    from ..data.shading import ShadingConfig

    if isinstance(supersample, bool) or not isinstance(supersample, int) or supersample < 1:
        raise ValueError(f"supersample must be a positive int, got {supersample!r}")
    height, width = camera.height, camera.width
    if len(mesh.faces) == 0:
        return MeshRender(rgb=np.zeros((height, width, 3), np.float32),
                          alpha=np.zeros((height, width), np.float32))
    fine = scale_camera(camera.to("cpu"), width * supersample, height * supersample)
    shaded = mesh.colors is not None and model.has_color
    if not shaded:  # no colour to show: grey, lit from the camera, to show the shape
        colors = np.full((len(mesh.vertices), 3), 0.8, np.float32)
        lighting = ShadingConfig(ambient=0.3, diffuse=0.7)
    else:  # the model's shading (when it has one) is applied below
        colors = mesh.colors.astype(np.float32) / 255.0
        lighting = ShadingConfig(ambient=1.0, diffuse=0.0)
    (view,) = render_views(mesh.vertices, mesh.faces, [fine], colors, lighting,
                           return_normals=True)
    hit = view.mask.reshape(-1)
    rgb = view.rgb.reshape(-1, 3) * hit[:, None]
    if model.shading is not None and shaded and hit.any():
        device = model.shading.diffuse_raw.device
        _, directions = pixel_rays(fine, device=device, dtype=torch.float32)
        rows = torch.from_numpy(np.flatnonzero(hit)).to(device)
        normals = torch.from_numpy(view.normals.reshape(-1, 3)[hit]).to(device)
        rotation = fine.R.to(device=device, dtype=torch.float32)
        factor = model.shading.factor(normals, directions[rows],
                                      rotation.expand(rows.shape[0], 3, 3))
        rgb[hit] *= factor.float().cpu().numpy()

    def pooled(values: np.ndarray) -> np.ndarray:
        blocks = values.reshape(height, supersample, width, supersample, -1)
        return blocks.sum(axis=(1, 3))

    rays = float(supersample * supersample)
    alpha = pooled(hit.astype(np.float32)[:, None])[..., 0] / rays
    return MeshRender(rgb=np.clip(pooled(rgb) / rays, 0.0, 1.0).astype(np.float32),
                      alpha=alpha.astype(np.float32))


def _crop_camera(camera: Camera, box: tuple[int, int, int, int]) -> Camera:
    """``camera`` restricted to the pixel box (x0, y0, x1, y1)."""
    x0, y0, x1, y1 = box
    K = camera.K.clone()
    K[0, 2] -= x0
    K[1, 2] -= y0
    return Camera(K=K, R=camera.R, t=camera.t, width=int(x1 - x0), height=int(y1 - y0))


def render_meshes_over(model: TrainedModel | None, rgb: np.ndarray, camera: Camera,
                       meshes: list[Mesh], alpha: float, supersample: int = 1,
                       max_side: int | None = None) -> np.ndarray:
    """``rgb`` [H, W, 3] uint8 with ``meshes`` (camera frame) ray cast with the model's shading
    (:func:`render_mesh`) and laid over it at opacity ``alpha``, each only in the box its
    vertices project to, at most ``max_side`` pixels a side there (then resized: a hand filling
    a 4K frame costs what a small one does; None: at the frame's resolution) -> [H, W, 3]
    uint8."""
    from PIL import Image


    out = rgb.copy()  # only the boxes around the hands are blended, in floats
    height, width = rgb.shape[:2]
    K = camera.K.double().cpu().numpy()
    for mesh in meshes:
        points = mesh.vertices.astype(np.float64)
        in_front = points[:, 2] > 1e-3
        if not in_front.any():
            continue
        pixels = (points[in_front] @ K.T)[:, :2] / points[in_front, 2:]
        x0, y0 = np.floor(pixels.min(0)).astype(int) - 2
        x1, y1 = np.ceil(pixels.max(0)).astype(int) + 2
        x0, y0, x1, y1 = max(x0, 0), max(y0, 0), min(x1, width), min(y1, height)
        if x1 - x0 < 2 or y1 - y0 < 2:
            continue
        box = _crop_camera(camera, (x0, y0, x1, y1))
        factor = 1.0 if max_side is None else min(1.0, max_side / max(x1 - x0, y1 - y0))
        small = scale_camera(box, max(int(round((x1 - x0) * factor)), 1),
                             max(int(round((y1 - y0) * factor)), 1))
        shown = render_mesh(model, mesh, small, supersample)
        colour, cover = shown.rgb, shown.alpha
        if small is not box:
            colour = np.stack([np.asarray(Image.fromarray(colour[..., c]).resize(
                (x1 - x0, y1 - y0), Image.BILINEAR)) for c in range(3)], -1)
            cover = np.asarray(Image.fromarray(cover).resize((x1 - x0, y1 - y0),
                                                             Image.BILINEAR))
        region = out[y0:y1, x0:x1].astype(np.float32) / 255.0
        blended = region * (1.0 - alpha * cover[..., None]) + colour * alpha
        out[y0:y1, x0:x1] = np.clip(blended * 255.0 + 0.5, 0, 255).astype(np.uint8)
    return out
