"""A hand mask for a photo: :func:`coarse_mask` from the 21 keypoints before the fit,
:func:`refine_mask` with the fitted hand's silhouette after it.
Several hands of one photo: :func:`split_masks` gives each pixel to one of them.

Both work in a crop around the hand, downscaled to at most :data:`GRABCUT_MAX_SIDE` pixels
(GrabCut's cost grows with the pixels; the mask is scaled back up), and measure every distance
in units of the hand's size in the image (:func:`hand_scale_px`: about the wrist-to-middle-knuckle
length, the least foreshortened of four palm measures), so that they behave alike on a 300 px
and a 4000 px photo.

With OpenCV (``cv2``, the ``[photo]`` extra), :func:`coarse_mask` runs GrabCut
(``cv2.grabCut``, :data:`GRABCUT_ITERATIONS` iterations) seeded by the keypoint skeleton:

* sure foreground: the bones drawn :data:`SURE_BONE_WIDTH` hand sizes wide and the palm polygon
  (:data:`PALM_KEYPOINTS`) shrunk towards its centre;
* probable foreground: the bones :data:`PROBABLE_BONE_WIDTH` wide and the convex hull of the
  keypoints grown by :data:`HULL_GROW`;
* probable background: up to :data:`BACKGROUND_DISTANCE` beyond that hull;
* sure background: everything further, and the forearm side of the wrist (more than
  :data:`WRIST_CUT` hand sizes beyond the wrist along the middle finger's axis: the hand model
  ends at the wrist, and the forearm has the hand's colour).

Of GrabCut's foreground, the connected pieces that touch the sure foreground are kept and their
holes filled.

Without OpenCV (CI installs no ``cv2``: ``--keypoints`` must work there too), the mask comes from
the keypoints alone (:func:`keypoint_mask`): the bones :data:`FALLBACK_BONE_WIDTH` hand sizes
wide (about a finger's width) with round joints, and the palm polygon filled. It is the right
size and shape for a hand of average build in that pose, not the hand's true outline.

:func:`refine_mask` reruns GrabCut seeded by the fitted hand's silhouette (sure foreground: the
silhouette where the coarse mask agrees, shrunk; probable foreground: their union; probable
background: a band of :data:`REFINE_BAND` around it; sure background beyond), so the result
follows the photo's edges near the fitted hand and cannot grow far from it. Without OpenCV it is
the silhouette plus the coarse mask's pixels within :data:`REFINE_FALLBACK_BAND` of it.
"""

from __future__ import annotations

import math

import numpy as np

from ...skeleton import NUM_KEYPOINTS

__all__ = [
    "HAND_BONES",
    "PALM_KEYPOINTS",
    "GRABCUT_MAX_SIDE",
    "grabcut_available",
    "mask_method",
    "hand_scale_px",
    "crop_box",
    "resize_array",
    "keypoint_mask",
    "coarse_mask",
    "refine_mask",
    "split_masks",
]

HAND_BONES = tuple((0 if index % 4 == 1 else index - 1, index)
                   for index in range(1, NUM_KEYPOINTS))
"""The 20 bones of the 21-keypoint skeleton as (parent, child) keypoint indices (OpenPose
order: the wrist to each finger's first keypoint, then along the finger)."""
PALM_KEYPOINTS = (0, 1, 2, 5, 9, 13, 17)
"""The palm polygon: wrist, thumb CMC and MCP (the web between thumb and index is skin in
every pose) and the four knuckles (MCP)."""

GRABCUT_MAX_SIDE = 320
"""GrabCut runs on the crop around the hand downscaled to at most this many pixels a side."""
GRABCUT_ITERATIONS = 5
"""Iterations of ``cv2.grabCut``."""
SURE_BONE_WIDTH = 0.07
"""Width of the bones of the sure foreground, hand sizes (:func:`hand_scale_px`)."""
PROBABLE_BONE_WIDTH = 0.3
"""Width of the bones of the probable foreground, hand sizes."""
HULL_GROW = 0.12
"""The keypoints' convex hull grown by this many hand sizes is probable foreground."""
BACKGROUND_DISTANCE = 0.6
"""Probable background up to this many hand sizes beyond the grown hull; sure background
further out."""
WRIST_CUT = 0.3
"""Pixels more than this many hand sizes beyond the wrist (away from the middle knuckle) are
sure background: the forearm."""
FALLBACK_BONE_WIDTH = 0.22
"""Without OpenCV: width of the bones of :func:`keypoint_mask`, hand sizes (a finger is about
0.18-0.2 of the wrist-to-knuckle length wide)."""
REFINE_BAND = 0.12
""":func:`refine_mask`: probable background up to this many hand sizes beyond the union of the
coarse mask and the silhouette; sure background further."""
REFINE_FALLBACK_BAND = 0.04
""":func:`refine_mask` without OpenCV: the coarse mask's pixels within this many hand sizes of
the silhouette are kept."""
_CROP_MARGIN = 0.8  # hand sizes of context around the keypoints for GrabCut
# Palm measures (keypoint pairs) and their length relative to the wrist-middle MCP one (the mesh
# template's mean hand: 0.99, 0.95, 0.68).
_PALM_MEASURES = (((0, 9), 1.0), ((0, 5), 1.0), ((0, 17), 0.9), ((5, 17), 0.65))


