"""The surface proxy of the point fit's first stages, and the articulated proxy stage.

The proxy is a cheap stand-in for the LISA field: points on the model's zero level set at rest
(mean shape code, or a fitted hand's) with their normals and the field's skinning weights, posed
by linear blend skinning. Its energy (per candidate): the robust distance from each of 256 random
cloud points to the nearest proxy point (mostly along that point's normal,
``FitPointsConfig.proxy_tangent_weight``: the proxy's spacing does not set a floor under the
distance), plus ``coverage_weight`` times a robust distance from each proxy point to the cloud
(the cloud's distance grid). The first term alone lets extra model surface go unpunished (a flat
finger beside the curled finger of a fist scan); the second is a bounded Geman-McClure term
(scale ``coverage_scale_mm``), so the unseen side of a partial scan costs little and pulls
weakly; with a one-view scan's sensor position it is asked only of the proxy points the sensor
could have returned (``coverage_seen_only``). ``sigma`` goes down geometrically from
``robust_scale_start_mm`` to ``robust_scale_mm`` over each stage (coarse to fine). For a
one-view scan whose sensor position is known, a third term, ``free_space_weight`` times the
bounded penalty (same scale) of how far each proxy point lies in the space the sensor saw to be
empty (:class:`~.free_space.DepthImage`; points beyond the wrist joint are not asked, a scan may
stop there), in every stage but the global search ('align', where a hand still turned the wrong way
would be pushed sideways rather than turned). For a hand resting on a surface found in the scan
(:mod:`.support`), ``support_weight`` times the bounded penalty of how far each proxy point lies
beyond it (2 mm allowed), in every stage.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import dataclass

import torch

from ...skeleton import NUM_JOINTS, POSE_DIM, forward_kinematics, linear_blend_skinning
from ...skeleton.params import HandParams
from ..priors import prior_mean_fingers
from ..robust import annealed_scale, robust_loss
from ..stages import StageReport
from .adam import Adam, cosine_factor
from .candidates import CandidateBatch, point_prior
from .cloud import TargetCloud, nearest_distance
from .monitor import FitMonitor

__all__ = ["SurfaceProxy", "build_surface_proxy", "covered_fraction", "unseen_fingers",
           "proxy_energy", "optimise_on_proxy", "fit_proxy_pose"]

_MM = 1e-3
_PROXY_STAGE_POINTS = 256  # cloud points per iteration of the proxy stages
_SUPPORT_MARGIN_M = 0.002  # proxy points may sink this far into a support (noise, flesh)


@dataclass
class SurfaceProxy:
    """Points on a model's surface at rest and their skinning weights.

    points_rest: [P, 3] metres (rest pose, zero global rotation); weights: [P, 16] (rows sum
    to 1); rest_joints: [16, 3] metres, the skeleton they are posed on; pivot: [3] metres, the
    points' centroid (the candidates rotate about it, :class:`CandidateBatch`); normals_rest:
    [P, 3] outward unit normals at rest, or None.
    """

    points_rest: torch.Tensor
    weights: torch.Tensor
    rest_joints: torch.Tensor
    pivot: torch.Tensor
    normals_rest: torch.Tensor | None = None

    @property
    def num_points(self) -> int:
        return self.points_rest.shape[0]

    def sample(self, count: int, generator: torch.Generator) -> torch.Tensor:
        """[min(P, count)] indices of random distinct proxy points (all when P <= count)."""
        num = self.points_rest.shape[0]
        if num <= count:
            return torch.arange(num, device=self.points_rest.device)
        return torch.randperm(num, generator=generator)[:count].to(self.points_rest.device)

    def posed(self, finger_pose: torch.Tensor, subset: torch.Tensor | None = None
              ) -> torch.Tensor:
        """[K, P, 3] the proxy (or its points ``subset``) posed by finger poses [K, 45]
        (radians), zero global rotation (rest frame)."""
        count = finger_pose.shape[0]
        pose = torch.cat([finger_pose.new_zeros(count, 3), finger_pose], dim=-1)
        kinematics = forward_kinematics(pose, self.rest_joints)
        rest, weights = self.points_rest, self.weights
        if subset is not None:
            rest, weights = rest[subset], weights[subset]
        return linear_blend_skinning(rest, weights, kinematics.transforms)

    def without_forearm(self, offset: float) -> SurfaceProxy:
        """The proxy without its points farther than ``offset`` metres beyond the wrist joint
        (rest pose: a right hand's forearm runs along +x), the same pivot: what a scan cut at
        the wrist does not show (:mod:`lisa_hand.skeleton.wrist`)."""
        keep = self.points_rest[:, 0] <= self.rest_joints[0, 0] + offset
        normals = None if self.normals_rest is None else self.normals_rest[keep]
        return SurfaceProxy(self.points_rest[keep], self.weights[keep], self.rest_joints,
                            self.pivot, normals)

    def world(self, batch: CandidateBatch, subset: torch.Tensor | None = None) -> torch.Tensor:
        """[K, P, 3] world metres: the proxy posed by the candidates (on its own skeleton)."""
        local = self.posed(batch.finger_pose, subset)
        rotation = batch.rotation()
        return (local - self.pivot) @ rotation.transpose(-1, -2) + batch.position[:, None]

    def world_normals(self, batch: CandidateBatch, subset: torch.Tensor | None = None
                      ) -> torch.Tensor | None:
        """[K, P, 3] the proxy's unit normals posed by the candidates (each point's normal
        turned by its skinning weights' blend of the bone rotations, then the global rotation),
        or None for a proxy without normals."""
        if self.normals_rest is None:
            return None
        count = batch.finger_pose.shape[0]
        pose = torch.cat([batch.finger_pose.new_zeros(count, 3), batch.finger_pose], dim=-1)
        rotations = forward_kinematics(pose, self.rest_joints).transforms[..., :3, :3]
        normals, weights = self.normals_rest, self.weights
        if subset is not None:
            normals, weights = normals[subset], weights[subset]
        blended = torch.einsum("pj,kjab->kpab", weights, rotations)
        local = torch.einsum("kpab,pb->kpa", blended, normals)
        world = local @ batch.rotation().transpose(-1, -2)
        return torch.nn.functional.normalize(world, dim=-1)


@torch.no_grad()
def build_surface_proxy(model, rest_joints: torch.Tensor, shape_code: torch.Tensor,
                        color_code: torch.Tensor | None, num_points: int,
                        generator: torch.Generator) -> SurfaceProxy:
    """The proxy of a trained model's field (:class:`lisa_hand.model.trained.TrainedModel`):
    its zero level set at rest (64^3 marching cubes) for the rest joints [16, 3] and the codes
    shape_code [D], color_code [D'] or None (on the field's device and dtype), at most
    ``num_points`` random vertices (``generator``), with the mesh's vertex normals and the
    field's skinning weights (the nearest bone region's for a field without them)."""
    import numpy as np
    import trimesh

    from ...geometry.meshing import extract_mesh
    from ...model.lisa import region_bounds

    field_model = model.field
    device, dtype = rest_joints.device, rest_joints.dtype
    state = field_model.prepare(
        torch.zeros(1, POSE_DIM, dtype=dtype, device=device), None, rest_joints[None],
        shape_code[None], None if color_code is None else color_code[None])
    low, high = region_bounds(state, field_model)
    low, high = low[0].cpu().double().numpy(), high[0].cpu().double().numpy()
    mesh = extract_mesh(field_model.sdf_fn(state), low, high, 64, lipschitz=2.0,
                        device=device, dtype=dtype)
    vertices = torch.from_numpy(mesh.vertices).to(device=device, dtype=dtype)
    if vertices.shape[0] == 0:
        raise ValueError("the model's surface at rest is empty: cannot fit with this model")
    normals = torch.from_numpy(np.array(trimesh.Trimesh(
        mesh.vertices, mesh.faces, process=False).vertex_normals)).to(device=device, dtype=dtype)
    if vertices.shape[0] > num_points:
        pick = torch.randperm(vertices.shape[0], generator=generator)[:num_points].to(device)
        vertices, normals = vertices[pick], normals[pick]
    out = field_model.field(state, vertices[None], with_color=False)
    if out.weights is not None:
        weights = out.weights[0]
    else:  # the single-MLP baseline has no skinning weights: the nearest bone region's
        excess = field_model.region_excess(state, vertices[None])[0]
        weights = torch.nn.functional.one_hot(excess.argmin(-1), NUM_JOINTS).to(dtype)
    return SurfaceProxy(vertices, weights, rest_joints, vertices.mean(dim=0), normals)


@torch.no_grad()
def covered_fraction(proxy: SurfaceProxy, cloud: TargetCloud, hand: HandParams,
                     distance: float) -> float:
    """Share of the proxy's points, posed as ``hand`` (a right hand on the proxy's skeleton),
    that lie within ``distance`` metres of the cloud (its distance grid,
    :meth:`TargetCloud.distance_grid`: good to about a 2 mm cell): near 1 for a scan from all
    sides, about a half for one side."""
    batch = CandidateBatch.from_hands([hand], proxy.pivot)
    gaps = cloud.distance_grid(proxy.world(batch))[0]
    return float((gaps < distance).to(torch.float64).mean())


@torch.no_grad()
def unseen_fingers(proxy: SurfaceProxy, cloud: TargetCloud, hand: HandParams,
                   seen_share: float) -> torch.Tensor | None:
    """[5] weights (0-1) of the fingers of :data:`~lisa_hand.fitting.priors.UNSEEN_FINGERS`
    (the four of ``COUPLED_FINGERS``, then the thumb) that a one-view scan's sensor could not
    see on ``hand`` (a right hand on the proxy's
    skeleton): 1 minus the share of the finger's proxy points the sensor could have returned
    (:meth:`.free_space.DepthImage.could_see`; each point counted for its dominant bone) over
    ``seen_share``, clamped to 0-1. None when the cloud has no sensor position.

    A finger that is hidden where the hand puts it tells the scan nothing, so its pose is the
    prior's: its neighbours' curl (:func:`~lisa_hand.fitting.priors.finger_coupling`) is a
    better guess than the mean pose (in a one-view fist, an unseen index left straight); an
    unseen thumb's is the mean pose (:func:`~lisa_hand.fitting.priors.thumb_pose_prior`: the
    free space alone would tuck a thumb hidden behind the palm under it)."""
    from ...skeleton import FINGER_JOINTS
    from ..priors import UNSEEN_FINGERS

    if cloud.depth is None:
        return None
    batch = CandidateBatch.from_hands([hand], proxy.pivot)
    normals = proxy.world_normals(batch)
    seeable = cloud.depth.could_see(proxy.world(batch)[0],
                                    None if normals is None else normals[0])
    bones = proxy.weights.argmax(-1)
    weights = []
    for name in UNSEEN_FINGERS:
        mine = torch.isin(bones, torch.tensor(FINGER_JOINTS[name], device=bones.device))
        share = float(seeable[mine].mean()) if bool(mine.any()) else 0.0
        weights.append(min(max(1.0 - share / seen_share, 0.0), 1.0))
    return torch.tensor(weights, device=proxy.points_rest.device, dtype=proxy.points_rest.dtype)


def proxy_energy(proxy: SurfaceProxy, cloud: TargetCloud, batch: CandidateBatch, config,
                 scale: float, subset: torch.Tensor | None = None,
                 num_points: int = _PROXY_STAGE_POINTS, free_space: bool = True
                 ) -> torch.Tensor:
    """[K] the proxy energy of the module docstring at robust scale ``scale`` (metres), on
    ``num_points`` random cloud points (drawn from ``cloud.generator``; 256 by default, the
    same for every candidate) and the proxy points ``subset`` (all: None). config: a
    :class:`~lisa_hand.fitting.points.config.FitPointsConfig`. free_space: add the free-space
    term (when the cloud has a depth image)."""
    proxy_points = proxy.world(batch, subset)
    points = cloud.points[cloud.sample(num_points)]
    tangent = config.proxy_tangent_weight
    seen_only = cloud.depth is not None and config.coverage_seen_only
    normals = proxy.world_normals(batch, subset) if tangent != 1.0 or seen_only else None
    distance = nearest_distance(points.expand(batch.count, -1, -1), proxy_points,
                                normals if tangent != 1.0 else None, tangent)
    energy = robust_loss(distance, config.robust_loss, scale).mean(-1)
    if config.coverage_weight > 0:
        uncovered = cloud.distance_grid(proxy_points)
        coverage = robust_loss(uncovered, "geman_mcclure", config.coverage_scale_mm * _MM)
        if cloud.depth is not None and config.coverage_seen_only:
            # a one-view scan shows only what faces its sensor and is not hidden behind
            # what it returned: the rest of the hand need not be near a scan point
            coverage = coverage * cloud.depth.could_see(proxy_points.detach(), None if normals
                                                        is None else normals.detach())
        energy = energy + config.coverage_weight * coverage.mean(-1)
    if free_space and cloud.depth is not None and config.free_space_weight > 0:
        # no proxy point where the sensor saw nothing (beyond the wrist joint it may stop)
        rest = proxy.points_rest if subset is None else proxy.points_rest[subset]
        hand_side = (rest[:, 0] <= proxy.rest_joints[0, 0]).to(proxy_points.dtype)
        seen = robust_loss(cloud.depth.violation(proxy_points), "geman_mcclure",
                           config.coverage_scale_mm * _MM)
        energy = energy + config.free_space_weight * (seen * hand_side).mean(-1)
    if cloud.support is not None and config.support_weight > 0:
        # the hand stays on its side of the surface it rests on (a small margin for noise)
        origin, normal = cloud.support
        beyond = (-((proxy_points - origin) @ normal) - _SUPPORT_MARGIN_M).clamp(min=0.0)
        energy = energy + config.support_weight * robust_loss(
            beyond, "geman_mcclure", config.coverage_scale_mm * _MM).mean(-1)
    return energy


def optimise_on_proxy(proxy: SurfaceProxy, cloud: TargetCloud, batch: CandidateBatch, config,
                      stage: str, iterations: int, *, like: HandParams,
                      proxy_subset: torch.Tensor | None = None, step_offset: int = 0,
                      total: int | None = None,
                      monitor: FitMonitor | None = None) -> torch.Tensor:
    """Adam on :func:`proxy_energy` for steps ``step_offset .. step_offset + iterations`` of a
    stage of ``total`` steps (the schedules' length; default ``iterations``), in place on
    ``batch``: 'align' moves the rotation and position, any other stage ('pose', 'fingers')
    also the finger pose (with the finger-pose and joint-limit prior). ``like`` and the batch's
    fixed skeletons make the monitor's hands (:meth:`CandidateBatch.hand`). -> [K] the final
    proxy energies."""
    total = iterations if total is None else total
    rates = (config.lr_rotation, config.lr_translation, config.lr_pose)
    tensors = batch.unknowns(with_shape=False)[: 2 if stage == "align" else 3]
    optimizer = Adam(list(zip(tensors, rates[: len(tensors)], strict=True)))
    mean_fingers = prior_mean_fingers(config.prior_pose, batch.pivot.device, batch.pivot.dtype)
    start, end = config.robust_scale_start_mm * _MM, config.robust_scale_mm * _MM
    energy = None
    for step in range(step_offset, step_offset + iterations):
        optimizer.factor = cosine_factor(step, total, config.lr_decay)
        energy = proxy_energy(proxy, cloud, batch, config, annealed_scale(start, end, step, total),
                              proxy_subset, free_space=stage != "align")
        loss = energy
        if stage != "align":
            loss = loss + point_prior(config, batch, mean_fingers, None, cloud.coupling)
        batch.clear_grads()
        loss.sum().backward()
        optimizer.step()
        if monitor is not None:
            monitor.record(stage, step, total, energy, lambda index: batch.hand(index, like))
    if energy is None:  # no iteration: score the starting points
        with torch.no_grad():
            energy = proxy_energy(proxy, cloud, batch, config,
                                  annealed_scale(start, end, step_offset, total), proxy_subset,
                                  free_space=stage != "align")
    batch.fold()
    return energy.detach()


def fit_proxy_pose(proxy: SurfaceProxy, cloud: TargetCloud, candidates: Sequence[HandParams],
                   config, *, monitor: FitMonitor | None = None
                   ) -> tuple[list[HandParams], StageReport]:
    """The articulated proxy stage ('pose', no network): ``config.pose_iters`` Adam steps of
    every candidate's global rotation, translation and finger pose on the proxy energy plus the
    finger-pose and joint-limit prior (batched).

    candidates: right hands (their rest joints should be the proxy's: the proxy is posed on its
    own). config: a :class:`~lisa_hand.fitting.points.config.FitPointsConfig`.
    -> (the candidates moved, in order; the :class:`StageReport` ('pose'): their final proxy
    energies, metres, in that order).
    """
    began = len(monitor.history) if monitor is not None else 0
    start = time.perf_counter()
    batch = CandidateBatch.from_hands(candidates, proxy.pivot)
    energy = optimise_on_proxy(proxy, cloud, batch, config, "pose", config.pose_iters,
                               like=candidates[0], monitor=monitor)
    hands = [batch.hand(index, candidates[index]) for index in range(batch.count)]
    history = monitor.history[began:] if monitor is not None else []
    energies = [float(e) for e in energy]
    return hands, StageReport(stage="pose", seconds=time.perf_counter() - start,
                              loss=min(energies), energies=energies, history=history)
