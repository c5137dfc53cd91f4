"""21 hand keypoints and the hand's side in a photo, offline, with MediaPipe Hands (the photo
extra: ``pip install -e '.[photo]'``, ``mediapipe==0.10.14``, whose wheel ships
``palm_detection_full.tflite`` and ``hand_landmark_full.tflite``).

MediaPipe's legacy ``solutions.hands`` runs a palm detector on the whole input letterboxed to
192 x 192 pixels, then a landmark model on a crop around each palm. Hands much smaller than about
a tenth of the input's long side are missed, and so can be hands that fill it; a small hand in a
large input is also lost to aliasing (the detector's resize does not low-pass). So
:func:`detect_hands` searches windows of the image, coarse to fine, each resized to a long side
of :attr:`DetectConfig.window_side_px` (Pillow's bicubic, which low-passes when it shrinks), and
stops at the first level that finds a hand: 1. the whole image, as it is and zoomed out (padded
with the median colour of its border, for hands that fill it); 2. 2 x 2 crops overlapping by half
a crop (:attr:`DetectConfig.grid_overlap`); 3. 3 x 3 crops; 4. 4 x 4 crops
(:attr:`DetectConfig.grids`). Rescaled copies of the whole image would show the detector the
same 192 pixels; crops are what make a small hand larger. The whole image is also searched for
at most two hands (:attr:`DetectConfig.pair_detector`).

Every hand found is **refined**: detected again in square windows 1.5 and 2.5 times its keypoint
box (:attr:`DetectConfig.refine_contexts`), resized to :attr:`DetectConfig.refine_side_px`, each
as it is and mirrored. Of these estimates and the first one, those within 10% of the hand's size
(:attr:`DetectConfig.agreement`) of their medoid are averaged, keypoints and side votes alike;
their number is its support. A hand found only in a crop must have a support of 2 or more. A
hand whose keypoint box spans about 5% of the photo's long side or more is found; smaller ones
often are, less reliably on textured backgrounds.

**One hand or two** is decided by the keypoints, not the boxes: hands one behind the other,
clasped or crossed have overlapping boxes. Two estimates are one hand when their keypoints agree
(:attr:`DetectConfig.same_hand`), when one is a part cut by a crop's edge (its keypoints
squeezed into the part) inside the other, or when nearly all of one's keypoints lie inside the
other's outline (:attr:`DetectConfig.same_outline`: MediaPipe's other reading of a hand, partial
or mirrored; a hand wholly inside another's outline is lost). The better supported one is kept.

**More hands.** The palm detector drops a palm next to a stronger one, and a smaller hand may
need crops, so while fewer than ``max_hands`` are found (:attr:`DetectConfig.further_search`)
the search goes on: (a) **beside** each hand, in windows 3 times its size shifted by its size
left, right, up and down, as they are and mirrored, with what its refinement windows showed;
(b) with the hands **painted out** (their keypoints' hull grown by 20% of their size, filled with
the border's colour), whole and zoomed out; both again around the hands they find; (c) if neither
finds one, in the coarsest crop level that shows a hand half the smallest one's size large enough
(:attr:`DetectConfig.further_smallest`), not painted out (a painted patch can make a neck its
best "palm"); (d) with the landmark model alone, without the palm detector, on squares around
each hand (:mod:`.detect_hidden`, :attr:`DetectConfig.hidden_search`): a hand behind another
whose fingers show but whose palm is hidden (interlaced fingers, a hand holding the other's
wrist). With only its thumb and the back of the hand showing a hand is still missed or called
the other side.

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
the base of the palm): on photos of the open hand model's hands it lies about 0.16-0.17 of the
wrist-to-middle-knuckle length nearer the fingers (``python -m benchmarks photo --subjects
train``: ``detector_wrist_shift``), the other 20 landmarks within about a tenth of that length
of the true ones. :func:`to_skeleton_wrist` moves it back
(:attr:`lisa_hand.fitting.photo.config.FitPhotoConfig.detector_wrist_shift`), OFF by default:
the offset belongs to the generator's long, flat-cut palms, not to MediaPipe; on photos of real
hands the moved wrist lies in the forearm, and the fitted hand does not follow it.

**3D landmarks** of each hand: :attr:`DetectedHand.landmarks_3d` (:mod:`.world_landmarks`).

**Time.** One process call takes 15-60 ms on one CPU core, whatever the window's size (the
models' inputs are fixed). A photo whose hand is found in the whole image takes about 0.2 s
without the further search and 0.5-1 s with it (16-32 calls), a photo without a hand (every
window searched) about 0.6 s. Importing MediaPipe takes about 1 s more, once.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Callable, Sequence
from contextlib import nullcontext
from dataclasses import dataclass, replace
from functools import partial
from typing import TYPE_CHECKING, Any

import numpy as np

from ..skeleton import KEYPOINT_NAMES, NUM_KEYPOINTS
from ..utils.stderr import native_stderr_captured
from .world_landmarks import mean_landmarks, world_landmarks

if TYPE_CHECKING:  # at run time through __getattr__: detect_video imports this module
    from .detect_video import VideoHandDetector

__all__ = ["PHOTO_EXTRA_HINT", "photo_extra_missing", "DetectConfig", "DetectedHand",
           "detect_hands", "MEDIAPIPE_LABEL_TO_SIDE", "MEDIAPIPE_WRIST_SHIFT", "MIDDLE_MCP",
           "to_skeleton_wrist", "VideoHandDetector"]

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
    same_hand: float = 0.25
    """Two estimates are one hand when their keypoints are this close on average, a fraction of
    the larger one's box diagonal, whatever their boxes' overlap..."""
    same_outline: float = 0.9
    """...or when this share of one's keypoints lies inside the other's hull (grown by 5%)."""
    duplicate_iou: float = 0.5
    """A part cut by a crop's edge is one with a hand whose box overlaps it more than this."""
    further_search: bool = True
    """Once hands are found, look for more while fewer than ``max_hands`` are (module docstring)."""
    hidden_search: bool = True
    """Last of the further search: the landmark model alone around each hand found, for hands
    whose palm is hidden (:mod:`lisa_hand.data.detect_hidden`)..."""
    hidden_context: float = 2.0
    """...on squares this many times a found hand's keypoint box."""
    beside_context: float = 3.0
    """Side of the windows beside a found hand, in units of its keypoint box's long side..."""
    beside_shift: float = 1.0
    """...and how far they are shifted left, right, up and down from it, same units."""
    further_smallest: float = 0.5
    """The crop level searched after another hand finds hands down to this fraction of its size."""
    paint_margin: float = 0.2
    """A hand is painted out as its keypoints' hull grown by this fraction of its box diagonal."""
    pair_detector: bool = True
    """When ``max_hands`` is above 2, the whole photo is also searched by MediaPipe looking for
    at most two hands: looking for four, it returned no hand at all in a zoomed-out window that
    holds two crossed hands, where looking for two it returned both."""

    def __post_init__(self) -> None:
        c = self
        bad = [f"{name} must be {rule}, got {getattr(self, name)!r}" for name, ok, rule in (
            ("min_detection_confidence", 0.0 < c.min_detection_confidence < 1.0, "in (0, 1)"),
            ("model_complexity", c.model_complexity in (0, 1), "0 or 1"),
            ("window_side_px", c.window_side_px >= 64, "at least 64 pixels"),
            ("refine_side_px", c.refine_side_px >= 64, "at least 64 pixels"),
            ("zoom_out", c.zoom_out >= 1.0, ">= 1"),
            ("grids", all(int(n) >= 1 for n in c.grids), "positive integers"),
            ("grid_overlap", 0.0 <= c.grid_overlap < 1.0, "in [0, 1)"),
            ("refine_contexts", all(context >= 1.0 for context in c.refine_contexts), ">= 1"),
            ("agreement", c.agreement > 0.0, "positive"),
            ("same_hand", 0.0 < c.same_hand < 1.0, "in (0, 1)"),
            ("same_outline", 0.0 < c.same_outline <= 1.0, "in (0, 1]"),
            ("duplicate_iou", 0.0 < c.duplicate_iou <= 1.0, "in (0, 1]"),
            ("beside_context", c.beside_context >= 1.0, ">= 1"),
            ("hidden_context", c.hidden_context >= 1.0, ">= 1"),
            ("beside_shift", c.beside_shift >= 0.0, ">= 0"),
            ("further_smallest", c.further_smallest > 0.0, "positive"),
            ("paint_margin", c.paint_margin >= 0.0, ">= 0")) if not ok]
        if bad:
            raise ValueError(bad[0])


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
    "3x3 crops", "4x4 crops"; after another hand: "beside another hand", "another hand painted
    out", "3x3 crops after another hand", "the landmark model alone beside another hand (palm
    hidden)" (...); in a greyscale photo found only once tinted,
    followed by ", greyscale photo tinted skin-coloured, side unknown" (:attr:`score` 0.5)."""
    side_votes: tuple[int, int] = (0, 0)
    """(right, left): how many of the agreeing estimates (plain and mirrored windows) call it
    each side; a split vote means MediaPipe's side changed with the window or the mirroring."""
    landmarks_3d: np.ndarray | None = None
    """[21, 3] float64 metres or None: MediaPipe's world landmarks in the camera's axes
    (:mod:`lisa_hand.data.world_landmarks`), the mean of the agreeing estimates."""

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
    cut: bool = False  # its box reaches a crop's edge inside the image: maybe a partial view
    support: int = 1  # how many estimates agree on it (refined: :func:`_consensus`)
    landmarks: np.ndarray | None = None  # [21, 3] metres, MediaPipe's world landmarks

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
        crop = np.full((y1 - y0, x1 - x0, 3), fill, np.uint8)
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
    marks = result.multi_hand_landmarks
    world = getattr(result, "multi_hand_world_landmarks", None) or [None] * len(marks)
    for landmarks, handedness, shape in zip(marks, result.multi_handedness, world, strict=True):
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
        score = float(label.score) if says_right else 1.0 - float(label.score)
        found.append(_Found(keypoints, score, cut=_cut(keypoints, window, *image.shape[1::-1]),
                            landmarks=world_landmarks(shape, mirrored)))
    return found


