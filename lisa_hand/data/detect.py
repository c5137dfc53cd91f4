"""21 hand keypoints and the hand's side in a photo, offline, with MediaPipe Hands (the photo
extra: ``pip install -e '.[photo]'``, ``mediapipe==0.10.14``, whose wheel ships
``palm_detection_full.tflite`` and ``hand_landmark_full.tflite``).

MediaPipe's legacy ``solutions.hands`` runs a palm detector on the whole input letterboxed to
192 x 192 pixels, then a landmark model on a crop around each palm. Hands much smaller than about
a tenth of the input's long side are missed, and so can be hands that fill it; large inputs also
lose small hands to aliasing (the detector's own resize does not low-pass, so a small hand in a
large photo can be missed at full size and found in the same photo averaged down). So
:func:`detect_hands` searches windows of the image, coarse to fine, each resized to a long side
of :attr:`DetectConfig.window_side_px` (Pillow's bicubic, which low-passes when it shrinks), and
stops at the first level that finds a hand:

1. the whole image, and the whole image zoomed out (padded on every side with the median colour
   of its border, for hands that fill it);
2. a grid of 2 x 2 crops overlapping by half a crop (:attr:`DetectConfig.grid_overlap`);
3. 3 x 3 crops; 4. 4 x 4 crops (:attr:`DetectConfig.grids`).

Because the detector sees 192 pixels whatever it is given, rescaled copies of the whole image
(640, 1280, 1920 px) would show it the same thing; crops are what make a small hand larger.

Every hand found is **refined**: detected again in square windows 1.5 and 2.5 times its keypoint
box (:attr:`DetectConfig.refine_contexts`), resized to :attr:`DetectConfig.refine_side_px`, each
as it is and mirrored. Of these estimates and the first one, those within 10% of the hand's size
(:attr:`DetectConfig.agreement`) of their medoid are averaged, keypoints and side votes alike.
A hand found only in a crop must be found again around it, or it is dropped. Candidates of one
level are merged largest first (a part of a hand cut by a crop's edge lies inside the whole
one); refined hands whose keypoint boxes overlap by more than :attr:`DetectConfig.duplicate_iou`
are one hand. A hand whose keypoint box spans about 5% of the photo's long side or more is
found; smaller ones often are, less reliably on textured backgrounds.

**Handedness.** MediaPipe labels a hand assuming a mirrored (selfie) image: its label is the
opposite of the true side in an ordinary photo. In a photo of the palm side of a thumbs-up fist
with the fingers pointing to the image's left and the thumb up, the hand is a right one (for a
right hand, thumb direction = finger direction x palm normal), and MediaPipe labels it "Left";
its labels agree with that geometry once swapped, so :attr:`DetectedHand.side` is ``"right"``
for the label "Left" and ``"left"`` for "Right".

**Greyscale photos.** MediaPipe looks for skin, and finds some hands in a greyscale photo (an
infrared camera's, an old print's) and not others, whatever its contrast. A greyscale photo in
which nothing is found is searched again with skin-coloured channels (gains :data:`_SKIN_TINT`).
The side MediaPipe gives a tinted photo is not to be trusted (it can call a hand's side with a
full score either way), so such a hand's score is 0.5 and ``lisa fit-photo --side auto`` fits it
as both sides. Tinted photos are also where false hands appear (small specks on textures such
as grass), so a hand found only tinted must span 5% of the photo's long side. A greyscale photo
without a hand takes twice the search time.

**Keypoint order.** MediaPipe's 21 landmarks (wrist, thumb CMC, MCP, IP, tip, then index, middle,
ring and pinky MCP, PIP, DIP, tip) are exactly :data:`lisa_hand.skeleton.KEYPOINT_NAMES`, so no
reordering is needed (checked against ``mediapipe.solutions.hands.HandLandmark`` in the tests).

**Wrist.** MediaPipe's wrist landmark is not the skeleton's wrist keypoint (the root joint, at
the base of the palm, where the open hand model's palm ends): on photos of the open hand model's
hands it lies about 0.16-0.17 of the wrist-to-middle-knuckle length nearer the fingers (``python
-m benchmarks photo --subjects train`` prints it as ``detector_wrist_shift``), while the
other 20 landmarks lie within about a tenth of that length of the true ones.
:func:`to_skeleton_wrist` moves the detected wrist back by such a fraction along the
wrist-to-middle-knuckle line
(:attr:`lisa_hand.fitting.photo.config.FitPhotoConfig.detector_wrist_shift`). It is OFF by
default: the offset belongs to the generator's hands (the wrist keypoint at the end of a long,
flat-cut palm), not to MediaPipe; on photos of real hands the moved wrist lies in the forearm,
below the visible wrist, and the fitted hand does not follow it.

**Time.** One process call takes 20-60 ms; with refinement a photo whose hand is found in the
whole image takes well under a second on one CPU core, a photo without a hand (every window
searched) about a second. Importing MediaPipe takes about 1 s more, once.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from ..skeleton import KEYPOINT_NAMES, NUM_KEYPOINTS
from ..utils.stderr import native_stderr_captured

__all__ = [
    "PHOTO_EXTRA_HINT",
    "photo_extra_missing",
    "DetectConfig",
    "DetectedHand",
    "detect_hands",
    "MEDIAPIPE_LABEL_TO_SIDE",
    "MEDIAPIPE_WRIST_SHIFT",
    "MIDDLE_MCP",
    "to_skeleton_wrist",
    "VideoHandDetector",
]

PHOTO_EXTRA_HINT = ("hand detection needs the photo extra (MediaPipe): pip install -e '.[photo]'; "
                    "or give the 21 keypoints with --keypoints KP.json")
"""The one line to print when MediaPipe is missing."""

MEDIAPIPE_LABEL_TO_SIDE = {"Left": "right", "Right": "left"}
"""MediaPipe's handedness label (mirrored-image convention) -> the true side in a photo."""

