"""Config utilities: frozen dataclasses <-> JSON, dotted command-line overrides, validation.

Every config in the project is a frozen dataclass with a docstring per field. These helpers give
all of them the same behaviour without a registry or metaprogramming:

- ``config_to_dict(cfg)``: a JSON-ready dict (nested dataclasses, tuples as lists, paths as str);
- ``config_from_dict(cls, data, source=...)``: the reverse, strict: an unknown key, a missing key
  without a default or a value of the wrong type is refused with a message naming the dotted key
  (and ``source``, usually the file);
- ``apply_overrides(cfg, ["training.lr=1e-4", "field.hidden=128"])``: values are parsed with the
  field's annotated type (``int``, ``float``, ``bool``, ``str``, ``Path``, ``Literal`` choices,
  ``tuple``/``list``, ``X | None``, nested dataclasses, enums);
- ``save_config(path, cfg)`` / ``load_config(cls, path)``: atomic JSON.

A config class that renamed a field lists it in a class attribute ``RENAMED: ClassVar[dict[str,
str]] = {"old_name": "new_name"}``: the old key is refused (by ``config_from_dict`` and
``apply_overrides``) in one line naming the new one (``renamed_field``).

A config may validate itself in ``__post_init__`` and/or a ``validate()`` method that raises
``ValueError`` naming the field; both helpers run them and prefix the message with the dotted
path of the config (``training: lr must be > 0, got -1.0``).
"""

from __future__ import annotations

import dataclasses
import difflib
import enum
import json
import os
import types
import typing
from collections.abc import Iterable, Mapping
from pathlib import Path, PurePath
from typing import Any, TypeVar

from .io import read_json, write_json

__all__ = [
    "check_int_fields",
    "config_to_dict",
    "config_from_dict",
    "apply_overrides",
    "parse_override",
    "renamed_field",
    "save_config",
    "load_config",
]

T = TypeVar("T")

_TRUE = ("true", "yes", "on", "1")
_FALSE = ("false", "no", "off", "0")
_NONE = ("none", "null")


class _ConfigError(ValueError):
    """Internal: a conversion error whose message already names the key."""


# ------------------------------------------------------------------------------------------------
# to dict


def config_to_dict(cfg: Any) -> dict[str, Any]:
    """Return a JSON-ready dict of the dataclass ``cfg`` (recursively).

    Nested dataclasses become dicts, tuples and lists become lists, paths become strings, enums
    their values. Field order is kept.
    """
    if not dataclasses.is_dataclass(cfg) or isinstance(cfg, type):
        raise TypeError(f"cfg must be a dataclass instance, got {type(cfg).__name__}")
    return _to_plain(cfg)


def _to_plain(value: Any) -> Any:
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return {f.name: _to_plain(getattr(value, f.name)) for f in dataclasses.fields(value)}
    if isinstance(value, enum.Enum):
        return _to_plain(value.value)
    if isinstance(value, PurePath):
        return str(value)
    if isinstance(value, Mapping):
        return {str(k): _to_plain(v) for k, v in value.items()}
    if isinstance(value, (tuple, list)):
        return [_to_plain(v) for v in value]
    if value is None or isinstance(value, (bool, int, float, str)):
        return value
    raise TypeError(f"cannot serialise a config value of type {type(value).__name__}: {value!r}")


# ------------------------------------------------------------------------------------------------
# from dict


def config_from_dict(cls: type[T], data: Mapping[str, Any], source: str | None = None) -> T:
    """Build the dataclass ``cls`` from ``data`` (as written by ``config_to_dict``).

    Missing keys take the field defaults. An unknown key, a missing key without a default, a value
    of the wrong type or a value refused by the config's own checks (``__post_init__`` /
    ``validate()``) raises ``ValueError`` naming the dotted key and ``source`` (e.g. the file).
    """
    if not (isinstance(cls, type) and dataclasses.is_dataclass(cls)):
        raise TypeError(f"cls must be a dataclass type, got {cls!r}")
    try:
        return _build(cls, data, prefix="")
    except _ConfigError as exc:
        raise ValueError(_with_source(source, str(exc))) from None


