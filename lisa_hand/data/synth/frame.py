"""One frame of a synthetic dataset: the posed hand's mesh, scan, SDF samples, images and
keypoints, written into its frame folder (the layout of :mod:`lisa_hand.data.layout`; the
generator and its choices are described in :mod:`lisa_hand.data.synth.dataset`).
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch

from ...geometry.cameras import Camera, save_cameras
from ...render.raycast import MeshRayCaster
from ...utils.io import write_json
from ..images import project_keypoints, render_views
from ..keypoints import write_keypoints
from ..layout import FramePaths, frame_id, write_depth, write_image, write_mask, write_npz
from ..scans import Scan, ScanConfig, sample_surface, sdf_samples, simulate_scan
from ..shading import GainBias
from .config import SynthConfig
from .scene import FrameSetup, SubjectRecord, frame_setup

__all__ = ["write_frame"]


def _scan_is_clean(scan: ScanConfig) -> bool:
    """Points exactly on the whole surface (no noise, no outliers, not partial)."""
    return (not scan.partial and scan.noise_normal_std == 0 and scan.noise_isotropic_std == 0
            and round(scan.outlier_fraction * scan.num_points) == 0)


# Directions of the inside/outside rays of :func:`_mesh_sdf_fn` (unit, none along a grid axis or
# a grid diagonal, so that no ray runs along the faces of a marching-cubes mesh).
_SIGN_DIRECTIONS = np.array([[0.4862, 0.7293, 0.4814], [-0.6521, 0.2314, -0.7219],
                             [0.2087, -0.8903, 0.4047]])
_SIGN_DIRECTIONS /= np.linalg.norm(_SIGN_DIRECTIONS, axis=1, keepdims=True)


def _mesh_sdf_fn(caster):
    """``points [N, 3] -> [N]`` signed distance to a watertight mesh, metres, negative inside.

    The magnitude is the distance to the closest point of the mesh (point-cloud-utils, recomputed
    in float64 from that point); the sign is the majority over three rays from the point: a ray
    whose first hit is a back face (its normal along the ray) starts inside. Same values as
    winding numbers for a watertight mesh, at half the cost on a 250k-face mesh.

    caster: a :class:`lisa_hand.data.images.MeshRayCaster` of the mesh (also used for the images).
    """
    import point_cloud_utils as pcu

    vertices = caster.vertices.astype(np.float64)
    faces = caster.faces

    def sdf_fn(points: torch.Tensor) -> torch.Tensor:
        query = points.detach().cpu().numpy().astype(np.float64)
        _, face_ids, barycentric = pcu.closest_points_on_mesh(query, vertices, faces)
        corners = vertices[faces[np.asarray(face_ids)]]  # [N, 3, 3]
        closest = (np.asarray(barycentric)[:, :, None] * corners).sum(axis=1)
        # A degenerate (zero-area) face can give NaN barycentric coordinates: its nearest
        # corner is then the closest point (the face is a point or a segment).
        broken = ~np.isfinite(closest).all(axis=1)
        if broken.any():
            gaps = np.linalg.norm(corners[broken] - query[broken, None], axis=-1)
            closest[broken] = corners[broken, gaps.argmin(axis=1)]
        magnitude = np.linalg.norm(query - closest, axis=1)
        votes = np.zeros(query.shape[0], dtype=np.int64)
        for direction in _SIGN_DIRECTIONS:
            directions = np.broadcast_to(direction, query.shape)
            hits = caster.intersect(query, directions)
            facing = (caster.face_normals[np.maximum(hits.face_ids, 0)] @ direction) > 0
            votes += hits.hit & facing
        inside = votes >= 2
        return torch.from_numpy(np.where(inside, -magnitude, magnitude)).to(points.dtype)

    return sdf_fn


def _template_weights(subject: SubjectRecord, setup: FrameSetup,
                      points: np.ndarray) -> np.ndarray:
    """[N, 16] float32 weights of the nearest vertex of the template posed like the frame (its
    mirror image for a left hand: the template is a right hand)."""
    from ...handmodel.template import load_template
    from ...skeleton import mirror_points, mirror_pose

    template = load_template()
    left = subject.hand.side == "left"
    pose, translation = setup.pose, setup.translation
    if left:
        pose, translation = mirror_pose(pose), mirror_points(translation)
    betas = torch.as_tensor(subject.template_betas, dtype=template.dtype)
    posed = template.forward(pose[None].to(template.dtype), betas[None],
                             translation[None].to(template.dtype))
    vertices = posed.vertices[0]
    if left:
        vertices = mirror_points(vertices)
    weights = template.skinning_weights_at(torch.from_numpy(points).to(template.dtype), vertices)
    return np.asarray(weights.detach().cpu().numpy(), dtype=np.float64).astype(np.float32)



class _Laps:
    """Seconds per stage: :meth:`lap` charges the time since the previous lap to a stage."""

    def __init__(self) -> None:
        self.times: dict[str, float] = {}
        self._clock = time.perf_counter()

    def lap(self, name: str) -> None:
        now = time.perf_counter()
        self.times[name] = self.times.get(name, 0.0) + now - self._clock
        self._clock = now


@dataclass
class _FrameData:
    """Everything one frame writes, before it is written."""

    setup: FrameSetup
    posed: Any
    """The :class:`lisa_hand.handmodel.PosedHand`."""
    mesh: Any
    """The ground-truth :class:`lisa_hand.geometry.meshing.Mesh`."""
    scan: Scan
    weights: np.ndarray
    """[N, 16] float32 exact skinning weights at the scan points."""
    template_weights: np.ndarray
    """[N, 16] float32 weights of the nearest posed template vertex."""
    sdf_points: np.ndarray
    """[M, 3] float32 metres."""
    sdf_values: np.ndarray
    """[M] float32 metres."""
    views: list
    """Per camera, its rendered :class:`lisa_hand.data.images.ViewImage` (rgb, mask, depth)."""
    keypoint_views: dict[str, dict[str, Any]]
    """Per camera name, its ``keypoints.json`` entry."""


def _near_surface_samples(config: SynthConfig, mesh, caster: MeshRayCaster, scan: Scan,
                          rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """SDF samples around the true surface, whatever the sensor's noise or view -> (points
    [M, 3], sdf [M]) float32 metres (empty when ``num_sdf_samples`` is 0)."""
    if not config.num_sdf_samples:
        return np.zeros((0, 3), np.float32), np.zeros(0, np.float32)
    if _scan_is_clean(config.scan):
        surface_points, surface_normals = scan.points, scan.normals
    else:
        surface = sample_surface(mesh.vertices, mesh.faces, config.num_sdf_samples, rng)
        surface_points, surface_normals = surface.points, surface.normals
    near = sdf_samples(_mesh_sdf_fn(caster), surface_points, surface_normals,
                       num_samples=config.num_sdf_samples, sigma=config.sdf_sigmas,
                       generator=rng)
    points, sdf = near.points, near.sdf
    broken = ~(np.isfinite(sdf) & np.isfinite(points).all(axis=1))
    if broken.any():  # seen once in 580 frames (one sample): replaced by copies of good ones
        good = np.flatnonzero(~broken)
        pick = good[rng.integers(0, good.size, int(broken.sum()))]
        points, sdf = points.copy(), sdf.copy()
        points[broken], sdf[broken] = points[pick], sdf[pick]
    return points, sdf


def _keypoint_views(posed, cameras: list[Camera], views: list) -> dict[str, dict[str, Any]]:
    """Per camera, the posed hand's keypoints projected, with occlusion from the depth map."""
    keypoint_views = {}
    for camera, view in zip(cameras, views, strict=True):
        projection = project_keypoints(posed.keypoints, camera, depth=view.depth)
        keypoint_views[camera.name] = {
            "keypoints": projection.pixels.astype(np.float64),
            "visible": projection.visible,
            "in_image": projection.in_image,
            "depth": projection.depth.astype(np.float64),
        }
    return keypoint_views