MEDIAPIPE_WRIST_SHIFT = 0.17
"""How far MediaPipe's wrist lies from the open hand model's wrist keypoint towards the middle
finger's knuckle on photos of the generator's hands, a fraction of the wrist-to-knuckle length
(on photos of training subjects; not a property of real hands: the module docstring)."""

MIDDLE_MCP = KEYPOINT_NAMES.index("middle_mcp")
"""Row of the middle finger's knuckle, the wrist shift's other end."""


def to_skeleton_wrist(keypoints: np.ndarray, shift: float = MEDIAPIPE_WRIST_SHIFT) -> np.ndarray:
    """Detected keypoints [21, 2] pixels -> a copy with the wrist (row 0) moved to where the
    skeleton's wrist keypoint would project: the detected wrist ``w`` lies a fraction ``shift``
    of the way from the skeleton's wrist ``s`` to the middle knuckle ``m`` (``w = s + shift (m -
    s)``), so ``s = (w - shift m) / (1 - shift)``: exact where the wrist-to-knuckle line is
    parallel to the image, a few percent of its length off where it tilts steeply in depth (the
    tests: 2.3% at 40 degrees, 0.4 m away). shift: in [0, 1); 0 returns the keypoints."""
    if not 0.0 <= shift < 1.0:
        raise ValueError(f"the wrist shift must be in [0, 1), got {shift!r}")
    moved = np.array(keypoints, dtype=np.float64, copy=True)
    moved[0] = (moved[0] - shift * moved[MIDDLE_MCP]) / (1.0 - shift)
    return moved

_WHOLE = "whole image"  # the first search level: the image as it is and zoomed out

Window = tuple[int, int, int, int]
"""(x0, y0, x1, y1) pixels of the image; may extend past its borders (padded)."""


def photo_extra_missing() -> str | None:
    """None when MediaPipe's ``solutions.hands`` imports, else :data:`PHOTO_EXTRA_HINT`."""
    try:
        _mediapipe_hands()
    except (ImportError, AttributeError):
        return PHOTO_EXTRA_HINT
    return None


