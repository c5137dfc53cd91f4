"""The MANO-like baseline: the mesh template fitted to a point cloud, subdivided for the metrics.

The paper fits MANO by optimising its pose and shape and, since MANO has 778 vertices, measures
its surface subdivided to about 100k vertices (Section 5.2). Here the template is the open hand
model's MANO-like mesh (:func:`lisa_hand.handmodel.template.load_template`; the real MANO when
the user builds the template from their ``MANO_RIGHT.pkl``, :func:`template_from_mano`).

Fit (:func:`fit_template_points`): unknowns are the 48-D pose, the translation and the template's
shape coefficients. Candidates: the template in the flat, relaxed and fist poses put on the
cloud in the 24 orientations that map its principal axes onto the cloud's
(:func:`lisa_hand.fitting.points.global_pose.cloud_candidate_rotations`). Every candidate is aligned
rigidly, the ``keep`` best then fit every unknown. Energy, per candidate, with ``S`` points
spread over the template's triangles (fixed barycentric coordinates, so they follow the posed
surface)::

    E = mean_i rho(d(c_i, S)) + w_c mean_s rho(d(s, C)) + priors

``rho`` is Geman-McClure (:func:`lisa_hand.fitting.robust.robust_loss`, scale
``robust_scale_mm``): the cloud-to-template term asks every scan point to be on the template;
the bounded template-to-cloud term keeps the template from growing where the scan has nothing.
Priors (:mod:`lisa_hand.fitting.priors`, shared with the other fitters): joint limits, a small
pull of the fingers towards ``prior_pose`` (relaxed) and of the shape coefficients towards 0.

A left hand (``side="left"``) is fitted as the right hand of the mirrored cloud and mirrored
back, as the point and image fits do.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch

from ..fitting.optim import adam, lr_schedule
from ..fitting.priors import PRIOR_POSES, finger_pose_prior, joint_limit_excess
from ..fitting.robust import robust_loss
from ..geometry.meshing import sample_triangles
from ..skeleton.params import HandParams
from ..utils.config import check_int_fields

__all__ = ["TemplateFitConfig", "TemplateFitResult", "fit_template_points", "subdivide_to",
           "template_mesh"]

_MM = 1e-3


@dataclass(frozen=True)
class TemplateFitConfig:
    """Settings of :func:`fit_template_points` (defaults: a few seconds on one CPU thread)."""

    init_poses: tuple[str, ...] = ("flat", "relaxed", "fist")
    """Named finger poses the candidates start from (``named_pose``)."""
    rigid_iters: int = 100
    """Iterations of the rigid alignment of every candidate."""
    full_iters: int = 300
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
    rotation_lr: float = 0.03
    """Adam step of the global rotation (axis-angle), radians."""
    translation_lr: float = 0.003
    """Adam step of the translation, metres."""
    pose_lr: float = 0.03
    """Adam step of the finger pose (axis-angle), radians."""
    betas_lr: float = 0.05
    """Adam step of the shape coefficients."""
    final_lr_fraction: float = 0.1
    """Learning rates decay exponentially to this fraction of their start."""
    limit_weight: float = 1.0
    """Weight of the squared excess over the joint limits
    (:func:`lisa_hand.fitting.priors.joint_limit_excess`, radians^2)."""
    pose_weight: float = 1e-4
    """Weight of the finger-pose prior (:func:`lisa_hand.fitting.priors.finger_pose_prior`:
    mean squared difference from ``prior_pose``, radians^2)."""
    prior_pose: str = "relaxed"
    """The pose the finger-pose prior pulls toward ('relaxed' or 'flat')."""
    betas_weight: float = 1e-5
    """Weight of the mean squared shape coefficients."""
    seed: int = 0
    """Seed of the surface points and of the random cloud subsets."""

    def __post_init__(self) -> None:
        check_int_fields(self, ("rigid_iters", "full_iters", "seed"), 0)
        check_int_fields(self, ("keep", "surface_points", "cloud_points",
                                "rigid_surface_points", "rigid_cloud_points"), 1)
        if not self.init_poses:
            raise ValueError("init_poses must name at least one pose")
        if not self.robust_scale_mm > 0:
            raise ValueError(f"robust_scale_mm must be > 0, got {self.robust_scale_mm!r}")
        if self.prior_pose not in PRIOR_POSES:
            raise ValueError(f"prior_pose must be one of {PRIOR_POSES}, got {self.prior_pose!r}")


@dataclass
class TemplateFitResult:
    """Result of :func:`fit_template_points`.

    params: the fitted hand: pose [48] radians, translation [3] metres, betas [K], the
        template's skeleton for them (``rest_joints``) and its side; no LISA codes
        (``shape_code`` is empty, ``model`` is "template"); ``params.extra["fit"]`` holds the
        numbers below.
    energy: the winning candidate's final energy (metres). seconds: the fit's wall time.
    """

    params: HandParams
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
    faces, u, v = sample_triangles(area, count, generator)
    bary = torch.stack([1 - u - v, u, v], dim=-1)
    return faces.to(template.device), bary.to(device=template.device, dtype=template.dtype)


class _TemplateEnergy:
    """The energy of the module docstring for candidates of one template and one cloud."""

    def __init__(self, template: Any, config: TemplateFitConfig, generator: torch.Generator
                 ) -> None:
        from ..fitting.priors import prior_mean_fingers

        self.template = template
        self.config = config
        self.face_ids, self.bary = _surface_samples(template, config.surface_points, generator)
        self.mean_fingers = prior_mean_fingers(config.prior_pose)
        self.scale = config.robust_scale_mm * _MM

    def surface(self, pose, betas, translation, count: int) -> torch.Tensor:
        """[K, count, 3] the first ``count`` surface points of the posed templates."""
        template = self.template
        vertices = template.forward(pose, betas, translation).vertices
        corners = vertices[:, template.faces[self.face_ids[:count]]]  # [K, S, 3, 3]
        return (corners * self.bary[None, :count, :, None]).sum(dim=2)

    def __call__(self, orient, fingers, betas, translation, cloud_sample: torch.Tensor,
                 count: int) -> torch.Tensor:
        """[K] energies of the candidates (orient [K, 3], fingers [K, 45], betas [K, B],
        translation [K, 3]) on cloud points [N, 3] and ``count`` surface points."""
        config = self.config
        pose = torch.cat([orient, fingers], dim=-1)
        samples = self.surface(pose, betas, translation, count)  # [K, S, 3]
        cloud_batch = cloud_sample[None].expand(samples.shape[0], -1, -1)
        with torch.no_grad():  # nearest neighbours without a graph (cdist's backward is slow)
            distance = torch.cdist(cloud_batch, samples.detach())
            to_surface, to_cloud = distance.argmin(dim=2), distance.argmin(dim=1)
        nearest_sample = samples.gather(1, to_surface[..., None].expand(-1, -1, 3))
        data = robust_loss((cloud_batch - nearest_sample).norm(dim=-1), "geman_mcclure",
                           self.scale).mean(dim=1)
        nearest_cloud = cloud_batch.gather(1, to_cloud[..., None].expand(-1, -1, 3))
        coverage = robust_loss((samples - nearest_cloud).norm(dim=-1), "geman_mcclure",
                               self.scale).mean(dim=1)
        prior = (config.limit_weight * joint_limit_excess(pose)
                 + config.pose_weight * finger_pose_prior(fingers, self.mean_fingers)
                 + config.betas_weight * betas.square().mean(dim=-1))
        return data + config.coverage_weight * coverage + prior


def _initial_candidates(template: Any, dense: torch.Tensor, config: TemplateFitConfig
                        ) -> dict[str, torch.Tensor]:
    """Every initial finger pose in the 24 axis-aligning orientations, the template's centroid
    on the cloud's: {"orient" [K, 3], "fingers" [K, 45], "betas" [K, B], "translation" [K, 3]}."""
    from ..fitting.points.global_pose import cloud_candidate_rotations, initial_finger_pose
    from ..geometry import matrix_to_axis_angle

    centroid = dense.mean(dim=0)
    orient, fingers, translation = [], [], []
    zero_betas = torch.zeros(1, int(template.num_betas))
    for name in config.init_poses:
        finger = initial_finger_pose(name).float()
        pose = torch.cat([torch.zeros(3), finger])[None]
        with torch.no_grad():
            posed = template.forward(pose, zero_betas, None).vertices[0]
        root = template.rest_joints(zero_betas)[0, 0]
        rotations = cloud_candidate_rotations(dense, posed)
        # The template rotates about its root joint: put its centroid on the cloud's.
        offset = ((posed.mean(dim=0) - root) @ rotations.transpose(-1, -2)) + root
        orient.append(matrix_to_axis_angle(rotations))
        fingers.append(finger.expand(rotations.shape[0], -1))
        translation.append(centroid - offset)
    orient = torch.cat(orient)
    return {"orient": orient, "fingers": torch.cat(fingers).clone(),
            "betas": torch.zeros(orient.shape[0], int(template.num_betas)),
            "translation": torch.cat(translation)}


