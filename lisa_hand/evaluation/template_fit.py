"""The MANO-like baseline: the mesh template fitted to a point cloud, subdivided for the metrics.

The paper fits MANO by optimising its pose and shape and, since MANO has 778 vertices, measures
its surface subdivided to about 100k vertices (Section 5.2). Here the template is the open hand
model's MANO-like mesh (:func:`lisa_hand.handmodel.template.load_template`; the real MANO when
the user builds the template from their ``MANO_RIGHT.pkl``, :func:`template_from_mano`).

Fit (:func:`fit_template_points`): unknowns are the 48-D pose, the translation and the template's
shape coefficients. Candidates: the template in the flat, relaxed and fist poses put on the
cloud in the 24 orientations that map its principal axes onto the cloud's
(:func:`lisa_hand.fitting.points.candidate_rotations`). Every candidate is aligned rigidly, the
``keep`` best then fit every unknown. Energy, per candidate, with ``S`` points spread over the
template's triangles (fixed barycentric coordinates, so they follow the posed surface)::

    E = mean_i rho(d(c_i, S)) + w_c mean_s rho(d(s, C)) + priors

``rho`` is Geman-McClure (scale ``robust_scale_mm``): the cloud-to-template term asks every
scan point to be on the template; the bounded template-to-cloud term keeps the template from
growing where the scan has nothing. Priors: joint limits, a small pull of the fingers towards
the relaxed pose and of the shape coefficients towards 0.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch

from ..utils.config import check_int_fields

__all__ = ["TemplateFitConfig", "TemplateFit", "fit_template_points", "subdivide_to",
           "template_mesh"]

_MM = 1e-3


@dataclass(frozen=True)
class TemplateFitConfig:
    """Settings of :func:`fit_template_points` (defaults: a few seconds on one CPU thread)."""

    init_poses: tuple[str, ...] = ("flat", "relaxed", "fist")
    """Named finger poses the candidates start from (``named_pose``)."""
    rigid_iters: int = 100
    """Iterations of the rigid alignment of every candidate."""
    iters: int = 300
    """Iterations of the full fit (pose, translation, shape) of the ``keep`` best candidates."""
    keep: int = 4
    """Candidates that go on to the full fit."""
    surface_points: int = 2000
    """Points on the template's triangles (fixed barycentric coordinates)."""
    cloud_points: int = 1000
    """Cloud points drawn per iteration of the full fit."""
    rigid_surface_points: int = 400
    """Template points (a subset of ``surface_points``) in the rigid alignment."""
    rigid_cloud_points: int = 200
    """Cloud points drawn per iteration of the rigid alignment."""
    robust_scale_mm: float = 4.0
    """Scale of the Geman-McClure loss, millimetres."""
    coverage_weight: float = 0.5
    """Weight of the template-to-cloud term."""
    lr_rotation: float = 0.03
    lr_translation: float = 0.003
    lr_pose: float = 0.03
    lr_betas: float = 0.05
    final_lr_fraction: float = 0.1
    """Learning rates decay exponentially to this fraction of their start."""
    lambda_limits: float = 1.0
    """Weight of the squared excess over the joint limits (radians^2)."""
    lambda_pose: float = 1e-4
    """Weight of the mean squared finger-pose difference from the relaxed pose."""
    lambda_betas: float = 1e-5
    """Weight of the mean squared shape coefficients."""
    seed: int = 0

    def __post_init__(self) -> None:
        check_int_fields(self, ("rigid_iters", "iters", "seed"), 0)
        check_int_fields(self, ("keep", "surface_points", "cloud_points",
                                "rigid_surface_points", "rigid_cloud_points"), 1)
        if not self.init_poses:
            raise ValueError("init_poses must name at least one pose")
        if not self.robust_scale_mm > 0:
            raise ValueError(f"robust_scale_mm must be > 0, got {self.robust_scale_mm!r}")


@dataclass
class TemplateFit:
    """The fitted template: pose [48] radians, translation [3] metres, betas [K]; ``energy``
    the winning candidate's final energy (metres), ``seconds`` the fit's wall time."""

    pose: torch.Tensor
    translation: torch.Tensor
    betas: torch.Tensor
    energy: float
    seconds: float


