"""Synthetic photos for the photo-fit tests: hands of a tiny LISA model rendered by the package's
renderer into one uncalibrated camera (R = I, t = 0: the camera frame is the world), over a
coloured background with noise, saved as JPEG, with their true 2D keypoints (the template's,
projected) and 3D keypoints (camera frame)."""

from __future__ import annotations

import json
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
import torch

from lisa_hand.fitting.images.folder import render_fitted_views
from lisa_hand.fitting.images.views import ImageView
from lisa_hand.geometry.cameras import Camera
from lisa_hand.skeleton.params import HandParams
from tests.fitting.image_scene import load_float_template, true_hand

WIDTH, HEIGHT, FOCAL = 128, 96, 130.0
BACKGROUND = (0.18, 0.38, 0.52)


@dataclass
class SyntheticPhoto:
    """image: [H, W, 3] float in [0, 1]; opacity: [H, W] of all hands; keypoints: per hand
    [21, 2] pixels; keypoints_3d: per hand [21, 3] metres (camera frame); hands: the true
    hands; camera: the true camera."""

    image: np.ndarray
    opacity: np.ndarray
    keypoints: list[np.ndarray]
    keypoints_3d: list[np.ndarray]
    hands: list[HandParams]
    camera: Camera


def photo_camera(width: int = WIDTH, height: int = HEIGHT, focal: float = FOCAL,
                 rotation: torch.Tensor | None = None,
                 shift: torch.Tensor | None = None) -> Camera:
    K = torch.tensor([[focal, 0.0, width / 2], [0.0, focal, height / 2], [0.0, 0.0, 1.0]])
    return Camera(K=K, R=torch.eye(3) if rotation is None else rotation,
                  t=torch.zeros(3) if shift is None else shift, width=width, height=height)


def photo_hand(model, centre=(0.0, 0.0, 0.32), seed: int = 1) -> HandParams:
    """:func:`tests.fitting.image_scene.true_hand` moved so that its keypoints' centre is at
    ``centre`` (metres, camera frame)."""
    hand = true_hand(model, seed)
    template = load_float_template()
    keypoints = template.forward(hand.pose[None], hand.betas[None],
                                 hand.translation[None]).keypoints[0]
    shift = torch.tensor(centre, dtype=torch.float32) - keypoints.mean(0)
    return replace(hand, translation=hand.translation + shift)


def hand_keypoints(hand: HandParams) -> torch.Tensor:
    """[21, 3] the true keypoints (the template's, as the fit projects them), metres."""
    template = load_float_template()
    return template.forward(hand.pose[None], hand.betas[None],
                            hand.translation[None]).keypoints[0]


def render_photo(model, hands: list[HandParams], camera: Camera | None = None,
                 seed: int = 0) -> SyntheticPhoto:
    """The hands rendered into ``camera`` (default :func:`photo_camera`) over
    :data:`BACKGROUND` with noise (std 0.01)."""
    camera = photo_camera() if camera is None else camera
    blank = ImageView(name="photo", camera=camera,
                      rgb=torch.zeros(camera.height, camera.width, 3))
    colour = np.zeros((camera.height, camera.width, 3))
    opacity = np.zeros((camera.height, camera.width))
    keypoints, keypoints_3d = [], []
    for hand in hands:
        render = render_fitted_views(model, hand, [blank], samples=24)[0]
        colour += render.rgb.numpy()  # over black: colour times opacity
        opacity += render.opacity.numpy()
        points = hand_keypoints(hand)
        pixels, _ = camera.project(points)
        keypoints.append(pixels.double().numpy())
        keypoints_3d.append((points.double() @ camera.R.double().T
                             + camera.t.double()).numpy())
    opacity = np.clip(opacity, 0.0, 1.0)
    image = colour + (1.0 - opacity[..., None]) * np.asarray(BACKGROUND)
    noise = np.random.default_rng(seed).normal(0.0, 0.01, image.shape)
    image = np.clip(image + noise, 0.0, 1.0).astype(np.float32)
    return SyntheticPhoto(image=image, opacity=opacity, keypoints=keypoints,
                          keypoints_3d=keypoints_3d, hands=list(hands), camera=camera)


def save_jpeg(path: Path, image: np.ndarray, quality: int = 95) -> Path:
    from PIL import Image

    path.parent.mkdir(parents=True, exist_ok=True)
    Image.fromarray((np.clip(image, 0, 1) * 255 + 0.5).astype(np.uint8)).save(
        path, format="JPEG", quality=quality)
    return path


def save_keypoints(path: Path, keypoints: np.ndarray | list, side: str | None = None) -> Path:
    """A ``--keypoints`` file: {"keypoints": [[u, v] x 21], "side"} (or a list of hands)."""
    if isinstance(keypoints, list):
        data = {"hands": [{"keypoints": np.asarray(k).tolist(), "side": side}
                          for k in keypoints]}
    else:
        data = {"keypoints": np.asarray(keypoints).tolist()}
        if side is not None:
            data["side"] = side
    path.write_text(json.dumps(data))
    return path