def _mediapipe_hands() -> Any:
    """``mediapipe.solutions.hands``, imported lazily (its protobuf deprecation warnings hidden)."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        import mediapipe as mp

        return mp.solutions.hands


@dataclass(frozen=True)
class DetectConfig:
    """How :func:`detect_hands` searches a photo (see the module docstring)."""

    min_detection_confidence: float = 0.3
    """MediaPipe's palm-detection threshold in (0, 1)."""
    model_complexity: int = 1
    """MediaPipe's landmark model: 0 (lite) or 1 (full)."""
    window_side_px: int = 640
    """Long side, pixels, that each search window is resized to before detection."""
    zoom_out: float = 1.6
    """The zoomed-out pass pads the image to this many times its size (hands that fill it)."""
    grids: tuple[int, ...] = (2, 3, 4)
    """Crop grids searched after the whole image, in order: n means n x n overlapping crops."""
    grid_overlap: float = 0.5
    """Overlap of neighbouring crops, a fraction of a crop's size, in [0, 1)."""
    refine_contexts: tuple[float, ...] = (1.5, 2.5)
    """Sides of the refinement windows, in units of the long side of the hand's keypoint box."""
    agreement: float = 0.1
    """Estimates of one hand agree when their keypoints are this close on average, a fraction of
    the hand's box diagonal."""
    refine_side_px: int = 512
    """Long side, pixels, that each refinement window is resized to."""
    mirror: bool = True
    """Refine on the mirrored window too; average the keypoints and the side's votes."""
    duplicate_iou: float = 0.5
    """Hands whose keypoint boxes overlap more than this (IoU) are one hand."""

    def __post_init__(self) -> None:
        if not 0.0 < self.min_detection_confidence < 1.0:
            raise ValueError("min_detection_confidence must be in (0, 1), got "
                             f"{self.min_detection_confidence}")
        if self.model_complexity not in (0, 1):
            raise ValueError(f"model_complexity must be 0 or 1, got {self.model_complexity}")
        for name in ("window_side_px", "refine_side_px"):
            if getattr(self, name) < 64:
                raise ValueError(f"{name} must be at least 64 pixels, got {getattr(self, name)}")
        if not self.zoom_out >= 1.0:
            raise ValueError(f"zoom_out must be >= 1, got {self.zoom_out}")
        if any(int(n) < 1 for n in self.grids):
            raise ValueError(f"grids must be positive integers, got {self.grids}")
        if not 0.0 <= self.grid_overlap < 1.0:
            raise ValueError(f"grid_overlap must be in [0, 1), got {self.grid_overlap}")
        if any(not context >= 1.0 for context in self.refine_contexts):
            raise ValueError(f"refine_contexts must be >= 1, got {self.refine_contexts}")
        if not self.agreement > 0.0:
            raise ValueError(f"agreement must be positive, got {self.agreement}")
        if not 0.0 < self.duplicate_iou <= 1.0:
            raise ValueError(f"duplicate_iou must be in (0, 1], got {self.duplicate_iou}")


@dataclass(frozen=True)
class DetectedHand:
    """One hand found in a photo."""

    keypoints: np.ndarray
    """[21, 2] float64 pixels of the searched image (continuous coordinates: pixel (u, v)
    covers [u, u + 1) x [v, v + 1)), in :data:`lisa_hand.skeleton.KEYPOINT_NAMES` order. A hand
    cut by the photo's edge may have keypoints outside the image (MediaPipe extrapolates)."""
    score: float
    """Confidence in :attr:`side`, in [0.5, 1]: MediaPipe's handedness score averaged over the
    agreeing estimates (plain and mirrored windows)."""
    side: str
    """"right" or "left": the true side of the hand in a non-mirrored photo."""
    box: tuple[float, float, float, float]
    """(x0, y0, x1, y1) pixels: the keypoints' bounding box."""
    found_by: str = ""
    """The search level that found it: "whole image" (as it is or zoomed out), "2x2 crops",
    "3x3 crops", "4x4 crops"; in a greyscale photo found only once tinted, followed by ", greyscale
    photo tinted skin-coloured, side unknown" (its :attr:`score` then 0.5)."""
    side_votes: tuple[int, int] = (0, 0)
    """(right, left): how many of the agreeing estimates (plain and mirrored windows) call it
    each side; a split vote means MediaPipe's side changed with the window or the mirroring."""

    @property
    def side_split(self) -> bool:
        """Some agreeing estimates call it the other side."""
        return min(self.side_votes) > 0


@dataclass
class _Found:
    """One MediaPipe detection mapped to image pixels."""

    keypoints: np.ndarray  # [21, 2] image pixels
    p_right: float  # probability that it is a right hand (true side)
    votes: tuple[int, int] = (0, 0)  # (right, left) of the estimates averaged into it

    @property
    def box(self) -> tuple[float, float, float, float]:
        low, high = self.keypoints.min(axis=0), self.keypoints.max(axis=0)
        return float(low[0]), float(low[1]), float(high[0]), float(high[1])