def _surface_samples(template: Any, count: int, generator: torch.Generator
                     ) -> tuple[torch.Tensor, torch.Tensor]:
    """(face ids [S], barycentric coordinates [S, 3]) area-weighted on the mean template."""
    vertices = template.rest_vertices(torch.zeros(template.num_betas, dtype=template.dtype,
                                                  device=template.device))[0]
    corners = vertices[template.faces]
    area = torch.linalg.cross(corners[:, 1] - corners[:, 0],
                              corners[:, 2] - corners[:, 0]).norm(dim=-1)
    faces = torch.multinomial(area.double().cpu(), count, replacement=True, generator=generator)
    u, v = torch.rand(2, count, generator=generator, dtype=torch.float64)
    flip = u + v > 1
    u, v = torch.where(flip, 1 - u, u), torch.where(flip, 1 - v, v)
    bary = torch.stack([1 - u - v, u, v], dim=-1)
    return faces.to(template.device), bary.to(device=template.device, dtype=template.dtype)


def _geman_mcclure(distance: torch.Tensor, scale: float) -> torch.Tensor:
    squared = distance.square()
    return scale * squared / (squared + scale * scale)


def fit_template_points(
    points: np.ndarray | torch.Tensor,
    template: Any = None,
    config: TemplateFitConfig | None = None,
) -> TemplateFit:
    """Fit the mesh template's pose, translation and shape to a point cloud of a right hand.

    points: [N, 3] metres, finite, any position and orientation.
    template: a :class:`~lisa_hand.handmodel.template.MeshTemplate` (default: the shipped one).
    -> :class:`TemplateFit` (on the CPU).
    """
    from ..fitting.images import _limit_excess, _relaxed_fingers
    from ..fitting.points import _dense_points, _initial_finger_pose, candidate_rotations
    from ..geometry import axis_angle_to_matrix, matrix_to_axis_angle
    from ..handmodel.template import load_template

    config = TemplateFitConfig() if config is None else config
    start = time.perf_counter()
    template = load_template() if template is None else template
    template = template.to(dtype=torch.float32, device=torch.device("cpu"))
    cloud = torch.as_tensor(np.asarray(points), dtype=torch.float32)
    if cloud.ndim != 2 or cloud.shape[1] != 3 or cloud.shape[0] < 10:
        raise ValueError(f"points must have shape [N, 3] with N >= 10, got {list(cloud.shape)}")
    if not torch.isfinite(cloud).all():
        raise ValueError("points has non-finite entries")
    generator = torch.Generator().manual_seed(config.seed)
    face_ids, bary = _surface_samples(template, config.surface_points, generator)
    dense = _dense_points(cloud[torch.randperm(cloud.shape[0], generator=generator)[:4096]])
    centroid = dense.mean(dim=0)
    num_betas = int(template.num_betas)
    relaxed = _relaxed_fingers(torch.device("cpu"))
    scale = config.robust_scale_mm * _MM

    def surface(pose, betas, translation, count):
        vertices = template.forward(pose, betas, translation).vertices
        corners = vertices[:, template.faces[face_ids[:count]]]  # [K, S, 3, 3]
        return (corners * bary[None, :count, :, None]).sum(dim=2)

    # Candidates: every initial finger pose in the 24 axis-aligning orientations.
    orient, fingers, translation = [], [], []
    zero_betas = torch.zeros(1, num_betas)
    for name in config.init_poses:
        finger = _initial_finger_pose(name).float()
        pose = torch.cat([torch.zeros(3), finger])[None]
        with torch.no_grad():
            posed = template.forward(pose, zero_betas, None).vertices[0]
        root = template.rest_joints(zero_betas)[0, 0]
        rotations = candidate_rotations(dense, posed)
        # The template rotates about its root joint: put its centroid on the cloud's.
        offset = ((posed.mean(dim=0) - root) @ rotations.transpose(-1, -2)) + root
        orient.append(matrix_to_axis_angle(rotations))
        fingers.append(finger.expand(rotations.shape[0], -1))
        translation.append(centroid - offset)
    orient, fingers = torch.cat(orient), torch.cat(fingers).clone()
    translation = torch.cat(translation)
    betas = torch.zeros(orient.shape[0], num_betas)

    def energy(orient, fingers, betas, translation, cloud_sample, count):
        pose = torch.cat([orient, fingers], dim=-1)
        samples = surface(pose, betas, translation, count)  # [K, S, 3]
        cloud_batch = cloud_sample[None].expand(samples.shape[0], -1, -1)
        with torch.no_grad():  # nearest neighbours without a graph (cdist's backward is slow)
            distance = torch.cdist(cloud_batch, samples.detach())
            to_surface, to_cloud = distance.argmin(dim=2), distance.argmin(dim=1)
        nearest_sample = samples.gather(1, to_surface[..., None].expand(-1, -1, 3))
        data = _geman_mcclure((cloud_batch - nearest_sample).norm(dim=-1), scale).mean(dim=1)
        nearest_cloud = cloud_batch.gather(1, to_cloud[..., None].expand(-1, -1, 3))
        coverage = _geman_mcclure((samples - nearest_cloud).norm(dim=-1), scale).mean(dim=1)
        prior = (config.lambda_limits * _limit_excess(pose)
                 + config.lambda_pose * (fingers - relaxed).square().mean(dim=-1)
                 + config.lambda_betas * betas.square().mean(dim=-1))
        return data + config.coverage_weight * coverage + prior

    def optimise(unknowns, rates, iterations, cloud_count, surface_count):
        for value in unknowns:
            value.requires_grad_(True)
        optimizer = torch.optim.Adam([{"params": [u], "lr": r}
                                      for u, r in zip(unknowns, rates, strict=True)])
        gamma = config.final_lr_fraction ** (1.0 / max(iterations, 1))
        schedule = torch.optim.lr_scheduler.ExponentialLR(optimizer, gamma)
        for _ in range(iterations):
            pick = torch.randint(0, cloud.shape[0], (cloud_count,), generator=generator)
            optimizer.zero_grad(set_to_none=True)
            energy(orient, fingers, betas, translation, cloud[pick],
                   surface_count).sum().backward()
            optimizer.step()
            schedule.step()
        for value in unknowns:
            value.requires_grad_(False)

    pick = torch.randperm(cloud.shape[0], generator=generator)[: 2 * config.cloud_points]
    evaluation = cloud[pick]
    optimise([orient, translation], [config.lr_rotation, config.lr_translation],
             config.rigid_iters, config.rigid_cloud_points, config.rigid_surface_points)
    with torch.no_grad():
        scores = energy(orient, fingers, betas, translation, evaluation,
                        config.rigid_surface_points)
    keep = scores.argsort()[: config.keep]
    orient, fingers = orient[keep].clone(), fingers[keep].clone()
    betas, translation = betas[keep].clone(), translation[keep].clone()
    optimise([orient, fingers, betas, translation],
             [config.lr_rotation, config.lr_pose, config.lr_betas, config.lr_translation],
             config.iters, config.cloud_points, config.surface_points)
    with torch.no_grad():
        scores = energy(orient, fingers, betas, translation, evaluation, config.surface_points)
    best = int(scores.argmin())
    # A rotation vector near pi can flip; normalise through the matrix.
    rotation = matrix_to_axis_angle(axis_angle_to_matrix(orient[best]))
    return TemplateFit(pose=torch.cat([rotation, fingers[best]]).detach(),
                       translation=translation[best].detach(), betas=betas[best].detach(),
                       energy=float(scores[best]), seconds=time.perf_counter() - start)


