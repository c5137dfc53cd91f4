"""Synthetic photos with ground truth for the photo benchmark (``python -m benchmarks photo``).

Each photo is one hand of a HELD-OUT subject of the open hand model: the test split
(:func:`lisa_hand.data.synth.split_subjects`) of the shipped models' dataset (290 subjects,
seed 0: its first six test subjects, s000, s001, s009, s010, s018, s020), rebuilt with
:func:`lisa_hand.data.synth.make_subject`, so the fit has never seen the hand. Every other photo
shows the mirror image of the subject (the same hand as a left hand). Per photo ``i`` (a
``numpy.random.SeedSequence`` keyed by ``(seed, 7, i)``, independent of the number of photos):

* a natural pose (:func:`lisa_hand.handmodel.sample_pose`, synergies plus noise, within the
  joint limits);
* an orientation as people hold a hand up to a phone: fingers up in the image, palm (or, one
  photo in three, the back of the hand) towards the camera, turned about the vertical by up to
  ``max_turn_deg``, tilted forwards or backwards by up to ``max_tilt_deg`` and rolled in the
  image plane by up to ``max_roll_deg``;
* a phone camera: horizontal field of view uniform in ``fov_range_deg``, the keypoints' centre at
  a distance uniform in ``distance_range_m``, shifted off the optical axis by up to a tenth of
  the view; the camera is the world frame (OpenCV: x right, y down, z forward), so the true 3D
  keypoints are in the camera frame;
* lit by one light from the camera's side (random in a cone above it) plus ambient, the skin's
  colour scaled by a random white balance, over a background of a random muted colour, plain
  (photos 0, 1, 4, 5, ...) or textured (2, 3, 6, 7, ...: two octaves of smooth brightness
  noise and a faint colour noise);
* rendered by Embree ray casting (:func:`lisa_hand.data.images.render_views`) at twice the size
  and averaged down (anti-aliased edges over the background), with sensor noise, and saved as a
  JPEG (quality 92) WITHOUT EXIF: the fit is given no calibration.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

__all__ = ["PhotoSceneConfig", "SyntheticPhoto", "held_out_subjects", "photo_orientation",
           "save_photo", "make_photo"]

_STREAM_PHOTO = 7
# The split the shipped models were trained on (README, "Pretrained model"): the 203-subject
# prior's 290-subject dataset, whose split the shipped LISA-full's 80-subject dataset keeps.
_TRAINING_SUBJECTS = 290
_TRAINING_SEED = 0
_HELD_OUT_PHOTO_SUBJECTS = 6


@dataclass(frozen=True)
class PhotoSceneConfig:
    """How the synthetic photos are made (see the module docstring)."""

    seed: int = 0
    """Seed of the photos' random choices (poses, placements, cameras, lights, backgrounds)."""
    width: int = 1024
    """Photo width, pixels."""
    height: int = 768
    """Photo height, pixels."""
    fov_range_deg: tuple[float, float] = (60.0, 70.0)
    """Horizontal field of view, degrees (a phone's main camera is about 65)."""
    distance_range_m: tuple[float, float] = (0.4, 0.6)
    """Distance from the camera to the centre of the hand's keypoints, metres."""
    max_turn_deg: float = 45.0
    """Largest turn of the hand about the image's vertical axis, degrees."""
    max_tilt_deg: float = 20.0
    """Largest tilt of the fingers towards or away from the camera, degrees."""
    max_roll_deg: float = 30.0
    """Largest roll of the hand in the image plane, degrees."""
    back_fraction: float = 1.0 / 3.0
    """Fraction of the photos that show the back of the hand."""
    noise_std: float = 0.01
    """Gaussian sensor noise, per pixel and channel, in [0, 1] colour units."""
    jpeg_quality: int = 92
    """JPEG quality (PIL's 1-95 scale)."""
    voxels_per_length: float = 250.0
    """Mesh resolution: hand length / voxel size (250: about 0.7 mm voxels, the dataset's)."""
    hand_model: str = "v1"
    """Version of the open hand model photographed (``lisa synth --hand-model``): "v1", the one
    the shipped model was trained on, or "v2" (rounded, padded palm, forearm stub: a hand the
    model never saw the like of, closer to a real one)."""
    subjects: str = "test"
    """Whose hands: "test", the first 6 held-out test subjects of the shipped models' split (the
    benchmark); "train", its first 6 training subjects (to measure a convention, such as where the
    detector puts the wrist, on hands that are not the benchmark's)."""

    def __post_init__(self) -> None:
        if self.subjects not in ("test", "train"):
            raise ValueError(f"subjects must be 'test' or 'train', got {self.subjects!r}")