def _with_source(source: str | os.PathLike | None, message: str) -> str:
    return f"{source}: {message}" if source else message


def _key(prefix: str, name: str) -> str:
    return f"{prefix}.{name}" if prefix else name


def _type_hints(cls: type) -> dict[str, Any]:
    try:
        return typing.get_type_hints(cls)
    except Exception as exc:  # unresolvable annotation: a bug in the config class itself
        raise TypeError(f"cannot resolve the field types of {cls.__name__}: {exc}") from exc


def renamed_field(cls: type, name: str) -> str | None:
    """The field that ``cls``'s former field ``name`` is now (dotted for a nested config's
    field), or None: a config class lists its renamed fields in a class attribute
    ``RENAMED: ClassVar[dict[str, str]] = {"old_name": "new_name"}``."""
    renamed = getattr(cls, "RENAMED", None)
    if isinstance(renamed, Mapping):
        new = renamed.get(name)
        if isinstance(new, str):
            return new
    return None


def _unknown_key_message(key: str, name: str, cls: type) -> str:
    """One line for the unknown key ``key`` (its last part ``name``) of the config ``cls``: the
    new name of a renamed field, else the nearest field (or a nested config's field of that
    name) and the known ones."""
    stem = key[: len(key) - len(name)]
    new = renamed_field(cls, name)
    if new is not None:
        return f"unknown key {key!r}: it was renamed {stem + new!r}"
    known = [f.name for f in dataclasses.fields(cls) if f.init]
    hints = _type_hints(cls)
    nested = [f"{stem}{f}.{name}" for f in known
              if isinstance(hints.get(f), type) and dataclasses.is_dataclass(hints[f])
              and name in {g.name for g in dataclasses.fields(hints[f]) if g.init}]
    close = nested[:1] or difflib.get_close_matches(name, known, n=1)
    hint = f"; did you mean {close[0]!r}?" if close else ""
    return f"unknown key {key!r}{hint} (known keys here: {', '.join(known)})"


def _build(cls: type[T], data: Any, prefix: str) -> T:
    where = prefix or cls.__name__
    if not isinstance(data, Mapping):
        raise _ConfigError(f"{where}: expected a mapping of fields, got {_describe(data)}")
    fields = {f.name: f for f in dataclasses.fields(cls) if f.init}
    hints = _type_hints(cls)
    for name in data:
        if name not in fields:
            raise _ConfigError(_unknown_key_message(_key(prefix, str(name)), str(name), cls))
    kwargs = {}
    for name, field in fields.items():
        key = _key(prefix, name)
        if name in data:
            kwargs[name] = _coerce(data[name], hints[name], key)
        elif (field.default is dataclasses.MISSING
              and field.default_factory is dataclasses.MISSING):
            raise _ConfigError(f"missing key {key!r} (it has no default)")
    return _construct(cls, kwargs, prefix)


def _construct(cls: type[T], kwargs: dict[str, Any], prefix: str, base: Any = None) -> T:
    """Instantiate (or ``replace`` ``base``) and run ``validate()``; errors name the config."""
    try:
        obj = cls(**kwargs) if base is None else dataclasses.replace(base, **kwargs)
        validate = getattr(obj, "validate", None)
        if callable(validate):
            validate()
    except (ValueError, TypeError) as exc:
        where = prefix or cls.__name__
        raise _ConfigError(f"{where}: {exc}") from None
    return obj


def _describe(value: Any) -> str:
    return f"{value!r} ({type(value).__name__})"


def _type_name(tp: Any) -> str:
    if tp is type(None):
        return "None"
    origin = typing.get_origin(tp)
    if origin is typing.Literal:
        return "one of " + ", ".join(repr(c) for c in typing.get_args(tp))
    if origin in (typing.Union, types.UnionType):
        return " or ".join(_type_name(a) for a in typing.get_args(tp))
    if origin is not None:
        args = ", ".join("..." if a is Ellipsis else _type_name(a) for a in typing.get_args(tp))
        return f"{origin.__name__}[{args}]"
    return getattr(tp, "__name__", repr(tp))