def _as_uint8(image: np.ndarray) -> np.ndarray:
    """[H, W, 3] float in [0, 1] (or uint8) -> contiguous uint8 RGB."""
    if not isinstance(image, np.ndarray):
        raise TypeError(f"image must be a numpy array [H, W, 3], got {type(image).__name__}")
    if image.ndim != 3 or image.shape[2] != 3 or min(image.shape[:2]) < 1:
        raise ValueError(f"image must have shape [H, W, 3], got {list(image.shape)}")
    if image.dtype == np.uint8:
        return np.ascontiguousarray(image)
    if not np.issubdtype(image.dtype, np.floating):
        raise ValueError(f"image must be float in [0, 1] or uint8, got {image.dtype}")
    return np.ascontiguousarray(np.clip(np.nan_to_num(image) * 255.0 + 0.5, 0, 255)
                                .astype(np.uint8))


def _render(image: np.ndarray, window: Window, long_side: int, fill: np.ndarray) -> np.ndarray:
    """The window of ``image`` [H, W, 3] uint8 (padded with ``fill`` past the borders), resized
    so that its long side is ``long_side`` pixels -> [h, w, 3] uint8 covering the window.

    Pillow's bicubic filter widens with the reduction, so downscaling low-passes (no aliasing)."""
    from PIL import Image

    x0, y0, x1, y1 = window
    height, width = image.shape[:2]
    if (x0, y0, x1, y1) == (0, 0, width, height):
        crop = image
    else:
        crop = np.empty((y1 - y0, x1 - x0, 3), np.uint8)
        crop[:] = fill
        ix0, iy0, ix1, iy1 = max(x0, 0), max(y0, 0), min(x1, width), min(y1, height)
        if ix0 < ix1 and iy0 < iy1:
            crop[iy0 - y0:iy1 - y0, ix0 - x0:ix1 - x0] = image[iy0:iy1, ix0:ix1]
    factor = long_side / max(crop.shape[:2])
    if factor == 1.0:
        return np.ascontiguousarray(crop)
    size = (max(1, round(crop.shape[1] * factor)), max(1, round(crop.shape[0] * factor)))
    return np.asarray(Image.fromarray(crop).resize(size, Image.Resampling.BICUBIC,
                                                   reducing_gap=3.0))


def _run(hands: Any, image: np.ndarray, window: Window, long_side: int, fill: np.ndarray,
         mirrored: bool = False) -> list[_Found]:
    """MediaPipe on one window -> the hands it finds, in image pixels."""
    rendered = _render(image, window, long_side, fill)
    if mirrored:
        rendered = np.ascontiguousarray(rendered[:, ::-1])
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # protobuf deprecation warnings inside mediapipe
        result = hands.process(rendered)
    if not result.multi_hand_landmarks:
        return []
    x0, y0, x1, y1 = window
    found = []
    for landmarks, handedness in zip(result.multi_hand_landmarks, result.multi_handedness,
                                     strict=True):
        normalised = np.array([[point.x, point.y] for point in landmarks.landmark], np.float64)
        if normalised.shape != (NUM_KEYPOINTS, 2) or not np.isfinite(normalised).all():
            continue
        if mirrored:
            normalised[:, 0] = 1.0 - normalised[:, 0]
        keypoints = np.stack([x0 + normalised[:, 0] * (x1 - x0),
                              y0 + normalised[:, 1] * (y1 - y0)], axis=-1)
        label = handedness.classification[0]
        # MediaPipe's label is mirrored; on a mirrored input it is the photo's own side.
        says_right = (label.label == "Right") if mirrored else (label.label == "Left")
        score = float(label.score)
        found.append(_Found(keypoints, score if says_right else 1.0 - score))
    return found


def _iou(a: Sequence[float], b: Sequence[float]) -> float:
    inter_w = max(0.0, min(a[2], b[2]) - max(a[0], b[0]))
    inter_h = max(0.0, min(a[3], b[3]) - max(a[1], b[1]))
    inter = inter_w * inter_h
    union = (a[2] - a[0]) * (a[3] - a[1]) + (b[2] - b[0]) * (b[3] - b[1]) - inter
    return inter / union if union > 0 else 0.0


