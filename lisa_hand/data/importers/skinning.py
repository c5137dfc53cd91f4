"""Skinning pseudo ground truth of imported frames (paper Eq. 15): the skinning weights of the
nearest vertex of the hand's fitted mesh, posed as the frame.

The mesh is the user's MANO at the frame's MANO parameters when both are given (as the paper
does with MANO fits), else the package's MANO-like template (``lisa_hand/assets/template.npz``,
mean shape) posed by the frame's pose with its wrist on the frame's posed wrist.

* :func:`skinning_pseudo_ground_truth`: weights at given points (a real scan's points).
* :func:`pseudo_scan_writer`: for image datasets (InterHand2.6M, FreiHAND), a ``scan.npz`` per
  frame with points sampled on that posed mesh and their weights, which is what ``lisa train``
  reads for its skinning loss ``L_w`` (``points``, ``normals``, ``template_weights``; no SDF
  samples: the mesh is a fit, not a measured surface, so ``lisa train-prior`` must not learn
  geometry from it).
"""

from __future__ import annotations

import functools
from typing import Any

import numpy as np
import torch

from ...skeleton.kinematics import mirror_points, mirror_pose
from ...skeleton.mano import ManoLayer
from ..layout import FramePaths, write_npz
from .common import ExtraFiles, FrameRecord, ManoParams

__all__ = ["posed_reference_mesh", "skinning_pseudo_ground_truth", "pseudo_scan_writer"]


@functools.lru_cache(maxsize=1)
def _template():
    from ...handmodel.template import load_template

    return load_template().to(dtype=torch.float64)


def posed_reference_mesh(pose: np.ndarray, translation: np.ndarray, rest_joints: np.ndarray,
                         side: str, mano: tuple[ManoLayer, ManoParams] | None = None
                         ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The posed mesh whose weights are the pseudo ground truth (see the module docstring).

    pose: [48] radians and translation: [3] metres of the frame on ``rest_joints`` [16, 3]
    (its subject's skeleton, in the side's convention). mano: the user's layer (float64,
    flat_hand_mean False) and the frame's parameters, or None for the template.
    -> vertices [V, 3] metres, faces [F, 3], weights [V, 16].
    """
    if mano is not None:
        layer, params = mano

        def tensor(value: np.ndarray) -> torch.Tensor:
            return torch.as_tensor(np.asarray(value)[None], dtype=layer.dtype)

        hand_pose = tensor(params.hand_pose)
        if params.flat_hand_mean:
            hand_pose = hand_pose - layer.hand_mean
        out = layer(hand_pose=hand_pose, global_orient=tensor(params.global_orient),
                    betas=tensor(params.betas), transl=tensor(params.transl))
        return (out.vertices[0].double().numpy(), layer.faces.numpy(),
                layer.skinning_weights.double().numpy())
    template = _template()
    pose_t = torch.as_tensor(pose, dtype=torch.float64)[None]
    wrist = torch.as_tensor(np.asarray(rest_joints)[0] + translation, dtype=torch.float64)
    betas = torch.zeros(1, template.num_betas, dtype=torch.float64)
    rest_wrist = template.rest_joints(betas)[0, 0]
    if side == "left":  # the template is a right hand: pose its mirror image, mirror back
        pose_t, wrist = mirror_pose(pose_t), mirror_points(wrist)
    vertices = template(pose_t, betas, (wrist - rest_wrist)[None]).vertices[0]
    faces = template.faces.numpy()
    if side == "left":
        vertices, faces = mirror_points(vertices), faces[:, [0, 2, 1]]
    return vertices.numpy(), faces, template.weights.double().numpy()


def skinning_pseudo_ground_truth(points: np.ndarray, pose: np.ndarray, translation: np.ndarray,
                                 rest_joints: np.ndarray, side: str,
                                 mano: tuple[ManoLayer, ManoParams] | None = None
                                 ) -> np.ndarray:
    """Skinning weights [N, 16] at ``points`` [N, 3] metres: those of the nearest vertex of
    :func:`posed_reference_mesh` (same arguments)."""
    from scipy.spatial import cKDTree

    vertices, _, weights = posed_reference_mesh(pose, translation, rest_joints, side, mano)
    _, nearest = cKDTree(vertices).query(np.asarray(points, np.float64))
    return weights[np.asarray(nearest)]


def pseudo_scan_writer(num_points: int, layers: dict[str, ManoLayer] | None, seed: int = 0
                       ) -> ExtraFiles:
    """A frame hook writing ``scan.npz`` of ``num_points`` samples of the posed reference mesh
    with their weights (see the module docstring)."""
    from scipy.spatial import cKDTree

    from ..scans import sample_surface

    def write(paths: FramePaths, record: FrameRecord, frame: dict[str, Any],
              rest: np.ndarray) -> None:
        layer = None if layers is None else layers.get(record.side)
        mano = (layer, record.mano) if layer is not None and record.mano is not None else None
        vertices, faces, weights = posed_reference_mesh(frame["pose"], frame["translation"],
                                                        rest, record.side, mano)
        samples = sample_surface(vertices, faces, num_points, np.random.default_rng(seed))
        points = np.asarray(samples.points, np.float64)
        _, nearest = cKDTree(vertices).query(points)
        write_npz(paths.scan, points=points.astype(np.float32),
                  normals=np.asarray(samples.normals, np.float32),
                  template_weights=weights[nearest].astype(np.float32),
                  sdf_points=np.zeros((0, 3), np.float32), sdf=np.zeros(0, np.float32))

    return write