@dataclass(frozen=True, eq=False)
class SyntheticPhoto:
    """One synthetic photo and its ground truth."""

    path: Path
    """The JPEG file (no EXIF)."""
    subject: str
    """Held-out subject id (``s002``, ...)."""
    side: str
    """'right' or 'left': the true side of the hand in the photo."""
    keypoints_3d: np.ndarray
    """[21, 3] float64 metres: the true keypoints in the camera frame (package order)."""
    keypoints_2d: np.ndarray
    """[21, 2] float64 pixels: their projections (continuous pixel coordinates)."""
    visible: np.ndarray
    """[21] bool: in the image and not hidden by another part of the hand."""
    K: np.ndarray
    """[3, 3] float64 the true intrinsics, pixels (never given to the fit)."""
    fov_deg: float
    """The true horizontal field of view, degrees."""
    back: bool
    """The back of the hand faces the camera (else the palm)."""
    textured: bool
    """Textured background (else plain)."""


def held_out_subjects(part: str = "test") -> list[int]:
    """Indices of the first 6 test subjects of the shipped models' split (no shipped model saw
    them), or with ``part="train"`` of its first 6 training subjects."""
    from lisa_hand.data.synth import split_subjects

    names = split_subjects(_TRAINING_SUBJECTS, seed=_TRAINING_SEED)[part]
    return [int(name[1:]) for name in names[:_HELD_OUT_PHOTO_SUBJECTS]]


def _rotation(axis, angle: float) -> np.ndarray:
    from lisa_hand.geometry.rotations import axis_angle_to_matrix

    vector = torch.as_tensor(np.asarray(axis, np.float64) * angle)
    return axis_angle_to_matrix(vector).numpy()


def photo_orientation(rng: np.random.Generator, side: str, back: bool,
                      config: PhotoSceneConfig) -> np.ndarray:
    """[3] axis-angle of the hand's wrist in the camera frame (see the module docstring); back:
    the back of the hand towards the camera."""
    from lisa_hand.geometry.rotations import matrix_to_axis_angle

    # Rest hand: fingers along -x (right) or +x (left), palm towards -y. Map the fingers to the
    # image's up (-y, camera frame) and the palm normal to the camera (-z).
    fingers_axis = np.array([0.0, 1.0, 0.0]) if side == "right" else np.array([0.0, -1.0, 0.0])
    palm_axis = np.array([0.0, 0.0, 1.0])  # the image of +y (rest), so -y goes to -z
    base = np.stack([fingers_axis, palm_axis, np.cross(fingers_axis, palm_axis)], axis=1)
    turn = math.radians(config.max_turn_deg) * rng.uniform(-1.0, 1.0) + (math.pi if back else 0)
    tilt = math.radians(config.max_tilt_deg) * rng.uniform(-1.0, 1.0)
    roll = math.radians(config.max_roll_deg) * rng.uniform(-1.0, 1.0)
    rotation = (_rotation([0.0, 0.0, 1.0], roll) @ _rotation([1.0, 0.0, 0.0], tilt)
                @ _rotation([0.0, 1.0, 0.0], turn) @ base)
    return matrix_to_axis_angle(torch.from_numpy(rotation)).numpy()


def _smooth_noise(rng: np.random.Generator, cells: int, height: int, width: int,
                  channels: int) -> np.ndarray:
    """[H, W, channels] float32 in about [-1, 1]: a ``cells``-row grid of uniform values,
    upsampled bicubically."""
    columns = max(2, round(cells * width / height))
    grid = torch.from_numpy(rng.uniform(-1.0, 1.0, size=(1, channels, cells, columns)))
    smooth = torch.nn.functional.interpolate(grid.float(), size=(height, width), mode="bicubic",
                                             align_corners=False)
    return smooth[0].permute(1, 2, 0).numpy()


def _background(rng: np.random.Generator, height: int, width: int, textured: bool) -> np.ndarray:
    """[H, W, 3] float32 in [0, 1]: a muted plain colour, or that colour with smooth brightness
    variations (two octaves) and a faint colour noise."""
    base = rng.uniform(0.15, 0.85) * (1.0 + rng.uniform(-0.2, 0.2, size=3))
    image = np.broadcast_to(np.clip(base, 0.05, 0.95), (height, width, 3)).astype(np.float32)
    if not textured:
        return image.copy()
    brightness = (0.35 * _smooth_noise(rng, 4, height, width, 1)
                  + 0.12 * _smooth_noise(rng, 32, height, width, 1))
    tint = 0.04 * _smooth_noise(rng, 8, height, width, 3)
    return np.clip(image * (1.0 + brightness) + tint, 0.0, 1.0)


def _placement(rng, posed_keypoints: np.ndarray, fov_deg: float, aspect: float, config):
    """[3] translation putting the keypoints' centre at the chosen distance, off-axis a little."""
    distance = rng.uniform(*config.distance_range_m)
    half_width = distance * math.tan(math.radians(fov_deg) / 2.0)
    centre = np.array([0.1 * half_width * rng.uniform(-1, 1),
                       0.1 * half_width / aspect * rng.uniform(-1, 1), distance])
    middle = 0.5 * (posed_keypoints.min(0) + posed_keypoints.max(0))
    return centre - middle


