"""``keypoints.json``: the writer gives the text ``lisa synth`` has always written, the reader
reads it back, and malformed files are refused with a message naming the file and the view."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch

from lisa_hand.data.keypoints import ViewKeypoints, read_keypoints, write_keypoints
from lisa_hand.skeleton import KEYPOINT_NAMES
from lisa_hand.utils.io import write_json


def _synth_entry(seed: int) -> dict:
    """An entry as ``lisa synth`` builds it: float32 projections, some keypoints hidden."""
    rng = np.random.default_rng(seed)
    pixels = (rng.random((21, 2)) * 100.0).astype(np.float32)
    visible = rng.random(21) > 0.3
    return {"keypoints": pixels.astype(np.float64).tolist(), "visible": visible.tolist(),
            "in_image": (visible | (rng.random(21) > 0.5)).tolist(),
            "depth": (0.5 + rng.random(21)).astype(np.float32).astype(np.float64).tolist()}


def test_writer_matches_the_format_synth_writes(tmp_path):
    entries = {"cam000": _synth_entry(0), "cam001": _synth_entry(1)}
    old = write_json(tmp_path / "old.json", {"names": list(KEYPOINT_NAMES), "views": entries})
    new = write_keypoints(tmp_path / "new.json", entries)
    assert new.read_text() == old.read_text()
    arrays = {name: {key: np.asarray(value, dtype=np.float32 if key in ("keypoints", "depth")
                                     else bool) for key, value in entry.items()}
              for name, entry in entries.items()}
    assert write_keypoints(tmp_path / "arrays.json", arrays).read_text() == old.read_text()
    tensors = {name: {key: torch.from_numpy(value) for key, value in entry.items()}
               for name, entry in arrays.items()}
    assert write_keypoints(tmp_path / "tensors.json", tensors).read_text() == old.read_text()


def test_round_trip_and_names(tmp_path):
    entries = {"cam000": _synth_entry(0), "cam001": _synth_entry(1)}
    path = write_keypoints(tmp_path / "keypoints.json", entries)
    read = read_keypoints(path)
    assert list(read) == ["cam000", "cam001"]
    for name, entry in entries.items():
        assert np.array_equal(read[name].keypoints, np.asarray(entry["keypoints"]))
        assert read[name].keypoints.dtype == np.float64 and read[name].keypoints.shape == (21, 2)
        assert read[name].visible.tolist() == entry["visible"]
        assert read[name].in_image.tolist() == entry["in_image"]
        assert np.array_equal(read[name].depth, np.asarray(entry["depth"]))
    assert list(read_keypoints(path, ["cam001", "cam7"])) == ["cam001"]
    again = write_keypoints(tmp_path / "again.json", read)  # ViewKeypoints are accepted
    assert again.read_text() == path.read_text()
    minimal = write_keypoints(tmp_path / "minimal.json", {"c": ViewKeypoints(
        keypoints=np.zeros((21, 2)), visible=np.ones(21, bool))})
    assert set(json.loads(minimal.read_text())["views"]["c"]) == {"keypoints", "visible"}
    only_points = tmp_path / "only_points.json"
    only_points.write_text(json.dumps({"views": {"c": {"keypoints": [[1.0, 2.0]] * 21}}}))
    entry = read_keypoints(only_points)["c"]
    assert bool(entry.visible.all()) and entry.in_image is None and entry.depth is None


def _file(tmp_path, data) -> str:
    path = tmp_path / "keypoints.json"
    path.write_text(json.dumps(data))
    return path


@pytest.mark.parametrize("data, message", [
    ([1, 2], r"keypoints\.json: expected an object with 'views'"),
    ({"names": ["a"], "views": {}}, r"keypoints\.json: 'names' must be the 21 keypoint names"),
    ({"views": {"c": [1]}}, r"keypoints\.json: view 'c': expected an object with 'keypoints'"),
    ({"views": {"c": {"keypoints": [["x", 1]] * 21}}}, r"view 'c': keypoints must be numbers"),
    ({"views": {"c": {"keypoints": [[1, 2]] * 20}}}, r"view 'c': 'keypoints' must be \[21, 2\]"),
    ({"views": {"c": {"keypoints": [[1, 2]] * 21, "visible": [1] * 3}}},
     r"view 'c': 'visible' must be \[21\], got \[3\]"),
    ({"views": {"c": {"keypoints": [[1, 2]] * 21, "depth": [1] * 2}}},
     r"view 'c': 'depth' must be \[21\], got \[2\]"),
    ({"views": {"c": {"keypoints": [[float("nan"), 2]] + [[1, 2]] * 20}}},
     r"view 'c': visible keypoints hold NaN or inf"),
])  # fmt: skip
def test_reader_errors_name_the_file_and_view(tmp_path, data, message):
    with pytest.raises(ValueError, match=message):
        read_keypoints(_file(tmp_path, data))


def test_hidden_keypoints_may_be_anything(tmp_path):
    data = {"views": {"c": {"keypoints": [[float("inf"), 2]] + [[1, 2]] * 20,
                            "visible": [False] + [True] * 20}}}
    assert not read_keypoints(_file(tmp_path, data))["c"].visible[0]


@pytest.mark.parametrize("views, message", [
    ({"c": {"keypoints": np.zeros((21, 2))}}, r"view 'c': expected the keys .*missing: visible"),
    ({"c": {"keypoints": np.zeros((21, 2)), "visible": [True] * 21, "score": [1] * 21}},
     r"view 'c': .*unknown: score"),
    ({"c": {"keypoints": np.zeros((20, 2)), "visible": [True] * 21}},
     r"view 'c': 'keypoints' must have shape \[21, 2\], got \[20, 2\]"),
    ({"c": [1, 2]}, r"view 'c': expected a ViewKeypoints or a mapping"),
])  # fmt: skip
def test_writer_refuses_malformed_views(tmp_path, views, message):
    with pytest.raises((ValueError, TypeError), match=message):
        write_keypoints(tmp_path / "keypoints.json", views)
    assert not (tmp_path / "keypoints.json").exists()
