"""A stand-in for MediaPipe Hands for the detection tests: "hands" are magenta rectangles with
a green patch on the thumb side (:class:`FakeHands`), painted by :func:`marker` on a
:func:`canvas`."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
from scipy import ndimage

MAGENTA, GREEN, GREY = (1.0, 0.0, 1.0), (0.0, 1.0, 0.0), (0.45, 0.45, 0.45)

# --- a stand-in for MediaPipe: "hands" are magenta rectangles, a green patch on the thumb side --


class FakeHands:
    """MediaPipe's ``Hands`` interface on marker rectangles (see :func:`marker`).

    A marker is found when its long side is 10-70% of the input's long side (like the palm
    detector, which misses hands that are too small or fill the input). Its 21 landmarks spread
    over its box on a 3 x 7 grid; its label follows MediaPipe's mirrored convention: "Left" when
    the green part is on the left of the marker (a right hand in a plain photo).
    """

    calls: list[dict] = []

    def __init__(self, square_only_fails: bool = False, crowded_fails: bool = False,
                 **kwargs):
        FakeHands.calls.append(kwargs)
        self.max_num_hands = kwargs.get("max_num_hands", 2)
        self.square_only_fails = square_only_fails
        self.crowded_fails = crowded_fails
        self.inputs: list[tuple[int, int]] = []

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        return False

    def process(self, rgb: np.ndarray):
        assert rgb.dtype == np.uint8 and rgb.flags["C_CONTIGUOUS"] and rgb.shape[2] == 3
        height, width = rgb.shape[:2]
        self.inputs.append((width, height))
        red, green, blue = (rgb[..., c].astype(int) for c in range(3))
        magenta = (red > 150) & (green < 110) & (blue > 150)
        greenish = (green > 150) & (red < 110) & (blue < 110)
        labels, count = ndimage.label(magenta)
        landmarks, handedness, world = [], [], []
        grid = np.stack(np.meshgrid(np.linspace(0, 1, 3), np.linspace(0, 1, 7)), -1).reshape(-1, 2)
        for index in range(1, count + 1):
            rows, cols = np.nonzero(labels == index)
            x0, x1, y0, y1 = cols.min(), cols.max() + 1, rows.min(), rows.max() + 1
            if not 0.1 <= max(x1 - x0, y1 - y0) / max(width, height) <= 0.7:
                continue
            if self.square_only_fails and width != height:
                pass  # found in crops (the image's aspect ratio)...
            elif self.square_only_fails:
                continue  # ...never in square refinement windows: a false detection
            green_cols = np.nonzero(greenish[y0:y1, x0:x1])[1] + x0
            label = "Left" if green_cols.size and green_cols.mean() < 0.5 * (x0 + x1) else "Right"
            if green_cols.size and label == "Right":  # from the thumb side, as a mirror shows it
                x0, x1 = x1, x0
            points = [SimpleNamespace(x=(x0 + u * (x1 - x0)) / width,
                                      y=(y0 + v * (y1 - y0)) / height) for u, v in grid]
            landmarks.append(SimpleNamespace(landmark=points))
            sign = 1.0 if x0 < x1 else -1.0  # the input's own x axis, mirrored or not
            world.append(SimpleNamespace(landmark=[
                SimpleNamespace(x=x, y=y, z=z) for x, y, z in world_shape(sign)]))
            handedness.append(SimpleNamespace(
                classification=[SimpleNamespace(label=label, score=0.9)]))
        if self.crowded_fails and self.max_num_hands > 2 and len(landmarks) > 1:
            landmarks, handedness, world = [], [], []  # as MediaPipe did on crossed hands
        # At most max_num_hands, as MediaPipe: the first found (the top of the input).
        landmarks, handedness = landmarks[:self.max_num_hands], handedness[:self.max_num_hands]
        world = world[:self.max_num_hands]
        return SimpleNamespace(multi_hand_landmarks=landmarks or None,
                               multi_handedness=handedness or None,
                               multi_hand_world_landmarks=world or None)


def world_shape(sign: float = 1.0) -> np.ndarray:
    """The fake's world landmarks [21, 3] metres: the 3 x 7 grid of its keypoints, 8 x 18 cm,
    leaning in depth along u; ``sign`` -1: seen in a mirrored input (x negated)."""
    grid = np.stack(np.meshgrid(np.linspace(0, 1, 3), np.linspace(0, 1, 7)), -1).reshape(-1, 2)
    return np.stack([sign * 0.08 * (grid[:, 0] - 0.5), 0.18 * (grid[:, 1] - 0.5),
                     0.03 * grid[:, 0]], -1)


def marker(image: np.ndarray, x0: int, y0: int, width: int, height: int,
           thumb: str = "left") -> None:
    """Paint a marker hand: a magenta rectangle with a green patch inside, near its thumb side
    (left or right), magenta all around it."""
    image[y0:y0 + height, x0:x0 + width] = MAGENTA
    rows = slice(y0 + height // 4, y0 + 3 * height // 4)
    inset, patch = max(2, width // 10), max(2, width // 6)
    if thumb == "left":
        image[rows, x0 + inset:x0 + inset + patch] = GREEN
    else:
        image[rows, x0 + width - inset - patch:x0 + width - inset] = GREEN


def canvas(width: int = 1000, height: int = 800) -> np.ndarray:
    return np.full((height, width, 3), GREY, np.float32)


def fake(**kwargs):
    return lambda **options: FakeHands(**kwargs, **options)
