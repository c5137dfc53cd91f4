"""Hand model v2 (rounded padded palm, forearm stub, D-shaped fingers): a valid signed distance,
one watertight piece, the new anatomy where it should be, and v1 left exactly as it was."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import torch

from lisa_hand.handmodel import HAND_MODELS, OpenHand, named_pose, sample_hand
from lisa_hand.handmodel.parts_v2 import FOREARM_LENGTH
from lisa_hand.skeleton import FINGER_JOINTS

F64 = torch.float64
COARSE = 0.0025  # test meshing voxel, metres


@pytest.fixture(scope="module")
def hand() -> OpenHand:
    return sample_hand(torch.Generator().manual_seed(11), model="v2")


@pytest.fixture(scope="module")
def relaxed(hand):
    return hand.posed(named_pose("relaxed"), dtype=F64)


@pytest.fixture(scope="module")
def relaxed_mesh(relaxed):
    return relaxed.mesh(voxel_size=COARSE, colors=False, skin_weights=False)


def _near_surface(mesh, num, band, seed):
    generator = torch.Generator().manual_seed(seed)
    vertices = torch.from_numpy(mesh.vertices).double()
    index = torch.randint(vertices.shape[0], (num,), generator=generator)
    return vertices[index] + torch.randn(num, 3, generator=generator, dtype=F64) * band


def test_finite_difference_gradient_norm_is_close_to_one(relaxed, relaxed_mesh):
    points = _near_surface(relaxed_mesh, 2000, 0.002, 0)
    step = 1e-5
    offsets = torch.eye(3, dtype=F64) * step
    gradient = torch.stack(
        [(relaxed.sdf(points + offsets[k]) - relaxed.sdf(points - offsets[k])) / (2 * step)
         for k in range(3)], dim=1)  # fmt: skip
    norm = gradient.norm(dim=1)
    assert abs(norm.median().item() - 1.0) < 0.04
    assert ((norm - 1.0).abs() < 0.05).double().mean() > 0.6  # blends dip below 1 elsewhere
    assert ((norm - 1.0).abs() < 0.25).double().mean() > 0.93
    assert norm.max() < 1.6
    # Continuity: the autograd gradient is the same field's derivative (to the differences'
    # truncation error, larger at the fine detail: nail rims, creases).
    query = points[:400].clone().requires_grad_(True)
    (autograd,) = torch.autograd.grad(relaxed.sdf(query).sum(), query)
    error = (autograd - gradient[:400]).abs().amax(1)
    assert (error < 1e-4).double().mean() > 0.98 and error.max() < 5e-3


def test_mesh_is_one_watertight_piece_on_the_zero_level(relaxed, relaxed_mesh):
    trimesh = pytest.importorskip("trimesh")
    mesh = trimesh.Trimesh(relaxed_mesh.vertices, relaxed_mesh.faces, process=False)
    assert mesh.is_watertight and mesh.volume > 0
    assert mesh.body_count == 1
    values = relaxed.sdf(torch.from_numpy(relaxed_mesh.vertices).double())
    assert values.abs().mean() < 0.05 * COARSE


def test_fist_at_the_generators_resolution_is_one_piece_without_lost_volume(hand):
    trimesh = pytest.importorskip("trimesh")
    # The fist at SynthConfig's default voxels_per_length (255).
    length = hand.shape.hand_length
    fist = hand.posed(named_pose("fist")).mesh(voxel_size=length / 255, colors=False,
                                               skin_weights=False)
    fist = trimesh.Trimesh(fist.vertices, fist.faces, process=False)
    assert fist.is_watertight and fist.body_count == 1
    # Parts of different fingers sinking into each other lose volume: a fist keeps about as much
    # of the flat hand's volume as v1's fist of the same shape does (both meshed coarser).
    kept = {}
    for model_hand in (hand, dataclasses.replace(hand, model="v1")):
        volumes = []
        for name in ("fist", "flat"):
            mesh = model_hand.posed(named_pose(name)).mesh(voxel_size=length / 128,
                                                            colors=False, skin_weights=False)
            volumes.append(trimesh.Trimesh(mesh.vertices, mesh.faces, process=False).volume)
        kept[model_hand.model] = volumes[0] / volumes[1]
    assert kept["v2"] > 0.94 and kept["v2"] > kept["v1"] - 0.01


def test_forearm_stub_continues_past_the_wrist(hand):
    v1 = dataclasses.replace(hand, model="v1")
    scale = hand.shape.hand_length / 0.185
    for model_hand, reaches in ((hand, True), (v1, False)):
        posed = model_hand.posed(None, dtype=F64)
        beyond = torch.tensor([[FOREARM_LENGTH * scale, 0.0, -0.002 * scale]], dtype=F64)
        assert (posed.sdf(beyond).item() < 0.0) == reaches
    # The wrist's section is an oval: wider (z) than deep (y).
    posed = hand.posed(None, dtype=F64)
    width = _extent(posed, torch.tensor([0.02 * scale, -0.0015, -0.002 * scale]), [0, 0, 1])
    depth = _extent(posed, torch.tensor([0.02 * scale, -0.0015, -0.002 * scale]), [0, 1, 0])
    assert width > 1.4 * depth


def _exit(posed, start, direction, reach=0.05) -> float:
    """Distance from ``start`` (inside) along ``direction`` to the surface, metres (to 25 um)."""
    direction = torch.as_tensor(direction, dtype=F64)
    ts = torch.linspace(0.0, reach, 2001, dtype=F64)
    values = posed.sdf(torch.as_tensor(start, dtype=F64) + ts[:, None] * direction)
    return float(ts[int(torch.nonzero(values > 0)[0])])


def _extent(posed, center, axis, reach=0.05) -> float:
    """Width of the solid along ``axis`` through ``center`` (both sides), metres."""
    axis = torch.as_tensor(axis, dtype=F64)
    return _exit(posed, center, axis, reach) + _exit(posed, center, -axis, reach)


def test_fingers_are_wider_than_deep_and_flatter_on_the_palm_side(hand):
    posed = hand.posed(None, dtype=F64)
    skel = hand.parts.skeleton
    bone = FINGER_JOINTS["middle"][0]
    center = 0.5 * (skel.joints[bone] + skel.bone_ends[bone])
    width = _extent(posed, center, skel.lateral[bone].tolist())
    depth = _extent(posed, center, skel.dorsal[bone].tolist())
    assert width > 1.04 * depth
    # Half a radius to the side the dorsal surface has fallen further than the palmar one.
    radius = float(skel.radii[bone].mean())
    heights = {}
    for lateral in (0.0, 0.5 * radius):
        base = center + skel.lateral[bone] * lateral
        for sign, name in ((1.0, "dorsal"), (-1.0, "palmar")):
            heights[name, lateral] = _exit(posed, base, sign * skel.dorsal[bone], 2 * radius)
    dorsal_drop = heights["dorsal", 0.0] - heights["dorsal", 0.5 * radius]
    palmar_drop = heights["palmar", 0.0] - heights["palmar", 0.5 * radius]
    assert dorsal_drop > palmar_drop + 0.0002


def test_palm_is_padded_in_front_and_rounded_on_the_back(hand):
    v1 = dataclasses.replace(hand, model="v1")
    scale, width = hand.shape.hand_length / 0.185, hand.shape.palm_width

    def palmar_face(model_hand, x, z) -> float:
        """Depth of the palmar surface below the palm's plane (y = 0) at (x, z), metres."""
        posed = model_hand.posed(None, dtype=F64)
        return _exit(posed, [x * scale, 0.0, z * scale * width], [0.0, -1.0, 0.0], 0.04)

    # The thenar and hypothenar eminences stand out of the palm's hollow (more than in v1).
    pads = {}
    for model_hand in (hand, v1):
        hollow = palmar_face(model_hand, -0.050, -0.004)
        pads[model_hand.model] = (palmar_face(model_hand, -0.022, 0.012) - hollow,
                                  palmar_face(model_hand, -0.040, -0.027) - hollow)
    assert pads["v2"][0] > 0.008 and pads["v2"][1] > 0.0035
    assert pads["v2"][0] > pads["v1"][0] + 0.001 and pads["v2"][1] > pads["v1"][1] + 0.001

    # The back falls off toward the little finger's side (no edge); v1's slab rises to an edge.
    def back(model_hand, z) -> float:
        posed = model_hand.posed(None, dtype=F64)
        return _exit(posed, [-0.06 * scale, -0.004, z * scale * width], [0.0, 1.0, 0.0], 0.04)

    assert back(hand, -0.002) > back(hand, -0.022) + 0.002
    assert back(v1, -0.002) < back(v1, -0.022)