def _contained(inner: Sequence[float], outer: Sequence[float]) -> float:
    """Fraction of ``inner``'s area inside ``outer``."""
    inter_w = max(0.0, min(inner[2], outer[2]) - max(inner[0], outer[0]))
    inter_h = max(0.0, min(inner[3], outer[3]) - max(inner[1], outer[1]))
    area = (inner[2] - inner[0]) * (inner[3] - inner[1])
    return inter_w * inter_h / area if area > 0 else 1.0


def _levels(width: int, height: int, config: DetectConfig) -> list[tuple[str, list[Window]]]:
    """The search levels, coarse to fine: (name, windows)."""
    pad_x = round(width * (config.zoom_out - 1.0) / 2.0)
    pad_y = round(height * (config.zoom_out - 1.0) / 2.0)
    whole: list[Window] = [(0, 0, width, height)]
    if pad_x > 0 or pad_y > 0:
        whole.append((-pad_x, -pad_y, width + pad_x, height + pad_y))
    levels = [(_WHOLE, whole)]
    for n in config.grids:
        n = int(n)
        if n == 1:
            continue
        fraction = 1.0 / (n - (n - 1) * config.grid_overlap)
        crop_w, crop_h = max(1, round(width * fraction)), max(1, round(height * fraction))
        starts_x = np.linspace(0, width - crop_w, n).round().astype(int)
        starts_y = np.linspace(0, height - crop_h, n).round().astype(int)
        windows = [(int(x), int(y), int(x) + crop_w, int(y) + crop_h)
                   for y in starts_y for x in starts_x]
        levels.append((f"{n}x{n} crops", windows))
    return levels


def _merge(candidates: list[_Found], overlap: float) -> list[_Found]:
    """Largest first; drop a candidate mostly inside (or overlapping) one already kept."""
    kept: list[_Found] = []
    for candidate in sorted(candidates, key=lambda c: -_area(c.box)):
        box = candidate.box
        if all(_iou(box, k.box) <= overlap and _contained(box, k.box) <= 0.6 for k in kept):
            kept.append(candidate)
    return kept


def _area(box: Sequence[float]) -> float:
    return max(0.0, box[2] - box[0]) * max(0.0, box[3] - box[1])


def _refine(hands: Any, image: np.ndarray, candidate: _Found, fill: np.ndarray,
            config: DetectConfig) -> tuple[_Found, int]:
    """Detect ``candidate`` again in square windows around it (each also mirrored) and keep the
    estimates that agree with their medoid -> (their mean, how many agree, the candidate's own
    estimate included)."""
    x0, y0, x1, y1 = candidate.box
    cx, cy = 0.5 * (x0 + x1), 0.5 * (y0 + y1)
    estimates = [candidate]
    for context in config.refine_contexts:
        side = max(8.0, context * max(x1 - x0, y1 - y0))
        left, top = math.floor(cx - side / 2), math.floor(cy - side / 2)
        window = (left, top, left + math.ceil(side), top + math.ceil(side))
        for mirrored in ((False, True) if config.mirror else (False,)):
            found = _run(hands, image, window, config.refine_side_px, fill, mirrored=mirrored)
            # The candidate may be a partial view (a hand cut by a crop's edge): inside the match.
            matches = [f for f in found if _iou(f.box, candidate.box) > 0.3
                       or _contained(candidate.box, f.box) > 0.7]
            if matches:
                estimates.append(max(matches, key=lambda f: _iou(f.box, candidate.box)))
    return _consensus(estimates, config.agreement)


def _consensus(estimates: list[_Found], agreement: float) -> tuple[_Found, int]:
    """The mean of the estimates within ``agreement`` (mean keypoint distance over the hand's
    box diagonal) of their medoid, and how many they are."""
    if len(estimates) == 1:
        one = estimates[0]
        return _Found(one.keypoints, one.p_right, (1, 0) if one.p_right >= 0.5 else (0, 1)), 1
    size = max(1.0, float(np.median([math.hypot(e.box[2] - e.box[0], e.box[3] - e.box[1])
                                     for e in estimates])))
    keypoints = np.stack([e.keypoints for e in estimates])  # [E, 21, 2]
    distance = np.linalg.norm(keypoints[:, None] - keypoints[None], axis=-1).mean(-1) / size
    medoid = int(np.argmin(distance.sum(axis=1)))
    agree = np.flatnonzero(distance[medoid] <= agreement)
    p_right = float(np.mean([estimates[i].p_right for i in agree]))
    right = int(sum(estimates[i].p_right >= 0.5 for i in agree))
    return _Found(keypoints[agree].mean(axis=0), p_right, (right, int(agree.size) - right)), \
        int(agree.size)