def _render(posed, hand_length: float, camera_2x, rng, config: PhotoSceneConfig):
    """(rgb [2H, 2W, 3] float32 with a black background, mask [2H, 2W], depth [2H, 2W])."""
    from lisa_hand.data.images import render_views
    from lisa_hand.data.shading import GainBias, ShadingConfig, sample_cone

    mesh = posed.mesh(voxel_size=hand_length / config.voxels_per_length)
    light = sample_cone(np.array([0.0, -0.6, -1.0]) / math.hypot(0.6, 1.0), 35.0, rng)
    ambient = rng.uniform(0.3, 0.45)
    shading = ShadingConfig(ambient=ambient, diffuse=1.0 - ambient,
                            light_directions=(tuple(float(v) for v in light),))
    white_balance = GainBias(gain=rng.uniform(0.9, 1.1, size=(1, 3)) * rng.uniform(0.9, 1.1),
                             bias=np.zeros((1, 3)))
    view = render_views(mesh.vertices, mesh.faces, [camera_2x], mesh.colors / 255.0,
                        shading=shading, gain_bias=white_balance)[0]
    return view.rgb, view.mask, view.depth


def save_photo(rgb: np.ndarray, mask: np.ndarray, textured: bool, rng: np.random.Generator,
               config: PhotoSceneConfig, path: Path) -> Path:
    """A rendering at twice the photo's size (``rgb`` [2H, 2W, 3], ``mask`` [2H, 2W]) over a
    plain or ``textured`` background, averaged down, with sensor noise, saved as a JPEG without
    EXIF at ``path`` -> ``path``."""
    from PIL import Image

    background = _background(rng, 2 * config.height, 2 * config.width, textured)
    image = np.where(mask[..., None], rgb, background)
    image = image.reshape(config.height, 2, config.width, 2, 3).mean(axis=(1, 3))
    image = image + config.noise_std * rng.standard_normal(image.shape)
    pixels = np.clip(np.round(255.0 * image), 0, 255).astype(np.uint8)
    path.parent.mkdir(parents=True, exist_ok=True)
    Image.fromarray(pixels).save(path, "JPEG", quality=config.jpeg_quality)
    return path


def make_photo(config: PhotoSceneConfig, index: int, out_dir: Path) -> SyntheticPhoto:
    """Photo ``index`` (see the module docstring), written to ``out_dir/photo_INDEX.jpg``."""

    from lisa_hand.data.images import project_keypoints
    from lisa_hand.data.synth import SynthConfig, make_subject
    from lisa_hand.geometry.cameras import Camera, intrinsics_from_fov
    from lisa_hand.handmodel import sample_pose

    rng = np.random.default_rng(np.random.SeedSequence([config.seed, _STREAM_PHOTO, index]))
    subjects = held_out_subjects(config.subjects)
    record = make_subject(SynthConfig(seed=_TRAINING_SEED, hand_model=config.hand_model),
                          subjects[index % len(subjects)], fit_template=False)
    side = "left" if index % 2 else "right"
    hand = dataclasses.replace(record.hand, side=side)
    generator = torch.Generator().manual_seed(int(rng.integers(0, 2**62)))
    pose = sample_pose(generator, 1, side=side)[0].double().clone()
    back = bool(rng.random() < config.back_fraction)
    pose[:3] = torch.from_numpy(photo_orientation(rng, side, back, config))
    centred = hand.posed(pose).keypoints.numpy()
    fov_deg = float(rng.uniform(*config.fov_range_deg))
    translation = _placement(rng, centred, fov_deg, config.width / config.height, config)
    posed = hand.posed(pose, torch.from_numpy(translation))

    eye, zero = np.eye(3), np.zeros(3)
    K = intrinsics_from_fov(fov_deg, config.width, config.height, dtype=torch.float64)
    camera = Camera(K=K, R=eye, t=zero, width=config.width, height=config.height)
    K_2x = K.clone()
    K_2x[:2] *= 2.0
    camera_2x = Camera(K=K_2x, R=eye, t=zero, width=2 * config.width, height=2 * config.height)
    rgb, mask, depth = _render(posed, hand.shape.hand_length, camera_2x, rng, config)
    textured = (index // 2) % 2 == 1
    path = save_photo(rgb, mask, textured, rng, config, Path(out_dir) / f"photo_{index:03d}.jpg")
    keypoints = posed.keypoints.numpy()
    visible = project_keypoints(keypoints, camera_2x, depth=depth).visible
    projection = project_keypoints(keypoints, camera)
    return SyntheticPhoto(path=path, subject=record.id, side=side, keypoints_3d=keypoints,
                          keypoints_2d=projection.pixels.astype(np.float64),
                          visible=visible & projection.in_image, K=K.numpy(), fov_deg=fov_deg,
                          back=back, textured=textured)
