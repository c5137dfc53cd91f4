"""Depth scans of the WebXR hand (:mod:`lisa_hand.data.webxr_hand`) in scenes with more than the
hand in them, as a depth camera sees them: lying on a table (:func:`table_scan`), held before a
wall that fills a depth camera's frame (:func:`wall_scan`), held out by a person whose arm and
body join it into one piece (:func:`person_scan`).

Each returns (points [N, 3] metres, the hand's outer surface (vertices [V, 3] metres, faces [F,
3]) as ground truth, the sensor position [3] metres): inputs for ``lisa fit-points`` with the
truth to score its fit and its removal of the table, wall or body (``fit_points(support=,
others=)``). ``python -m benchmarks fit --webxr ... --webxr-table/--webxr-wall/--webxr-person``
(from the repository root) measures the fit on them.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

from .webxr_hand import (
    FOREARM_START_M,
    WEBXR_POSES,
    extend_forearm,
    outer_surface,
    palm_normal,
    pose_webxr_hand,
    webxr_wrist,
)

__all__ = ["TABLE_SIDE_M", "WALL_DEPTH_M", "PERSON_DEPTH_M", "PERSON_ARM_M", "PERSON_TORSO_M",
           "table_scan", "wall_scan", "person_scan"]

TABLE_SIDE_M = 0.3
"""Side of the square table under the hand in :func:`table_scan`, metres."""


def table_scan(path: str | Path, pose: str, down: str, seed: int = 0, num_points: int = 8000):
    """A one-view scan of the WebXR hand lying on a table, the table in the scan, as a depth
    camera above a desk sees it: the hand posed (:data:`WEBXR_POSES`) and turned so that its
    ``down`` side ('palm' or 'back') faces the table, lowered until its lowest point is 0.5 mm
    above it (the rest pose lies on its thumb), a :data:`TABLE_SIDE_M` square of table centred
    under it, scanned from 45 cm above, 7 cm off the vertical (noise 0.3 mm).

    -> (points [N, 3] metres, the hand's outer surface (vertices [V, 3] metres, faces [F, 3]),
    the sensor [3] metres)."""
    from ..data.scans import ScanConfig, simulate_scan

    if down not in ("palm", "back"):
        raise ValueError(f"down must be 'palm' or 'back', got {down!r}")
    posed, faces = pose_webxr_hand(path, pose)
    vertices, faces = outer_surface(posed, faces)
    with np.load(path, allow_pickle=False) as data:
        joints = data["joints"].astype(np.float64) * 1e-3
        names = [str(n) for n in data["joint_names"]]
    normal = palm_normal(joints, names)
    up = normal if down == "back" else -normal  # the new +z
    along = joints[names.index("middle-finger-phalanx-proximal")] - joints[0]
    along -= up * (along @ up)
    along /= np.linalg.norm(along)
    rotation = np.stack([along, np.cross(up, along), up])  # rows: the new axes
    hand = (vertices - vertices.mean(0)) @ rotation.T
    hand[:, 2] -= hand[:, 2].min() - 0.0005
    centre, half = hand[:, :2].mean(0), TABLE_SIDE_M / 2
    table = np.array([[centre[0] + x, centre[1] + y, 0.0]
                      for x, y in ((-half, -half), (half, -half), (half, half), (-half, half))])
    scene = np.concatenate([hand, table])
    scene_faces = np.concatenate([faces, np.array([[0, 1, 2], [0, 2, 3]]) + len(hand)])
    sensor = np.array([centre[0] + 0.05, centre[1] - 0.05, 0.45])
    scan = simulate_scan(scene, scene_faces, ScanConfig(
        num_points=num_points, partial=True, viewpoint=tuple(sensor), noise_normal_std=3e-4),
        seed=seed)
    return scan.points, (hand, faces), sensor


WALL_DEPTH_M = (0.4, 0.7)
"""The hand's centre and the wall behind it in :func:`wall_scan`, metres from the camera."""


