"""Global-pose search of the image fit: where the hand is and how it is turned, before any
optimisation (the start of :func:`lisa_hand.fitting.images.keypoint_stage.fit_keypoints`).

* :func:`triangulate`: DLT triangulation of the keypoints seen in two or more views.
* :func:`solve_translation`: the translation in closed form, linear least squares on the
  keypoints' DLT rows (the palm's only, or all of them); :func:`translation_from_masks` without
  keypoints, from the mask centroids (and, with one mask, its area).
* :func:`view_candidate_rotations`: a pool of ``rotation_pool`` random global rotations (plus,
  when two or more views have keypoints, the Kabsch alignment of the template's keypoints with
  the triangulated ones) is scored without optimisation, each with its translation in closed
  form: the palm keypoints' L1 reprojection error plus the silhouette terms. The ``restarts``
  best, ``restart_separation_deg`` apart, are the keypoint stage's starts.
"""

from __future__ import annotations

import math
from typing import Any

import torch

from ...geometry.rotations import axis_angle_to_matrix, matrix_to_axis_angle
from ...skeleton import NUM_KEYPOINTS
from .config import FitImagesConfig
from .terms import ViewData, keypoint_l1, silhouette_terms

__all__ = [
    "random_rotations",
    "rotation_angles",
    "triangulate",
    "kabsch_rotation",
    "solve_translation",
    "translation_from_masks",
    "view_candidate_rotations",
]

_TYPICAL_SILHOUETTE_M2 = 0.006  # silhouette area of an adult hand seen from a random side, m^2
_SCORE_CHUNK = 256  # rotations scored at once (bounded memory)


def random_rotations(num: int, generator: torch.Generator) -> torch.Tensor:
    """[num, 3] axis-angle (radians) of uniformly random rotations (unit quaternions)."""
    quat = torch.randn(num, 4, generator=generator, dtype=torch.float64)
    quat = quat / quat.norm(dim=-1, keepdim=True)
    quat = quat * torch.where(quat[:, :1] < 0, -1.0, 1.0)
    half = torch.acos(quat[:, 0].clamp(-1.0, 1.0))
    axis = quat[:, 1:] / torch.sin(half).clamp_min(1e-12)[:, None]
    return (axis * (2.0 * half)[:, None]).float()


def rotation_angles(first: torch.Tensor, second: torch.Tensor) -> torch.Tensor:
    """Angles (radians) between rotation matrices first [A, 3, 3] and second [B, 3, 3] ->
    [A, B]."""
    trace = torch.einsum("aij,bij->ab", first, second)
    return torch.acos(((trace - 1.0) / 2.0).clamp(-1.0, 1.0))


def triangulate(data: ViewData) -> tuple[torch.Tensor, torch.Tensor]:
    """DLT triangulation of every keypoint seen in two or more views.

    -> points [21, 3] metres (world), valid [21] bool.
    """
    projections = torch.cat([data.R, data.t[..., None]], dim=-1).double()
    projections = data.K.double() @ projections  # [C, 3, 4]
    keypoints = data.keypoints.double()
    points = torch.zeros(NUM_KEYPOINTS, 3, dtype=torch.float64, device=data.device)
    valid = torch.zeros(NUM_KEYPOINTS, dtype=torch.bool, device=data.device)
    for k in range(NUM_KEYPOINTS):  # 21 tiny SVDs, once per fit
        seen = data.visible[:, k] > 0
        if int(seen.sum()) < 2:
            continue
        proj, uv = projections[seen], keypoints[seen, k]
        rows = torch.cat([uv[:, :1] * proj[:, 2] - proj[:, 0],
                          uv[:, 1:] * proj[:, 2] - proj[:, 1]])  # [2 n, 4]
        rows = rows / rows.norm(dim=-1, keepdim=True).clamp_min(1e-12)
        homogeneous = torch.linalg.svd(rows).Vh[-1]
        if abs(float(homogeneous[3])) < 1e-12:
            continue
        points[k] = homogeneous[:3] / homogeneous[3]
        valid[k] = True
    return points.float(), valid


