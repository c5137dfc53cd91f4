"""The artist-made WebXR hand's rig (:mod:`lisa_hand.data.webxr_hand`, ``tests/assets/
webxr_hand``, MIT, Amazon): posed by its own skeleton in the poses the point-fit tests and
benchmarks use, the surface a scanner sees of it, and the hand in other proportions (checked on a
small synthetic rig in the OpenXR joint order against the closed form of the map)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from lisa_hand.data.webxr_hand import (
    WEBXR_POSES,
    outer_surface,
    pose_webxr_hand,
    reshape_webxr_rig,
    webxr_side,
)
from lisa_hand.fitting.points.io import read_point_cloud
from tests.assets import WEBXR_HAND as WEBXR


def _joints_mm() -> dict[str, np.ndarray]:
    """The WebXR bind-pose joints by OpenXR name, millimetres."""
    with np.load(WEBXR / "right_hand.npz", allow_pickle=False) as data:
        return {str(name): joint.astype(np.float64)
                for name, joint in zip(data["joint_names"], data["joints"], strict=True)}


def test_poses_of_the_webxr_rig():
    obj_points, _ = read_point_cloud(WEBXR / "right_hand.obj")
    rest, faces = pose_webxr_hand(WEBXR / "right_hand.npz", "rest")
    np.testing.assert_allclose(rest, obj_points * 1e-3, atol=1e-6)  # the OBJ is the bind pose
    assert faces.shape == (2314, 3)
    joints = _joints_mm()
    wrist = joints["wrist"] * 1e-3
    tip = joints["index-finger-tip"] * 1e-3
    # The vertex nearest the index tip moves towards the wrist when the finger bends.
    nearest = int(np.argmin(np.linalg.norm(rest - tip, axis=1)))
    for pose in WEBXR_POSES:
        posed, same_faces = pose_webxr_hand(WEBXR / "right_hand.npz", pose)
        assert posed.shape == rest.shape and np.array_equal(same_faces, faces)
        reach = np.linalg.norm(posed[nearest] - wrist)
        if pose == "rest":
            assert reach == pytest.approx(np.linalg.norm(rest[nearest] - wrist))
        else:
            assert reach < 0.8 * np.linalg.norm(rest[nearest] - wrist), pose
    with pytest.raises(ValueError, match="unknown WebXR pose"):
        pose_webxr_hand(WEBXR / "right_hand.npz", "wave")


def test_the_fingers_curl_in_their_own_plane():
    """The four fingers of the bent and fist poses curl as hinges in the plane of their rest
    direction and the knuckle plane's normal: their fingertips stay in that plane (measured
    0.05-0.84 mm off), and the bent index's distal phalanx turns 0.9 + 1.2 + 0.7 rad in all.
    Fingers turned about axes of the thumb's plane, 45 degrees off, would leave it by 21-43 mm."""
    joints = {name: value * 1e-3 for name, value in _joints_mm().items()}
    wrist = joints["wrist"]
    normal = np.cross(joints["index-finger-phalanx-proximal"] - wrist,
                      joints["pinky-finger-phalanx-proximal"] - wrist)
    normal /= np.linalg.norm(normal)
    with np.load(WEBXR / "right_hand.npz", allow_pickle=False) as data:
        rest_vertices, weights = data["vertices"] * 1e-3, data["weights"]
        names = [str(n) for n in data["joint_names"]]
    for pose, curled in (("bent_index", ("index",)),
                         ("fist", ("index", "middle", "ring", "pinky"))):
        posed, _ = pose_webxr_hand(WEBXR / "right_hand.npz", pose)
        for finger in curled:
            base = joints[f"{finger}-finger-phalanx-proximal"]
            # The plane of the finger's rest direction and the palm normal through its knuckle.
            direction = joints[f"{finger}-finger-tip"] - base
            plane = np.cross(direction, normal)
            plane /= np.linalg.norm(plane)
            # Vertices of the fingertip (skinned to its distal phalanx): their mean's
            # offset from the plane, before and after posing, differs by under 2 mm.
            distal = weights[:, names.index(f"{finger}-finger-phalanx-distal")] > 0.9
            before = (rest_vertices[distal].mean(0) - base) @ plane
            after = (posed[distal].mean(0) - base) @ plane
            assert abs(after - before) < 0.002, (pose, finger, after - before)
    # The bent index: the distal phalanx turned 0.9 + 1.2 + 0.7 rad about one axis.
    posed, _ = pose_webxr_hand(WEBXR / "right_hand.npz", "bent_index")
    distal = weights[:, names.index("index-finger-phalanx-distal")] > 0.9
    before = rest_vertices[distal] - rest_vertices[distal].mean(0)
    after = posed[distal] - posed[distal].mean(0)
    u, _, vt = np.linalg.svd(after.T @ before)  # Kabsch: after = R before
    turn = u @ np.diag([1.0, 1.0, np.linalg.det(u @ vt)]) @ vt
    angle = math.degrees(math.acos((np.trace(turn) - 1.0) / 2.0))
    assert angle == pytest.approx(math.degrees(0.9 + 1.2 + 0.7), abs=1.0)