def template_mesh(template: Any, pose: torch.Tensor, betas: torch.Tensor,
                  translation: torch.Tensor) -> tuple[np.ndarray, np.ndarray]:
    """The posed template: (vertices [V, 3] float64 metres, faces [F, 3] int64).

    pose: [48] radians; betas: [K]; translation: [3] metres.
    """
    template = template.to(dtype=torch.float32, device=torch.device("cpu"))
    with torch.no_grad():
        out = template.forward(pose.float().cpu()[None], betas.float().cpu()[None],
                               translation.float().cpu()[None])
    return (out.vertices[0].double().numpy(),
            template.faces.cpu().numpy().astype(np.int64))


def subdivide_to(vertices: np.ndarray, faces: np.ndarray, target: int = 100_000
                 ) -> tuple[np.ndarray, np.ndarray]:
    """Loop-subdivide a mesh (trimesh) the number of times that brings its vertex count
    closest to ``target`` (in ratio; each subdivision about quadruples it), as the paper does
    with MANO's 778 vertices (about 100k). -> (vertices [V', 3] float64, faces [F', 3] int64).
    """
    import trimesh

    mesh = trimesh.Trimesh(np.asarray(vertices, np.float64), np.asarray(faces, np.int64),
                           process=False)
    count = len(mesh.vertices)
    steps = 0
    while count * 4 <= target or abs(math.log(count * 4 / target)) < abs(math.log(count / target)):
        count *= 4
        steps += 1
    if steps:
        mesh = mesh.subdivide_loop(iterations=steps)
    return np.asarray(mesh.vertices, np.float64), np.asarray(mesh.faces, np.int64)
