"""Config utilities: JSON round trip, strict loading, dotted overrides, clear errors."""

from __future__ import annotations

import json
import re
from dataclasses import dataclass
from dataclasses import field as dc_field
from pathlib import Path
from typing import ClassVar, Literal

import pytest

from lisa_hand.training.config import TrainerConfig
from lisa_hand.utils.config import (
    apply_overrides,
    config_from_dict,
    config_to_dict,
    load_config,
    parse_override,
    renamed_field,
    save_config,
)


@dataclass(frozen=True)
class FieldCfg:
    """A nested config with its own checks."""

    hidden: int = 64
    """Width."""
    activation: Literal["relu", "softplus"] = "softplus"
    """Nonlinearity."""
    widths: tuple[int, ...] = (64, 64)
    """Layer widths."""
    min_radius: float = 0.0
    """Lower bound (must stay below max_radius)."""
    max_radius: float = 1.0
    """Upper bound."""

    def validate(self) -> None:
        if self.hidden < 1:
            raise ValueError(f"hidden must be >= 1, got {self.hidden}")
        if not self.min_radius < self.max_radius:
            raise ValueError(f"min_radius ({self.min_radius}) must be below max_radius "
                             f"({self.max_radius})")


@dataclass(frozen=True)
class RunCfg:
    """A top-level config as the LISA trainers will have."""

    name: str = "run"
    """Run name."""
    data_root: Path = Path("data")
    """Folder."""
    field: FieldCfg = dc_field(default_factory=FieldCfg)
    """Network."""
    training: TrainerConfig = dc_field(default_factory=TrainerConfig)
    """Loop."""
    crop: tuple[float, float] = (0.0, 1.0)
    """A fixed-length tuple."""
    max_items: int | None = None
    """Optional."""
    verbose: bool = False
    """A flag."""


def _custom() -> RunCfg:
    return RunCfg(
        name="x", data_root=Path("/tmp/some where"),
        field=FieldCfg(hidden=3, activation="relu", widths=(5, 6, 7), max_radius=2.5),
        training=TrainerConfig(steps=7, lr=1e-3, lr_schedule="cosine", betas=(0.8, 0.9)),
        crop=(0.25, 0.75), max_items=9, verbose=True,
    )


def test_round_trip_through_json(tmp_path):
    cfg = _custom()
    data = config_to_dict(cfg)
    assert data["data_root"] == "/tmp/some where"
    assert data["field"]["widths"] == [5, 6, 7]
    assert data["training"]["betas"] == [0.8, 0.9]
    back = config_from_dict(RunCfg, json.loads(json.dumps(data)))
    assert back == cfg
    assert isinstance(back.data_root, Path) and isinstance(back.field.widths, tuple)
    path = save_config(tmp_path / "sub" / "config.json", cfg)
    assert json.loads(path.read_text()) == data
    assert load_config(RunCfg, path) == cfg
    assert not list(path.parent.glob(".config.json*"))  # no temporary left behind


def test_missing_keys_take_defaults():
    cfg = config_from_dict(RunCfg, {"field": {"hidden": 3}, "training": {"lr": 1}})
    assert cfg.field == FieldCfg(hidden=3)
    assert cfg.training.lr == 1.0 and isinstance(cfg.training.lr, float)
    assert cfg.name == "run" and cfg.max_items is None


