"""Rendered clips with ground truth for the video benchmark (``python -m benchmarks video``).

Each clip is one hand of a HELD-OUT subject of the open hand model (the subjects of
:mod:`benchmarks._photo_scenes`: the shipped models' test split, rebuilt with
:func:`lisa_hand.data.synth.make_subject`; clip ``i`` shows subject ``i mod 6``, and clips 1, 4,
7, ... show it as a left hand, its mirror image) moving for ``frames`` frames at ``fps``, seen by
a fixed, known camera. Per clip ``i`` (a ``numpy.random.SeedSequence`` keyed by
``(seed, 11, i)``, independent of the number of clips):

* the fingers: through the named poses ``key_poses`` (:func:`lisa_hand.handmodel.named_pose`,
  relaxed -> fist -> point -> relaxed by default), the anatomical joint angles interpolated
  between consecutive key poses with a smoothstep ease (the hand slows at each key pose, as a
  hand does), the key poses evenly spaced in time;
* the wrist: a starting orientation as :func:`benchmarks._photo_scenes.photo_orientation` picks
  one for a photo (fingers up, palm towards the camera; turned, tilted and rolled by less than a
  photo's), then turned about the camera's vertical axis by an angle uniform in
  ``turn_range_deg`` over the clip (smoothstep in time, centred on the start), about the middle
  of the hand;
* the place: the middle of the hand (of its first frame's keypoints' box) at a distance uniform
  in ``distance_range_m``, a little off-axis, moving ``shift_m`` in a random direction (mostly
  across the image, a little in depth) over the clip (smoothstep, centred);
* the camera: focal ``focal_px`` pixels, principal point at the image's centre, the world frame
  (OpenCV: x right, y down, z forward), so the true keypoints are in the camera frame; written as
  ``camera.json`` in the ``cameras.json`` convention (one ``{name, K, R, t, width, height}``
  entry) for ``fit_video(camera_json=...)``;
* light, white balance and background fixed for the clip (one light from the camera's side plus
  ambient, a textured muted background), chosen as a photo's; sensor noise drawn anew each frame;
* each frame rendered as a synthetic photo is (:func:`benchmarks._photo_scenes._render`: the
  posed hand meshed by marching cubes, Embree ray casting at twice the size averaged down) and
  saved as a lossless PNG in ``frames/`` (``frame_0000.png``, ...), with the truth in
  ``truth.json`` beside it (and the settings that made the clip: a folder that already holds a
  clip made with the same settings and index is read back, not rendered again).
"""

from __future__ import annotations

import dataclasses
import json
import math
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

__all__ = ["VideoSceneConfig", "SyntheticClip", "clip_side", "clip_motion", "make_clip"]

_STREAM_CLIP = 11


@dataclass(frozen=True)
class VideoSceneConfig:
    """How the rendered clips are made (see the module docstring)."""

    seed: int = 0
    """Seed of the clips' random choices (orientation, place, motion, light, background)."""
    frames: int = 40
    """Frames a clip."""
    fps: float = 25.0
    """Frames a second."""
    width: int = 640
    height: int = 480
    """Frame size, pixels."""
    focal_px: float = 550.0
    """Focal length, pixels (principal point at the centre)."""
    distance_range_m: tuple[float, float] = (0.45, 0.55)
    """Distance from the camera to the middle of the hand, metres."""
    key_poses: tuple[str, ...] = ("relaxed", "fist", "point", "relaxed")
    """The named poses the fingers pass through, evenly spaced over the clip."""
    turn_range_deg: tuple[float, float] = (30.0, 40.0)
    """How far the hand turns about the camera's vertical axis over the clip, degrees (the sign
    is random)."""
    shift_m: float = 0.04
    """How far the middle of the hand moves over the clip, metres."""
    max_start_turn_deg: float = 15.0
    max_start_tilt_deg: float = 10.0
    max_start_roll_deg: float = 20.0
    """The starting orientation's random turn, tilt and roll (as a photo's, smaller)."""
    left_every: int = 3
    """Clips ``1, 1 + left_every, ...`` show a left hand (0: none)."""
    noise_std: float = 0.01
    """Gaussian sensor noise, per pixel and channel, in [0, 1] colour units."""
    voxels_per_length: float = 250.0
    """Mesh resolution: hand length / voxel size (250: about 0.7 mm voxels, as the photos')."""
    hand_model: str = "v1"
    """Version of the open hand model (the one the shipped model was trained on)."""

    def __post_init__(self) -> None:
        if isinstance(self.frames, bool) or not isinstance(self.frames, int) or self.frames < 3:
            raise ValueError(f"frames must be an integer >= 3, got {self.frames!r}")
        if len(self.key_poses) < 2:
            raise ValueError(f"key_poses must name at least 2 poses, got {self.key_poses!r}")
        if not self.fps > 0:
            raise ValueError(f"fps must be positive, got {self.fps!r}")


