"""The surface proxy of the point fit's first stages, and the articulated proxy stage.

The proxy is a cheap stand-in for the LISA field: points on the model's zero level set at rest
(mean shape code, or a fitted hand's) with their normals and the field's skinning weights, posed
by linear blend skinning. Its energy (:func:`proxy_energy`) is the sum of the terms of
:mod:`.proxy_terms`: the robust distance from random cloud points to the proxy, the proxy's
coverage by the cloud, and for a one-view scan or a hand on a desk, the free space the sensor
saw and the support plane. The robust scale goes down geometrically from
``robust_scale_start_mm`` to ``robust_scale_mm`` over each stage (coarse to fine).
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import dataclass

import torch

from ...skeleton import NUM_JOINTS, POSE_DIM, forward_kinematics, linear_blend_skinning
from ...skeleton.params import HandParams
from ..optim import adam, lr_schedule
from ..priors import prior_mean_fingers
from ..robust import annealed_scale
from ..stages import StageReport
from ..terms import hand_prior
from .candidates import CandidateBatch
from .cloud import TargetCloud
from .monitor import FitMonitor
from .proxy_terms import ProxySample, proxy_terms

__all__ = ["SurfaceProxy", "build_surface_proxy", "covered_fraction", "unseen_fingers",
           "proxy_energy", "optimise_on_proxy", "fit_proxy_pose"]

_MM = 1e-3
_PROXY_STAGE_POINTS = 256  # cloud points per iteration of the proxy stages


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
    """[K] the proxy energy (:func:`.proxy_terms.proxy_terms`) at robust scale ``scale``
    (metres), on ``num_points`` random cloud points (drawn from ``cloud.generator``; 256 by
    default, the same for every candidate) and the proxy points ``subset`` (all: None). config:
    a :class:`~lisa_hand.fitting.points.config.FitPointsConfig`. free_space: with the
    free-space term (when the cloud has a depth image)."""
    seen_only = cloud.depth is not None and config.coverage_seen_only
    normals = (proxy.world_normals(batch, subset)
               if config.proxy_tangent_weight != 1.0 or seen_only else None)
    sample = ProxySample(proxy=proxy, cloud=cloud, points=proxy.world(batch, subset),
                         normals=normals,
                         rest=proxy.points_rest if subset is None else proxy.points_rest[subset],
                         targets=cloud.points[cloud.sample(num_points)], scale=scale,
                         config=config)
    return proxy_terms(config, free_space)(sample)


def optimise_on_proxy(proxy: SurfaceProxy, cloud: TargetCloud, batch: CandidateBatch, config,
                      stage: str, iterations: int, *, like: HandParams,
                      proxy_subset: torch.Tensor | None = None, step_offset: int = 0,
                      total: int | None = None, monitor: FitMonitor | None = None,
                      unseen: torch.Tensor | None = None) -> torch.Tensor:
    """Adam on :func:`proxy_energy` for steps ``step_offset .. step_offset + iterations`` of a
    stage of ``total`` steps (the schedules' length; default ``iterations``), in place on
    ``batch``: 'align' moves the rotation and position, any other stage ('pose', 'fingers')
    also the finger pose (with the finger-pose and joint-limit prior). ``like`` and the batch's
    fixed skeletons make the monitor's hands (:meth:`CandidateBatch.hand`). unseen: [5] weights of
    the fingers a one-view sensor could not see (:func:`unseen_fingers`), or None. -> [K] the
    final proxy energies."""
    total = iterations if total is None else total
    rates = (config.rotation_lr, config.translation_lr, config.pose_lr)
    tensors = batch.unknowns(with_shape=False)[: 2 if stage == "align" else 3]
    optimizer = adam(list(zip(tensors, rates[: len(tensors)], strict=True)))
    schedule = lr_schedule(optimizer, total, config.final_lr_fraction, start=step_offset)
    mean_fingers = prior_mean_fingers(config.prior_pose, batch.pivot.device, batch.pivot.dtype)
    prior = hand_prior(config, mean_fingers, coupling=unseen)
    start, end = config.robust_scale_start_mm * _MM, config.robust_scale_mm * _MM
    energy = None
    for step in range(step_offset, step_offset + iterations):
        energy = proxy_energy(proxy, cloud, batch, config, annealed_scale(start, end, step, total),
                              proxy_subset, free_space=stage != "align")
        loss = energy
        if stage != "align":
            loss = loss + prior(batch.terms())
        batch.clear_grads()
        loss.sum().backward()
        optimizer.step()
        schedule.step()
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
                   config, *, monitor: FitMonitor | None = None,
                   unseen: torch.Tensor | None = None) -> tuple[list[HandParams], StageReport]:
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
                               like=candidates[0], monitor=monitor, unseen=unseen)
    hands = [batch.hand(index, candidates[index]) for index in range(batch.count)]
    history = monitor.history[began:] if monitor is not None else []
    energies = [float(e) for e in energy]
    return hands, StageReport(stage="pose", seconds=time.perf_counter() - start,
                              loss=min(energies), energies=energies, history=history)
