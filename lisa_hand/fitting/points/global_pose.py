"""The global-pose search of the point fit: where the hand is and which way it faces, from
scratch, with no network.

A hand in a scan can be in any orientation. The surface proxy
(:mod:`lisa_hand.fitting.points.proxy`)
is put on the cloud in 24 orientations per initial finger pose (``init_poses``: flat, relaxed,
fist): the rotations that map the proxy's principal axes onto the cloud's, up to the order and
the signs of the axes (the 24 rotations of a cube). The cloud's centroid and axes come from its
dense part (scattered outliers dropped). All candidates are refined at once by a rigid alignment
of the proxy energy; after a third of the iterations only the ``align_keep`` best distinct ones
go on, and the ``restarts`` best distinct ones are the result.
"""

from __future__ import annotations

import itertools
import math
import time

import torch

from ...skeleton import POSE_DIM
from ...skeleton.params import HandParams
from ..stages import StageReport
from .candidates import CandidateBatch
from .cloud import TargetCloud, dense_points
from .monitor import FitMonitor
from .proxy import SurfaceProxy, optimise_on_proxy

__all__ = ["cube_rotations", "principal_axes", "cloud_candidate_rotations",
           "initial_finger_pose", "distinct_best", "search_global_pose"]

_FINGER_DIM = POSE_DIM - 3
_DISTINCT_ANGLE = math.radians(30.0)  # candidates closer than this and _DISTINCT_DISTANCE
_DISTINCT_DISTANCE = 0.02  # metres      are the same candidate
_ALIGN_FIRST = 0.35  # fraction of the align iterations run by every candidate
_ALIGN_FIRST_PROXY = 300  # proxy points in that first part
_CENTRE_POINTS = 4096  # cloud points whose dense part gives the centroid and the axes


def cube_rotations(dtype: torch.dtype = torch.float64) -> torch.Tensor:
    """The 24 rotations of a cube: signed permutation matrices with determinant +1.

    -> [24, 3, 3]; the first one is the identity.
    """
    rotations = []
    for perm in itertools.permutations(range(3)):
        for signs in itertools.product((1.0, -1.0), repeat=3):
            matrix = torch.zeros(3, 3, dtype=torch.float64)
            for row, col in enumerate(perm):
                matrix[row, col] = signs[row]
            if torch.det(matrix) > 0:
                rotations.append(matrix)
    return torch.stack(rotations).to(dtype)


def principal_axes(points: torch.Tensor) -> torch.Tensor:
    """Principal axes of a point set as a rotation matrix.

    points: [N, 3]. -> [3, 3] whose columns are the unit eigenvectors of the covariance, in
    decreasing order of variance, the third flipped if needed so that the determinant is +1.
    """
    centred = points - points.mean(dim=0)
    covariance = centred.T @ centred / max(points.shape[0], 1)
    _, vectors = torch.linalg.eigh(covariance.double())  # ascending eigenvalues
    axes = vectors.flip(-1)
    if torch.det(axes) < 0:
        axes[:, 2] = -axes[:, 2]
    return axes.to(points.dtype)


def cloud_candidate_rotations(cloud: torch.Tensor, proxy: torch.Tensor) -> torch.Tensor:
    """The 24 rotations ``R = A_cloud C A_proxy^T`` that map the proxy's principal axes onto
    the cloud's, for every cube rotation ``C`` (any order and signs of the axes); the image
    fit's counterpart, scored on views, is
    :func:`lisa_hand.fitting.images.pose_search.view_candidate_rotations`.

    cloud: [N, 3]; proxy: [P, 3] (any frames). -> [24, 3, 3] rotations (proxy -> cloud).
    """
    cloud_axes = principal_axes(cloud)
    proxy_axes = principal_axes(proxy)
    cubes = cube_rotations(cloud.dtype).to(cloud.device)
    return cloud_axes @ cubes @ proxy_axes.T


def initial_finger_pose(name: str) -> torch.Tensor:
    """[45] finger pose (radians) of a named pose
    (:func:`lisa_hand.handmodel.poses.named_pose`), or zeros for 'zero'."""
    if name == "zero":
        return torch.zeros(_FINGER_DIM)
    from ...handmodel.poses import named_pose

    return named_pose(name)[3:]


def _angle(first: torch.Tensor, second: torch.Tensor) -> float:
    """Angle (radians) of the rotation between two rotation matrices [3, 3]."""
    cosine = (torch.trace(first.T @ second) - 1.0) / 2.0
    return float(torch.arccos(cosine.clamp(-1.0, 1.0)))