Named = tuple[_Found, str]  # a hand and what found it


def _cut(keypoints: np.ndarray, window: Window, width: int, height: int) -> bool:
    """Whether the keypoints reach (within 2%) an edge of the window inside the image: a crop's."""
    x0, y0, x1, y1 = window
    margin = 0.02 * max(x1 - x0, y1 - y0)
    low, high = keypoints.min(axis=0), keypoints.max(axis=0)
    return bool((x0 > 0 and low[0] <= x0 + margin) or (y0 > 0 and low[1] <= y0 + margin)
                or (x1 < width and high[0] >= x1 - margin)
                or (y1 < height and high[1] >= y1 - margin))


def _iou(a: Sequence[float], b: Sequence[float]) -> float:
    inter = _area((max(a[0], b[0]), max(a[1], b[1]), min(a[2], b[2]), min(a[3], b[3])))
    union = _area(a) + _area(b) - inter
    return inter / union if union > 0 else 0.0


def _contained(inner: Sequence[float], outer: Sequence[float]) -> float:
    """Fraction of ``inner``'s area inside ``outer``."""
    inter = _area((max(inner[0], outer[0]), max(inner[1], outer[1]), min(inner[2], outer[2]),
                   min(inner[3], outer[3])))
    return inter / _area(inner) if _area(inner) > 0 else 1.0


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


