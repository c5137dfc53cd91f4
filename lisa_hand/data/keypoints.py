"""``keypoints.json``: the 2D hand keypoints of a frame's views (written by ``lisa synth``, read by
``lisa fit-images``).

The file is one JSON object:

* ``"names"``: [21] the keypoint names in OpenPose order
  (:data:`lisa_hand.skeleton.KEYPOINT_NAMES`: wrist, thumb CMC, ...). Always written; optional
  when reading, but if present it must be exactly that list.
* ``"views"``: ``{camera name: entry}``; a camera missing here has no keypoints. Each entry:

  ============  =========  ===================================================================
  key           shape      meaning
  ============  =========  ===================================================================
  ``keypoints`` [21, 2] px continuous pixel coordinates ``(u, v)``: ``u`` to the right, ``v``
                           down, pixel ``(col, row)`` covers ``[col, col + 1) x [row, row + 1)``
                           (its centre is at ``+0.5``). Values of keypoints that are not visible
                           are not used (they may be anything, even non-finite).
  ``visible``   [21] bool  which keypoints count (optional when reading: all of them). ``lisa
                           synth``: in the image and not hidden by another part of the hand.
  ``in_image``  [21] bool  optional: in front of the camera and inside the image.
  ``depth``     [21] m     optional: depth of the 3D keypoint along the camera's ``z`` axis.
  ============  =========  ===================================================================

:func:`read_keypoints` reads it (errors name the file and the view), :func:`write_keypoints`
writes it (atomically, the same text for the same values).
"""

from __future__ import annotations

import os
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ..skeleton import KEYPOINT_NAMES, NUM_KEYPOINTS
from ..utils.io import read_json, write_json

__all__ = ["ViewKeypoints", "read_keypoints", "write_keypoints"]

_ENTRY_KEYS = ("keypoints", "visible", "in_image", "depth")


@dataclass
class ViewKeypoints:
    """The keypoints of one view (see the module docstring).

    keypoints: [21, 2] float64 pixels. visible: [21] bool. in_image: [21] bool or None.
    depth: [21] float64 metres or None.
    """

    keypoints: np.ndarray
    visible: np.ndarray
    in_image: np.ndarray | None = None
    depth: np.ndarray | None = None


def read_keypoints(path: str | os.PathLike,
                   names: Sequence[str] | None = None) -> dict[str, ViewKeypoints]:
    """Read ``keypoints.json`` -> {view name: :class:`ViewKeypoints`}.

    names: the views to read (default: every view of the file); a name the file does not list
        is left out of the result (that view has no keypoints).
    Errors (ValueError naming the file and the view): not an object with ``"views"``, wrong
    ``"names"``, an entry without ``"keypoints"``, values that are not numbers, wrong shapes,
    and visible keypoints that are NaN or infinite.
    """
    path = Path(path)
    data = read_json(path)
    views = data.get("views") if isinstance(data, dict) else None
    if not isinstance(views, dict):
        raise ValueError(f"{path}: expected an object with 'views': {{name: {{'keypoints': "
                         "[21 x 2] pixels, 'visible': [21]}}}}")
    listed = data.get("names")
    if listed is not None and list(listed) != list(KEYPOINT_NAMES):
        raise ValueError(f"{path}: 'names' must be the 21 keypoint names in OpenPose order "
                         f"({', '.join(KEYPOINT_NAMES[:3])}, ...)")
    result = {}
    for name in (list(views) if names is None else names):
        entry = views.get(name)
        if entry is None:
            continue
        result[name] = _read_entry(entry, f"{path}: view {name!r}")
    return result


def _read_entry(entry: Any, where: str) -> ViewKeypoints:
    """One view's entry of ``keypoints.json`` (``where`` names the file and the view)."""
    if not isinstance(entry, dict) or "keypoints" not in entry:
        raise ValueError(f"{where}: expected an object with 'keypoints' [21, 2]")
    try:
        keypoints = np.asarray(entry["keypoints"], dtype=np.float64)
        visible_raw = entry.get("visible")
        visible = (np.ones(NUM_KEYPOINTS, dtype=bool) if visible_raw is None
                   else np.asarray(visible_raw, dtype=np.float64) > 0)
        in_image = (None if entry.get("in_image") is None
                    else np.asarray(entry["in_image"], dtype=np.float64) > 0)
        depth = (None if entry.get("depth") is None
                 else np.asarray(entry["depth"], dtype=np.float64))
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{where}: keypoints must be numbers ({exc})") from None
    if keypoints.shape != (NUM_KEYPOINTS, 2):
        raise ValueError(f"{where}: 'keypoints' must be [21, 2] pixels, got "
                         f"{list(keypoints.shape)}")
    for key, value in (("visible", visible), ("in_image", in_image), ("depth", depth)):
        if value is not None and value.shape != (NUM_KEYPOINTS,):
            raise ValueError(f"{where}: '{key}' must be [21], got {list(value.shape)}")
    if not np.isfinite(keypoints[visible]).all():
        raise ValueError(f"{where}: visible keypoints hold NaN or inf")
    return ViewKeypoints(keypoints=keypoints, visible=visible, in_image=in_image, depth=depth)


def write_keypoints(path: str | os.PathLike,
                    views: Mapping[str, ViewKeypoints | Mapping[str, Any]]) -> Path:
    """Write ``keypoints.json`` (atomic; see the module docstring) and return its path.

    views: {camera name: a :class:`ViewKeypoints`, or a mapping with ``"keypoints"`` [21, 2] px
        and ``"visible"`` [21] bool, and optionally ``"in_image"`` [21] bool and ``"depth"``
        [21] m} (numpy arrays, tensors or lists). The views keep their order; ``None``
        optional values are left out.
    """
    entries = {}
    for name, view in views.items():
        where = f"keypoints of view {name!r}"
        if isinstance(view, ViewKeypoints):
            view = {key: getattr(view, key) for key in _ENTRY_KEYS}
        if not isinstance(view, Mapping):
            raise TypeError(f"{where}: expected a ViewKeypoints or a mapping, got "
                            f"{type(view).__name__}")
        unknown = sorted(set(view) - set(_ENTRY_KEYS))
        missing = [key for key in ("keypoints", "visible") if view.get(key) is None]
        if unknown or missing:
            raise ValueError(f"{where}: expected the keys {', '.join(_ENTRY_KEYS[:2])} (and "
                             f"optionally {', '.join(_ENTRY_KEYS[2:])}); "
                             + (f"unknown: {', '.join(unknown)}" if unknown
                                else f"missing: {', '.join(missing)}"))
        entry = {}
        for key in _ENTRY_KEYS:
            if view.get(key) is None:
                continue
            kind = bool if key in ("visible", "in_image") else np.float64
            value = np.asarray(_to_numpy(view[key]), dtype=kind)
            shape = (NUM_KEYPOINTS, 2) if key == "keypoints" else (NUM_KEYPOINTS,)
            if value.shape != shape:
                raise ValueError(f"{where}: '{key}' must have shape {list(shape)}, got "
                                 f"{list(value.shape)}")
            entry[key] = value.tolist()
        entries[str(name)] = entry
    return write_json(path, {"names": list(KEYPOINT_NAMES), "views": entries})


def _to_numpy(value: Any) -> Any:
    """A tensor (any device) as a numpy array; anything else unchanged."""
    if hasattr(value, "detach") and hasattr(value, "cpu"):
        return value.detach().cpu().numpy()
    return value
