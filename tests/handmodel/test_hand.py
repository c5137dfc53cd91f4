"""The posed open hand: exact SDF, ownership, keypoints, meshes, samples, mirroring, seeds."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from lisa_hand.handmodel import (
    Appearance,
    HandShape,
    OpenHand,
    SurfaceSamples,
    named_pose,
    sample_hand,
)
from lisa_hand.skeleton import FINGER_JOINTS, FINGER_NAMES, KEYPOINT_NAMES, mirror_points

F64 = torch.float64
COARSE = 0.0025  # test meshing voxel, metres


@pytest.fixture(scope="module")
def hand() -> OpenHand:
    return sample_hand(torch.Generator().manual_seed(11))


@pytest.fixture(scope="module")
def relaxed(hand):
    return hand.posed(named_pose("relaxed"), torch.tensor([0.01, -0.02, 0.03]), dtype=F64)


@pytest.fixture(scope="module")
def relaxed_mesh(relaxed):
    return relaxed.mesh(voxel_size=COARSE)


def _near_surface(mesh, num, band, seed):
    generator = torch.Generator().manual_seed(seed)
    vertices = torch.from_numpy(mesh.vertices).double()
    index = torch.randint(vertices.shape[0], (num,), generator=generator)
    return vertices[index] + torch.randn(num, 3, generator=generator, dtype=F64) * band


def test_gradient_norm_is_close_to_one_near_the_surface(relaxed, relaxed_mesh):
    points = _near_surface(relaxed_mesh, 4000, 0.002, 0).requires_grad_(True)
    (gradient,) = torch.autograd.grad(relaxed.sdf(points).sum(), points)
    norm = gradient.norm(dim=1)
    assert abs(norm.median().item() - 1.0) < 0.03
    assert ((norm - 1.0).abs() < 0.05).double().mean() > 0.7  # blends dip below 1 elsewhere
    assert ((norm - 1.0).abs() < 0.25).double().mean() > 0.93
    assert norm.max() < 1.6
    # Away from parts' junctions and details the field is an exact distance: a finite
    # difference along the gradient changes the value by the step (|grad| = 1 along the ray).


def test_sdf_sign_and_distance(relaxed, hand):
    skel = hand.parts.skeleton
    palm_center = 0.5 * (skel.joints[0] + skel.joints[FINGER_JOINTS["middle"][0]])
    inside = relaxed.transforms[0, :3, :3] @ palm_center + relaxed.transforms[0, :3, 3]
    assert relaxed.sdf(inside[None]).item() < -0.008  # deep inside the palm
    low, high = relaxed.bounding_box()
    far = torch.tensor(np.stack([high + 0.05, low - 0.05, [high[0] + 0.1, low[1], 0.0]]))
    values = relaxed.sdf(far)
    assert torch.all(values > 0.04)
    # Far from the hand the field grows like a distance.
    direction = torch.tensor([0.0, 1.0, 0.0], dtype=F64)
    top = torch.tensor([[-0.05, 0.1, 0.0]], dtype=F64) + relaxed.translation
    step = relaxed.sdf(top + 0.01 * direction) - relaxed.sdf(top)
    assert step.item() == pytest.approx(0.01, rel=0.05)


def test_mesh_is_watertight_and_on_the_zero_level(relaxed, relaxed_mesh):
    trimesh = pytest.importorskip("trimesh")
    mesh = trimesh.Trimesh(relaxed_mesh.vertices, relaxed_mesh.faces, process=False)
    assert mesh.is_watertight
    assert mesh.volume > 0  # outward faces
    values = relaxed.sdf(torch.from_numpy(relaxed_mesh.vertices).double())
    assert values.abs().mean() < 0.05 * COARSE
    assert relaxed_mesh.colors.shape == (relaxed_mesh.num_vertices, 3)
    assert relaxed_mesh.skin_weights.shape == (relaxed_mesh.num_vertices, 16)
    assert np.allclose(relaxed_mesh.skin_weights.sum(1), 1.0, atol=1e-5)


@pytest.mark.slow
def test_default_mesh_has_100k_vertices_and_is_watertight():
    trimesh = pytest.importorskip("trimesh")
    posed = OpenHand(shape=HandShape(hand_length=0.16)).posed(named_pose("fist"))
    mesh = posed.mesh(colors=False, skin_weights=False)
    assert mesh.num_vertices >= 100_000
    assert trimesh.Trimesh(mesh.vertices, mesh.faces, process=False).is_watertight


def test_keypoints_fingertips_on_surface_and_owned_by_distal_bones(relaxed, relaxed_mesh):
    assert relaxed.joints.shape == (16, 3) and relaxed.keypoints.shape == (len(KEYPOINT_NAMES), 3)
    assert torch.allclose(relaxed.keypoints[0], relaxed.joints[0])
    assert torch.allclose(relaxed.joints[0], relaxed.translation)  # wrist at the origin + transl
    values, weights = relaxed.sdf_and_ownership(relaxed.fingertips)
    assert values.abs().max() < 1e-6
    low, high = relaxed_mesh.vertices.min(0), relaxed_mesh.vertices.max(0)
    tips = relaxed.fingertips.numpy()
    assert np.all(tips >= low - 1e-3) and np.all(tips <= high + 1e-3)
    distal = [FINGER_JOINTS[name][2] for name in FINGER_NAMES]
    assert torch.all(weights[torch.arange(5), distal] > 0.95)
    # A knuckle point is shared by the joint's two bones.
    pip = FINGER_JOINTS["middle"][1]
    _, knuckle = relaxed.sdf_and_ownership(relaxed.joints[pip][None])
    shared = knuckle[0, pip] + knuckle[0, pip - 1]
    assert shared > 0.9 and knuckle[0, pip] > 0.1 and knuckle[0, pip - 1] > 0.1


def test_ownership_weights_sum_to_one(relaxed, relaxed_mesh):
    points = _near_surface(relaxed_mesh, 3000, 0.005, 1)
    _, weights = relaxed.sdf_and_ownership(points)
    assert weights.shape == (3000, 16)
    assert torch.all(weights >= 0.0)
    assert torch.allclose(weights.sum(1), torch.ones(3000, dtype=F64), atol=1e-9)


def test_culling_matches_the_full_evaluation(relaxed, relaxed_mesh):
    points = _near_surface(relaxed_mesh, 5000, 0.01, 2)
    culled = relaxed._field.evaluate(points, cull=True)
    full = relaxed._field.evaluate(points, cull=False)
    assert torch.allclose(culled.sdf, full.sdf, atol=1e-7)
    assert torch.allclose(culled.weights, full.weights, atol=1e-5)


def test_surface_samples(relaxed):
    samples = relaxed.surface_samples(2000, torch.Generator().manual_seed(3), voxel_size=0.004)
    assert samples.points.shape == (2000, 3)
    assert relaxed.sdf(samples.points).abs().max() < 1e-6
    assert torch.allclose(samples.normals.norm(dim=1), torch.ones(2000, dtype=F64), atol=1e-9)
    # Normals point outward: stepping along them increases the distance.
    stepped = relaxed.sdf(samples.points + 5e-4 * samples.normals)
    assert (stepped > 3e-4).double().mean() > 0.97
    assert torch.allclose(samples.weights.sum(1), torch.ones(2000, dtype=F64), atol=1e-9)
    assert samples.colors.min() >= 0.0 and samples.colors.max() <= 1.0
    again = relaxed.surface_samples(2000, torch.Generator().manual_seed(3), voxel_size=0.004)
    assert torch.equal(samples.points, again.points)


def test_surface_samples_select_and_concatenate(relaxed):
    samples = relaxed.surface_samples(200, torch.Generator().manual_seed(4), voxel_size=0.004)
    first, rest = samples.select(slice(0, 50)), samples.select(torch.arange(50, 200))
    assert first.points.shape == (50, 3) and rest.weights.shape == (150, 16)
    joined = SurfaceSamples.concatenate([first, rest])
    for name in ("points", "normals", "weights", "colors"):
        assert torch.equal(getattr(joined, name), getattr(samples, name))
    assert joined.face_ids is None
    with pytest.raises(ValueError, match="different attributes"):
        SurfaceSamples.concatenate([samples, SurfaceSamples(samples.points, samples.normals)])


def test_albedo_palm_lighter_and_skin_tones_ordered():
    light = OpenHand(appearance=Appearance(skin_tone=0.1)).posed(dtype=F64)
    dark = OpenHand(appearance=Appearance(skin_tone=0.9)).posed(dtype=F64)
    back = torch.tensor([[-0.05, 0.02, 0.0]], dtype=F64)
    front = torch.tensor([[-0.05, -0.03, 0.0]], dtype=F64)
    back, front = light.project_to_surface(back), light.project_to_surface(front)
    # Palms are lighter on dark skin, pinker (redder than green) on light skin.
    assert dark.albedo(front).sum() > dark.albedo(back).sum() + 0.2
    palm, dorsum = light.albedo(front)[0], light.albedo(back)[0]
    assert (palm[0] - palm[1]) > (dorsum[0] - dorsum[1]) - 0.01
    assert light.albedo(back).sum() > dark.albedo(back).sum() + 0.9
    # The colour moves with the skin: a fingertip keeps its albedo when the hand moves (away
    # from contacts, where the touching surfaces' ownership mixes).
    moved = OpenHand(appearance=Appearance(skin_tone=0.1)).posed(
        named_pose("relaxed"), torch.tensor([0.1, 0.0, 0.0]), dtype=F64
    )
    assert torch.allclose(light.albedo(light.fingertips), moved.albedo(moved.fingertips), atol=0.01)


def test_left_hand_is_the_mirror_image(hand):
    left_hand = OpenHand(hand.shape, hand.appearance, hand.detail_seed, side="left")
    pose = named_pose("point", dtype=F64)
    right = hand.posed(pose, dtype=F64)
    left = left_hand.posed(named_pose("point", side="left", dtype=F64), dtype=F64)
    assert torch.allclose(left.joints, mirror_points(right.joints), atol=1e-12)
    assert torch.allclose(left.keypoints, mirror_points(right.keypoints), atol=1e-9)
    points = torch.randn(500, 3, generator=torch.Generator().manual_seed(4), dtype=F64) * 0.05
    points[:, 0] -= 0.08
    assert torch.allclose(left.sdf(mirror_points(points)), right.sdf(points), atol=1e-12)
    assert torch.allclose(left.albedo(mirror_points(points)), right.albedo(points), atol=1e-12)


def test_same_seed_same_hand_and_different_seeds_differ():
    first = sample_hand(torch.Generator().manual_seed(5))
    second = sample_hand(torch.Generator().manual_seed(5))
    other = sample_hand(torch.Generator().manual_seed(6))
    assert first == second and first != other
    points = torch.randn(300, 3, generator=torch.Generator().manual_seed(0), dtype=F64) * 0.04
    points[:, 0] -= 0.08
    pose = named_pose("ok")
    assert torch.equal(first.posed(pose).sdf(points), second.posed(pose).sdf(points))
    assert not torch.allclose(first.posed(pose).sdf(points), other.posed(pose).sdf(points))
    mesh_a, mesh_b = (h.posed(pose).mesh(voxel_size=0.004) for h in (first, second))
    assert np.array_equal(mesh_a.vertices, mesh_b.vertices)
    assert np.array_equal(mesh_a.colors, mesh_b.colors)
    # The detail seed alone changes the surface slightly (creases, bumps), not the skeleton.
    detail = OpenHand(first.shape, first.appearance, first.detail_seed + 1)
    delta = (detail.posed(pose).sdf(points) - first.posed(pose).sdf(points)).abs()
    assert 1e-6 < delta.max() < 1.5e-3
    assert torch.equal(detail.posed(pose).joints, first.posed(pose).joints)


def test_pose_dependent_deformation_is_not_rigid(hand):
    """Flexing a joint changes the surface near it beyond a rigid motion of the parts."""
    flat = hand.posed(dtype=F64)
    fist = hand.posed(named_pose("fist"), dtype=F64)
    pip = FINGER_JOINTS["middle"][1]
    # The palmar side of the flexed PIP joint fills in (bulges) relative to the straight finger.
    rest_point = (
        hand.parts.skeleton.joints[pip]
        - 0.8 * hand.parts.skeleton.dorsal[pip] * (hand.parts.skeleton.radii[pip, 0])
    )
    for posed in (flat, fist):
        transform = posed.transforms[pip]
        world = transform[:3, :3] @ rest_point + transform[:3, 3]
        value = posed.sdf(world[None]).item()
        if posed is flat:
            flat_value = value
    assert value < flat_value - 0.0005


def test_bad_inputs_are_rejected(hand, relaxed):
    with pytest.raises(ValueError, match="pose"):
        hand.posed(torch.zeros(45))
    with pytest.raises(ValueError, match="translation"):
        hand.posed(translation=torch.zeros(2))
    with pytest.raises(ValueError, match="NaN"):
        hand.posed(torch.full((48,), float("nan")))
    with pytest.raises(ValueError, match="points"):
        relaxed.sdf(torch.zeros(10, 2, dtype=F64))
    with pytest.raises(TypeError, match="points"):
        relaxed.sdf(np.zeros((10, 3)))
    with pytest.raises(ValueError, match="side"):
        OpenHand(side="both")
    with pytest.raises(TypeError, match="shape"):
        OpenHand(shape={"hand_length": 0.18})
    with pytest.raises(ValueError, match="voxel_size or resolution"):
        relaxed.mesh(voxel_size=0.002, resolution=100)
    with pytest.raises(ValueError, match="voxel_size"):
        relaxed.mesh(voxel_size=1.0)
    with pytest.raises(TypeError, match="dtype"):
        hand.posed(dtype=torch.float16)