def _merge(candidates: list[_Found], config: DetectConfig) -> list[_Found]:
    """Largest first; drop a candidate that is the same hand as one already kept."""
    kept: list[_Found] = []
    for candidate in sorted(candidates, key=lambda c: -_area(c.box)):
        if not any(_same_hand(candidate, k, config) for k in kept):
            kept.append(candidate)
    return kept


def _same_hand(a: _Found, b: _Found, config: DetectConfig) -> bool:
    """Whether two estimates are one hand (the module docstring, "One hand or two")."""
    size = max(1.0, _diagonal(a.box), _diagonal(b.box))
    if (_distance(a, b) < config.same_hand * size
            or max(_inside(a, b), _inside(b, a)) >= config.same_outline):
        return True
    return any(part.cut and (_contained(part.box, whole.box) > 0.6
                             or _iou(part.box, whole.box) > config.duplicate_iou)
               for part, whole in ((a, b), (b, a)))


def _inside(a: _Found, b: _Found) -> float:
    """The share of ``a``'s keypoints inside ``b``'s convex hull grown by 5% of its diagonal."""
    from scipy.spatial import ConvexHull, QhullError

    try:
        planes = ConvexHull(b.keypoints).equations  # [F, 3]: unit outward normal, offset
    except (QhullError, ValueError):  # degenerate: the keypoints on a line
        return 0.0
    grown = 0.05 * _diagonal(b.box)
    return float(np.mean((a.keypoints @ planes[:, :2].T + planes[:, 2] <= grown).all(axis=1)))


