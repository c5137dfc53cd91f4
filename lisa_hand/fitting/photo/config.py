"""The settings of ``lisa fit-photo`` (:class:`FitPhotoConfig`) and the image fit's defaults for
photos (:func:`photo_fit_defaults`); the fit itself is :mod:`lisa_hand.fitting.photo.fit`."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from ...data.photo import DEFAULT_MAX_SIDE
from ...skeleton.wrist import WRIST_CLIP_M
from ..images.config import FitImagesConfig

__all__ = ["photo_fit_defaults", "FitPhotoConfig"]


def photo_fit_defaults(**overrides: Any) -> FitImagesConfig:
    """The image fit's settings for photos: :class:`FitImagesConfig`'s defaults with fewer
    iterations and rays (300 keypoint-stage iterations, 40 colour-stage iterations of 256 rays),
    so that a photo takes well under half a minute on 2 CPU cores, most of it the colour stage
    and the guard's marching cubes. Then ``overrides``."""
    values: dict[str, Any] = {"keypoint_iters": 300, "color_iters": 40, "num_rays": 256}
    values.update(overrides)
    return FitImagesConfig(**values)


@dataclass(frozen=True)
class FitPhotoConfig:
    """Settings of :func:`fit_photo_folder` (the image fit's own in ``fit``)."""

    fit: FitImagesConfig = field(default_factory=photo_fit_defaults)
    """The image fit (:class:`FitImagesConfig`; default :func:`photo_fit_defaults`)."""
    max_side: int = DEFAULT_MAX_SIDE
    """Photos are downscaled to at most this long side for detection and masks, pixels."""
    view_max_side: int = 320
    """The region around the hand that the fit sees is scaled to at most this long side."""
    crop_margin: float = 0.5
    """That region: the keypoints' box grown by this many hand sizes on each side (hand size:
    :func:`lisa_hand.fitting.photo.mask.hand_scale_px`, about the wrist-to-knuckle length)."""
    min_hand_px: float = 16.0
    """Smaller hands are refused: the wrist-to-knuckle length in the downscaled photo, pixels."""
    max_hands: int = 4
    """At most this many hands are detected in a photo."""
    side_confidence: float = 0.75
    """``--side auto``: a detected side less certain than this (the detector's score, 0.5-1) is
    not trusted: both sides are fitted and the better one kept. A side the detector's own
    estimates disagree on (:attr:`lisa_hand.data.detect.DetectedHand.side_votes`: it
    changed with the window or the mirroring) only gets a note: its keypoints still fit the
    side it chose better than the other."""
    detector_wrist_shift: float = 0.0
    """Detected hands: the detector's wrist is moved back towards the forearm by this fraction of
    the wrist-to-middle-knuckle length (:func:`lisa_hand.data.detect.to_skeleton_wrist`)
    before the fit; 0 (default): as detected. :data:`~lisa_hand.data.detect.
    MEDIAPIPE_WRIST_SHIFT` (0.17) matches photos of the open hand model's hands but not real
    ones (:mod:`lisa_hand.data.detect`, "Wrist"). ``--keypoints`` files are taken as
    they are."""
    mesh_resolution: int = 128
    """Marching-cubes samples a side of ``mesh.ply``."""
    wrist_clip_m: float | None = WRIST_CLIP_M
    """``mesh.ply`` (and so the overlay and the refined mask) ends this far past the fitted
    wrist joint, towards the forearm, as ``lisa fit-points``' mesh does
    (:func:`lisa_hand.skeleton.wrist.wrist_plane`), metres: a photo shows the forearm, which
    the model does not know (the models trained on hand model v2 end their 4 cm forearm stub
    in a ragged rim of specks). None: the model's whole stub."""
    render_supersample: int = 2
    """Rays a pixel side of the rendering of ``mesh.ply`` into the photos (overlay,
    silhouette; :func:`lisa_hand.inference.mesh_render.render_mesh`)."""
    render_max_side: int = 512
    """The fitted hand is rendered into each photo's crop at most this long side, pixels (then
    resized)."""
    inconsistent_fraction: float = 0.08
    """Several photos: a photo whose mean keypoint error after the joint fit exceeds this
    fraction of the hand's size in it gets a note."""

    def __post_init__(self) -> None:
        if not isinstance(self.fit, FitImagesConfig):
            raise TypeError(f"fit must be a FitImagesConfig, got {type(self.fit).__name__}")
        for name in ("max_side", "view_max_side", "max_hands", "mesh_resolution",
                     "render_supersample", "render_max_side"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or value < 1:
                raise ValueError(f"{name} must be a positive integer, got {value!r}")
        if self.wrist_clip_m is not None and not -0.05 <= self.wrist_clip_m <= 0.2:
            raise ValueError(f"wrist_clip_m must be None or within [-0.05, 0.2] metres, got "
                             f"{self.wrist_clip_m!r}")
        for name in ("crop_margin", "min_hand_px", "inconsistent_fraction", "side_confidence"):
            if not getattr(self, name) >= 0:
                raise ValueError(f"{name} must be >= 0, got {getattr(self, name)!r}")
        if not 0.0 <= self.detector_wrist_shift < 1.0:
            raise ValueError("detector_wrist_shift must be in [0, 1), got "
                             f"{self.detector_wrist_shift!r}")
