"""The files of ``lisa fit-video`` (lisa_hand.fitting.video.artefacts): the skinned poser
against :func:`lisa_hand.inference.mesh.repose_mesh` and against skinning done here, on a
small synthetic mesh of both sides; which entries of an output folder a video fit owns; the
overlay of a frame where no hand can be drawn."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from lisa_hand.fitting.sides import mirror_hand
from lisa_hand.fitting.video.artefacts import VIDEO_FILES, video_entry
from lisa_hand.geometry.cameras import Camera
from lisa_hand.geometry.meshing import Mesh
from lisa_hand.handmodel.template import load_template
from lisa_hand.inference.mesh import repose_mesh
from lisa_hand.inference.mesh_render import render_meshes_over
from lisa_hand.inference.skinned import SkinnedMesh
from lisa_hand.skeleton import forward_kinematics, linear_blend_skinning, mirror_points
from lisa_hand.skeleton.params import HandParams


def rest_points_and_weights(seed: int = 0) -> tuple[torch.Tensor, torch.Tensor]:
    """[V, 3] float64 points within 1 cm of the template's rest joints (20 a joint) and [V, 16]
    random skinning weights, rows summing to 1."""
    template = load_template()
    joints = template.rest_joints(torch.zeros(1, int(template.num_betas),
                                              dtype=torch.float64))[0]
    generator = torch.Generator().manual_seed(seed)
    offsets = 0.01 * torch.randn(16, 20, 3, generator=generator, dtype=torch.float64)
    points = (joints[:, None] + offsets).reshape(-1, 3)
    weights = torch.rand(points.shape[0], 16, generator=generator, dtype=torch.float64) ** 4
    return points, weights / weights.sum(-1, keepdim=True)


def right_params() -> HandParams:
    template = load_template()
    joints = template.rest_joints(torch.zeros(1, int(template.num_betas),
                                              dtype=torch.float64))[0]
    pose = 0.3 * torch.randn(48, generator=torch.Generator().manual_seed(1))
    pose[:3] = torch.tensor([math.pi / 2, 0.2, -0.1])
    return HandParams(pose=pose, translation=torch.tensor([0.05, -0.02, 0.45]),
                      rest_joints=joints.float(), shape_code=torch.zeros(4))


def skinned(points: torch.Tensor, weights: torch.Tensor, params: HandParams,
            pose: torch.Tensor, translation: torch.Tensor) -> np.ndarray:
    """Rest points posed by linear blend skinning, done here: [V, 3]."""
    kinematics = forward_kinematics(pose.double()[None], params.rest_joints.double()[None],
                                    translation.double()[None])
    return linear_blend_skinning(points, weights, kinematics.transforms)[0].numpy()


def hand_mesh(side: str) -> tuple[Mesh, HandParams, torch.Tensor, torch.Tensor]:
    """A mesh of ``side`` posed in its params' pose (posed from known rest points), its
    params, its rest points and weights."""
    points, weights = rest_points_and_weights()
    params = right_params()
    if side == "left":
        params, points = mirror_hand(params), mirror_points(points)
    vertices = skinned(points, weights, params, params.pose, params.translation)
    faces = np.arange(99).reshape(33, 3)
    colors = np.random.default_rng(2).integers(0, 256, size=(len(vertices), 3), dtype=np.uint8)
    mesh = Mesh(vertices=vertices, faces=faces, colors=colors,
                skin_weights=weights.float().numpy())
    return mesh, params, points, weights


@pytest.mark.parametrize("side", ["right", "left"])
def test_poser_equals_repose_mesh_and_skinning(side):
    mesh, params, points, weights = hand_mesh(side)
    assert params.side == side
    poser = SkinnedMesh(mesh, params)
    np.testing.assert_allclose(poser.rest.vertices, points.numpy(), atol=1e-5)  # unposed
    generator = torch.Generator().manual_seed(3)
    for _ in range(3):
        pose = 0.4 * torch.randn(48, generator=generator, dtype=torch.float64)
        translation = torch.tensor([0.1, 0.0, 0.6], dtype=torch.float64) \
            + 0.05 * torch.randn(3, generator=generator, dtype=torch.float64)
        posed = poser.posed(pose.numpy(), translation.numpy())
        reference = repose_mesh(mesh, params, pose, translation)
        np.testing.assert_allclose(posed.vertices, reference.vertices, atol=1e-5)
        np.testing.assert_allclose(posed.vertices,
                                   skinned(points, weights.float().double(), params, pose,
                                           translation), atol=1e-5)
        assert np.abs(posed.vertices - mesh.vertices).max() > 0.01  # the pose did move it
        np.testing.assert_array_equal(posed.faces, mesh.faces)
        np.testing.assert_array_equal(posed.colors, mesh.colors)
    back = poser.posed(params.pose.numpy(), params.translation.numpy())
    np.testing.assert_allclose(back.vertices, mesh.vertices, atol=1e-5)


def test_poser_of_a_decimated_mesh_moves_it_rigidly_with_its_bone():
    """A closed sphere (marching cubes) skinned wholly to the wrist, decimated for the overlay:
    at most max_faces faces, colours and weights kept per vertex, and every pose moves it
    rigidly with the wrist's bone: x' = R' R^T (x - a) + a', [R | a] and [R' | a'] the wrist's
    transforms in the fitted pose and in the new one."""
    from lisa_hand.geometry.meshing import extract_mesh

    params = right_params()
    wrist = params.rest_joints[0].double() + params.translation.double()
    sphere = extract_mesh(lambda points: (points - wrist.float()).norm(dim=-1) - 0.02,
                          (wrist - 0.03).tolist(), (wrist + 0.03).tolist(), 24)
    weights = np.zeros((len(sphere.vertices), 16), np.float32)
    weights[:, 0] = 1.0
    colors = np.random.default_rng(5).integers(0, 256, size=(len(sphere.vertices), 3),
                                               dtype=np.uint8)
    mesh = Mesh(vertices=sphere.vertices, faces=sphere.faces, colors=colors,
                skin_weights=weights)
    assert len(mesh.faces) > 400
    poser = SkinnedMesh(mesh, params, max_faces=200)
    assert 0 < len(poser.rest.faces) <= 200
    assert (poser.rest.skin_weights[:, 0] == 1.0).all()
    original = {tuple(colour) for colour in colors.tolist()}
    assert all(tuple(colour) in original for colour in poser.rest.colors.tolist())
    old = forward_kinematics(params.pose.double()[None], params.rest_joints.double()[None],
                             params.translation.double()[None]).transforms[0, 0]
    pose = 0.5 * torch.randn(48, generator=torch.Generator().manual_seed(6),
                             dtype=torch.float64)
    translation = torch.tensor([-0.1, 0.05, 0.7], dtype=torch.float64)
    new = forward_kinematics(pose[None], params.rest_joints.double()[None],
                             translation[None]).transforms[0, 0]
    kept = poser.posed(params.pose.numpy(), params.translation.numpy()).vertices  # as decimated
    moved = poser.posed(pose.numpy(), translation.numpy())
    rotation = new[:3, :3] @ old[:3, :3].T
    expected = (torch.from_numpy(kept).double() - old[:3, 3]) @ rotation.T + new[:3, 3]
    np.testing.assert_allclose(moved.vertices, expected.numpy(), atol=1e-5)
    np.testing.assert_array_equal(moved.faces, poser.rest.faces)
    assert SkinnedMesh(mesh, params, max_faces=10 ** 6).rest.faces.shape == mesh.faces.shape


def test_video_entry(tmp_path):
    for name in VIDEO_FILES:
        (tmp_path / name).write_text("x")
        assert video_entry(tmp_path / name), name
    for name in ("notes.txt", "params.json.bak", "overlay.png"):
        (tmp_path / name).write_text("x")
        assert not video_entry(tmp_path / name), name
    hand = tmp_path / "hand0"
    hand.mkdir()
    for name in ("params.json", "mesh.ply", "hand.glb"):
        (hand / name).write_text("x")
    assert video_entry(hand)
    (tmp_path / "hand12").mkdir()
    (tmp_path / "hand12" / "params.json").write_text("x")
    assert video_entry(tmp_path / "hand12")
    (hand / "notes.txt").write_text("x")
    assert not video_entry(hand)  # a hand folder holding something else
    nested = tmp_path / "hand1"
    (nested / "params.json").mkdir(parents=True)  # a folder named like a file
    assert not video_entry(nested)
    for name in ("hands", "handA", "hand_0", "params"):
        (tmp_path / name).mkdir()
        (tmp_path / name / "params.json").write_text("x")
        assert not video_entry(tmp_path / name), name
    (tmp_path / "link.json").symlink_to(tmp_path / "params.json")
    (tmp_path / "hand7").symlink_to(tmp_path / "hand12")
    linked = tmp_path / "hand3"
    linked.mkdir()
    (linked / "params.json").symlink_to(tmp_path / "params.json")
    sym = tmp_path / "sub"
    sym.mkdir()
    (sym / "track.json").symlink_to(tmp_path / "track.json")
    assert not video_entry(sym / "track.json")  # a link named like a video file
    assert not video_entry(tmp_path / "hand7") and not video_entry(linked)
    assert not video_entry(tmp_path / "missing.json")


def test_render_frame_without_a_drawable_hand_returns_the_frame():
    rgb = np.random.default_rng(4).integers(0, 256, size=(48, 64, 3), dtype=np.uint8)
    camera = Camera(K=[[60.0, 0.0, 32.0], [0.0, 60.0, 24.0], [0.0, 0.0, 1.0]], R=np.eye(3),
                    t=np.zeros(3), width=64, height=48)
    behind = Mesh(vertices=[[0.0, 0.0, -1.0], [0.1, 0.0, -1.0], [0.0, 0.1, -1.2]],
                  faces=[[0, 1, 2]])
    aside = Mesh(vertices=[[5.0, 0.0, 1.0], [5.1, 0.0, 1.0], [5.0, 0.1, 1.0]], faces=[[0, 1, 2]])
    for meshes in ([], [behind], [aside], [behind, aside]):
        # The model is never reached: a model=None would raise if it were.
        out = render_meshes_over(None, rgb, camera, meshes, alpha=0.75)
        assert out.dtype == np.uint8 and out.shape == rgb.shape
        np.testing.assert_array_equal(out, rgb)