def _distance(a: _Found, b: _Found) -> float:
    """Mean distance between the keypoints of two estimates, pixels."""
    return float(np.linalg.norm(a.keypoints - b.keypoints, axis=1).mean())


def _area(box: Sequence[float]) -> float:
    return max(0.0, box[2] - box[0]) * max(0.0, box[3] - box[1])


def _diagonal(box: Sequence[float]) -> float:
    return math.hypot(box[2] - box[0], box[3] - box[1])


def _square(cx: float, cy: float, side: float) -> Window:
    """The square window of ``side`` pixels centred on (cx, cy)."""
    left, top = math.floor(cx - side / 2), math.floor(cy - side / 2)
    return left, top, left + math.ceil(side), top + math.ceil(side)


def _refine(hands: Any, image: np.ndarray, candidate: _Found, fill: np.ndarray,
            config: DetectConfig) -> tuple[_Found, list[_Found]]:
    """Detect ``candidate`` again in square windows around it (each also mirrored) and keep the
    estimates that agree with their medoid -> (their mean, its ``support`` how many agree, the
    candidate's own estimate included; the other hands the windows showed)."""
    x0, y0, x1, y1 = candidate.box
    cx, cy = 0.5 * (x0 + x1), 0.5 * (y0 + y1)
    estimates, others = [candidate], []
    for context in config.refine_contexts:
        window = _square(cx, cy, max(8.0, context * max(x1 - x0, y1 - y0)))
        for mirrored in ((False, True) if config.mirror else (False,)):
            found = _run(hands, image, window, config.refine_side_px, fill, mirrored=mirrored)
            # The candidate may be a part cut by a crop's edge; a hand overlapping it is another.
            matches = [f for f in found if _same_hand(candidate, f, config)]
            if matches:
                estimates.append(min(matches, key=lambda f: _distance(f, candidate)))
            others += [f for f in found if not any(f is match for match in matches)]
    return _consensus(estimates, config.agreement)[0], others


