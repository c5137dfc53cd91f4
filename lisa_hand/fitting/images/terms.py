"""The 2D terms of the image fit, shared by its stages: the views' cameras and keypoints stacked
(:class:`ViewData`), the keypoint L1 (the paper's L_joints, in pixels), the silhouette terms
of projected template vertices against the masks, and the bone directions of the detector's
3D landmarks (:func:`bone_directions`, :func:`direction_misfit`: the depth one view leaves
open). The pose and shape priors are every fitter's
(:func:`lisa_hand.fitting.terms.hand_prior`, with the training subjects' hand size,
:class:`lisa_hand.fitting.images.shape_prior.HandSizePrior`).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
import torch
import torch.nn.functional as F

from ...skeleton import KEYPOINT_PARENTS, NUM_KEYPOINTS
from .views import ImageView

__all__ = [
    "PALM_KEYPOINTS",
    "MIN_DEPTH",
    "ViewData",
    "keypoint_l1",
    "keypoint_px",
    "bone_directions",
    "DIRECTION_MARGIN",
    "direction_misfit",
    "sample_map",
    "silhouette_terms",
]

PALM_KEYPOINTS = (0, 1, 5, 9, 13, 17)
"""Wrist, thumb CMC and the four MCP joints: nearly rigid, the rigid phase's keypoints."""
MIN_DEPTH = 1e-3
"""Metres: projections divide by at least this (the keypoint stage keeps the hand 5 cm away)."""


