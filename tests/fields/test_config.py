"""FieldConfig: defaults, validation, dict round trip."""

from __future__ import annotations

import dataclasses
import json

import pytest

from lisa_hand.fields import COMPOSITIONS, FieldConfig


def test_defaults_follow_the_paper():
    config = FieldConfig()
    assert config.composition == "lisa"
    assert config.shape_dim == 128 and config.color_dim == 128
    assert config.softplus_beta == 100.0
    assert config.pose_conditioning == "local"
    assert config.per_bone and not FieldConfig(composition="single").per_bone


def test_every_field_has_a_docstring():
    import inspect

    source = inspect.getsource(FieldConfig)
    for field in dataclasses.fields(FieldConfig):
        after = source.split(f"    {field.name}:", 1)[1].split("\n", 2)
        assert after[1].strip().startswith('"""'), field.name


@pytest.mark.parametrize("composition", COMPOSITIONS)
def test_json_round_trip(composition):
    config = FieldConfig(composition=composition, sdf_hidden=32, inference_precision="bfloat16")
    restored = FieldConfig.from_dict(json.loads(json.dumps(config.to_dict())))
    assert restored == config


def test_from_dict_defaults_and_unknown_keys():
    assert FieldConfig.from_dict({"sdf_hidden": 64}) == FieldConfig(sdf_hidden=64)
    with pytest.raises(ValueError, match="unknown FieldConfig keys \\['hidden'\\]"):
        FieldConfig.from_dict({"hidden": 64})
    with pytest.raises(TypeError, match="dict"):
        FieldConfig.from_dict([("sdf_hidden", 64)])


@pytest.mark.parametrize(
    "overrides, message",
    [
        ({"composition": "snarf"}, "composition"),
        ({"pose_conditioning": "global"}, "pose_conditioning"),
        ({"inference_precision": "float16"}, "inference_precision"),
        ({"sdf_hidden": 0}, "sdf_hidden"),
        ({"sdf_depth": 0}, "sdf_depth"),
        ({"shape_dim": 2.5}, "shape_dim"),
        ({"pe_frequencies": -1}, "pe_frequencies"),
        ({"coordinate_scale": 0.0}, "coordinate_scale"),
        ({"finger_region_radius": -0.01}, "finger_region_radius"),
        ({"outside_margin": -1.0}, "outside_margin"),
    ],
)
def test_invalid_values_name_the_field(overrides, message):
    with pytest.raises(ValueError, match=message):
        FieldConfig(**overrides)


def test_frozen():
    with pytest.raises(dataclasses.FrozenInstanceError):
        FieldConfig().sdf_hidden = 3