_SKIN_TINT = (1.0, 0.78, 0.66)
"""RGB gains that give a greyscale photo a skin's colour before a second search."""
_TINTED = "greyscale photo tinted skin-coloured, side unknown"
_GREY_TOLERANCE = 2  # uint8 levels: channels this close everywhere make a greyscale photo
_MIN_TINTED_SIZE = 0.05
"""A hand found only tinted must span this share of the photo's long side (its keypoints' box):
a tinted texture such as grass can hold a small false "hand"."""


def _greyscale(pixels: np.ndarray) -> bool:
    """Whether the uint8 RGB image [H, W, 3] has (nearly) equal channels everywhere."""
    wide = pixels.astype(np.int16)
    return bool(np.abs(wide - wide[..., :1]).max() <= _GREY_TOLERANCE)


def _search(hands: Any, pixels: np.ndarray, config: DetectConfig) -> list[tuple[_Found, str]]:
    """The coarse-to-fine search (the module docstring) with MediaPipe's ``hands`` -> the hands
    of the first level that finds any, each with that level's name."""
    height, width = pixels.shape[:2]
    border = np.concatenate([pixels[0], pixels[-1], pixels[:, 0], pixels[:, -1]])
    fill = np.median(border, axis=0).astype(np.uint8)
    hands_found: list[tuple[_Found, str]] = []
    for level, windows in _levels(width, height, config):
        candidates = [found for window in windows
                      for found in _run(hands, pixels, window, config.window_side_px, fill)]
        for candidate in _merge(candidates, config.duplicate_iou):
            refined, support = _refine(hands, pixels, candidate, fill, config)
            if support < 2 and level != _WHOLE:
                continue  # seen in one crop only, not found again with more context
            hands_found.append((refined, level))
        if hands_found:
            break
    return hands_found


def detect_hands(image: np.ndarray, max_hands: int = 4, config: DetectConfig | None = None,
                 hands_factory: Callable[..., Any] | None = None) -> list[DetectedHand]:
    """Find the hands in a photo (see the module docstring for the search).

    image: [H, W, 3] float32 RGB in [0, 1] (a :class:`lisa_hand.data.photo.Photo`'s image; uint8
    is accepted too); max_hands: at most this many hands (the largest keypoint boxes);
    hands_factory: what builds the detector, called with MediaPipe's ``Hands`` keyword arguments
    and used as a context manager whose ``process(rgb)`` returns MediaPipe's results (default:
    ``mediapipe.solutions.hands.Hands``).
    -> the hands, de-duplicated, sorted left to right by their box centres; [] when none.
    Needs the photo extra (ImportError with :data:`PHOTO_EXTRA_HINT` otherwise).
    """
    config = config or DetectConfig()
    if isinstance(max_hands, bool) or not isinstance(max_hands, int) or max_hands < 1:
        raise ValueError(f"max_hands must be a positive integer, got {max_hands!r}")
    pixels = _as_uint8(image)
    if hands_factory is None:
        try:
            hands_factory = _mediapipe_hands().Hands
        except (ImportError, AttributeError):
            raise ImportError(PHOTO_EXTRA_HINT) from None
    # The start-up lines come from MediaPipe's threads while the graph starts: hold them back
    # for the whole search.
    with native_stderr_captured(), hands_factory(
            static_image_mode=True, max_num_hands=max_hands,
            model_complexity=config.model_complexity,
            min_detection_confidence=config.min_detection_confidence) as hands:
        hands_found = _search(hands, pixels, config)
        if not hands_found and _greyscale(pixels):  # no skin colour to go by: lend it one
            tinted = np.round(pixels * np.asarray(_SKIN_TINT)).astype(np.uint8)
            smallest = _MIN_TINTED_SIZE * max(pixels.shape[:2])
            hands_found = [(replace(found, p_right=0.5, votes=(0, 0)),
                            f"{level}, {_TINTED}")
                           for found, level in _search(hands, tinted, config)
                           if max(found.box[2] - found.box[0], found.box[3] - found.box[1])
                           >= smallest]
    unique: list[tuple[_Found, str]] = []
    for found, level in sorted(hands_found, key=lambda pair: -abs(pair[0].p_right - 0.5)):
        if all(_iou(found.box, other.box) <= config.duplicate_iou for other, _ in unique):
            unique.append((found, level))
    unique = sorted(unique, key=lambda pair: -_area(pair[0].box))[:max_hands]
    result = [DetectedHand(keypoints=found.keypoints, score=max(found.p_right, 1 - found.p_right),
                           side="right" if found.p_right >= 0.5 else "left", box=found.box,
                           found_by=level, side_votes=found.votes) for found, level in unique]
    return sorted(result, key=lambda hand: 0.5 * (hand.box[0] + hand.box[2]))