def _coerce(value: Any, tp: Any, key: str) -> Any:
    """Convert a JSON-like ``value`` to the annotated type ``tp`` or raise naming ``key``."""
    if tp is Any:
        return value
    origin = typing.get_origin(tp)
    args = typing.get_args(tp)
    if origin in (typing.Union, types.UnionType):
        if value is None and type(None) in args:
            return None
        for arg in args:
            if arg is type(None):
                continue
            try:
                return _coerce(value, arg, key)
            except _ConfigError:
                continue
        raise _ConfigError(f"{key} expects {_type_name(tp)}, got {_describe(value)}")
    if origin is typing.Literal:
        for choice in args:
            if type(choice) is type(value) and choice == value:
                return choice
        raise _ConfigError(f"{key} must be {_type_name(tp)}, got {_describe(value)}")
    if origin in (tuple, list):
        if not isinstance(value, (list, tuple)):
            raise _ConfigError(f"{key} expects a {_type_name(tp)}, got {_describe(value)}")
        if origin is tuple and args and not (len(args) == 2 and args[1] is Ellipsis):
            if len(value) != len(args):
                raise _ConfigError(
                    f"{key} expects {len(args)} values ({_type_name(tp)}), got {len(value)}")
            items = [_coerce(v, a, f"{key}[{i}]")
                     for i, (v, a) in enumerate(zip(value, args, strict=True))]
        else:
            item_tp = args[0] if args else Any
            items = [_coerce(v, item_tp, f"{key}[{i}]") for i, v in enumerate(value)]
        return tuple(items) if origin is tuple else items
    if origin in (dict, Mapping):
        if not isinstance(value, Mapping):
            raise _ConfigError(f"{key} expects a mapping, got {_describe(value)}")
        value_tp = args[1] if len(args) == 2 else Any
        return {str(k): _coerce(v, value_tp, f"{key}.{k}") for k, v in value.items()}
    if origin is not None:
        raise TypeError(f"{key}: unsupported config field type {_type_name(tp)}")
    if isinstance(tp, type) and dataclasses.is_dataclass(tp):
        if isinstance(value, tp):
            return value
        return _build(tp, value, prefix=key)
    if tp is bool:
        if isinstance(value, bool):
            return value
    elif tp is int:
        if isinstance(value, int) and not isinstance(value, bool):
            return value
    elif tp is float:
        if isinstance(value, (int, float)) and not isinstance(value, bool):
            return float(value)
    elif tp is str:
        if isinstance(value, str):
            return value
    elif isinstance(tp, type) and issubclass(tp, PurePath):
        if isinstance(value, (str, PurePath)):
            return tp(value)
    elif isinstance(tp, type) and issubclass(tp, enum.Enum):
        for member in tp:
            if value == member.value or value == member.name or value is member:
                return member
        choices = ", ".join(repr(m.value) for m in tp)
        raise _ConfigError(f"{key} must be one of {choices}, got {_describe(value)}")
    elif isinstance(tp, type):
        if isinstance(value, tp):
            return value
    else:
        raise TypeError(f"{key}: unsupported config field type {tp!r}")
    raise _ConfigError(f"{key} expects {_type_name(tp)}, got {_describe(value)}")


# ------------------------------------------------------------------------------------------------
# overrides


def parse_override(text: str) -> tuple[str, str]:
    """Split ``"training.lr=1e-4"`` into ``("training.lr", "1e-4")``."""
    if not isinstance(text, str) or "=" not in text:
        raise ValueError(f"override {text!r} must look like key=value (e.g. training.lr=1e-4)")
    key, value = text.split("=", 1)
    key = key.strip()
    if not key or any(not part for part in key.split(".")):
        raise ValueError(f"override {text!r}: empty key")
    return key, value.strip()


