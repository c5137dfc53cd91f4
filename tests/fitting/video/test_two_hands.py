"""Two hands through one clip: the real clip beside its mirror image (a right hand on the left,
the same hand as a left hand on the right) fitted by :func:`lisa_hand.fitting.video.fit_video`.
The mirror image is an independent reference: the left hand's fit must be the right hand's
mirrored (up to what the detector sees differently in a mirrored picture)."""

from __future__ import annotations

import numpy as np
import pytest

from lisa_hand.data.detect import photo_extra_missing
from tests.assets import ASSETS

cv2 = pytest.importorskip("cv2")
pytestmark = pytest.mark.skipif(photo_extra_missing() is not None,
                                reason="needs the photo extra (MediaPipe)")

CLIP = ASSETS / "videos" / "hand_landmarker_test_video.mp4"


@pytest.fixture(scope="module")
def two_hands(tmp_path_factory):
    from lisa_hand.fitting.video import FitVideoConfig, fit_video
    from lisa_hand.utils.threads import cpu_threads

    path = tmp_path_factory.mktemp("clip") / "two_hands.avi"
    capture = cv2.VideoCapture(str(CLIP))
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), 25, (1280, 360))
    for index in range(160):
        ok, frame = capture.read()
        assert ok
        if index >= 150:  # 10 frames of the open hand
            writer.write(np.concatenate([frame, frame[:, ::-1]], axis=1))
    writer.release()
    with cpu_threads(1):
        return fit_video(path, progress=False, log=None, device="cpu",
                         config=FitVideoConfig(num_threads=1))


def test_both_hands_are_followed_with_their_sides(two_hands):
    assert [hand.side for hand in two_hands.hands] == ["right", "left"]
    for hand in two_hands.hands:
        assert hand.track.detected.all()
        assert np.isfinite(hand.motion.keypoints_3d).all()


def test_the_left_hand_is_the_right_one_mirrored(two_hands):
    right, left = two_hands.hands
    K = two_hands.camera.K.double().numpy()
    width = 1280
    assert K[0, 2] == pytest.approx(width / 2)  # the mirror of the picture is x -> -x
    mirrored_2d = left.keypoints_2d.copy()
    mirrored_2d[..., 0] = width - mirrored_2d[..., 0]
    gap_px = np.linalg.norm(mirrored_2d - right.keypoints_2d, axis=-1).mean()
    assert gap_px < 5.0  # measured 2.8 px: the detector sees a mirrored picture a little apart
    mirrored_3d = left.motion.keypoints_3d * np.array([-1.0, 1.0, 1.0])
    relative = (mirrored_3d - mirrored_3d[:, :1]) - (right.motion.keypoints_3d
                                                    - right.motion.keypoints_3d[:, :1])
    assert np.linalg.norm(relative, axis=-1).mean() < 0.008  # metres (measured 3.1 mm)


def test_where_the_hands_are_from_each_other(two_hands):
    """The left hand is the right one mirrored through the picture's middle (x -> -x): its
    wrist is the right wrist's mirror, so right-to-left is (-2 x, 0, 0) of the right wrist, to
    what the detector sees differently in a mirrored picture (measured: x within 0.6 mm, y 2.3
    mm, depth 5.2 mm); hands this far apart do not meet."""
    right, _ = two_hands.hands
    contact = two_hands.contact
    wrist = right.motion.keypoints_3d[:, 0]  # [N, 3] metres
    offset = contact.right_to_left_m
    assert offset.shape == (10, 3) and np.isfinite(offset).all()
    assert (offset[:, 0] > 0.1).all()  # the left hand on the right of the picture
    np.testing.assert_allclose(offset[:, 0], -2.0 * wrist[:, 0], atol=0.005)
    assert np.abs(offset[:, 1:]).max() < 0.015
    np.testing.assert_array_equal(contact.penetration_mm, np.zeros(10))
    assert contact.deepest_mm == 0.0


def test_a_hand_inside_another_is_measured(two_hands):
    """The right hand and a copy of it 5 mm to the side: one inside the other in every frame
    (measured 6.0-6.1 mm deep); 20 cm to the side, apart."""
    from dataclasses import replace

    from lisa_hand.fitting.video.contact import clip_contact

    right, _ = two_hands.hands

    def moved(shift_m: float):
        motion = replace(right.motion, translation=right.motion.translation
                         + np.array([shift_m, 0.0, 0.0]),
                         keypoints_3d=right.motion.keypoints_3d + np.array([shift_m, 0.0, 0.0]))
        return replace(right, motion=motion)

    near = clip_contact(two_hands.model, [right, moved(0.005)])
    assert (near.penetration_mm > 4.0).all() and (near.penetration_mm < 9.0).all(), \
        near.penetration_mm
    assert np.isnan(near.right_to_left_m).all()  # two right hands: no right-to-left
    far = clip_contact(two_hands.model, [right, moved(0.2)])
    np.testing.assert_array_equal(far.penetration_mm, np.zeros(10))


def test_hands_json(two_hands):
    import json

    from lisa_hand.fitting.video.artefacts import hands_record

    record = json.loads(json.dumps(hands_record(two_hands)))  # plain JSON
    assert record["hands"] == [{"identity": 0, "side": "right", "folder": "hand0"},
                               {"identity": 1, "side": "left", "folder": "hand1"}]
    assert record["frame"] == "camera" and record["penetration_mm"] == 0.0
    frames = record["frames"]
    assert [frame["index"] for frame in frames] == two_hands.indices.tolist()
    np.testing.assert_allclose([frame["right_to_left_m"] for frame in frames],
                               two_hands.contact.right_to_left_m, atol=1e-6)
    assert all(frame["penetration_mm"] == 0.0 for frame in frames)