class ViewData:
    """The views' cameras and keypoints stacked, and per-view mask helpers (one device).

    views: the views (:func:`lisa_hand.fitting.images.views.read_views`), tensors on one device.
    coverage_pixels: mask contour pixels kept per view for the coverage term (a random subset
        drawn with ``generator``; 0: no coverage term).

    Attributes: ``K``, ``R`` [C, 3, 3], ``t`` [C, 3]; ``keypoints`` [C, 21, 2] pixels (0 where
    missing), ``visible`` [C, 21] (1.0 / 0.0), ``num_visible``; ``directions`` [C, 20, 3] the
    bone directions of the views' 3D landmarks (0 where a view has none), ``has_directions``
    [C] (1.0 / 0.0), ``num_directions``; ``palm_visible`` and
    ``num_palm_visible`` (:data:`PALM_KEYPOINTS` only); per view ``outside`` (the mask's
    outside distance transform [1, 1, H, W] pixels, or None) and ``coverage`` (contour pixel
    centres [M, 2], or None); ``num_masks``; ``vertex_subset`` (:meth:`choose_vertices`).
    """

    def __init__(self, views: Sequence[ImageView], coverage_pixels: int,
                 generator: torch.Generator) -> None:
        device = views[0].rgb.device
        self.views = list(views)
        self.device = device
        self.K = torch.stack([v.camera.K for v in views]).float()  # [C, 3, 3]
        self.R = torch.stack([v.camera.R for v in views]).float()
        self.t = torch.stack([v.camera.t for v in views]).float()
        num = len(views)
        self.keypoints = torch.zeros(num, NUM_KEYPOINTS, 2, device=device)
        self.visible = torch.zeros(num, NUM_KEYPOINTS, device=device)
        for index, view in enumerate(views):
            if view.keypoints is not None:
                self.keypoints[index] = view.keypoints.float()
                self.visible[index] = view.visible.float()
        self.num_visible = float(self.visible.sum())
        self.directions = torch.zeros(num, NUM_KEYPOINTS - 1, 3, device=device)
        self.has_directions = torch.zeros(num, device=device)
        for index, view in enumerate(views):
            if view.landmarks_3d is not None:
                self.directions[index] = bone_directions(view.landmarks_3d.float())
                self.has_directions[index] = 1.0
        self.num_directions = float(self.has_directions.sum())
        palm = torch.zeros(NUM_KEYPOINTS, device=device)
        palm[list(PALM_KEYPOINTS)] = 1.0
        self.palm_visible = self.visible * palm
        self.num_palm_visible = float(self.palm_visible.sum())
        self.outside: list[torch.Tensor | None] = []
        self.coverage: list[torch.Tensor | None] = []
        for view in views:
            outside, coverage = _mask_maps(view, coverage_pixels, generator)
            self.outside.append(outside)
            self.coverage.append(coverage)
        self.num_masks = sum(o is not None for o in self.outside)
        self.vertex_subset: torch.Tensor | None = None

    def choose_vertices(self, num_vertices: int, most: int, generator: torch.Generator) -> None:
        """Fix the template vertices (at most ``most``, random) that the coverage term uses."""
        if num_vertices > most:
            self.vertex_subset = torch.randperm(num_vertices, generator=generator)[:most].to(
                self.device)

    def camera_points(self, points: torch.Tensor) -> torch.Tensor:
        """points [B, N, 3] world metres -> [B, C, N, 3] in each camera's frame."""
        return torch.einsum("bnk,cjk->bcnj", points, self.R) + self.t[None, :, None]

    def direction_misfit(self, keypoints: torch.Tensor) -> torch.Tensor:
        """keypoints [B, 21, 3] world metres -> [B] the mean :func:`direction_misfit` over the
        views with 3D landmarks (0 when none has them)."""
        if self.num_directions == 0:
            return keypoints.new_zeros(keypoints.shape[0])
        misfit = direction_misfit(self.camera_points(keypoints), self.directions)  # [B, C]
        return (misfit * self.has_directions).sum(1) / self.num_directions

    def project(self, points: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """points [B, N, 3] metres -> pixels [B, C, N, 2], depth [B, C, N] metres.

        :func:`lisa_hand.geometry.cameras.project_points` for every camera at once, written
        with einsum (one matrix product instead of B x C tiny batched ones, ~10x faster on a
        CPU).
        """
        x_cam = self.camera_points(points)
        homogeneous = torch.einsum("bcnk,cjk->bcnj", x_cam, self.K)
        depth = x_cam[..., 2]
        return homogeneous[..., :2] / depth.clamp_min(MIN_DEPTH)[..., None], depth


def _mask_maps(view: ImageView, coverage_pixels: int, generator: torch.Generator
               ) -> tuple[torch.Tensor | None, torch.Tensor | None]:
    """A view's outside distance transform [1, 1, H, W] (pixels, 0 inside) and a random subset
    of its mask's contour pixel centres [M, 2] (None, None without a mask)."""
    from scipy.ndimage import binary_erosion, distance_transform_edt

    if view.mask is None:
        return None, None
    device = view.rgb.device
    mask = view.mask.cpu().numpy()
    outside = distance_transform_edt(~mask).astype(np.float32)
    contour = mask & ~binary_erosion(mask, border_value=0)
    pixels = torch.from_numpy(np.argwhere(contour)[:, ::-1].copy()).float() + 0.5
    if pixels.shape[0] > coverage_pixels:
        pick = torch.randperm(pixels.shape[0], generator=generator)
        pixels = pixels[pick[:coverage_pixels]]
    return (torch.from_numpy(outside)[None, None].to(device),
            pixels.to(device) if coverage_pixels else None)


def keypoint_l1(pixels: torch.Tensor, data: ViewData, palm_only: bool = False) -> torch.Tensor:
    """Mean L1 (pixels) over the visible keypoints (``palm_only``: the palm's, see
    :data:`PALM_KEYPOINTS`, when at least 3 are visible): pixels [B, C, 21, 2] -> [B]."""
    visible, count = data.visible, data.num_visible
    if palm_only and data.num_palm_visible >= 3:
        visible, count = data.palm_visible, data.num_palm_visible
    if count == 0:
        return pixels.new_zeros(pixels.shape[0])
    residual = (pixels - data.keypoints).abs().sum(-1)  # [B, C, 21]
    return (residual * visible).sum((1, 2)) / count


def keypoint_px(pixels: torch.Tensor, data: ViewData) -> torch.Tensor:
    """Mean Euclidean error (pixels) over the visible keypoints: [B, C, 21, 2] -> [B] (NaN if
    none)."""
    if data.num_visible == 0:
        return pixels.new_full((pixels.shape[0],), math.nan)
    distance = (pixels - data.keypoints).norm(dim=-1)
    return (distance * data.visible).sum((1, 2)) / data.num_visible


def bone_directions(points: torch.Tensor) -> torch.Tensor:
    """The unit vectors of the 20 bones of 21 keypoints (parent -> child,
    :data:`lisa_hand.skeleton.KEYPOINT_PARENTS`): points [..., 21, 3] -> [..., 20, 3]."""
    bones = points[..., 1:, :] - points[..., list(KEYPOINT_PARENTS[1:]), :]
    return bones / bones.norm(dim=-1, keepdim=True).clamp_min(1e-9)


DIRECTION_MARGIN = 0.15
"""How far the component along the camera's ray of a unit bone may differ from the detector's
before it costs (:func:`direction_misfit`): its depths are coarse, and within this the image
and the skeleton decide."""


def direction_misfit(points: torch.Tensor, directions: torch.Tensor,
                     margin: float = DIRECTION_MARGIN) -> torch.Tensor:
    """How far the bones of ``points`` [..., 21, 3] (camera frame, metres) lean along the
    camera's rays otherwise than ``directions`` [..., 20, 3] (unit, the camera's axes; e.g.
    :func:`bone_directions` of MediaPipe's world landmarks) -> [...]: the mean over the bones of
    ``max(0, |(u - d) . r| - margin)^2``, ``u`` the fitted bone's unit vector, ``d`` the given
    one and ``r`` the unit ray through the bone's first keypoint.

    The image fixes each bone's direction across the rays, not along them (a finger bent
    toward the camera and one bent away project alike); the detector's 3D landmarks tell
    which. Only that component counts, and only beyond ``margin``, so that it settles the
    depth without pulling against the keypoints' pixels; nor does their size (an average
    hand's) or origin (their wrist is not the skeleton's)."""
    ray = points[..., list(KEYPOINT_PARENTS[1:]), :].detach()
    ray = ray / ray.norm(dim=-1, keepdim=True).clamp_min(1e-9)
    gap = ((bone_directions(points) - directions) * ray).sum(-1).abs()
    return (torch.relu(gap - margin) ** 2).mean(-1)


def sample_map(image: torch.Tensor, pixels: torch.Tensor) -> torch.Tensor:
    """Bilinear lookup of a map [1, 1, H, W] at continuous pixels [B, N, 2] -> [B, N]; outside
    the image the border value plus the distance to the image (pixels)."""
    height, width = image.shape[-2:]
    scale = pixels.new_tensor([2.0 / width, 2.0 / height])
    grid = (pixels * scale - 1.0)[None]  # [1, B, N, 2]
    values = F.grid_sample(image, grid, mode="bilinear", padding_mode="border",
                           align_corners=False)[0, 0]
    size = pixels.new_tensor([width, height])
    beyond = (F.relu(-pixels) + F.relu(pixels - size)).sum(-1)
    return values + beyond


def silhouette_terms(vertex_pixels: torch.Tensor, data: ViewData
                     ) -> tuple[torch.Tensor, torch.Tensor]:
    """Outside-mask distance of projected vertices and mask coverage, pixels, averaged over the
    views with masks: vertex_pixels [B, C, V, 2] -> ([B], [B]).

    Outside: the mean of the mask's outside distance transform at the vertices. Coverage: the
    mean distance from the chosen contour pixels to their nearest projected vertex (of
    ``data.vertex_subset`` when set).
    """
    batch = vertex_pixels.shape[0]
    outside = vertex_pixels.new_zeros(batch)
    coverage = vertex_pixels.new_zeros(batch)
    if data.num_masks == 0:
        return outside, coverage
    for index, (distance_map, cover) in enumerate(zip(data.outside, data.coverage,
                                                      strict=True)):
        if distance_map is None:
            continue
        pixels = vertex_pixels[:, index]
        outside = outside + sample_map(distance_map, pixels).mean(-1)
        if cover is not None:
            if data.vertex_subset is not None:
                pixels = pixels[:, data.vertex_subset]
            contour = cover[None].expand(batch, -1, -1)
            with torch.no_grad():  # nearest vertex of each contour pixel; gradient via gather
                # argmin |p - c|^2 = argmin |p|^2 - 2 c.p: one batched product, no sqrt
                score = torch.baddbmm((pixels * pixels).sum(-1)[:, None], contour,
                                      pixels.transpose(1, 2), alpha=-2.0)
                nearest = score.argmin(-1)
            closest = torch.gather(pixels, 1, nearest[..., None].expand(-1, -1, 2))
            coverage = coverage + (closest - contour).norm(dim=-1).mean(-1)
    return outside / data.num_masks, coverage / data.num_masks
