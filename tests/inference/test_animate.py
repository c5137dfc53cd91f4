"""Re-posing a hand along a sequence (lisa_hand.inference.animate); the files it writes are
checked end to end in tests/cli/test_mesh_render_animate_cli.py."""

from __future__ import annotations

import json

import pytest
import torch

from lisa_hand import inference
from lisa_hand.data.meshio import load_mesh

from .helpers import PADDING, hand_params


def test_skinning_meshes_share_faces_and_poses_are_saved(model, tmp_path):
    params = hand_params(model)
    poses = params.pose.expand(2, 48).clone()
    poses[1, 3:] = 0.3
    result = inference.animate_hand(
        model, params, poses, None, tmp_path, mesh_resolution=16, mesh_mode="skinning",
        mesh_config=inference.MeshConfig(padding=PADDING), frames=False,
    )  # fmt: skip
    assert result.frame_paths == [] and result.gif_path is None and result.camera is None
    first, second = (load_mesh(path) for path in result.mesh_paths)
    assert (first.faces == second.faces).all() and abs(first.vertices - second.vertices).max() > 0
    saved = json.loads((tmp_path / "poses.json").read_text())
    torch.testing.assert_close(torch.tensor(saved["poses"]), poses)
    torch.testing.assert_close(torch.tensor(saved["translations"]),
                               params.translation.expand(2, 3))


@pytest.mark.parametrize("kwargs, message", [
    ({"poses": torch.zeros(2, 45)}, r"poses must have shape \[T, 48\]"),
    ({"translations": torch.zeros(3, 3)}, r"translations must have shape \[T, 3\] = \[2, 3\]"),
    ({"mesh_mode": "morph"}, "mesh_mode must be one of"),
    ({"mesh_suffix": ".stl"}, "mesh_suffix must be one of"),
    ({"mesh_resolution": None, "frames": False}, "nothing to write"),
    ({"fps": 0.0}, "fps must be > 0"),
])
def test_bad_inputs_write_nothing(model, tmp_path, kwargs, message):
    params = hand_params(model)
    arguments = {"poses": params.pose.expand(2, 48), "translations": None, **kwargs}
    poses, translations = arguments.pop("poses"), arguments.pop("translations")
    with pytest.raises(ValueError, match=message):
        inference.animate_hand(model, params, poses, translations, tmp_path / "out", **arguments)
    assert not (tmp_path / "out").exists()
