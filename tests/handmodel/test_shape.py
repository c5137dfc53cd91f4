"""Hand shape parameters, their distribution, and the rest skeleton's conventions."""

from __future__ import annotations

import ast
import dataclasses
import inspect
import textwrap

import numpy as np
import pytest
import torch

from lisa_hand.handmodel import HandShape, rest_skeleton, sample_shape
from lisa_hand.skeleton import FINGER_JOINTS


def _field_docstrings(cls: type) -> dict[str, str]:
    """The docstring written under each annotated field of a dataclass's body."""
    (body,) = ast.parse(textwrap.dedent(inspect.getsource(cls))).body
    docs = {}
    for statement, following in zip(body.body, body.body[1:] + [None], strict=True):
        if isinstance(statement, ast.AnnAssign) and isinstance(statement.target, ast.Name):
            is_doc = (isinstance(following, ast.Expr) and isinstance(following.value, ast.Constant)
                      and isinstance(following.value.value, str))
            docs[statement.target.id] = following.value.value.strip() if is_doc else ""
    return docs


def test_at_least_ten_documented_parameters():
    fields = dataclasses.fields(HandShape)
    assert len(fields) >= 10
    docs = _field_docstrings(HandShape)
    assert list(docs) == [field.name for field in fields]
    for field in fields:
        assert docs[field.name], f"HandShape.{field.name} has no docstring"


def test_sampled_shapes_cover_adult_hands_and_are_seeded():
    shapes = [sample_shape(torch.Generator().manual_seed(seed)) for seed in range(300)]
    lengths = np.array([s.hand_length for s in shapes])
    assert lengths.min() >= 0.16 and lengths.max() <= 0.22
    assert lengths.min() < 0.165 and lengths.max() > 0.205  # both ends of the adult range
    assert 0.175 < lengths.mean() < 0.19
    assert sample_shape(torch.Generator().manual_seed(7)) == shapes[7]
    assert shapes[0] != shapes[1]
    ratios = np.array([s.pinky_ratio for s in shapes])
    assert ratios.std() > 0.01


def test_rest_skeleton_conventions():
    shape = HandShape()
    skel = rest_skeleton(shape)
    assert torch.equal(skel.joints[0], torch.zeros(3, dtype=torch.float64))
    # Fingers along -x: the middle fingertip is one hand length from the wrist.
    middle_tip = skel.fingertips[2]
    assert middle_tip[0].item() == pytest.approx(-shape.hand_length, rel=1e-3)
    assert skel.fingertips[2].norm().item() == pytest.approx(shape.hand_length, rel=0.01)
    # Palm length: wrist to the middle MCP joint.
    mcp = skel.joints[FINGER_JOINTS["middle"][0]]
    assert -mcp[0].item() == pytest.approx(shape.palm_length * shape.hand_length, rel=1e-9)
    # Thumb on +z, index on +z of the little finger, palm facing -y (thumb tip below the palm).
    assert skel.fingertips[0, 2] > skel.joints[FINGER_JOINTS["index"][0], 2] > 0.0
    assert skel.joints[FINGER_JOINTS["pinky"][0], 2] < skel.joints[FINGER_JOINTS["ring"][0], 2] < 0
    # Anatomical frames: orthonormal, right-handed, lateral = dorsal x direction.
    frames = torch.stack([skel.lateral, skel.dorsal, skel.bone_dirs], dim=-1)
    eye = torch.eye(3, dtype=torch.float64).expand(16, 3, 3)
    assert torch.allclose(frames.transpose(-1, -2) @ frames, eye, atol=1e-12)
    assert torch.allclose(torch.linalg.det(frames), torch.ones(16, dtype=torch.float64))
    # Distal bones end at the fingertips; bones taper.
    for k, finger in enumerate(("thumb", "index", "middle", "ring", "pinky")):
        chain = FINGER_JOINTS[finger]
        assert torch.allclose(skel.bone_ends[chain[2]], skel.fingertips[k])
        assert skel.radii[chain[2], 1] < skel.radii[chain[0], 0]


def test_length_scales_the_skeleton():
    small = rest_skeleton(HandShape(hand_length=0.16))
    large = rest_skeleton(HandShape(hand_length=0.20))
    assert torch.allclose(large.joints, small.joints * 0.20 / 0.16, atol=1e-12)


@pytest.mark.parametrize(
    "kwargs, error",
    [
        ({"hand_length": 0.5}, ValueError),
        ({"pinky_ratio": float("nan")}, ValueError),
        ({"palm_width": "wide"}, TypeError),
        ({"knuckle_size": -1.0}, ValueError),
    ],
)
def test_bad_shapes_are_rejected_with_the_field_name(kwargs, error):
    with pytest.raises(error, match=next(iter(kwargs))):
        HandShape(**kwargs)


def test_bad_generator_and_shape_types():
    with pytest.raises(TypeError, match="generator"):
        sample_shape(0)
    with pytest.raises(TypeError, match="shape"):
        rest_skeleton("average")
