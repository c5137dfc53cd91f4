"""MediaPipe's world landmarks (lisa_hand.data.world_landmarks) through the photo detector: the
fake MediaPipe of test_detect gives each marker a 3D shape in its input's own axes."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np

from lisa_hand.data.detect import detect_hands
from lisa_hand.data.world_landmarks import mean_landmarks, world_landmarks

from .mediapipe_fake import canvas, fake, marker, world_shape


def test_world_landmarks_in_the_photo_axes_from_plain_and_mirrored_windows():
    """The detector's 3D landmarks come back in the photo's own axes whether a window was
    mirrored or not (x negated back), averaged over the agreeing estimates; a mirrored photo
    gives them mirrored."""
    image = canvas()
    marker(image, 300, 200, 200, 150, thumb="left")
    (hand,) = detect_hands(image, hands_factory=fake())
    np.testing.assert_allclose(hand.landmarks_3d, world_shape(), atol=1e-12)
    (mirrored,) = detect_hands(image[:, ::-1], hands_factory=fake())
    np.testing.assert_allclose(mirrored.landmarks_3d, world_shape(-1.0), atol=1e-12)


def test_world_landmarks_read_mirrored_and_averaged():
    shape = SimpleNamespace(landmark=[SimpleNamespace(x=x, y=y, z=z) for x, y, z in
                                      world_shape()])
    np.testing.assert_array_equal(world_landmarks(shape, mirrored=True), world_shape(-1.0))
    assert world_landmarks(None, False) is None
    assert world_landmarks(SimpleNamespace(landmark=shape.landmark[:20]), False) is None
    np.testing.assert_allclose(mean_landmarks([world_shape(), None, world_shape(-1.0)]),
                               world_shape(0.0))
    assert mean_landmarks([None, None]) is None