def _consensus(estimates: list[_Found], agreement: float) -> tuple[_Found, int]:
    """The mean of the estimates within ``agreement`` (mean keypoint distance over the hand's
    box diagonal) of their medoid, and how many they are."""
    if len(estimates) == 1:
        one = estimates[0]
        return _Found(one.keypoints, one.p_right, (1, 0) if one.p_right >= 0.5 else (0, 1),
                      landmarks=one.landmarks), 1
    size = max(1.0, float(np.median([math.hypot(e.box[2] - e.box[0], e.box[3] - e.box[1])
                                     for e in estimates])))
    keypoints = np.stack([e.keypoints for e in estimates])  # [E, 21, 2]
    distance = np.linalg.norm(keypoints[:, None] - keypoints[None], axis=-1).mean(-1) / size
    medoid = int(np.argmin(distance.sum(axis=1)))
    agree = np.flatnonzero(distance[medoid] <= agreement)
    p_right = float(np.mean([estimates[i].p_right for i in agree]))
    right = int(sum(estimates[i].p_right >= 0.5 for i in agree))
    return _Found(keypoints[agree].mean(axis=0), p_right, (right, int(agree.size) - right),
                  support=int(agree.size),
                  landmarks=mean_landmarks([estimates[i].landmarks for i in agree])),\
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


def _search(hands: Any, pixels: np.ndarray, config: DetectConfig, max_hands: int,
            pair: Any = None, landmark: Any = None) -> list[Named]:
    """The coarse-to-fine search with MediaPipe's ``hands`` -> the hands of the first level that
    finds any, with that level's name, and those the further search finds after them. ``pair``
    (MediaPipe looking for at most two hands, or None) searches the whole photo too;
    ``landmark`` (the landmark model alone, or None) looks for hands whose palm is hidden."""
    height, width = pixels.shape[:2]
    border = np.concatenate([pixels[0], pixels[-1], pixels[:, 0], pixels[:, -1]])
    fill = np.median(border, axis=0).astype(np.uint8)
    levels = _levels(width, height, config)
    for index, (level, windows) in enumerate(levels):
        extra = [] if pair is None or level != _WHOLE else [
            found for window in windows
            for found in _run(pair, pixels, window, config.window_side_px, fill)]
        found, around = _find(hands, pixels, windows, config.window_side_px, fill, config, [],
                              confirm=level != _WHOLE, extra=extra)
        if found:
            further = []
            if config.further_search and len(found) < max_hands:
                from .detect_further import search_further

                further = search_further(hands, pixels, found, around, levels, index, fill,
                                         config, max_hands, landmark)
            return [(hand, level) for hand in found] + further
    return []


def _find(hands: Any, pixels: np.ndarray, windows: list[Window], long_side: int,
          fill: np.ndarray, config: DetectConfig, known: list[_Found], confirm: bool,
          mirror: bool = False, extra: Sequence[_Found] = ()) -> tuple[list[_Found], list[_Found]]:
    """MediaPipe on the windows (each also mirrored with ``mirror``), and the ``extra``
    candidates -> (the hands other than the ``known`` ones, merged, refined, best supported first,
    with ``confirm`` only those of support >= 2; the other hands the refinement windows showed)."""
    flips = (False, True) if mirror else (False,)
    candidates = list(extra) + [found for window in windows for flip in flips
                                for found in _run(hands, pixels, window, long_side, fill, flip)]
    refined, around = [], []
    for candidate in _merge(candidates, config):
        if not any(_same_hand(candidate, hand, config) for hand in known if hand.support > 1):
            hand, others = _refine(hands, pixels, candidate, fill, config)
            refined.append(hand)
            around += others
    new: list[_Found] = []
    for hand in sorted(refined, key=lambda hand: (-hand.support, -_area(hand.box))):
        # A better-supported estimate of a known hand is kept too: it replaces it (_unique).
        if (hand.support >= 2 or not confirm) and not any(
                _same_hand(hand, other, config) and other.support >= hand.support
                for other in known + new):
            new.append(hand)
    return new, around


def _unique(hands_found: list[Named], config: DetectConfig) -> list[Named]:
    """Most often found again first, then most confident side; drop those the same as one kept."""
    unique: list[Named] = []
    for found, level in sorted(hands_found, key=lambda p: (-p[0].support, -abs(p[0].p_right - .5))):
        if not any(_same_hand(found, other, config) for other, _ in unique):
            unique.append((found, level))
    return unique


