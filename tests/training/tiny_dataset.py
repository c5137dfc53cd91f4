"""A tiny dataset in the exact on-disk layout of ``lisa synth`` (:mod:`lisa_hand.data.layout`).

The hand is an analytic stand-in: one capsule around each region segment of LISA's bones
(:func:`lisa_hand.fields.bones.bone_segments`: five palm capsules from the wrist to the finger
bases, one per finger bone, the last one extended past its joint), posed rigidly with the bone
transforms of :func:`lisa_hand.skeleton.forward_kinematics`, united with ``min``. Each frame is
meshed with :func:`lisa_hand.geometry.meshing.extract_mesh`, scanned with
:func:`lisa_hand.data.scans.simulate_scan` (plus :func:`~lisa_hand.data.scans.sdf_samples` from
the analytic SDF) and rendered with :func:`lisa_hand.data.images.render_views` into the cameras
of :func:`lisa_hand.geometry.cameras.make_rig` with a random per-camera gain and bias. Skinning
weights (true and "template") are one-hot on the bone of the nearest capsule.

Subjects differ by a global scale of the skeleton, their capsule radii and their colour. The
whole dataset (3 subjects x 2 frames x 3 views of 64 x 48) is written in about a second.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from lisa_hand.data.images import render_views
from lisa_hand.data.layout import (
    FORMAT_NAME,
    FORMAT_VERSION,
    FramePaths,
    frame_id,
    subject_id,
    write_image,
    write_mask,
    write_npz,
)
from lisa_hand.data.scans import ScanConfig, sdf_samples, simulate_scan
from lisa_hand.data.shading import GainBiasConfig
from lisa_hand.fields.bones import SEGMENT_BONES, bone_segments, segment_distances
from lisa_hand.geometry.cameras import make_rig, save_cameras
from lisa_hand.geometry.meshing import extract_mesh
from lisa_hand.skeleton import NUM_JOINTS, forward_kinematics
from lisa_hand.utils.io import write_json

__all__ = [
    "TinyDatasetConfig",
    "base_rest_joints",
    "capsule_hand",
    "write_tiny_dataset",
]

TIP_EXTENSION = 0.8
_NUM_PALM_SEGMENTS = 5


@dataclass(frozen=True)
class TinyDatasetConfig:
    """Sizes of the tiny dataset."""

    num_subjects: int = 3
    """Subjects s000, s001, ...; the last one goes to the 'val' split, the others to 'train'."""
    num_frames: int = 2
    """Frames (poses) per subject."""
    num_views: int = 3
    """Cameras per frame (the same rig for every frame)."""
    width: int = 64
    """Image width, pixels."""
    height: int = 48
    """Image height, pixels."""
    num_scan_points: int = 600
    """Scan points per frame."""
    num_sdf_samples: int = 300
    """Near-surface SDF samples per frame."""
    mesh_resolution: int = 40
    """Marching-cubes samples per axis."""
    seed: int = 0
    """Seed of every random choice."""


def base_rest_joints() -> torch.Tensor:
    """A right hand's rest skeleton [16, 3] metres, MANO order; fingers along +x, palm normal -y.

    Each finger starts at its base joint and goes on with the listed segment lengths.
    """
    joints = torch.zeros(NUM_JOINTS, 3, dtype=torch.float64)
    fingers = {  # first joint index: (base position, direction, segment lengths)
        1: ((0.085, 0.0, 0.024), (1.0, 0.0, 0.08), (0.035, 0.022, 0.020)),  # index
        4: ((0.090, 0.0, 0.002), (1.0, 0.0, 0.0), (0.038, 0.025, 0.022)),  # middle
        7: ((0.075, 0.0, -0.036), (1.0, 0.0, -0.15), (0.028, 0.018, 0.016)),  # pinky
        10: ((0.085, 0.0, -0.018), (1.0, 0.0, -0.08), (0.035, 0.024, 0.020)),  # ring
        13: ((0.025, -0.008, 0.030), (0.7, -0.2, 0.7), (0.035, 0.030, 0.025)),  # thumb
    }
    for first, (base, direction, lengths) in fingers.items():
        direction = torch.tensor(direction, dtype=torch.float64)
        direction = direction / direction.norm()
        position = torch.tensor(base, dtype=torch.float64)
        joints[first] = position
        for k in range(1, 3):
            position = position + lengths[k - 1] * direction
            joints[first + k] = position
    return joints


def capsule_hand(rest_joints: torch.Tensor, pose: torch.Tensor, translation: torch.Tensor,
                 palm_radius: float, finger_radius: float):
    """The posed stand-in hand.

    rest_joints: [16, 3] m; pose: [48] rad; translation: [3] m (float64).
    -> (sdf_fn(points [N, 3]) -> [N] metres, owner_fn(points [N, 3]) -> [N] bone index)
    """
    kin = forward_kinematics(pose[None], rest_joints, translation[None])
    start, end = bone_segments(rest_joints[None], TIP_EXTENSION)
    transforms = kin.transforms[0, list(SEGMENT_BONES)]  # [20, 4, 4]
    rot, shift = transforms[:, :3, :3], transforms[:, :3, 3]
    posed_start = (rot @ start[0, :, :, None])[..., 0] + shift
    posed_end = (rot @ end[0, :, :, None])[..., 0] + shift
    radii = torch.full((len(SEGMENT_BONES),), finger_radius, dtype=torch.float32)
    radii[:_NUM_PALM_SEGMENTS] = palm_radius
    owners = torch.tensor(SEGMENT_BONES)
    origin = kin.joints[0, 0]
    axis = posed_end - posed_start
    length = axis.norm(dim=-1)
    segments = ((posed_start - origin).float()[None], (axis / length[:, None]).float()[None],
                length.float()[None])

    def distances(points: torch.Tensor) -> torch.Tensor:
        relative = (points.to(torch.float64) - origin).float()[None]
        return segment_distances(relative, *segments)[0] - radii  # [N, S]

    def sdf_fn(points: torch.Tensor) -> torch.Tensor:
        return distances(points).amin(dim=-1).to(points.dtype)

    def owner_fn(points: torch.Tensor) -> torch.Tensor:
        return owners[distances(points).argmin(dim=-1)]

    return sdf_fn, owner_fn


def _one_hot(owner: torch.Tensor) -> np.ndarray:
    return torch.nn.functional.one_hot(owner, NUM_JOINTS).to(torch.float32).numpy()


def _random_pose(rng: np.random.Generator, curl: float) -> np.ndarray:
    """Small global rotation, fingers flexed by about ``curl`` radians per joint (about -z)."""
    pose = np.zeros((NUM_JOINTS, 3))
    pose[0] = rng.normal(0.0, 0.15, 3)
    for joint in range(1, NUM_JOINTS):
        pose[joint, 2] = -curl * rng.uniform(0.5, 1.0)
        pose[joint, :2] = rng.normal(0.0, 0.05, 2)
    return pose.reshape(-1)


def write_tiny_dataset(root: str | Path, config: TinyDatasetConfig | None = None) -> Path:
    """Write the tiny dataset into ``root`` (created); return ``root``."""
    config = TinyDatasetConfig() if config is None else config
    root = Path(root)
    rng = np.random.default_rng(config.seed)
    cameras = make_rig(config.num_views, target=(0.06, 0.0, 0.0), radius=0.45,
                       width=config.width, height=config.height, fov_deg=40.0, seed=config.seed)
    camera_names = [camera.name for camera in cameras]
    gain_bias = GainBiasConfig().sample(config.num_views, rng)
    subjects = [subject_id(i) for i in range(config.num_subjects)]
    base = base_rest_joints()
    for index, subject in enumerate(subjects):
        scale = 0.9 + 0.2 * index / max(config.num_subjects - 1, 1)
        rest_joints = base * scale
        palm_radius = 0.013 * scale
        finger_radius = (0.0075 + 0.001 * index) * scale
        albedo = np.array([0.75, 0.55, 0.45]) * (0.85 + 0.1 * index)
        write_json(root / subject / "subject.json", {
            "id": subject,
            "side": "right",
            "shape": {"scale": scale},
            "appearance": {"albedo": albedo.tolist()},
            "detail_seed": index,
            "rest_joints": rest_joints.tolist(),
            "template_betas": [0.0] * 10,
            "template_rest_joints": rest_joints.tolist(),
        })
        for frame in range(config.num_frames):
            pose = _random_pose(rng, curl=0.5 * frame)
            translation = rng.normal(0.0, 0.005, 3)
            pose_t = torch.from_numpy(pose)
            translation_t = torch.from_numpy(translation)
            sdf_fn, owner_fn = capsule_hand(rest_joints, pose_t, translation_t, palm_radius,
                                            finger_radius)
            kin = forward_kinematics(pose_t[None], rest_joints, translation_t[None])
            joints = kin.joints[0]
            lo = joints.amin(0) - 0.05
            hi = joints.amax(0) + 0.05
            mesh = extract_mesh(sdf_fn, lo.numpy(), hi.numpy(), config.mesh_resolution)
            scan = simulate_scan(mesh.vertices, mesh.faces,
                                 ScanConfig(num_points=config.num_scan_points), seed=rng)
            points_t = torch.from_numpy(scan.points).double()
            weights = _one_hot(owner_fn(points_t))
            near = sdf_samples(sdf_fn, scan.points, scan.normals,
                               num_samples=config.num_sdf_samples, sigma=(0.002, 0.01),
                               generator=rng)
            paths = FramePaths(root / subject / frame_id(frame))
            write_npz(paths.scan, points=scan.points, normals=scan.normals, weights=weights,
                      template_weights=weights, sdf_points=near.points, sdf=near.sdf)
            views = render_views(mesh.vertices, mesh.faces, cameras, albedo.astype(np.float32),
                                 generator=rng, gain_bias=gain_bias)
            for name, view in zip(camera_names, views, strict=True):
                write_image(paths.image(name), view.rgb)
                write_mask(paths.mask(name), view.mask)
            save_cameras(paths.cameras, cameras)
            write_json(paths.params, {
                "pose": pose.tolist(),
                "translation": translation.tolist(),
                "joints": joints.tolist(),
                "keypoints": None,
                "pose_name": None,
                "camera_gain": {n: gain_bias.gain[i].tolist() for i, n in enumerate(camera_names)},
                "camera_bias": {n: gain_bias.bias[i].tolist() for i, n in enumerate(camera_names)},
            })
    write_json(root / "split.json", {"train": subjects[:-1], "val": subjects[-1:], "test": []})
    write_json(root / "dataset.json", {
        "format": FORMAT_NAME,
        "version": FORMAT_VERSION,
        "generator": "tests.training.tiny_dataset",
        "num_subjects": config.num_subjects,
        "num_frames": config.num_frames,
        "num_views": config.num_views,
    })
    return root