@torch.no_grad()
def distinct_best(batch: CandidateBatch, energy: torch.Tensor, count: int) -> torch.Tensor:
    """Indices of the ``count`` lowest energies [K], skipping candidates that repeat a better
    one (same initial finger pose ``batch.tag``, rotation within 30 degrees, position within
    2 cm). -> [<= count] long."""
    rotation = batch.rotation()
    chosen: list[int] = []
    for index in torch.argsort(energy).tolist():
        if all(int(batch.tag[index]) != int(batch.tag[other])
               or _angle(rotation[index], rotation[other]) > _DISTINCT_ANGLE
               or float((batch.position[index] - batch.position[other]).norm())
               > _DISTINCT_DISTANCE for other in chosen):
            chosen.append(index)
        if len(chosen) == count:
            break
    return torch.tensor(chosen, device=energy.device)


def _initial_batch(proxy: SurfaceProxy, cloud: TargetCloud, config, like: HandParams
                   ) -> CandidateBatch:
    """Every initial finger pose in the 24 orientations of :func:`cloud_candidate_rotations`,
    the posed proxy's centroid on the dense cloud's; codes and skeleton of ``like``."""
    device, dtype = proxy.pivot.device, proxy.pivot.dtype
    sample = dense_points(cloud.points[cloud.sample(_CENTRE_POINTS)])
    centroid = sample.mean(dim=0)
    rotations, positions, fingers, tags = [], [], [], []
    for number, name in enumerate(config.init_poses):
        finger = initial_finger_pose(name).to(device=device, dtype=dtype)
        posed = proxy.posed(finger[None])[0]
        candidates = cloud_candidate_rotations(sample, posed)
        # Put the posed proxy's centroid on the cloud's.
        offset = (candidates @ (posed.mean(dim=0) - proxy.pivot)[:, None])[..., 0]
        rotations.append(candidates)
        positions.append(centroid - offset)
        fingers.append(finger.expand(candidates.shape[0], -1))
        tags.append(torch.full((candidates.shape[0],), number, device=device))
    count = sum(r.shape[0] for r in rotations)
    shape_code = like.shape_code.to(proxy.pivot).expand(count, -1)
    rest_joints = like.rest_joints.to(proxy.pivot).expand(count, -1, -1)
    return CandidateBatch(torch.cat(rotations), torch.cat(positions), torch.cat(fingers),
                          shape_code, None, torch.cat(tags), pivot=proxy.pivot,
                          rest_joints=rest_joints)


def search_global_pose(proxy: SurfaceProxy, cloud: TargetCloud, config, like: HandParams, *,
                       monitor: FitMonitor | None = None
                       ) -> tuple[list[HandParams], StageReport]:
    """The global-pose search ('align', see the module docstring).

    proxy: the model's :class:`SurfaceProxy`; cloud: the target (its generator draws the
    subsets). config: a :class:`~lisa_hand.fitting.points.config.FitPointsConfig`
    (``init_poses``, ``align_iters``, ``align_keep``, ``restarts``, the proxy energy's
    settings). like: a right hand at rest on the proxy's skeleton whose skeleton, codes, side
    and model the candidates share (its shape code is the proxies').
    -> (the ``restarts`` best distinct candidates, best first; the :class:`StageReport`
    ('align') with their proxy energies, metres, and every initial candidate's after the first
    part, ``screened_energies``).
    """
    began = len(monitor.history) if monitor is not None else 0
    start = time.perf_counter()
    batch = _initial_batch(proxy, cloud, config, like)
    first = int(round(_ALIGN_FIRST * config.align_iters))
    proxy_subset = proxy.sample(_ALIGN_FIRST_PROXY, cloud.generator)

    def align(batch, iterations, **kwargs):
        return optimise_on_proxy(proxy, cloud, batch, config, "align", iterations, like=like,
                                 monitor=monitor, **kwargs)

    screened = align(batch, first, proxy_subset=proxy_subset)
    batch = batch.select(distinct_best(batch, screened, config.align_keep))
    energy = align(batch, config.align_iters - first, step_offset=first,
                   total=config.align_iters)
    index = distinct_best(batch, energy, config.restarts)
    picked = batch.select(index)
    hands = [picked.hand(number, like) for number in range(picked.count)]
    history = monitor.history[began:] if monitor is not None else []
    energies = [float(e) for e in energy[index]]
    return hands, StageReport(stage="align", seconds=time.perf_counter() - start,
                              loss=min(energies), energies=energies, history=history,
                              screened_energies=[float(e) for e in screened])