@pytest.mark.parametrize(
    ("data", "expected"),
    [
        ({"field": {"hiden": 3}}, r"unknown key 'field.hiden'; did you mean 'hidden'"),
        ({"nmae": "a"}, r"unknown key 'nmae'; did you mean 'name'"),
        ({"training": {"lr": "fast"}}, r"training.lr expects float, got 'fast'"),
        ({"field": {"hidden": 3.5}}, r"field.hidden expects int, got 3.5"),
        ({"field": {"hidden": True}}, r"field.hidden expects int, got True"),
        ({"verbose": 1}, r"verbose expects bool, got 1"),
        ({"field": {"activation": "tanh"}}, r"field.activation must be one of 'relu', 'softplus'"),
        ({"field": {"widths": [1, "a"]}}, r"field.widths\[1\] expects int"),
        ({"crop": [1.0]}, r"crop expects 2 values"),
        ({"field": 3}, r"field: expected a mapping of fields, got 3"),
        ({"max_items": "many"}, r"max_items expects int or None, got 'many'"),
        ({"field": {"hidden": 0}}, r"field: hidden must be >= 1, got 0"),
        ({"training": {"steps": 0}}, r"training: steps must be a positive int, got 0"),
        ({"training": {"lr_schedule": "linear"}}, r"training.lr_schedule must be one of"),
    ],
)
def test_bad_dicts_are_refused_naming_the_key_and_the_source(data, expected):
    with pytest.raises(ValueError, match=expected) as info:
        config_from_dict(RunCfg, data, source="runs/a/config.json")
    assert str(info.value).startswith("runs/a/config.json: ")


def test_missing_key_without_default():
    @dataclass(frozen=True)
    class NeedsRoot:
        root: str
        """No default."""

    with pytest.raises(ValueError, match="missing key 'root'"):
        config_from_dict(NeedsRoot, {})


def test_load_config_names_the_file(tmp_path):
    path = tmp_path / "config.json"
    path.write_text(json.dumps({"training": {"stepz": 3}}))
    with pytest.raises(ValueError, match=rf"{path}: unknown key 'training.stepz'"):
        load_config(RunCfg, path)
    path.write_text("{not json")
    with pytest.raises(ValueError, match=rf"{path}: not valid JSON"):
        load_config(RunCfg, path)
    with pytest.raises(FileNotFoundError, match="nothing.json"):
        load_config(RunCfg, tmp_path / "nothing.json")


def test_overrides_parse_with_the_field_types():
    cfg = RunCfg()
    new = apply_overrides(cfg, [
        "training.lr=1e-4", "field.hidden=128", "field.widths=32,16,8", "field.activation=relu",
        "verbose=yes", "max_items=7", "crop=0.1, 0.9", "data_root=/x/y",
        "training.device=cuda:1", "training.betas=[0.5, 0.6]", "training.steps=1e3",
        "name=a=b",
    ])
    assert new.training.lr == 1e-4
    assert new.field.hidden == 128 and new.field.widths == (32, 16, 8)
    assert new.field.activation == "relu"
    assert new.verbose is True and new.max_items == 7 and new.crop == (0.1, 0.9)
    assert new.data_root == Path("/x/y") and new.training.device == "cuda:1"
    assert new.training.betas == (0.5, 0.6) and new.training.steps == 1000
    assert new.name == "a=b"
    assert cfg == RunCfg()  # the original is untouched
    assert apply_overrides(new, ["max_items=none"]).max_items is None
    assert apply_overrides(cfg, ["field.widths="]).field.widths == ()


def test_overrides_valid_only_together_are_applied_at_once():
    # min_radius=2 alone violates min < max (max is 1); with max_radius=3 it is fine.
    new = apply_overrides(RunCfg(), ["field.min_radius=2", "field.max_radius=3"])
    assert (new.field.min_radius, new.field.max_radius) == (2.0, 3.0)
    with pytest.raises(ValueError, match=r"field: min_radius \(2.0\) must be below max_radius"):
        apply_overrides(RunCfg(), ["field.min_radius=2"])


def test_override_with_a_json_object_merges_into_the_nested_config():
    new = apply_overrides(RunCfg(field=FieldCfg(activation="relu")), ['field={"hidden": 5}'])
    assert new.field == FieldCfg(hidden=5, activation="relu")


def test_mapping_overrides():
    new = apply_overrides(RunCfg(), {"training.lr": 1e-3, "field.hidden": "12"})
    assert new.training.lr == 1e-3 and new.field.hidden == 12
    with pytest.raises(ValueError, match="field.hidden expects int, got 1.5"):
        apply_overrides(RunCfg(), {"field.hidden": 1.5})


