"""Hand model v3: the MakeHuman kit, its population, the rest mesh and the posed ground truth."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import torch
import trimesh

from lisa_hand.handmodel import OpenHand, named_pose, sample_hand
from lisa_hand.handmodel.anthropometry import sample_measurements
from lisa_hand.handmodel.makehuman import (
    MakeHumanShape,
    fit_hand_size,
    load_kit,
    measure_hand,
    morph,
    sample_makehuman_shape,
)
from lisa_hand.handmodel.mesh_hand import PosedMeshHand
from lisa_hand.handmodel.mesh_rest import build_mesh_rest
from lisa_hand.handmodel.shape import HandShape, rest_skeleton
from lisa_hand.skeleton.tree import FINGER_JOINTS

F64 = torch.float64


def _length_mm(shape: MakeHumanShape) -> float:
    kit = load_kit()
    _, joints = morph(shape)
    return float(np.linalg.norm(joints[kit.joint("finger3-3.R____tail")]
                                - joints[kit.joint("wrist.R____head")]))


@pytest.mark.parametrize(("shape", "length_mm"), [
    (MakeHumanShape(gender=0.0), 167.5),
    (MakeHumanShape(gender=1.0), 203.1),
    (MakeHumanShape(gender=1.0, age=1.0, muscle=1.0, weight=1.0), 174.1),
    (MakeHumanShape(gender=0.0, hand_scale=0.5), 196.1),
])
def test_morphs_reproduce_the_kits_sanity_table(shape, length_mm):
    # The kit's README measured these on MakeHuman's full mesh.
    assert _length_mm(shape) == pytest.approx(length_mm, abs=0.05)


def test_bad_shapes_are_refused():
    with pytest.raises(ValueError, match="gender"):
        MakeHumanShape(gender=1.5)
    with pytest.raises(TypeError, match="hand_scale"):
        MakeHumanShape(hand_scale="big")
    with pytest.raises(TypeError, match="MakeHumanShape"):
        OpenHand(model="v3")  # a v3 hand needs a MakeHuman shape


def test_sizes_are_solved_to_the_drawn_anthropometry():
    shape = fit_hand_size(MakeHumanShape(gender=0.0), 0.180, 0.078)
    vertices, joints = morph(shape)
    measured = measure_hand(vertices, joints)
    assert measured["hand_length"] == pytest.approx(0.180, abs=1e-4)
    assert measured["hand_breadth"] == pytest.approx(0.078, abs=1e-4)
    for seed in range(3):
        drawn = sample_measurements(torch.Generator().manual_seed(seed))
        shape = sample_makehuman_shape(torch.Generator().manual_seed(seed))
        assert shape == sample_makehuman_shape(torch.Generator().manual_seed(seed))
        assert shape.hand_length == pytest.approx(drawn["hand_length"], abs=2e-4)
        assert (shape.gender < 0.5) == drawn.female and 18 <= shape.years <= 80


@pytest.fixture(scope="module")
def hand() -> OpenHand:
    return sample_hand(torch.Generator().manual_seed(1), model="v3")


def test_the_rest_mesh_is_closed_in_the_package_frame_with_v1_bone_directions(hand):
    rest = build_mesh_rest(hand.shape)
    mesh = trimesh.Trimesh(rest.vertices, rest.faces, process=False)
    assert mesh.is_watertight and mesh.is_winding_consistent and mesh.volume > 2e-4
    skeleton = rest.skeleton
    joints = skeleton.joints.numpy()
    assert np.abs(joints[0]).max() < 1e-12  # the wrist at the origin
    middle = joints[FINGER_JOINTS["middle"][0]]
    assert middle[0] < -0.08 and abs(middle[1]) < 1e-9 and abs(middle[2]) < 1e-9
    assert skeleton.fingertips[0, 2] > 0.03  # the thumb on +z
    # Every bone turned to the mean hand's direction (distal bones: to the tip on the skin).
    mean_dirs = rest_skeleton(HandShape()).bone_dirs
    distal = [chain[2] for chain in FINGER_JOINTS.values()]
    inner = [j for j in range(1, 16) if j not in distal]
    torch.testing.assert_close(skeleton.bone_dirs[inner], mean_dirs[inner], atol=1e-6, rtol=0)
    assert (skeleton.bone_dirs[distal] * mean_dirs[distal]).sum(1).min() > 0.99
    np.testing.assert_allclose(rest.weights.sum(axis=1), 1.0, atol=1e-9)
    # Nails on the back of the fingertips, the palm facing -y.
    nails = rest.features["nail"] > 0.5
    vertex_area = np.zeros(len(rest.vertices))
    np.add.at(vertex_area, rest.faces.ravel(), np.repeat(mesh.area_faces / 3.0, 3))
    assert 3e-4 < vertex_area[nails].sum() < 1e-3  # five nails, 3-10 cm^2 in all
    owner = rest.weights[nails].argmax(axis=1)  # a nail's distal bone
    above = rest.vertices[nails] - joints[owner]
    assert ((above * skeleton.dorsal.numpy()[owner]).sum(1) > 0).mean() > 0.95
    palm = rest.features["palmar"] > 0.9
    assert np.median(rest.vertices[palm, 1]) < np.median(rest.vertices[:, 1])


def test_posed_ground_truth_is_exact_on_its_mesh(hand):
    posed = hand.posed(named_pose("fist", dtype=F64), torch.tensor([0.1, 0.0, 0.3], dtype=F64),
                       dtype=F64)
    vertices = torch.from_numpy(posed.vertices[::500])
    assert posed.sdf(vertices).abs().max() < 1e-9
    assert posed.sdf(posed.joints[:1]).item() < -0.005  # the wrist joint is inside
    far = posed.joints[:1] + torch.tensor([[0.0, 0.5, 0.0]], dtype=F64)
    assert posed.sdf(far).item() == pytest.approx(
        float(np.linalg.norm(posed.vertices - far.numpy(), axis=1).min()), abs=1e-6)
    samples = posed.surface_samples(300, torch.Generator().manual_seed(0))
    assert posed.sdf(samples.points).abs().max() < 1e-9
    # Off the surface (an open hand: a fist's skin folds into itself), distances are exact.
    posed = hand.posed(None, dtype=F64)
    samples = posed.surface_samples(300, torch.Generator().manual_seed(0))
    out = posed.evaluate(samples.points + 0.002 * samples.normals)
    sdf = out.sdf.numpy()  # 2 mm, or less where another part of the skin is nearer
    assert sdf.max() <= 0.002 + 1e-12 and sdf.min() > 0 and np.median(sdf) == pytest.approx(0.002)
    torch.testing.assert_close(out.weights.sum(1), torch.ones(300, dtype=F64))
    normals = posed.normals(samples.points + 0.003 * samples.normals)
    assert (normals * samples.normals).sum(1).mean() > 0.95
    assert posed.keypoints.shape == (21, 3)
    # Zero pose: the rest joints, moved by the translation.
    rest = hand.posed(None, torch.tensor([0.1, 0.0, 0.3], dtype=F64))
    torch.testing.assert_close(rest.joints, hand.rest_joints + torch.tensor([0.1, 0.0, 0.3],
                                                                            dtype=F64))


def test_a_left_hand_is_the_mirror_image(hand):
    left = dataclasses.replace(hand, side="left")
    pose = named_pose("point", dtype=F64)
    right_posed = hand.posed(pose, dtype=F64)
    left_posed = left.posed(named_pose("point", side="left", dtype=F64), dtype=F64)
    mirror = torch.tensor([-1.0, 1.0, 1.0], dtype=F64)
    points = torch.from_numpy(right_posed.vertices[::300]) + 0.003
    torch.testing.assert_close(left_posed.sdf(points * mirror), right_posed.sdf(points))
    torch.testing.assert_close(left_posed.keypoints, right_posed.keypoints * mirror)
    assert left_posed.volume() == pytest.approx(right_posed.volume(), rel=1e-9)


def test_skinning_corrections_keep_more_volume_than_lbs(hand):
    rest = hand.posed(dtype=F64).volume()
    fist = named_pose("fist", dtype=F64)
    lbs = PosedMeshHand(hand, fist, None, skinning="linear", corrective=0.0).volume()
    dqs = PosedMeshHand(hand, fist, None, corrective=0.0).volume()
    corrected = PosedMeshHand(hand, fist, None).volume()
    assert lbs < dqs < corrected <= rest * 1.01
    assert abs(corrected / rest - 1) < 0.5 * abs(lbs / rest - 1)