@dataclass(frozen=True, eq=False)
class SyntheticClip:
    """One rendered clip and its ground truth."""

    folder: Path
    """The folder of frames (``frame_0000.png``, ...): ``fit_video``'s input."""
    camera_json: Path
    """The true camera (``cameras.json`` convention)."""
    subject: str
    """Held-out subject id (``s000``, ...)."""
    side: str
    """'right' or 'left'."""
    keypoints_3d: np.ndarray
    """[F, 21, 3] float64 metres: the true keypoints in the camera frame (package order,
    :data:`lisa_hand.skeleton.KEYPOINT_NAMES`)."""
    keypoints_2d: np.ndarray
    """[F, 21, 2] float64 pixels: their projections."""
    K: np.ndarray
    """[3, 3] float64 the true intrinsics, pixels."""
    fps: float
    turn_deg: float
    """The turn about the vertical over the clip (signed), degrees."""
    seconds_render: float
    """Seconds spent making the clip (meshing and rendering every frame)."""
    read_back: bool = False
    """The clip was made by an earlier run and read back from its folder."""

    @property
    def num_frames(self) -> int:
        return len(self.keypoints_3d)


def clip_side(config: VideoSceneConfig, index: int) -> str:
    """The side of clip ``index``: left for clips 1, 1 + left_every, ...; else right."""
    every = config.left_every
    return "left" if every and index % every == 1 % every else "right"


def _smoothstep(t: np.ndarray | float) -> np.ndarray:
    t = np.clip(np.asarray(t, np.float64), 0.0, 1.0)
    return t * t * (3.0 - 2.0 * t)


def _finger_poses(config: VideoSceneConfig, side: str) -> torch.Tensor:
    """[F, 48] float64 finger poses (zero global orientation) through ``key_poses``."""
    from lisa_hand.handmodel import named_pose
    from lisa_hand.handmodel.poses import angles_to_pose, pose_to_angles

    keys = torch.stack([pose_to_angles(named_pose(name, side=side, dtype=torch.float64), side)
                        for name in config.key_poses])  # [K, 15, 3]
    position = np.linspace(0.0, len(keys) - 1.0, config.frames)
    segment = np.minimum(np.floor(position).astype(int), len(keys) - 2)
    weight = torch.from_numpy(_smoothstep(position - segment))[:, None, None]
    segment = torch.from_numpy(segment)
    angles = keys[segment] + weight * (keys[segment + 1] - keys[segment])
    return angles_to_pose(angles, None, side=side).double()