def wall_scan(path: str | Path, pose: str, seed: int = 0):
    """A depth camera's frame (:func:`lisa_hand.data.scans.depth_camera_scan`, 320 x 240, 1 mm
    noise at 40 cm growing with the square of the depth) of the WebXR hand, posed
    (:data:`WEBXR_POSES`) and turned at random (from ``seed`` and the pose), its centre
    :data:`WALL_DEPTH_M` [0] in front of the camera, before a wall at [1] that fills the frame:
    the whole frame, as the camera returns it (about 90% of the points on the wall, 3 mm noise
    there).

    -> (points [N, 3] metres in the camera's frame, the hand's outer surface (vertices [V, 3]
    metres, faces [F, 3]), the sensor [3]: the origin)."""
    from ..data.scans import depth_camera_scan
    from ..geometry import axis_angle_to_matrix

    posed, faces = pose_webxr_hand(path, pose)
    vertices, faces = outer_surface(posed, faces)
    generator = torch.Generator().manual_seed(1000 * seed + list(WEBXR_POSES).index(pose))
    rotation = axis_angle_to_matrix(3.0 * torch.rand(3, generator=generator,
                                                     dtype=torch.float64)).numpy()
    hand = (vertices - vertices.mean(0)) @ rotation.T + np.array([0.0, 0.0, WALL_DEPTH_M[0]])
    half = 2.0
    wall = np.array([[-half, -half, WALL_DEPTH_M[1]], [half, -half, WALL_DEPTH_M[1]],
                     [half, half, WALL_DEPTH_M[1]], [-half, half, WALL_DEPTH_M[1]]])
    scene = np.concatenate([hand, wall])
    scene_faces = np.concatenate([faces, np.array([[0, 2, 1], [0, 3, 2]]) + len(hand)])
    scan = depth_camera_scan(scene, scene_faces, seed=seed)
    return scan.points, (hand, faces), np.zeros(3)


PERSON_DEPTH_M = 0.45
"""How far before the depth camera the hand's centre is held in :func:`person_scan`, metres."""
PERSON_ARM_M = 0.3
"""The forearm of :func:`person_scan`, from the wrist to where it enters the body, metres."""
PERSON_TORSO_M = (0.4, 0.6, 0.25)
"""The body of :func:`person_scan`: a box this wide, tall and deep, metres."""


def person_scan(path: str | Path, pose: str, seed: int = 0):
    """A depth camera's frame of a person holding the WebXR hand out towards it: the hand posed
    (:data:`WEBXR_POSES`), its forearm extended :data:`PERSON_ARM_M` (:func:`extend_forearm`)
    pointing away from the camera, within 60 degrees of its axis and turned at random about
    itself (from ``seed`` and the pose), the hand's centre :data:`PERSON_DEPTH_M` before the
    camera, and the arm entering a body (a :data:`PERSON_TORSO_M` box, its front 5 cm before
    the arm's end, the arm's end 10 cm off its middle): the whole frame, as the camera returns
    it (:func:`lisa_hand.data.scans.depth_camera_scan`), one connected piece 0.6-1 m across.

    -> (points [N, 3] metres in the camera's frame, the hand and forearm's outer surface
    (vertices [V, 3] metres, faces [F, 3]), the sensor [3]: the origin)."""
    from scipy.spatial.transform import Rotation

    from ..data.scans import depth_camera_scan
    from ..geometry import axis_angle_to_matrix

    posed, faces = pose_webxr_hand(path, pose)
    wrist, forearm = webxr_wrist(path)
    vertices, faces = outer_surface(*extend_forearm(posed, faces, wrist, forearm,
                                                    length=PERSON_ARM_M))
    rng = np.random.default_rng(1000 * seed + list(WEBXR_POSES).index(pose))
    tilt, azimuth, roll = np.arccos(rng.uniform(0.5, 1.0)), rng.uniform(0, 2 * np.pi), \
        rng.uniform(0, 2 * np.pi)
    away = np.array([np.sin(tilt) * np.cos(azimuth), np.sin(tilt) * np.sin(azimuth),
                     np.cos(tilt)])
    align = Rotation.align_vectors(away[None], forearm[None])[0].as_matrix()
    spin = axis_angle_to_matrix(torch.as_tensor(away * roll)).numpy()
    rotation = spin @ align
    hand_centre = posed.mean(0)
    place = np.array([0.0, 0.0, PERSON_DEPTH_M])
    body = (vertices - hand_centre) @ rotation.T + place
    arm_end = (wrist + (FOREARM_START_M + PERSON_ARM_M) * forearm - hand_centre) @ rotation.T \
        + place
    width, height, depth = PERSON_TORSO_M
    centre = arm_end + np.array([0.1, 0.1, depth / 2 - 0.05])
    corners = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)]) \
        * np.array([width, height, depth]) / 2 + centre
    box = np.array([[0, 1, 3], [0, 3, 2], [4, 6, 7], [4, 7, 5], [0, 4, 5], [0, 5, 1],
                    [2, 3, 7], [2, 7, 6], [0, 2, 6], [0, 6, 4], [1, 5, 7], [1, 7, 3]])
    scene = np.concatenate([body, corners])
    scene_faces = np.concatenate([faces, box + len(body)])
    scan = depth_camera_scan(scene, scene_faces, seed=seed)
    return scan.points, (body, faces), np.zeros(3)