def _generate(config: SynthConfig, subject: SubjectRecord, frame: int, cameras: list[Camera],
              gain_bias: GainBias, laps: _Laps) -> _FrameData:
    """Pose, mesh, scan, weights, SDF samples, images and keypoints of one frame (in this
    order: each stage draws from the frame's generator after the previous one)."""
    hand = subject.hand
    setup = frame_setup(config, subject, frame)
    rng = setup.rng
    posed = hand.posed(setup.pose, setup.translation)
    laps.lap("pose")

    voxel_size = hand.shape.hand_length / config.voxels_per_length
    mesh = posed.mesh(voxel_size=voxel_size)
    caster = MeshRayCaster(mesh.vertices, mesh.faces)  # for the SDF signs and the images
    laps.lap("mesh")

    scan = simulate_scan(mesh.vertices, mesh.faces, config.scan, seed=rng)
    with torch.no_grad():
        weights = posed.evaluate(torch.from_numpy(scan.points)).weights
    weights = weights.float().cpu().numpy()
    laps.lap("scan")

    template_weights = _template_weights(subject, setup, scan.points)
    laps.lap("template")

    sdf_points, sdf_values = _near_surface_samples(config, mesh, caster, scan, rng)
    laps.lap("sdf")

    albedo = mesh.colors.astype(np.float32) / 255.0
    views = render_views(None, None, cameras, albedo, shading=config.shading, generator=rng,
                         gain_bias=gain_bias, supersample=config.supersample, caster=caster)
    laps.lap("render")

    keypoint_views = _keypoint_views(posed, cameras, views)
    laps.lap("keypoints")
    return _FrameData(setup=setup, posed=posed, mesh=mesh, scan=scan, weights=weights,
                      template_weights=template_weights, sdf_points=sdf_points,
                      sdf_values=sdf_values, views=views, keypoint_views=keypoint_views)