def clip_motion(config: VideoSceneConfig, index: int, hand) -> dict:
    """The motion of clip ``index`` for ``hand`` (an ``OpenHand`` of the clip's side): poses
    [F, 48] and translations [F, 3] (float64 tensors), the turn (degrees) and the generator of
    the clip's further random choices (light, background, noise)."""
    from lisa_hand.geometry.rotations import axis_angle_to_matrix, matrix_to_axis_angle

    from ._photo_scenes import PhotoSceneConfig, photo_orientation

    rng = np.random.default_rng(np.random.SeedSequence([config.seed, _STREAM_CLIP, index]))
    side = hand.side
    start = PhotoSceneConfig(max_turn_deg=config.max_start_turn_deg,
                             max_tilt_deg=config.max_start_tilt_deg,
                             max_roll_deg=config.max_start_roll_deg)
    base = axis_angle_to_matrix(torch.from_numpy(photo_orientation(rng, side, False, start)))
    turn = math.radians(rng.uniform(*config.turn_range_deg)) * rng.choice([-1.0, 1.0])
    ease = _smoothstep(np.linspace(0.0, 1.0, config.frames)) - 0.5  # [-0.5, 0.5]
    vertical = torch.tensor([0.0, 1.0, 0.0], dtype=torch.float64)
    orients = [matrix_to_axis_angle(axis_angle_to_matrix(vertical * turn * float(e)) @ base)
               for e in ease]
    poses = _finger_poses(config, side)
    poses[:, :3] = torch.stack(orients)

    distance = rng.uniform(*config.distance_range_m)
    half_width = distance * config.width / (2.0 * config.focal_px)
    half_height = distance * config.height / (2.0 * config.focal_px)
    centre = np.array([0.1 * half_width * rng.uniform(-1, 1),
                       0.1 * half_height * rng.uniform(-1, 1), distance])
    direction = np.array([rng.normal(), rng.normal(), 0.3 * rng.normal()])
    direction /= np.linalg.norm(direction)
    targets = centre + config.shift_m * ease[:, None] * direction  # the hand's middle per frame
    # The pivot: the middle of the first frame's keypoints, carried by the global rotation (the
    # fingers curl about it, the hand turns about it).
    first_fingers = poses[0].clone()
    translations = []
    for orient in poses[:, :3]:
        first_fingers[:3] = orient
        keypoints = hand.posed(first_fingers, dtype=torch.float64).keypoints.numpy()
        middle = 0.5 * (keypoints.min(0) + keypoints.max(0))
        translations.append(targets[len(translations)] - middle)
    return {"poses": poses, "translations": torch.from_numpy(np.stack(translations)),
            "turn_deg": math.degrees(turn), "rng": rng}


def _made_with(config: VideoSceneConfig, index: int) -> dict:
    """The settings a clip's ``truth.json`` records (JSON's view of them)."""
    return json.loads(json.dumps({"scene": dataclasses.asdict(config), "index": index}))


def _read_clip(config: VideoSceneConfig, index: int, folder: Path) -> SyntheticClip | None:
    """The clip in ``folder`` when it was made with ``config`` as clip ``index`` and all its
    frames are there; else None."""
    try:
        truth = json.loads((folder / "truth.json").read_text())
    except (OSError, ValueError):
        return None
    frames_dir = folder / "frames"
    if (truth.get("made_with") != _made_with(config, index) or not all(
            (frames_dir / f"frame_{frame:04d}.png").is_file() for frame in range(config.frames))):
        return None
    return SyntheticClip(folder=frames_dir, camera_json=folder / "camera.json",
                         subject=truth["subject"], side=truth["side"],
                         keypoints_3d=np.asarray(truth["keypoints_3d"], np.float64),
                         keypoints_2d=np.asarray(truth["keypoints_2d"], np.float64),
                         K=np.asarray(truth["K"], np.float64), fps=float(truth["fps"]),
                         turn_deg=float(truth["turn_deg"]),
                         seconds_render=float(truth["seconds_render"]), read_back=True)