def kabsch_rotation(source: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """Rotation (about the centroids) taking source [N, 3] onto target [N, 3] -> [3, 3]."""
    src = source.double() - source.double().mean(0)
    dst = target.double() - target.double().mean(0)
    u, _, vh = torch.linalg.svd(src.T @ dst)
    sign = torch.sign(torch.linalg.det(vh.T @ u.T))
    fix = torch.diag(torch.tensor([1.0, 1.0, float(sign)], dtype=torch.float64,
                                  device=source.device))
    return (vh.T @ fix @ u.T).float()


def solve_translation(points: torch.Tensor, data: ViewData, palm_only: bool = False
                      ) -> torch.Tensor:
    """Least-squares translation from keypoints: points [B, 21, 3] metres (posed, zero
    translation) -> [B, 3] metres such that ``points + T`` projects onto the visible 2D
    keypoints (DLT rows; only the palm's with ``palm_only``, when 3 or more are visible)."""
    kt_r = data.K @ data.R  # [C, 3, 3]
    offset = points[:, None] @ kt_r.transpose(-1, -2)[None] + (data.K @ data.t[..., None])[
        None, :, None, :, 0]  # [B, C, 21, 3]: K (R X + t)
    uv = data.keypoints[None]  # [1, C, 21, 2]
    visible = data.palm_visible if palm_only and data.num_palm_visible >= 3 else data.visible
    weight = visible[None, ..., None]  # [1, C, 21, 1]
    # (u M_2 - M_0) . T = -(u m_2 - m_0), likewise for v; M = K R, m = K (R X + t).
    rows_u = uv[..., :1, None] * kt_r[None, :, None, 2:3] - kt_r[None, :, None, 0:1]
    rows_v = uv[..., 1:, None] * kt_r[None, :, None, 2:3] - kt_r[None, :, None, 1:2]
    rhs_u = -(uv[..., 0] * offset[..., 2] - offset[..., 0])
    rhs_v = -(uv[..., 1] * offset[..., 2] - offset[..., 1])
    rows = torch.cat([rows_u[..., 0, :].expand(offset.shape[0], -1, -1, -1),
                      rows_v[..., 0, :].expand(offset.shape[0], -1, -1, -1)], dim=2)
    rhs = torch.cat([rhs_u, rhs_v], dim=2)  # [B, C, 42]
    weights = torch.cat([weight, weight], dim=2)  # [1, C, 42, 1]
    matrix = (rows * weights).reshape(offset.shape[0], -1, 3).double()
    vector = (rhs * weights[..., 0]).reshape(offset.shape[0], -1).double()
    normal = matrix.transpose(1, 2) @ matrix + 1e-9 * torch.eye(3, dtype=torch.float64,
                                                                 device=points.device)
    return torch.linalg.solve(normal, matrix.transpose(1, 2) @ vector[..., None])[..., 0].float()


def translation_from_masks(vertices: torch.Tensor, data: ViewData) -> torch.Tensor:
    """Translation from the masks alone: the template's centroid goes to the point nearest to
    the rays through the mask centroids (with one mask: at the depth where a hand would cover
    the mask's area). vertices [B, V, 3] metres (posed, zero translation) -> [B, 3] metres."""
    origins, directions, depths = [], [], []
    for view in data.views:
        if view.mask is None:
            continue
        coords = view.mask.nonzero().float()  # [M, 2] (row, col)
        centre = coords.mean(0).flip(0) + 0.5  # (u, v)
        camera = view.camera
        direction = camera.R.T @ torch.linalg.solve(camera.K, torch.cat([centre,
                                                                         centre.new_ones(1)]))
        direction = direction / direction.norm()
        focal = float(camera.K[0, 0] * camera.K[1, 1]) ** 0.5
        depths.append(focal * math.sqrt(_TYPICAL_SILHOUETTE_M2 / float(coords.shape[0])))
        origins.append(camera.center.float())
        directions.append(direction.float())
    origins_t, directions_t = torch.stack(origins), torch.stack(directions)
    if len(origins) >= 2:
        # argmin_x sum |(I - d d^T)(x - o)|^2
        eye = torch.eye(3, device=origins_t.device)
        projector = eye - directions_t[:, :, None] * directions_t[:, None, :]
        point = torch.linalg.solve(projector.sum(0), (projector @ origins_t[..., None]).sum(0))
        point = point[:, 0]
    else:
        point = origins_t[0] + depths[0] * directions_t[0]
    return point - vertices.mean(1)


def _score_rotations(matrices: torch.Tensor, keypoints: torch.Tensor, vertices: torch.Tensor,
                     pivot: torch.Tensor, data: ViewData, config: FitImagesConfig
                     ) -> torch.Tensor:
    """Score of the template turned by each rotation [P, 3, 3] about ``pivot`` [3], with its
    translation in closed form: the palm keypoints' L1 (pixels) plus the weighted silhouette
    terms. keypoints [21, 3], vertices [V, 3]: about the pivot. -> [P]."""
    scores = []
    for begin in range(0, matrices.shape[0], _SCORE_CHUNK):
        turned = matrices[begin:begin + _SCORE_CHUNK]
        posed_keypoints = torch.einsum("pij,kj->pki", turned, keypoints) + pivot
        posed_vertices = torch.einsum("pij,vj->pvi", turned, vertices) + pivot
        score = posed_keypoints.new_zeros(turned.shape[0])
        if data.num_visible:
            shift = solve_translation(posed_keypoints, data, palm_only=True)
            pixels, _ = data.project(posed_keypoints + shift[:, None])
            score = score + keypoint_l1(pixels, data, palm_only=True)
        else:
            shift = translation_from_masks(posed_vertices, data)
        if data.num_masks:
            pixels, _ = data.project(posed_vertices + shift[:, None])
            outside, coverage = silhouette_terms(pixels, data)
            score = score + config.silhouette_weight * outside + config.coverage_weight * coverage
        scores.append(score)
    return torch.cat(scores)


def view_candidate_rotations(template: Any, data: ViewData, config: FitImagesConfig,
                             start_fingers: torch.Tensor, generator: torch.Generator
                             ) -> torch.Tensor:
    """``config.restarts`` starting global rotations [R, 3] axis-angle radians, best first,
    scored on the views (the point fit's counterpart, from a cloud's principal axes, is
    :func:`lisa_hand.fitting.points.global_pose.cloud_candidate_rotations`).

    template: the mesh template (``forward(pose, betas, translation)``, ``num_betas``).
    start_fingers: [45] the finger pose (radians) of the template that is turned about its
    wrist and scored (see the module docstring). Also fixes the template vertices of the
    coverage term (:meth:`ViewData.choose_vertices`), drawing from ``generator``.
    """
    device = data.device
    num_betas = int(template.num_betas)
    start_pose = torch.cat([torch.zeros(3, device=device), start_fingers])[None]
    rest = template.forward(start_pose, torch.zeros(1, num_betas, device=device), None)
    pivot = rest.joints[0, 0]  # the global rotation turns the hand about its wrist joint
    keypoints = rest.keypoints[0] - pivot
    vertices = rest.vertices[0] - pivot
    data.choose_vertices(vertices.shape[0], config.coverage_vertices, generator)
    pool = [random_rotations(config.rotation_pool, generator).to(device)]
    if data.num_visible:
        points, valid = triangulate(data)
        if int(valid.sum()) >= 4:
            rotation = kabsch_rotation(keypoints[valid], points[valid])
            pool.insert(0, matrix_to_axis_angle(rotation)[None])
    pool_aa = torch.cat(pool)
    matrices = axis_angle_to_matrix(pool_aa)
    order = _score_rotations(matrices, keypoints, vertices, pivot, data, config).argsort()
    separation = math.radians(config.restart_separation_deg)
    chosen: list[int] = []
    for index in order.tolist():
        if chosen and bool((rotation_angles(matrices[index:index + 1], matrices[chosen])
                            < separation).any()):
            continue
        chosen.append(index)
        if len(chosen) == config.restarts:
            break
    return pool_aa[chosen]
