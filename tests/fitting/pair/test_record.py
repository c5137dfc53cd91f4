"""What a fit of several hands writes (lisa_hand.fitting.pair.record): the right-to-left root
offset and its error (InterHand2.6M's MRRPE) on numbers worked by hand, ``hands.json``'s
record, and the meshes of all hands joined into one."""

from __future__ import annotations

import json

import numpy as np
import torch

from lisa_hand.fitting.pair.record import hands_record, joined_mesh, right_to_left
from lisa_hand.geometry.meshing import Mesh
from lisa_hand.skeleton.params import HandParams

ROOTS = np.array([[0.0, 0.0, 0.5], [0.1, 0.02, 0.5]])  # right, left (metres)
TRUE_ROOTS = np.array([[0.01, 0.0, 0.5], [0.1, 0.0, 0.51]])


def test_right_to_left_is_the_left_root_minus_the_right_one():
    np.testing.assert_allclose(right_to_left(["right", "left"], ROOTS), [0.1, 0.02, 0.0])
    np.testing.assert_allclose(right_to_left(["left", "right"], ROOTS), [-0.1, -0.02, 0.0])
    assert right_to_left(["right", "right"], ROOTS) is None
    assert right_to_left(["left", "left"], ROOTS) is None
    assert right_to_left(["right"], ROOTS[:1]) is None
    assert right_to_left(["right", "left", "right"], np.concatenate([ROOTS, ROOTS[:1]])) is None


def hand(side: str) -> HandParams:
    return HandParams(pose=torch.zeros(48), translation=torch.zeros(3),
                      rest_joints=torch.arange(48.0).reshape(16, 3) * 0.01,
                      shape_code=torch.zeros(4), side=side)


def test_hands_record_holds_each_hand_the_offset_and_the_penetration():
    penetration = np.array([[0.0, 1.23456], [0.5, 0.0]])
    roots = ROOTS + 1e-9  # rounded to the micrometre
    record = hands_record([hand("right"), hand("left")], ["hand_0", "hand_1"], roots,
                          penetration, "camera", {"iters": 3}, ["a note"])
    assert set(record) == {"hands", "right_to_left_m", "penetration_mm",
                           "penetration_pairs_mm", "frame", "joint", "notes"}
    assert record["hands"] == [
        {"folder": "hand_0", "side": "right", "root_m": [0.0, 0.0, 0.5]},
        {"folder": "hand_1", "side": "left", "root_m": [0.1, 0.02, 0.5]}]
    np.testing.assert_allclose(record["right_to_left_m"], [0.1, 0.02, 0.0], atol=1e-12)
    assert record["penetration_mm"] == 1.235
    assert record["penetration_pairs_mm"] == [[0.0, 1.235], [0.5, 0.0]]
    assert record["frame"] == "camera" and record["joint"] == {"iters": 3}
    assert record["notes"] == ["a note"]
    assert json.loads(json.dumps(record)) == record  # plain JSON
    # Two right hands: no right-to-left offset; no joint stage; no overlap.
    record = hands_record([hand("right"), hand("right")], ["a", "b"], ROOTS, np.zeros((2, 2)),
                          "camera", None, [])
    assert record["right_to_left_m"] is None and record["joint"] is None
    assert record["penetration_mm"] == 0.0 and record["notes"] == []
    assert [entry["side"] for entry in record["hands"]] == ["right", "right"]


def test_joined_mesh_offsets_faces_and_keeps_colours():
    rng = np.random.default_rng(0)

    def mesh(vertices: int, faces: int, colors: bool = True) -> Mesh:
        return Mesh(vertices=rng.normal(size=(vertices, 3)),
                    faces=rng.integers(0, vertices, size=(faces, 3)),
                    colors=rng.integers(0, 256, (vertices, 3), dtype=np.uint8) if colors
                    else None,
                    skin_weights=np.full((vertices, 16), 1.0 / 16, np.float32))

    parts = [mesh(5, 4), mesh(7, 6), mesh(3, 1)]
    joined = joined_mesh(parts)
    assert joined.vertices.shape == (15, 3) and joined.faces.shape == (11, 3)
    np.testing.assert_array_equal(joined.vertices, np.concatenate([p.vertices for p in parts]))
    np.testing.assert_array_equal(joined.faces[:4], parts[0].faces)
    np.testing.assert_array_equal(joined.faces[4:10], parts[1].faces + 5)
    np.testing.assert_array_equal(joined.faces[10:], parts[2].faces + 12)
    # Every face of the joined mesh is the same triangle as in its own mesh.
    np.testing.assert_array_equal(joined.vertices[joined.faces[4:10]],
                                  parts[1].vertices[parts[1].faces])
    np.testing.assert_array_equal(joined.colors, np.concatenate([p.colors for p in parts]))
    assert joined.skin_weights is None  # each hand's weights belong to its own skeleton
    # One mesh without colours: none kept.
    assert joined_mesh([parts[0], mesh(4, 2, colors=False)]).colors is None