def make_clip(config: VideoSceneConfig, index: int, out_dir: Path, log=None) -> SyntheticClip:
    """Clip ``index`` (see the module docstring), written to ``out_dir/clip_INDEX/``:
    ``frames/frame_NNNN.png``, ``camera.json`` and ``truth.json``; read back instead when that
    folder already holds it (made with the same ``config`` and index, every frame there)."""
    from PIL import Image

    from lisa_hand.data.images import project_keypoints
    from lisa_hand.data.synth import SynthConfig, make_subject
    from lisa_hand.geometry.cameras import Camera

    from ._photo_scenes import _TRAINING_SEED, _background, _render, held_out_subjects

    folder = Path(out_dir) / f"clip_{index:03d}"
    made = _read_clip(config, index, folder)
    if made is not None:
        return made
    began = time.perf_counter()
    subjects = held_out_subjects("test")
    record = make_subject(SynthConfig(seed=_TRAINING_SEED, hand_model=config.hand_model),
                          subjects[index % len(subjects)], fit_template=False)
    side = clip_side(config, index)
    hand = dataclasses.replace(record.hand, side=side)
    motion = clip_motion(config, index, hand)
    rng = motion["rng"]

    width, height = config.width, config.height
    K = torch.tensor([[config.focal_px, 0.0, width / 2.0], [0.0, config.focal_px, height / 2.0],
                      [0.0, 0.0, 1.0]], dtype=torch.float64)
    eye, zero = np.eye(3), np.zeros(3)
    camera = Camera(K=K, R=eye, t=zero, width=width, height=height, name="frames")
    K_2x = K.clone()
    K_2x[:2] *= 2.0
    camera_2x = Camera(K=K_2x, R=eye, t=zero, width=2 * width, height=2 * height)
    light_seed = int(rng.integers(0, 2**62))  # the same light and white balance every frame
    background = _background(rng, 2 * height, 2 * width, textured=True)

    frames_dir = folder / "frames"
    (folder / "truth.json").unlink(missing_ok=True)  # an older clip's, about to be overwritten
    frames_dir.mkdir(parents=True, exist_ok=True)
    keypoints_3d, keypoints_2d = [], []
    for frame, (pose, translation) in enumerate(zip(motion["poses"], motion["translations"],
                                                    strict=True)):
        posed = hand.posed(pose, translation)
        rgb, mask, _ = _render(posed, hand.shape.hand_length, camera_2x,
                               np.random.default_rng(light_seed), config)
        image = np.where(mask[..., None], rgb, background)
        image = image.reshape(height, 2, width, 2, 3).mean(axis=(1, 3))
        image = image + config.noise_std * rng.standard_normal(image.shape)
        pixels = np.clip(np.round(255.0 * image), 0, 255).astype(np.uint8)
        Image.fromarray(pixels).save(frames_dir / f"frame_{frame:04d}.png")
        keypoints = posed.keypoints.double().numpy()
        keypoints_3d.append(keypoints)
        keypoints_2d.append(project_keypoints(keypoints, camera).pixels.astype(np.float64))
        if log is not None and (frame + 1) % 10 == 0:
            log(f"    rendered {frame + 1}/{config.frames} frames of clip {index}")

    camera_json = folder / "camera.json"
    camera_json.write_text(json.dumps([camera.to_dict()], indent=1))
    seconds = time.perf_counter() - began
    truth = {"subject": record.id, "side": side, "fps": config.fps,
             "turn_deg": motion["turn_deg"], "K": K.tolist(),
             "keypoints_3d": np.stack(keypoints_3d).tolist(),
             "keypoints_2d": np.stack(keypoints_2d).tolist(),
             "seconds_render": seconds, "made_with": _made_with(config, index)}
    staged = folder / "truth.json.partial"  # written last: its presence means a whole clip
    staged.write_text(json.dumps(truth))
    staged.replace(folder / "truth.json")
    return SyntheticClip(folder=frames_dir, camera_json=camera_json, subject=record.id, side=side,
                         keypoints_3d=np.stack(keypoints_3d), keypoints_2d=np.stack(keypoints_2d),
                         K=K.numpy(), fps=config.fps, turn_deg=motion["turn_deg"],
                         seconds_render=seconds)