def _optimise(energy: _TemplateEnergy, unknowns: dict[str, torch.Tensor],
              rates: dict[str, float], iterations: int, cloud: torch.Tensor, cloud_count: int,
              surface_count: int, generator: torch.Generator) -> None:
    """Adam (:func:`lisa_hand.fitting.optim.lr_schedule`) on the unknowns named in ``rates``,
    in place; every iteration on ``cloud_count`` random cloud points (with replacement) and
    ``surface_count`` surface points."""
    names = list(rates)
    for name in names:
        unknowns[name].requires_grad_(True)
    optimizer = adam([(unknowns[name], rates[name]) for name in names])
    schedule = lr_schedule(optimizer, iterations, energy.config.final_lr_fraction)
    for _ in range(iterations):
        pick = torch.randint(0, cloud.shape[0], (cloud_count,), generator=generator)
        optimizer.zero_grad(set_to_none=True)
        energy(**unknowns, cloud_sample=cloud[pick], count=surface_count).sum().backward()
        optimizer.step()
        schedule.step()
    for name in names:
        unknowns[name].requires_grad_(False)


def _check_points(points) -> torch.Tensor:
    cloud = torch.as_tensor(np.asarray(points), dtype=torch.float32)
    if cloud.ndim != 2 or cloud.shape[1] != 3 or cloud.shape[0] < 10:
        raise ValueError(f"points must have shape [N, 3] with N >= 10, got {list(cloud.shape)}")
    if not torch.isfinite(cloud).all():
        raise ValueError("points has non-finite entries")
    return cloud