def test_v1_is_unchanged_and_the_default():
    # Numbers of a v1 subject computed before hand model v2 existed.
    hand = sample_hand(torch.Generator().manual_seed(7))
    assert hand.model == "v1" and OpenHand().model == "v1" and HAND_MODELS == ("v1", "v2", "v3")
    shape = dataclasses.asdict(hand.shape)
    assert shape["hand_length"] == 0.18704753959412035
    assert shape["palm_width"] == 0.9524299934629422
    assert shape["flesh"] == 1.009379128490328
    assert hand.detail_seed == 924125290
    assert hand.parts.cone_bone.shape == (36,) and hand.parts.crease_bone.shape == (44,)
    posed = hand.posed(named_pose("fist"), dtype=F64)
    generator = torch.Generator().manual_seed(0)
    points = torch.rand(64, 3, generator=generator, dtype=F64) * 0.2 - torch.tensor(
        [0.15, 0.05, 0.05], dtype=F64)  # fmt: skip
    values = posed.sdf(points)
    expected = [0.09019776501246614, 0.11832525565146866, 0.041329973469558696,
                0.028762001589608607]  # fmt: skip
    assert np.allclose(values[:4].numpy(), expected, rtol=0, atol=1e-12)
    assert values.sum().item() == pytest.approx(4.882730577995084, abs=1e-11)