@pytest.mark.parametrize(
    ("override", "expected"),
    [
        ("training.lrr=1", r"unknown key 'training.lrr'; did you mean 'lr'"),
        ("training.lr=abc", r"training.lr expects float, got 'abc'"),
        ("field.hidden=1.5", r"field.hidden expects int, got '1.5'"),
        ("field.activation=tanh", r"field.activation must be one of 'relu', 'softplus'"),
        ("field.hidden=0", r"field: hidden must be >= 1, got 0"),
        ("training.steps=-5", r"training: steps must be a positive int, got -5"),
        ("training.lr=-1", r"training: lr must be a positive finite number"),
        ("verbose=maybe", r"verbose expects bool, got 'maybe'"),
        ("crop=1,2,3", r"crop expects 2 comma-separated values"),
        ("field.hidden.x=1", r"field.hidden is not a nested config"),
        ("field=3", r"field expects a JSON object"),
        ("training.betas=[0.5", r"training.betas: value '\[0.5' is not valid JSON"),
        ("lr", r"override 'lr' must look like key=value"),
        ("=3", r"empty key"),
    ],
)
def test_bad_overrides_name_the_key(override, expected):
    with pytest.raises(ValueError, match=expected):
        apply_overrides(RunCfg(), [override])


def test_duplicate_and_conflicting_overrides():
    with pytest.raises(ValueError, match="overridden twice"):
        apply_overrides(RunCfg(), ["seed=1", "seed=2"])
    with pytest.raises(ValueError, match="conflicts"):
        apply_overrides(RunCfg(), ['field={"hidden": 2}', "field.hidden=3"])


def test_parse_override_and_type_errors():
    assert parse_override(" training.lr = 1e-4 ") == ("training.lr", "1e-4")
    with pytest.raises(TypeError, match="list of 'key=value' strings"):
        apply_overrides(RunCfg(), "training.lr=1")
    with pytest.raises(TypeError, match="dataclass instance"):
        config_to_dict({"a": 1})
    with pytest.raises(TypeError, match="dataclass type"):
        config_from_dict(dict, {})


@dataclass(frozen=True)
class RenamedCfg:
    """A config that renamed two fields (one into its nested config)."""

    RENAMED: ClassVar[dict[str, str]] = {"width": "hidden_size", "field_width": "field.hidden"}
    """Former names -> present ones."""

    hidden_size: int = 8
    """Width."""
    field: FieldCfg = dc_field(default_factory=FieldCfg)
    """Network."""


@pytest.mark.parametrize(("key", "expected"), [
    ("width", "unknown key 'width': it was renamed 'hidden_size'"),
    ("field_width", "unknown key 'field_width': it was renamed 'field.hidden'"),
    ("hidden", "unknown key 'hidden'; did you mean 'field.hidden'?"),
])
def test_a_renamed_or_nested_key_is_named(key, expected):
    assert renamed_field(RenamedCfg, "width") == "hidden_size"
    assert renamed_field(RenamedCfg, "hidden_size") is None and renamed_field(RunCfg, "x") is None
    with pytest.raises(ValueError, match=re.escape(expected)):
        config_from_dict(RenamedCfg, {key: 3})
    with pytest.raises(ValueError, match=re.escape(expected)):
        apply_overrides(RenamedCfg(), [f"{key}=3"])
    # In a nested config, the renamed key's new name carries its prefix.
    with pytest.raises(ValueError, match=re.escape("'outer.width': it was renamed "
                                                   "'outer.hidden_size'")):
        apply_overrides(OuterCfg(), ["outer.width=3"])


@dataclass(frozen=True)
class OuterCfg:
    """A config holding :class:`RenamedCfg`."""

    outer: RenamedCfg = dc_field(default_factory=RenamedCfg)
    """The nested config."""
