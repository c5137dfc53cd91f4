"""The animated hand's ``.glb``: the file parsed and skinned here as a glTF viewer does, against
the package's own posing (right and left hands), trimesh loads it, errors, atomic writes."""

from __future__ import annotations

import io
import json
import struct

import numpy as np
import pytest
import torch

from lisa_hand.data.gltf import animated_hand_glb, write_animated_glb
from lisa_hand.geometry.meshing import Mesh
from lisa_hand.inference.mesh import mirror_mesh, repose_mesh
from lisa_hand.skeleton import (
    AVERAGE_REST_JOINTS,
    JOINT_NAMES,
    forward_kinematics,
    linear_blend_skinning,
    mirror_points,
    mirror_pose,
)
from lisa_hand.skeleton.params import HandParams

trimesh = pytest.importorskip("trimesh")

TIMES = np.array([0.0, 0.1, 0.25, 0.4])


def right_hand(seed: int = 0) -> tuple[Mesh, np.ndarray, np.ndarray, np.ndarray]:
    """A closed ellipsoid around the average skeleton with random sparse weights (1 to 6 joints
    a vertex, so that keeping the top 4 matters), random colours, poses (0.3 rad std) and
    translations. -> (mesh, rest joints [16, 3], poses [T, 48], translations [T, 3])."""
    rng = np.random.default_rng(seed)
    sphere = trimesh.creation.icosphere(subdivisions=3)  # 642 vertices, outward faces
    vertices = sphere.vertices * [0.09, 0.02, 0.05] + [-0.08, -0.01, 0.0]
    weights = np.zeros((len(vertices), 16))
    for row, count in zip(weights, rng.integers(1, 7, len(vertices)), strict=True):
        row[rng.choice(16, count, replace=False)] = rng.random(count) + 0.05
    weights /= weights.sum(axis=1, keepdims=True)
    colors = rng.integers(0, 256, (len(vertices), 3)).astype(np.uint8)
    mesh = Mesh(vertices=vertices, faces=sphere.faces, colors=colors, skin_weights=weights)
    joints = np.asarray(AVERAGE_REST_JOINTS) + rng.normal(0, 0.002, (16, 3))
    poses = rng.normal(0, 0.3, (len(TIMES), 48))
    translations = rng.normal(0, 0.1, (len(TIMES), 3))
    return mesh, joints, poses, translations


def top4(weights: np.ndarray) -> np.ndarray:
    """[V, 16] -> [V, 16]: each row's four largest weights renormalised, the others zero."""
    keep = np.argsort(-weights, axis=1)[:, :4]
    out = np.zeros_like(weights, dtype=np.float64)
    np.put_along_axis(out, keep, np.take_along_axis(weights, keep, axis=1), axis=1)
    return out / out.sum(axis=1, keepdims=True)


def parse_glb(data: bytes) -> tuple[dict, bytes]:
    magic, version, length = struct.unpack_from("<4sII", data, 0)
    assert (magic, version, length) == (b"glTF", 2, len(data))
    json_length, json_type = struct.unpack_from("<II", data, 12)
    assert json_type == 0x4E4F534A and json_length % 4 == 0
    document = json.loads(data[20 : 20 + json_length])
    start = 20 + json_length
    bin_length, bin_type = struct.unpack_from("<II", data, start)
    assert bin_type == 0x004E4942 and start + 8 + bin_length == len(data)
    return document, data[start + 8 : start + 8 + bin_length]


def accessor(document: dict, binary: bytes, index: int) -> np.ndarray:
    """Accessor ``index`` as [count, components] (normalized bytes as floats in [0, 1])."""
    acc = document["accessors"][index]
    view = document["bufferViews"][acc["bufferView"]]
    dtype = {5126: "<f4", 5121: "u1", 5123: "<u2", 5125: "<u4"}[acc["componentType"]]
    width = {"SCALAR": 1, "VEC3": 3, "VEC4": 4, "MAT4": 16}[acc["type"]]
    offset = view.get("byteOffset", 0) + acc.get("byteOffset", 0)
    assert offset % 4 == 0 and "byteStride" not in view
    array = np.frombuffer(binary, dtype, acc["count"] * width, offset).reshape(-1, width)
    return array / 255.0 if acc.get("normalized") else array


def quaternion_matrix(q: np.ndarray) -> np.ndarray:
    x, y, z, w = np.asarray(q, np.float64) / np.linalg.norm(q)
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                     [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                     [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])


