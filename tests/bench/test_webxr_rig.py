"""The WebXR hand in other proportions (``reshape_webxr_rig``): checked on a small synthetic rig
in the OpenXR joint order, so that it runs without the shared data, against the closed form of
the map (a scale across the palm and through it, a stretch beyond the knuckle line)."""

from __future__ import annotations

import numpy as np
import pytest

from lisa_hand.bench._webxr import _check_webxr_args, reshape_webxr_rig

FINGERS = ("index-finger", "middle-finger", "ring-finger", "pinky-finger")


def _rig() -> tuple[np.ndarray, list[str]]:
    """[25, 3] metres and the OpenXR names: a right hand with the wrist at the origin, fingers
    along +y, the palm facing +z (the thumb's proximal joint in front of the palm)."""
    names = ["wrist", "thumb-metacarpal", "thumb-phalanx-proximal", "thumb-phalanx-distal",
             "thumb-tip"]
    joints = [[0, 0, 0], [0.02, 0.02, 0.01], [0.04, 0.045, 0.02], [0.05, 0.07, 0.02],
              [0.055, 0.09, 0.02]]
    for number, finger in enumerate(FINGERS):
        x = 0.017 - number * 0.017  # the middle finger on the y axis
        names += [f"{finger}-metacarpal"] + [f"{finger}-phalanx-{part}" for part in
                                             ("proximal", "intermediate", "distal")]
        names.append(f"{finger}-tip")
        knuckle = 0.095 - 0.005 * abs(number - 1)
        joints += [[x / 3, 0.02, 0], [x, knuckle, 0], [x, knuckle + 0.045, 0],
                   [x, knuckle + 0.07, 0], [x, knuckle + 0.09, 0]]
    return np.asarray(joints, dtype=np.float64), names


def test_the_identity_leaves_the_hand_as_it_is():
    joints, names = _rig()
    points = np.random.default_rng(0).normal(0.0, 0.05, (50, 3))
    vertices, moved = reshape_webxr_rig(points, joints, names, (1.0, 1.0, 1.0))
    np.testing.assert_allclose(vertices, points, atol=1e-12)
    np.testing.assert_allclose(moved, joints, atol=1e-12)


def test_breadth_thickness_and_finger_length_follow_the_closed_form():
    joints, names = _rig()
    knuckle_line = np.mean([joints[names.index(f"{f}-phalanx-proximal"), 1] for f in FINGERS])
    points = np.array([[0.03, 0.05, 0.01],     # on the palm, before the knuckle line
                       [-0.02, 0.17, -0.004]])  # on a finger, beyond it
    vertices, moved = reshape_webxr_rig(points, joints, names, (1.1, 1.2, 0.9))
    # The frame here is x across the palm, y along the fingers, z through the palm; the palm's
    # normal points to the thumb's side (+z) and across = normal x along = (-1, 0, 0): only the
    # sign of x's axis flips, which a scale does not see.
    expected = points * [1.1, 1.0, 1.2]
    expected[1, 1] = knuckle_line + 0.9 * (points[1, 1] - knuckle_line)
    np.testing.assert_allclose(vertices, expected, atol=1e-12)
    np.testing.assert_allclose(moved[0], joints[0], atol=1e-12)  # the wrist stays
    tip, proximal = (names.index(f"middle-finger-{part}") for part in ("tip", "phalanx-proximal"))
    assert moved[tip, 1] - moved[proximal, 1] == pytest.approx(
        0.9 * (joints[tip, 1] - joints[proximal, 1]), abs=1e-12)
    spread = (names.index("index-finger-phalanx-proximal"),
              names.index("pinky-finger-phalanx-proximal"))
    assert np.ptp(moved[list(spread), 0]) == pytest.approx(1.1 * np.ptp(joints[list(spread), 0]))


def test_proportions_out_of_range_are_refused():
    with pytest.raises(ValueError, match="proportions must be three factors"):
        _check_webxr_args("none", ("as-is",), 1.0, (1.1, 1.0))
    with pytest.raises(ValueError, match="proportions must be three factors"):
        _check_webxr_args("none", ("as-is",), 1.0, (1.1, 1.0, 2.0))
    _check_webxr_args("none", ("as-is",), 1.0, (0.9, 1.0, 1.1))