def fit_template_points(
    points: np.ndarray | torch.Tensor,
    template: Any = None,
    config: TemplateFitConfig | None = None,
    *,
    side: str = "right",
) -> TemplateFitResult:
    """Fit the mesh template's pose, translation and shape to a point cloud of one hand.

    points: [N, 3] metres, finite, any position and orientation.
    template: a :class:`~lisa_hand.handmodel.template.MeshTemplate` (default: the shipped one).
    side: 'right' or 'left' (a left hand is fitted mirrored, see the module docstring).
    -> :class:`TemplateFitResult` (on the CPU).
    """
    from ..fitting.points.cloud import dense_points
    from ..fitting.sides import mirror_cloud, mirror_hand
    from ..handmodel.template import load_template

    config = TemplateFitConfig() if config is None else config
    start = time.perf_counter()
    template = load_template() if template is None else template
    template = template.to(dtype=torch.float32, device=torch.device("cpu"))
    cloud = mirror_cloud(_check_points(points), side)
    generator = torch.Generator().manual_seed(config.seed)
    energy = _TemplateEnergy(template, config, generator)
    dense = dense_points(cloud[torch.randperm(cloud.shape[0], generator=generator)[:4096]])
    unknowns = _initial_candidates(template, dense, config)
    pick = torch.randperm(cloud.shape[0], generator=generator)[: 2 * config.cloud_points]
    evaluation = cloud[pick]
    _optimise(energy, unknowns, {"orient": config.rotation_lr,
                                 "translation": config.translation_lr},
              config.rigid_iters, cloud, config.rigid_cloud_points, config.rigid_surface_points,
              generator)
    with torch.no_grad():
        scores = energy(**unknowns, cloud_sample=evaluation, count=config.rigid_surface_points)
    keep = scores.argsort()[: config.keep]
    unknowns = {name: value[keep].clone() for name, value in unknowns.items()}
    _optimise(energy, unknowns, {"orient": config.rotation_lr, "fingers": config.pose_lr,
                                 "betas": config.betas_lr,
                                 "translation": config.translation_lr},
              config.full_iters, cloud, config.cloud_points, config.surface_points, generator)
    with torch.no_grad():
        scores = energy(**unknowns, cloud_sample=evaluation, count=config.surface_points)
    best = int(scores.argmin())
    params = _fitted_hand(template, unknowns, best)
    seconds = time.perf_counter() - start
    params.extra["fit"] = {"energy": float(scores[best]), "seconds": seconds}
    if side == "left":
        params = mirror_hand(params)
    return TemplateFitResult(params=params, energy=float(scores[best]), seconds=seconds)


def _fitted_hand(template: Any, unknowns: dict[str, torch.Tensor], best: int) -> HandParams:
    """Candidate ``best`` as a right hand (the template's skeleton for its betas)."""
    from ..geometry import axis_angle_to_matrix, matrix_to_axis_angle

    # A rotation vector near pi can flip; normalise through the matrix.
    rotation = matrix_to_axis_angle(axis_angle_to_matrix(unknowns["orient"][best]))
    betas = unknowns["betas"][best].detach()
    with torch.no_grad():
        rest_joints = template.rest_joints(betas[None])[0]
    return HandParams(pose=torch.cat([rotation, unknowns["fingers"][best]]).detach(),
                      translation=unknowns["translation"][best].detach(),
                      rest_joints=rest_joints, shape_code=torch.zeros(0), betas=betas,
                      side="right", model="template")


def template_mesh(template: Any, pose: torch.Tensor, betas: torch.Tensor,
                  translation: torch.Tensor, side: str = "right"
                  ) -> tuple[np.ndarray, np.ndarray]:
    """The posed template: (vertices [V, 3] float64 metres, faces [F, 3] int64).

    pose: [48] radians; betas: [K]; translation: [3] metres; side: of the hand they describe
    (a left hand is the mirror image of the template's right hand, faces turned so that they
    still face outwards).
    """
    from ..skeleton import check_side, mirror_points, mirror_pose

    left = check_side(side) == "left"
    pose, translation = pose.float().cpu(), translation.float().cpu()
    if left:
        pose, translation = mirror_pose(pose), mirror_points(translation)
    template = template.to(dtype=torch.float32, device=torch.device("cpu"))
    with torch.no_grad():
        out = template.forward(pose[None], betas.float().cpu()[None], translation[None])
    vertices = out.vertices[0]
    faces = template.faces.cpu().numpy().astype(np.int64)
    if left:
        vertices, faces = mirror_points(vertices), np.ascontiguousarray(faces[:, ::-1])
    return vertices.double().numpy(), faces


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