def test_bad_model_is_rejected():
    with pytest.raises(ValueError, match="v1, v2, v3"):
        OpenHand(model="v4")
    with pytest.raises(ValueError, match="v1, v2"):
        sample_hand(torch.Generator().manual_seed(0), model="V2")


def _caliper(posed, center, axis, across, reach) -> float:
    """A caliper's reading along ``axis``: the farthest surface on each side over probes through
    ``center`` shifted along ``across`` by -10..10 mm, metres."""
    axis, across = torch.tensor(axis, dtype=F64), torch.tensor(across, dtype=F64)
    probes = [center + shift * across for shift in torch.linspace(-0.01, 0.01, 9).tolist()]
    return (max(_exit(posed, probe, axis, reach) for probe in probes)
            + max(_exit(posed, probe, -axis, reach) for probe in probes))


def test_rest_hand_has_the_drawn_breadth_and_thickness():
    from lisa_hand.handmodel.anthropometry import sample_anthropometric_shape, shape_measurements

    for seed in range(3):
        shape = sample_anthropometric_shape(torch.Generator().manual_seed(seed))
        posed = OpenHand(shape=shape, model="v2").posed(None, dtype=F64)
        middle = posed.hand.parts.skeleton.joints[FINGER_JOINTS["middle"][0]]
        # Across and through the metacarpal heads, just proximal of the MCP joints.
        center = middle + torch.tensor([0.006 * shape.hand_length / 0.185, 0.0, 0.0], dtype=F64)
        drawn = shape_measurements(shape)
        breadth = _caliper(posed, center, [0.0, 0.0, 1.0], [0.0, 1.0, 0.0], 0.08)
        thickness = _caliper(posed, center, [0.0, 1.0, 0.0], [0.0, 0.0, 1.0], 0.04)
        assert breadth == pytest.approx(drawn["hand_breadth"], rel=0.02)
        assert thickness == pytest.approx(drawn["palm_thickness"], rel=0.08)


def test_left_v2_hand_is_the_mirror_image(hand, relaxed_mesh):
    from lisa_hand.skeleton import mirror_points

    left = dataclasses.replace(hand, side="left").posed(named_pose("relaxed", side="left"),
                                                         dtype=F64)
    points = _near_surface(relaxed_mesh, 500, 0.003, 4)
    right = hand.posed(named_pose("relaxed"), dtype=F64)
    assert torch.allclose(left.sdf(mirror_points(points)), right.sdf(points), atol=1e-9)
