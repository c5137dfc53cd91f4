"""Two hands of the shipped model for the joint-fit tests: the model's mean hand (mean shape
code, the mesh template's mean skeleton) as a right hand turned to face the camera, and a left
hand that is its exact mirror image through a plane z = c (the camera frame: x right, y down,
z forward), so that the two hands touch back to back."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import torch

from lisa_hand.fitting.sides import mirror_hand
from lisa_hand.geometry.rotations import axis_angle_to_matrix, matrix_to_axis_angle
from lisa_hand.skeleton.params import HandParams

K = torch.tensor([[600.0, 0.0, 320.0], [0.0, 600.0, 240.0], [0.0, 0.0, 1.0]])
"""The camera's intrinsics (640 x 480 pixels; the camera frame is the world)."""
WIDTH, HEIGHT = 640, 480

FACING = torch.tensor([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]], dtype=torch.float64)
"""The right hand's root rotation: its fingers (-x at the zero pose) up the image (-y), its
palm (-y at the zero pose) towards the camera (-z), its back (+z) away."""

BACK_M = 0.4616
"""Where the right hand's back reaches (metres of depth, its mesh's largest z) when its wrist
is at depth 0.45: its mirror image through z = c overlaps it by 2 (BACK_M - c)."""


def turned(hand: HandParams, rotation: torch.Tensor) -> HandParams:
    """The hand rotated by ``rotation`` [3, 3] about the world's origin (its root rotation
    composed, its wrist moved; a rigid motion of the whole hand)."""
    root = axis_angle_to_matrix(hand.pose[:3].double())
    pose = hand.pose.clone()
    pose[:3] = matrix_to_axis_angle(rotation @ root).float()
    wrist = hand.rest_joints[0].double()
    translation = rotation @ (wrist + hand.translation.double()) - wrist
    return replace(hand, pose=pose, translation=translation.float())


def mean_right_hand(model, wrist=(0.04, 0.06, 0.45)) -> HandParams:
    """The model's mean hand, flat, turned by :data:`FACING`, its wrist at ``wrist`` (no
    colour code for a geometry-only model)."""
    from lisa_hand.handmodel.template import load_template

    colour = model.mean_color_code()
    template = load_template()
    betas = torch.zeros(1, template.num_betas, dtype=template.dtype)
    rest = template.rest_joints(betas)[0].float()
    hand = HandParams(pose=torch.zeros(48), translation=-rest[0], rest_joints=rest,
                      shape_code=model.mean_shape_code().float(),
                      color_code=None if colour is None else colour.float(),
                      betas=betas[0].float())
    hand = turned(hand, FACING)
    return replace(hand, translation=hand.translation + torch.tensor(wrist))


def mirrored_left(right: HandParams, plane_z: float, shift=(0.0, 0.0, 0.0)) -> HandParams:
    """The left hand that is ``right``'s mirror image through the plane z = ``plane_z``, then
    moved by ``shift`` (metres)."""
    half_turn = torch.diag(torch.tensor([-1.0, 1.0, -1.0], dtype=torch.float64))  # about y
    left = mirror_hand(turned(right, half_turn))  # (x, y, z) -> (x, y, -z)
    move = torch.tensor([shift[0], shift[1], 2.0 * plane_z + shift[2]])
    return replace(left, translation=left.translation + move)


def project(points: np.ndarray) -> np.ndarray:
    """Camera-frame points [N, 3] -> pixels [N, 2]."""
    projected = np.asarray(points, np.float64) @ K.double().numpy().T
    return projected[:, :2] / projected[:, 2:]


def silhouette(mesh) -> np.ndarray:
    """[HEIGHT, WIDTH] bool: the mesh's faces projected and filled."""
    from PIL import Image, ImageDraw

    pixels = project(mesh.vertices)
    canvas = Image.new("L", (WIDTH, HEIGHT), 0)
    draw = ImageDraw.Draw(canvas)
    for face in mesh.faces:
        draw.polygon([tuple(pixels[index]) for index in face], fill=255)
    return np.asarray(canvas) > 0
