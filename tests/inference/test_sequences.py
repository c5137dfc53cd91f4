"""Pose sequences (lisa_hand.inference.sequences): files, completion, named motions."""

from __future__ import annotations

import json

import pytest
import torch

from lisa_hand import inference
from lisa_hand.handmodel.poses import named_pose

from .helpers import hand_params


def test_pose_sequences(tmp_path, model):
    params = hand_params(model)
    fingers = torch.full((3, 45), 0.2)
    path = tmp_path / "seq.json"
    path.write_text(json.dumps(fingers.tolist()))
    poses, translations = inference.resolve_poses(params, inference.read_pose_sequence(path))
    assert poses.shape == (3, 48) and torch.equal(poses[:, :3], params.pose[:3].expand(3, 3))
    assert torch.equal(poses[:, 3:], fingers) and torch.equal(translations[1], params.translation)
    path.write_text(json.dumps(
        {"poses": torch.zeros(2, 48).tolist(), "translations": [[0, 0, 1], [0, 0, 2]]}))
    poses, translations = inference.resolve_poses(params, inference.read_pose_sequence(path))
    assert torch.equal(poses, torch.zeros(2, 48)) and translations[1, 2] == 2.0
    for bad, message in ((["x"], "poses must be"), ([[0.0] * 47], r"\[T, 48\] or \[T, 45\]"),
                         ({"poses": [[0.0] * 48], "translations": [[0.0]]}, "translations"),
                         ({"pose": []}, "keys"), ([], "non-empty list")):
        path.write_text(json.dumps(bad))
        with pytest.raises(ValueError, match=message) as info:
            inference.read_pose_sequence(path)
        assert str(path) in str(info.value)

    motion = inference.motion_poses(params, "fist", frames_per_segment=3)
    assert motion.shape == (7, 48)
    torch.testing.assert_close(motion[0], params.pose)
    torch.testing.assert_close(motion[-1], params.pose, atol=1e-5, rtol=0)
    torch.testing.assert_close(motion[3, 3:], named_pose("fist")[3:], atol=1e-5, rtol=0)
    torch.testing.assert_close(motion[:, :3], params.pose[:3].expand(7, 3), atol=1e-5, rtol=0)
    with pytest.raises(ValueError, match="unknown pose name"):
        inference.motion_poses(params, "wave")
