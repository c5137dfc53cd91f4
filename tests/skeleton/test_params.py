"""params.json: round trip and clear errors (lisa_hand.skeleton.params)."""

from __future__ import annotations

import json

import pytest
import torch

from lisa_hand.skeleton.params import HandParams, read_params, write_params


def _params(**kwargs) -> HandParams:
    g = torch.Generator().manual_seed(0)
    base = dict(pose=torch.randn(48, generator=g), translation=torch.randn(3, generator=g),
                rest_joints=torch.randn(16, 3, generator=g), shape_code=torch.randn(8, generator=g),
                color_code=torch.randn(4, generator=g), betas=torch.randn(10, generator=g))
    base.update(kwargs)
    return HandParams(**base)


def test_round_trip(tmp_path):
    params = _params(extra={"loss": 0.5})
    write_params(tmp_path / "params.json", params)
    again = read_params(tmp_path / "params.json")
    for name in ("pose", "translation", "rest_joints", "shape_code", "color_code", "betas"):
        assert torch.equal(getattr(again, name), getattr(params, name)), name
    assert again.extra == {"loss": 0.5} and again.side == "right"
    batch = again.batch()
    assert batch["pose"].shape == (1, 48) and batch["rest_joints"].shape == (1, 16, 3)
    geometry_only = _params(color_code=None, betas=None)
    write_params(tmp_path / "g.json", geometry_only)
    assert read_params(tmp_path / "g.json").color_code is None


def test_bad_params_name_the_file_and_key(tmp_path):
    with pytest.raises(ValueError, match="pose must have shape"):
        _params(pose=torch.zeros(45))
    with pytest.raises(ValueError, match="translation holds NaN"):
        _params(translation=torch.tensor([0.0, float("nan"), 0.0]))
    data = _params().to_dict()
    del data["shape_code"]
    path = tmp_path / "p.json"
    path.write_text(json.dumps(data))
    with pytest.raises(ValueError, match="p.json: missing key"):
        read_params(path)
    data = _params().to_dict()
    data["rest_joints"] = [[0.0, 0.0]] * 16
    path.write_text(json.dumps(data))
    with pytest.raises(ValueError, match=r"p.json: rest_joints must have shape \[16, 3\]"):
        read_params(path)
    path.write_text("{not json")
    with pytest.raises(ValueError, match="p.json"):
        read_params(path)