def _write_files(paths: FramePaths, config: SynthConfig, subject: SubjectRecord,
                 data: _FrameData, cameras: list[Camera], gain_bias: GainBias) -> None:
    """The frame folder's files (see ``docs/data_formats.md``)."""
    from ..meshio import save_mesh

    scan, setup, posed = data.scan, data.setup, data.posed
    save_mesh(paths.mesh, data.mesh)
    write_npz(paths.scan, points=scan.points, normals=scan.normals, weights=data.weights,
              template_weights=data.template_weights, sdf_points=data.sdf_points,
              sdf=data.sdf_values, is_outlier=scan.is_outlier)
    for camera, view in zip(cameras, data.views, strict=True):
        write_image(paths.image(camera.name), view.rgb)
        write_mask(paths.mask(camera.name), view.mask)
        if config.write_depth:
            write_depth(paths.depth(camera.name), view.depth)
    save_cameras(paths.cameras, cameras)
    write_keypoints(paths.keypoints, data.keypoint_views)
    names = [camera.name for camera in cameras]
    write_json(paths.params, {
        "subject": subject.id,
        "side": subject.hand.side,
        "pose": setup.pose.tolist(),
        "translation": setup.translation.tolist(),
        "joints": posed.joints.tolist(),
        "keypoints": posed.keypoints.tolist(),
        "pose_name": setup.pose_name,
        "camera_gain": {n: gain_bias.gain[i].astype(np.float64).tolist()
                        for i, n in enumerate(names)},
        "camera_bias": {n: gain_bias.bias[i].astype(np.float64).tolist()
                        for i, n in enumerate(names)},
    })


def write_frame(root: Path, config: SynthConfig, subject: SubjectRecord, frame: int,
                cameras: list[Camera], gain_bias: GainBias) -> dict[str, float]:
    """Generate and write frame ``frame`` of ``subject`` into ``root / subject / fNNN``.

    cameras, gain_bias: the dataset's rig and colour responses
    (:func:`lisa_hand.data.synth.scene.dataset_rig`).
    -> seconds per stage (pose, mesh, scan, template, sdf, render, keypoints, write).
    """
    laps = _Laps()
    data = _generate(config, subject, frame, cameras, gain_bias, laps)
    _write_files(FramePaths(root / subject.id / frame_id(frame)), config, subject, data, cameras,
                 gain_bias)
    laps.lap("write")
    return laps.times