def skin_from_file(data: bytes, key: int) -> np.ndarray:
    """What a glTF viewer shows at animation key ``key``: node TRS (animated where a channel
    targets it), global matrices down the hierarchy, joint matrices ``global_j ibm_j``, and the
    vertices blended with the file's JOINTS_0 / WEIGHTS_0. -> [V, 3] float64."""
    document, binary = parse_glb(data)
    nodes = document["nodes"]
    trs = [{"translation": np.asarray(n.get("translation", [0, 0, 0]), np.float64),
            "rotation": np.asarray(n.get("rotation", [0, 0, 0, 1]), np.float64),
            "scale": np.asarray(n.get("scale", [1, 1, 1]), np.float64)} for n in nodes]
    (animation,) = document["animations"]
    for channel in animation["channels"]:
        sampler = animation["samplers"][channel["sampler"]]
        assert sampler["interpolation"] == "LINEAR"
        np.testing.assert_allclose(accessor(document, binary, sampler["input"])[key, 0],
                                   TIMES[key], atol=1e-7)
        target = channel["target"]
        trs[target["node"]][target["path"]] = accessor(document, binary, sampler["output"])[key]
    world = [None] * len(nodes)

    def visit(index: int, parent: np.ndarray) -> None:
        local = np.eye(4)
        local[:3, :3] = quaternion_matrix(trs[index]["rotation"]) * trs[index]["scale"]
        local[:3, 3] = trs[index]["translation"]
        world[index] = parent @ local
        for child in nodes[index].get("children", []):
            visit(child, world[index])

    for root in document["scenes"][document["scene"]]["nodes"]:
        visit(root, np.eye(4))
    (skin,) = document["skins"]
    inverse_binds = accessor(document, binary, skin["inverseBindMatrices"])
    inverse_binds = inverse_binds.reshape(-1, 4, 4).transpose(0, 2, 1)  # column-major
    joint_matrices = np.stack([world[n] for n in skin["joints"]]) @ inverse_binds
    attributes = document["meshes"][0]["primitives"][0]["attributes"]
    positions = accessor(document, binary, attributes["POSITION"]).astype(np.float64)
    joints = accessor(document, binary, attributes["JOINTS_0"]).astype(np.int64)
    weights = accessor(document, binary, attributes["WEIGHTS_0"]).astype(np.float64)
    blended = np.einsum("vk,vkrc->vrc", weights, joint_matrices[joints])
    return np.einsum("vrc,vc->vr", blended[:, :3, :3], positions) + blended[:, :3, 3]


def lbs(mesh: Mesh, joints, pose, translation) -> np.ndarray:
    """The package's posing: forward kinematics and linear blend skinning, top-4 weights."""
    kinematics = forward_kinematics(torch.as_tensor(pose)[None].double(),
                                    torch.as_tensor(joints).double(),
                                    torch.as_tensor(translation)[None].double())
    weights = torch.from_numpy(top4(mesh.skin_weights))
    vertices = torch.from_numpy(mesh.vertices).double()
    return linear_blend_skinning(vertices, weights, kinematics.transforms)[0].numpy()


def test_right_hand_file_skins_as_the_package_poses_it():
    mesh, joints, poses, translations = right_hand()
    data = animated_hand_glb(mesh, joints, poses, torch.from_numpy(translations), TIMES)
    worst = 0.0
    for key in range(len(TIMES)):
        got, want = skin_from_file(data, key), lbs(mesh, joints, poses[key], translations[key])
        worst = max(worst, float(np.abs(got - want).max()))
    assert worst < 1e-5, worst


def test_left_hand_file_is_the_mirrored_right_hand():
    """A left hand as the package stores it (everything mirrored, pose by mirror_pose): the
    file skins to the mirror of the right hand posed, which is also repose_mesh's left hand."""
    right, joints, poses, translations = right_hand(seed=1)
    left = mirror_mesh(right)
    left_joints, left_poses = mirror_points(torch.as_tensor(joints)), mirror_pose(
        torch.as_tensor(poses))
    left_translations = mirror_points(torch.as_tensor(translations))
    data = animated_hand_glb(left, left_joints, left_poses, left_translations, TIMES, side="left")
    at_rest = HandParams(pose=torch.zeros(48), translation=torch.zeros(3),
                         rest_joints=left_joints.float(), shape_code=torch.zeros(0), side="left")
    left_top4 = Mesh(left.vertices, left.faces, skin_weights=top4(left.skin_weights))
    worst = 0.0
    for key in range(len(TIMES)):
        got = skin_from_file(data, key)
        mirrored = lbs(right, joints, poses[key], translations[key]) * [-1.0, 1.0, 1.0]
        reposed = repose_mesh(left_top4, at_rest, left_poses[key], left_translations[key])
        worst = max(worst, float(np.abs(got - mirrored).max()))
        np.testing.assert_allclose(got, reposed.vertices, atol=1e-5)
    assert worst < 1e-5, worst
    assert parse_glb(data)[0]["nodes"][0]["extras"] == {"side": "left"}