def grabcut_available() -> bool:
    """Whether OpenCV (``cv2``, from the ``[photo]`` extra) imports."""
    try:
        import cv2  # noqa: F401
    except ImportError:
        return False
    return True


def mask_method() -> str:
    """How :func:`coarse_mask` makes masks here: ``"grabcut"`` (OpenCV imports) or
    ``"keypoints"`` (:func:`keypoint_mask`)."""
    return "grabcut" if grabcut_available() else "keypoints"


def _check_inputs(image: np.ndarray, keypoints: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    image = np.asarray(image)
    if image.ndim != 3 or image.shape[2] != 3:
        raise ValueError(f"image must be [H, W, 3], got {list(image.shape)}")
    keypoints = np.asarray(keypoints, dtype=np.float64)
    if keypoints.shape != (NUM_KEYPOINTS, 2) or not np.isfinite(keypoints).all():
        raise ValueError(f"keypoints must be finite [21, 2] pixels, got "
                         f"{list(keypoints.shape)}")
    return image, keypoints


def hand_scale_px(keypoints: np.ndarray) -> float:
    """The hand's size in the image, pixels: the largest of four palm measures (wrist to the
    index, middle and little knuckles, index to little knuckle), each divided by its typical
    ratio to the wrist-to-middle-knuckle length (the least foreshortened one wins); at least
    a quarter of the keypoints' box diagonal and 1 pixel.

    keypoints: [21, 2] pixels (OpenPose order) -> pixels.
    """
    keypoints = np.asarray(keypoints, dtype=np.float64)
    measures = [np.linalg.norm(keypoints[a] - keypoints[b]) / ratio
                for (a, b), ratio in _PALM_MEASURES]
    diagonal = float(np.linalg.norm(keypoints.max(0) - keypoints.min(0)))
    return max(max(measures), 0.25 * diagonal, 1.0)


def _draw(shape: tuple[int, int], keypoints: np.ndarray, bone_width: float,
          palm_shrink: float | None, hull_grow: float | None = None) -> np.ndarray:
    """[H, W] bool: the bones ``bone_width`` pixels wide with round joints, the palm polygon
    (scaled by ``palm_shrink`` about its centre; None: left out) and the keypoints' convex hull
    grown by ``hull_grow`` pixels (None: left out)."""
    from PIL import Image, ImageDraw

    height, width = shape
    canvas = Image.new("L", (width, height), 0)
    draw = ImageDraw.Draw(canvas)
    points = [tuple(map(float, point)) for point in keypoints]
    if hull_grow is not None:
        hull = _convex_hull(keypoints)
        draw.polygon([tuple(map(float, point)) for point in hull], fill=255)
        _draw_round_lines(draw, [(tuple(hull[i]), tuple(hull[(i + 1) % len(hull)]))
                                 for i in range(len(hull))], 2.0 * hull_grow)
    if palm_shrink is not None:
        palm = keypoints[list(PALM_KEYPOINTS)]
        centre = palm.mean(0)
        palm = centre + palm_shrink * (palm - centre)
        draw.polygon([tuple(map(float, point)) for point in palm], fill=255)
    _draw_round_lines(draw, [(points[a], points[b]) for a, b in HAND_BONES], bone_width)
    return np.asarray(canvas) > 0


def _draw_round_lines(draw, segments, line_width: float) -> None:
    """Segments ``line_width`` pixels wide with round caps (filled discs at the ends)."""
    radius = max(line_width / 2.0, 0.5)
    for start, end in segments:
        draw.line([start, end], fill=255, width=max(int(round(line_width)), 1))
        for x, y in (start, end):
            draw.ellipse([x - radius, y - radius, x + radius, y + radius], fill=255)


def _convex_hull(points: np.ndarray) -> np.ndarray:
    """[M, 2] the convex hull of [N, 2] points, in order (monotone chain; the points themselves
    when they are collinear)."""
    ordered = sorted({(float(x), float(y)) for x, y in points})
    if len(ordered) < 3:
        return np.asarray(ordered)

    def half(sequence):
        chain: list[tuple[float, float]] = []
        for point in sequence:
            while len(chain) >= 2 and ((chain[-1][0] - chain[-2][0]) * (point[1] - chain[-2][1])
                                       - (chain[-1][1] - chain[-2][1])
                                       * (point[0] - chain[-2][0])) <= 0:
                chain.pop()
            chain.append(point)
        return chain[:-1]

    return np.asarray(half(ordered) + half(ordered[::-1]))


def keypoint_mask(shape: tuple[int, int], keypoints: np.ndarray) -> np.ndarray:
    """The mask from the keypoints alone (no photo): the bones :data:`FALLBACK_BONE_WIDTH` hand
    sizes wide with round joints, and the palm polygon.

    shape: (H, W) pixels. keypoints: [21, 2] pixels. -> [H, W] bool.
    """
    keypoints = np.asarray(keypoints, dtype=np.float64)
    scale = hand_scale_px(keypoints)
    return _draw(tuple(shape), keypoints, FALLBACK_BONE_WIDTH * scale, palm_shrink=1.0)


def crop_box(shape: tuple[int, int], points: np.ndarray, margin: float
             ) -> tuple[int, int, int, int]:
    """(x0, y0, x1, y1) integer pixels: the box of ``points`` grown by ``margin`` pixels,
    clipped to the image."""
    height, width = shape
    low = np.floor(points.min(0) - margin).astype(int)
    high = np.ceil(points.max(0) + margin).astype(int)
    x0, y0 = max(int(low[0]), 0), max(int(low[1]), 0)
    x1, y1 = min(int(high[0]), width), min(int(high[1]), height)
    return x0, y0, max(x1, x0 + 1), max(y1, y0 + 1)


def resize_array(array: np.ndarray, size: tuple[int, int], nearest: bool = False) -> np.ndarray:
    """Resize a [h, w] bool mask (bilinear then > 0.5, or nearest) or a [h, w(, 3)] uint8
    image to ``size`` = (width, height) pixels."""
    from PIL import Image

    if array.dtype == bool:
        resized = Image.fromarray(array.astype(np.uint8) * 255).resize(
            size, Image.NEAREST if nearest else Image.BILINEAR)
        return np.asarray(resized) >= 128
    return np.asarray(Image.fromarray(array).resize(
        size, Image.NEAREST if nearest else Image.BILINEAR))


def _to_uint8(image: np.ndarray) -> np.ndarray:
    image = np.asarray(image)
    if image.dtype == np.uint8:
        return np.ascontiguousarray(image)
    return (np.clip(image, 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8)


def _keep_seeded(mask: np.ndarray, seeds: np.ndarray) -> np.ndarray:
    """The connected pieces of ``mask`` that touch ``seeds``, holes filled, united with the
    seeds."""
    from scipy import ndimage

    labels, count = ndimage.label(mask)
    if count:
        touched = np.unique(labels[seeds & mask])
        mask = np.isin(labels, touched[touched > 0])
    return ndimage.binary_fill_holes(mask | seeds)


def _grabcut(image: np.ndarray, labels: np.ndarray) -> np.ndarray | None:
    """GrabCut on a uint8 RGB image with an initial label map (cv2.GC_* values) -> [h, w] bool
    foreground, or None when the labels lack foreground or background pixels. GrabCut's
    k-means draws from OpenCV's global generator: it is seeded first, so the same photo gives
    the same mask in any call of any process."""
    import cv2

    is_fg = (labels == cv2.GC_FGD) | (labels == cv2.GC_PR_FGD)
    if is_fg.sum() < 16 or (~is_fg).sum() < 16:
        return None
    work = labels.astype(np.uint8).copy()
    background_model = np.zeros((1, 65), np.float64)
    foreground_model = np.zeros((1, 65), np.float64)
    cv2.setRNGSeed(0)
    try:
        cv2.grabCut(image, work, None, background_model, foreground_model,
                    GRABCUT_ITERATIONS, cv2.GC_INIT_WITH_MASK)
    except cv2.error:
        return None
    return (work == cv2.GC_FGD) | (work == cv2.GC_PR_FGD)


def _cropped(shape: tuple[int, int], box: tuple[int, int, int, int]) -> tuple[float, tuple]:
    """(the factor that scales the crop ``box`` to at most GRABCUT_MAX_SIDE a side, and the
    scaled size (w, h))."""
    x0, y0, x1, y1 = box
    factor = min(1.0, GRABCUT_MAX_SIDE / max(x1 - x0, y1 - y0))
    return factor, (max(int(round((x1 - x0) * factor)), 1),
                    max(int(round((y1 - y0) * factor)), 1))


def _wrist_side(shape: tuple[int, int], keypoints: np.ndarray, scale: float) -> np.ndarray:
    """[h, w] bool: pixels more than WRIST_CUT hand sizes beyond the wrist, away from the
    middle knuckle (none when the palm is seen end on: its 2D direction is unreliable)."""
    height, width = shape
    axis = keypoints[0] - keypoints[9]
    length = float(np.linalg.norm(axis))
    if length < 0.5 * scale:
        return np.zeros(shape, dtype=bool)
    axis = axis / length
    columns, rows = np.meshgrid(np.arange(width) + 0.5, np.arange(height) + 0.5)
    along = (columns - keypoints[0, 0]) * axis[0] + (rows - keypoints[0, 1]) * axis[1]
    return along > WRIST_CUT * scale


def coarse_mask(image: np.ndarray, keypoints: np.ndarray, *,
                use_grabcut: bool | None = None) -> np.ndarray:
    """The hand's mask before the fit (see the module docstring).

    image: [H, W, 3] float RGB in [0, 1] (or uint8). keypoints: [21, 2] pixels in that image,
    OpenPose order (continuous coordinates, :mod:`lisa_hand.geometry.cameras`).
    use_grabcut: None: GrabCut when OpenCV imports (:func:`grabcut_available`), else
    :func:`keypoint_mask`; True / False forces one (True without OpenCV: ImportError).
    -> [H, W] bool, foreground True. Deterministic.
    """
    image, keypoints = _check_inputs(image, keypoints)
    shape = image.shape[:2]
    if use_grabcut is None:
        use_grabcut = grabcut_available()
    if not use_grabcut:
        return keypoint_mask(shape, keypoints)
    import cv2

    scale = hand_scale_px(keypoints)
    box = crop_box(shape, keypoints, (_CROP_MARGIN + HULL_GROW) * scale)
    x0, y0, x1, y1 = box
    factor, size = _cropped(shape, box)
    local = (keypoints - [x0, y0]) * factor
    small_scale = scale * factor
    small_shape = (size[1], size[0])
    labels = np.full(small_shape, cv2.GC_BGD, np.uint8)
    labels[_draw(small_shape, local, 2.0 * BACKGROUND_DISTANCE * small_scale, None,
                 hull_grow=(HULL_GROW + BACKGROUND_DISTANCE) * small_scale)] = cv2.GC_PR_BGD
    labels[_wrist_side(small_shape, local, small_scale)] = cv2.GC_BGD
    labels[_draw(small_shape, local, PROBABLE_BONE_WIDTH * small_scale, 1.0,
                 hull_grow=HULL_GROW * small_scale)] = cv2.GC_PR_FGD
    sure = _draw(small_shape, local, max(SURE_BONE_WIDTH * small_scale, 1.0), 0.6)
    labels[sure] = cv2.GC_FGD
    crop = resize_array(_to_uint8(image[y0:y1, x0:x1]), size)
    found = _grabcut(crop, labels)
    if found is None:
        return keypoint_mask(shape, keypoints)
    found = _keep_seeded(found, sure)
    mask = np.zeros(shape, dtype=bool)
    mask[y0:y1, x0:x1] = resize_array(found, (x1 - x0, y1 - y0))
    return mask


def _disc(radius: float) -> np.ndarray:
    radius = max(int(math.ceil(radius)), 1)
    offsets = np.arange(-radius, radius + 1)
    return (offsets[:, None] ** 2 + offsets[None, :] ** 2) <= radius * radius


def refine_mask(image: np.ndarray, coarse: np.ndarray, silhouette: np.ndarray, *,
                use_grabcut: bool | None = None) -> np.ndarray:
    """The mask after the fit: the coarse mask refined with the fitted hand's silhouette (see
    the module docstring).

    image: [H, W, 3] float RGB in [0, 1] (or uint8). coarse: [H, W] bool (:func:`coarse_mask`
    or a given ``--mask``). silhouette: [H, W] bool, the fitted hand rendered into the photo's
    camera. use_grabcut: as :func:`coarse_mask`. -> [H, W] bool. An empty silhouette (the fit
    left the image) gives the coarse mask back.
    """
    from scipy import ndimage

    image = np.asarray(image)
    coarse = np.asarray(coarse, dtype=bool)
    silhouette = np.asarray(silhouette, dtype=bool)
    if image.ndim != 3 or coarse.shape != image.shape[:2] or silhouette.shape != coarse.shape:
        raise ValueError(f"image [H, W, 3], coarse [H, W] and silhouette [H, W] must agree, got "
                         f"{list(image.shape)}, {list(coarse.shape)}, {list(silhouette.shape)}")
    if not silhouette.any():
        return coarse.copy()
    union = coarse | silhouette
    scale = math.sqrt(float(union.sum()))  # about the wrist-to-knuckle length for a hand
    if use_grabcut is None:
        use_grabcut = grabcut_available()
    if not use_grabcut:
        near = ndimage.binary_dilation(silhouette, _disc(REFINE_FALLBACK_BAND * scale))
        return silhouette | (coarse & near)
    import cv2

    rows, columns = np.nonzero(union)
    points = np.stack([columns, rows], axis=1).astype(np.float64)
    box = crop_box(coarse.shape, points, 2.0 * REFINE_BAND * scale + 2.0)
    x0, y0, x1, y1 = box
    factor, size = _cropped(coarse.shape, box)
    small_union = resize_array(union[y0:y1, x0:x1], size)
    small_sure = resize_array(coarse[y0:y1, x0:x1] & silhouette[y0:y1, x0:x1], size)
    small_sure = ndimage.binary_erosion(small_sure, _disc(0.03 * scale * factor))
    band = ndimage.binary_dilation(small_union, _disc(REFINE_BAND * scale * factor))
    labels = np.full(small_union.shape, cv2.GC_BGD, np.uint8)
    labels[band] = cv2.GC_PR_BGD
    labels[small_union] = cv2.GC_PR_FGD
    labels[small_sure] = cv2.GC_FGD
    crop = resize_array(_to_uint8(image[y0:y1, x0:x1]), size)
    found = _grabcut(crop, labels)
    if found is None or not small_sure.any():
        return union if found is None else _paste(coarse.shape, box, found)
    return _paste(coarse.shape, box, _keep_seeded(found, small_sure))


def _paste(shape: tuple[int, int], box: tuple[int, int, int, int],
           small: np.ndarray) -> np.ndarray:
    """A crop's mask (downscaled) put back at full size into an empty [H, W] mask."""
    x0, y0, x1, y1 = box
    mask = np.zeros(shape, dtype=bool)
    mask[y0:y1, x0:x1] = resize_array(small, (x1 - x0, y1 - y0))
    return mask


def _bone_distance(pixels: np.ndarray, keypoints: np.ndarray) -> np.ndarray:
    """[M] the distance, pixels, of pixel centres [M, 2] to the nearest bone of a hand's
    keypoint skeleton [21, 2] (segments :data:`HAND_BONES`)."""
    start = keypoints[[a for a, _ in HAND_BONES]]  # [20, 2]
    along = keypoints[[b for _, b in HAND_BONES]] - start
    length = np.maximum((along ** 2).sum(-1), 1e-9)
    offset = pixels[:, None] - start[None]  # [M, 20, 2]
    t = np.clip((offset * along[None]).sum(-1) / length[None], 0.0, 1.0)
    return np.linalg.norm(offset - t[..., None] * along[None], axis=-1).min(axis=1)


def split_masks(masks: list[np.ndarray], keypoints: list[np.ndarray]) -> list[np.ndarray]:
    """Several hands' masks of one photo made exclusive: a pixel claimed by several goes to
    the hand whose keypoint skeleton is nearest (in units of each hand's size,
    :func:`hand_scale_px`, so that a large hand does not take a small one's pixels).

    masks: K [H, W] bool. keypoints: K [21, 2] pixels. -> K [H, W] bool, no pixel in two."""
    if len(masks) != len(keypoints):
        raise ValueError(f"{len(masks)} masks for {len(keypoints)} hands")
    if len(masks) < 2:
        return [np.asarray(mask, bool).copy() for mask in masks]
    stack = np.stack([np.asarray(mask, bool) for mask in masks])  # [K, H, W]
    shared = stack.sum(0) > 1
    rows, columns = np.nonzero(shared)
    out = stack.copy()
    if rows.size:
        pixels = np.stack([columns + 0.5, rows + 0.5], axis=-1)
        distance = np.stack([
            _bone_distance(pixels, np.asarray(points, np.float64)) / hand_scale_px(points)
            for points in keypoints])  # [K, M]
        distance[~stack[:, rows, columns]] = np.inf
        owner = distance.argmin(axis=0)
        out[:, rows, columns] = False
        out[owner, rows, columns] = True
    return list(out)