@pytest.mark.parametrize("hand", ["right", "left"])
def test_the_fist_closes_on_the_palm_side(hand):
    """Either hand's fist closes towards its palm: every fingertip (the vertices skinned to its
    distal phalanx) ends on the side of the knuckle plane where the thumb's proximal joint is
    (the palm's side), 3-5 cm from that plane, not back over the back of the hand."""
    path = WEBXR / f"{hand}_hand.npz"
    assert webxr_side(path) == hand  # what the benchmark fits it as (fit_points(side=))
    with np.load(path, allow_pickle=False) as data:
        weights, names = data["weights"], [str(n) for n in data["joint_names"]]
        joints = {name: joint * 1e-3 for name, joint in zip(names, data["joints"], strict=True)}
    wrist = joints["wrist"]
    normal = np.cross(joints["index-finger-phalanx-proximal"] - wrist,
                      joints["pinky-finger-phalanx-proximal"] - wrist)
    normal /= np.linalg.norm(normal)
    palm_side = np.sign((joints["thumb-phalanx-proximal"] - wrist) @ normal)
    posed, _ = pose_webxr_hand(path, "fist")
    for finger in ("index", "middle", "ring", "pinky"):
        tip = weights[:, names.index(f"{finger}-finger-phalanx-distal")] > 0.9
        depth = palm_side * (posed[tip].mean(0) - wrist) @ normal
        assert 0.01 < depth < 0.06, (hand, finger, depth)


def test_outer_surface_drops_the_faces_inside_the_hand():
    """A box with a smaller box wholly inside it (a fingertip sunk into the palm, in the small):
    the inner box's 12 faces and 8 vertices go, the outer box is kept exactly; a box beside it
    is kept whole. On the WebXR fist 2-3% of the area is inside, none in the rest pose."""
    import trimesh

    big = trimesh.creation.box(extents=(0.1, 0.1, 0.1))
    small = trimesh.creation.box(extents=(0.02, 0.02, 0.02))
    for shift, kept_faces in ((0.0, 12), (0.2, 24)):
        vertices = np.concatenate([big.vertices, small.vertices + [shift, 0.0, 0.0]])
        faces = np.concatenate([big.faces, small.faces + len(big.vertices)])
        outer_vertices, outer_faces = outer_surface(vertices, faces)
        assert len(outer_faces) == kept_faces
        assert len(outer_vertices) == 8 * kept_faces // 12
        np.testing.assert_array_equal(outer_vertices[outer_faces[:12]], big.vertices[big.faces])
    for pose, low, high in (("rest", 0.0, 0.0), ("fist", 0.01, 0.05)):
        posed, faces = pose_webxr_hand(WEBXR / "right_hand.npz", pose)
        kept_vertices, kept = outer_surface(posed, faces)
        area = trimesh.Trimesh(posed, faces, process=False).area
        inside = 1.0 - trimesh.Trimesh(kept_vertices, kept, process=False).area / area
        assert low <= inside <= high + 1e-12, (pose, inside)


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