def test_document_content():
    mesh, joints, poses, translations = right_hand()
    data = animated_hand_glb(mesh, joints, poses, translations, TIMES, name="my hand")
    document, binary = parse_glb(data)
    assert document["asset"] == {"version": "2.0", "generator": "lisa-hand"}
    assert data[20 + struct.unpack_from("<I", data, 12)[0] - 1 :][:1] in (b" ", b"}")
    primitive = document["meshes"][0]["primitives"][0]
    attributes = primitive["attributes"]
    position = document["accessors"][attributes["POSITION"]]
    np.testing.assert_array_equal(position["min"], mesh.vertices.min(0))
    np.testing.assert_array_equal(position["max"], mesh.vertices.max(0))
    normals = accessor(document, binary, attributes["NORMAL"])
    np.testing.assert_allclose(np.linalg.norm(normals, axis=1), 1.0, atol=1e-6)
    outward = np.einsum("vc,vc->v", normals, mesh.vertices - mesh.vertices.mean(0))
    assert (outward > 0).all()  # an ellipsoid's smooth normals point away from its centre
    colors = accessor(document, binary, attributes["COLOR_0"])
    np.testing.assert_array_equal(np.rint(colors[:, :3] * 255), mesh.colors)
    np.testing.assert_array_equal(colors[:, 3], 1.0)
    weights = accessor(document, binary, attributes["WEIGHTS_0"])
    np.testing.assert_allclose(weights.sum(axis=1), 1.0, atol=1e-6)
    faces = accessor(document, binary, primitive["indices"]).reshape(-1, 3)
    np.testing.assert_array_equal(faces, mesh.faces)
    material = document["materials"][primitive["material"]]
    assert material["pbrMetallicRoughness"]["metallicFactor"] == 0.0
    assert material["pbrMetallicRoughness"]["baseColorFactor"] == [1.0, 1.0, 1.0, 1.0]
    (skin,) = document["skins"]
    assert [document["nodes"][n]["name"] for n in skin["joints"]] == list(JOINT_NAMES)
    assert skin["skeleton"] == skin["joints"][0]
    times = document["accessors"][document["animations"][0]["samplers"][0]["input"]]
    assert (times["min"], times["max"]) == ([0.0], [pytest.approx(0.4)])
    assert document["nodes"][0]["name"] == "my hand"
    assert document["animations"][0]["name"] == "clip"


def test_trimesh_loads_the_file():
    mesh, joints, poses, translations = right_hand()
    data = animated_hand_glb(mesh, joints, poses, translations, TIMES)
    scene = trimesh.load(io.BytesIO(data), file_type="glb")
    (geometry,) = scene.geometry.values()
    assert len(geometry.vertices) == mesh.num_vertices
    assert len(geometry.faces) == mesh.num_faces


def test_one_frame_and_no_colours():
    mesh, joints, poses, translations = right_hand()
    plain = Mesh(mesh.vertices, mesh.faces, skin_weights=mesh.skin_weights)
    data = animated_hand_glb(plain, joints, poses[:1], translations[:1], [0.0])
    document, _ = parse_glb(data)
    assert "COLOR_0" not in document["meshes"][0]["primitives"][0]["attributes"]


def test_errors():
    mesh, joints, poses, translations = right_hand()
    bare = Mesh(mesh.vertices, mesh.faces)
    with pytest.raises(ValueError, match="skin_weights"):
        animated_hand_glb(bare, joints, poses, translations, TIMES)
    with pytest.raises(ValueError, match="strictly increasing"):
        animated_hand_glb(mesh, joints, poses, translations, [0.0, 0.2, 0.2, 0.4])
    with pytest.raises(ValueError, match=r"poses must have shape \[T, 48\]"):
        animated_hand_glb(mesh, joints, poses[:, :45], translations, TIMES)
    with pytest.raises(ValueError, match=r"translations must have shape \[4, 3\]"):
        animated_hand_glb(mesh, joints, poses, translations[:3], TIMES)
    with pytest.raises(ValueError, match="finite"):
        animated_hand_glb(mesh, joints, poses * np.nan, translations, TIMES)
    with pytest.raises(ValueError, match="side"):
        animated_hand_glb(mesh, joints, poses, translations, TIMES, side="middle")


def test_write_is_atomic(tmp_path):
    mesh, joints, poses, translations = right_hand()
    path = write_animated_glb(tmp_path / "hand.glb", mesh, joints, poses, translations, TIMES)
    assert path == tmp_path / "hand.glb"
    assert [p.name for p in tmp_path.iterdir()] == ["hand.glb"]
    data = path.read_bytes()
    assert len(data) % 4 == 0 and struct.unpack_from("<I", data, 8)[0] == len(data)
    with pytest.raises(ValueError):
        write_animated_glb(tmp_path / "bad.glb", mesh, joints, poses[:, :45], translations, TIMES)
    assert [p.name for p in tmp_path.iterdir()] == ["hand.glb"]