def detect_hands(image: np.ndarray, max_hands: int = 4, config: DetectConfig | None = None,
                 hands_factory: Callable[..., Any] | None = None,
                 landmark_factory: Callable[[], Any] | None = None) -> list[DetectedHand]:
    """Find the hands in a photo (see the module docstring for the search).

    image: [H, W, 3] float32 RGB in [0, 1] (a :class:`lisa_hand.data.photo.Photo`'s image; uint8
    is accepted too); max_hands: at most this many hands (the largest keypoint boxes);
    hands_factory: what builds the detector, called with MediaPipe's ``Hands`` keyword arguments
    and used as a context manager whose ``process(rgb)`` returns MediaPipe's results (default:
    ``mediapipe.solutions.hands.Hands``); landmark_factory: what builds the landmark model
    alone (:attr:`DetectConfig.hidden_search`; a context manager with ``read(pixels, square)``;
    default: :class:`lisa_hand.data.detect_hidden.LandmarkModel` with MediaPipe's detector,
    none with another ``hands_factory``).
    -> the hands, de-duplicated, sorted left to right by their box centres; [] when none.
    Needs the photo extra (ImportError with :data:`PHOTO_EXTRA_HINT` otherwise).
    """
    config = config or DetectConfig()
    if isinstance(max_hands, bool) or not isinstance(max_hands, int) or max_hands < 1:
        raise ValueError(f"max_hands must be a positive integer, got {max_hands!r}")
    pixels = _as_uint8(image)
    default_factory = hands_factory is None
    if hands_factory is None:
        try:
            hands_factory = _mediapipe_hands().Hands
        except (ImportError, AttributeError):
            raise ImportError(PHOTO_EXTRA_HINT) from None
    # The start-up lines come from MediaPipe's threads while the graph starts: hold them back
    # for the whole search.
    options = dict(static_image_mode=True, model_complexity=config.model_complexity,
                   min_detection_confidence=config.min_detection_confidence)
    if not config.hidden_search:
        landmark_factory = None
    elif landmark_factory is None and default_factory:
        from .detect_hidden import LandmarkModel

        landmark_factory = partial(LandmarkModel, config.model_complexity)
    two = config.pair_detector and max_hands > 2
    with native_stderr_captured(), hands_factory(max_num_hands=max_hands, **options) as hands, \
            (hands_factory(max_num_hands=2, **options) if two else nullcontext()) as pair, \
            (landmark_factory() if landmark_factory else nullcontext()) as landmark:
        hands_found = _search(hands, pixels, config, max_hands, pair, landmark)
        if not hands_found and _greyscale(pixels):  # no skin colour to go by: lend it one
            tinted = np.round(pixels * np.asarray(_SKIN_TINT)).astype(np.uint8)
            smallest = _MIN_TINTED_SIZE * max(pixels.shape[:2])
            hands_found = [(replace(found, p_right=0.5, votes=(0, 0)), f"{level}, {_TINTED}")
                           for found, level in _search(hands, tinted, config, max_hands,
                                                       pair, landmark)
                           if max(found.box[2] - found.box[0], found.box[3] - found.box[1])
                           >= smallest]
    unique = sorted(_unique(hands_found, config), key=lambda p: -_area(p[0].box))[:max_hands]
    result = [DetectedHand(keypoints=found.keypoints, score=max(found.p_right, 1 - found.p_right),
                           side="right" if found.p_right >= 0.5 else "left", box=found.box,
                           found_by=level, side_votes=found.votes, landmarks_3d=found.landmarks)
              for found, level in unique]
    return sorted(result, key=lambda hand: 0.5 * (hand.box[0] + hand.box[2]))


def __getattr__(name: str) -> Any:
    """:class:`~lisa_hand.data.detect_video.VideoHandDetector`, imported on first use (PEP 562)."""
    if name != "VideoHandDetector":
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    from .detect_video import VideoHandDetector

    return VideoHandDetector