def _parse_string(text: str, tp: Any, key: str) -> Any:
    """Parse the command-line string ``text`` as the annotated type ``tp``."""
    if tp is Any:
        return text
    origin = typing.get_origin(tp)
    args = typing.get_args(tp)
    if origin in (typing.Union, types.UnionType):
        if type(None) in args and text.lower() in _NONE:
            return None
        non_none = [a for a in args if a is not type(None)]
        for arg in non_none:
            try:
                return _parse_string(text, arg, key)
            except _ConfigError:
                continue
        raise _ConfigError(f"{key} expects {_type_name(tp)}, got {text!r}")
    if origin is typing.Literal:
        for choice in args:
            if str(choice) == text or (isinstance(choice, bool)
                                       and text.lower() == str(choice).lower()):
                return choice
        raise _ConfigError(f"{key} must be {_type_name(tp)}, got {text!r}")
    container = origin in (tuple, list, dict, Mapping) or (
        isinstance(tp, type) and dataclasses.is_dataclass(tp))
    if container:
        stripped = text.strip()
        if stripped[:1] in ("[", "{"):
            try:
                return _coerce(json.loads(stripped), tp, key)
            except json.JSONDecodeError as exc:
                raise _ConfigError(f"{key}: value {text!r} is not valid JSON ({exc})") from None
        if origin in (tuple, list):
            stripped = stripped.strip("()")
            parts = [p.strip() for p in stripped.split(",")] if stripped else []
            if parts and parts[-1] == "":  # a trailing comma: "1,"
                parts = parts[:-1]
            fixed = origin is tuple and args and not (len(args) == 2 and args[1] is Ellipsis)
            if fixed:
                if len(parts) != len(args):
                    raise _ConfigError(
                        f"{key} expects {len(args)} comma-separated values ({_type_name(tp)}), "
                        f"got {text!r}")
                items = [_parse_string(p, a, f"{key}[{i}]")
                         for i, (p, a) in enumerate(zip(parts, args, strict=True))]
            else:
                item_tp = args[0] if args else str
                items = [_parse_string(p, item_tp, f"{key}[{i}]") for i, p in enumerate(parts)]
            return tuple(items) if origin is tuple else items
        raise _ConfigError(f"{key} expects a JSON object, got {text!r}")
    if tp is bool:
        low = text.lower()
        if low in _TRUE:
            return True
        if low in _FALSE:
            return False
    elif tp is int:
        try:
            return int(text.replace("_", ""))
        except ValueError:
            try:
                as_float = float(text)
            except ValueError:
                as_float = None
            if as_float is not None and as_float.is_integer():
                return int(as_float)
    elif tp is float:
        try:
            return float(text.replace("_", ""))
        except ValueError:
            pass
    elif tp is str:
        return text
    elif isinstance(tp, type) and issubclass(tp, PurePath):
        return tp(text)
    elif isinstance(tp, type) and issubclass(tp, enum.Enum):
        for member in tp:
            if text in (member.name, str(member.value)):
                return member
        choices = ", ".join(repr(m.value) for m in tp)
        raise _ConfigError(f"{key} must be one of {choices}, got {text!r}")
    else:
        raise TypeError(f"{key}: unsupported config field type {_type_name(tp)}")
    raise _ConfigError(f"{key} expects {_type_name(tp)}, got {text!r}")