class VideoHandDetector:
    """Hands in the frames of a clip, one frame after the other, with MediaPipe's tracking mode
    (``static_image_mode=False``): the palm detector runs only until a hand is found, then each
    hand is followed by the landmark model on a crop around its previous keypoints (about 25 ms
    a 720p frame on one core, where the photo search of :func:`detect_hands` takes up to a
    second). It finds a hand again when it is lost. Frames must come in order.

    Use as a context manager: ``with VideoHandDetector(max_hands=2) as detector:
    detector(frame_rgb)`` -> the frame's :class:`DetectedHand` list (``found_by`` "video",
    ``side_votes`` (1, 0) or (0, 1)), left to right. hands_factory: as :func:`detect_hands`.
    """

    def __init__(self, max_hands: int = 2, min_detection_confidence: float = 0.5,
                 min_tracking_confidence: float = 0.5, model_complexity: int = 1,
                 hands_factory: Callable[..., Any] | None = None) -> None:
        if isinstance(max_hands, bool) or not isinstance(max_hands, int) or max_hands < 1:
            raise ValueError(f"max_hands must be a positive integer, got {max_hands!r}")
        for name, value in (("min_detection_confidence", min_detection_confidence),
                            ("min_tracking_confidence", min_tracking_confidence)):
            if not 0.0 < value < 1.0:
                raise ValueError(f"{name} must be in (0, 1), got {value}")
        if hands_factory is None:
            try:
                hands_factory = _mediapipe_hands().Hands
            except (ImportError, AttributeError):
                raise ImportError(PHOTO_EXTRA_HINT) from None
        self._arguments = dict(static_image_mode=False, max_num_hands=max_hands,
                               model_complexity=model_complexity,
                               min_detection_confidence=min_detection_confidence,
                               min_tracking_confidence=min_tracking_confidence)
        self._factory = hands_factory
        self._hands: Any = None
        self._context: Any = None
        self._quiet_frames = 2

    def __enter__(self) -> VideoHandDetector:
        with native_stderr_captured():
            self._context = self._factory(**self._arguments)
            self._hands = self._context.__enter__()
            # MediaPipe's threads log their start-up while the graph first runs: run it once on
            # a blank frame here, so that those lines are held back too.
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                self._hands.process(np.zeros((64, 64, 3), np.uint8))
        return self

    def __exit__(self, *exc: Any) -> None:
        context, self._context, self._hands = self._context, None, None
        if context is not None:
            context.__exit__(*exc)

    def __call__(self, frame: np.ndarray) -> list[DetectedHand]:
        """frame: [H, W, 3] uint8 RGB (or float in [0, 1]) -> the hands found in it."""
        if self._hands is None:
            raise RuntimeError("VideoHandDetector is used inside a 'with' block")
        pixels = _as_uint8(frame)
        height, width = pixels.shape[:2]
        window = (0, 0, width, height)
        if self._quiet_frames > 0:  # the landmark model starts with the first hand found
            with native_stderr_captured():
                found = _run(self._hands, pixels, window, max(height, width),
                             np.zeros(3, np.uint8))
            self._quiet_frames -= bool(found)
        else:
            found = _run(self._hands, pixels, window, max(height, width), np.zeros(3, np.uint8))
        hands = [DetectedHand(keypoints=one.keypoints, score=max(one.p_right, 1 - one.p_right),
                              side="right" if one.p_right >= 0.5 else "left", box=one.box,
                              found_by="video",
                              side_votes=(1, 0) if one.p_right >= 0.5 else (0, 1))
                 for one in found]
        return sorted(hands, key=lambda hand: 0.5 * (hand.box[0] + hand.box[2]))