def apply_overrides(cfg: T, overrides: Iterable[str] | Mapping[str, Any]) -> T:
    """Return a copy of the dataclass ``cfg`` with dotted-key overrides applied.

    ``overrides`` is a list of ``"key=value"`` strings (``["training.lr=1e-4", "seed=3"]``) or a
    mapping ``{"training.lr": 1e-4}``. String values are parsed with the field's type: numbers,
    booleans (true/false/yes/no/1/0), ``none`` for optional fields, ``Literal`` choices,
    comma-separated or JSON lists for tuples, a JSON object for a nested config (merged into the
    current value). Non-string mapping values are checked like JSON values. The result is built
    once per changed (nested) config, so overrides that are only valid together are accepted,
    and then validated (``__post_init__`` and ``validate()``). Errors name the key.
    """
    if not dataclasses.is_dataclass(cfg) or isinstance(cfg, type):
        raise TypeError(f"cfg must be a dataclass instance, got {type(cfg).__name__}")
    if isinstance(overrides, Mapping):
        items = [(str(k), v) for k, v in overrides.items()]
    elif isinstance(overrides, str):
        raise TypeError("overrides must be a list of 'key=value' strings, not one string")
    else:
        items = [parse_override(text) for text in overrides]
    if not items:
        return cfg
    tree: dict[str, Any] = {}
    for key, value in items:
        node = tree
        parts = key.split(".")
        for part in parts[:-1]:
            child = node.setdefault(part, {})
            if not isinstance(child, dict):
                raise ValueError(f"override {key!r} conflicts with another override of "
                                 f"{part!r}")
            node = child
        if parts[-1] in node:
            raise ValueError(f"key {key!r} is overridden twice")
        node[parts[-1]] = (_LEAF, value)
    try:
        return _apply(cfg, tree, prefix="")
    except _ConfigError as exc:
        keys = ", ".join(k for k, _ in items)
        raise ValueError(f"override ({keys}): {exc}") from None


_LEAF = object()


def _apply(cfg: Any, tree: dict[str, Any], prefix: str) -> Any:
    cls = type(cfg)
    fields = {f.name: f for f in dataclasses.fields(cls) if f.init}
    hints = _type_hints(cls)
    changes = {}
    for name, sub in tree.items():
        key = _key(prefix, name)
        if name not in fields:
            raise _ConfigError(_unknown_key_message(key, name, cls))
        tp = hints[name]
        current = getattr(cfg, name)
        if isinstance(sub, tuple) and sub and sub[0] is _LEAF:
            value = sub[1]
            nested = dataclasses.is_dataclass(current) and not isinstance(current, type)
            if isinstance(value, str) and nested and value.strip()[:1] == "{":
                try:
                    patch = json.loads(value)
                except json.JSONDecodeError as exc:
                    raise _ConfigError(f"{key}: value {value!r} is not valid JSON ({exc})") \
                        from None
                value = patch
            if nested and isinstance(value, Mapping):
                merged = {**config_to_dict(current), **value}
                changes[name] = _build(type(current), merged, prefix=key)
            elif isinstance(value, str):
                changes[name] = _parse_string(value, tp, key)
            else:
                changes[name] = _coerce(value, tp, key)
        else:
            if not (dataclasses.is_dataclass(current) and not isinstance(current, type)):
                raise _ConfigError(f"{key} is not a nested config (it is {_type_name(tp)}), "
                                   f"so {key}.<field> cannot be set")
            changes[name] = _apply(current, sub, key)
    return _construct(cls, changes, prefix, base=cfg)


# ------------------------------------------------------------------------------------------------
# files


def save_config(path: str | os.PathLike, cfg: Any) -> Path:
    """Write the dataclass ``cfg`` as JSON to ``path`` atomically; return the path."""
    return write_json(path, config_to_dict(cfg))


def load_config(cls: type[T], path: str | os.PathLike) -> T:
    """Read a config written by ``save_config``; errors name the file and the key."""
    return config_from_dict(cls, read_json(path), source=str(path))


def check_int_fields(config: Any, names: Iterable[str], minimum: int) -> None:
    """Raise ValueError naming the first of ``config``'s fields ``names`` that is not an int
    (bools excluded) of at least ``minimum``; for the ``__post_init__`` of typed configs."""
    for name in names:
        value = getattr(config, name)
        if isinstance(value, bool) or not isinstance(value, int) or value < minimum:
            raise ValueError(f"{name} must be an int >= {minimum}, got {value!r}")
