"""``sources.json``: a frame's references to original images (the layout's one extension)."""

from __future__ import annotations

import json
import os

import numpy as np
import pytest

from lisa_hand.data.layout import FramePaths, read_image, read_sources, write_image


def test_local_files_win_and_sources_fill_in(tmp_path):
    frame = tmp_path / "s000" / "f000"
    original = tmp_path / "originals" / "a.jpg"
    original.parent.mkdir(parents=True)
    import imageio.v3 as iio

    iio.imwrite(original, np.full((4, 6, 3), 200, np.uint8), extension=".jpg")
    frame.mkdir(parents=True)
    (frame / "sources.json").write_text(json.dumps(
        {"images": {"cam0": os.path.relpath(original, frame), "cam1": str(original)},
         "masks": {}}))
    paths = FramePaths(frame)
    assert paths.image("cam0").resolve() == original.resolve()
    assert paths.image("cam1") == original  # absolute paths stay as they are
    assert read_image(paths.image("cam0")).shape == (4, 6, 3)
    assert paths.image("cam2") == frame / "images" / "cam2.png"  # not named: the usual path
    assert paths.mask("cam0") == frame / "masks" / "cam0.png"
    write_image(frame / "images" / "cam0.png", np.zeros((2, 2, 3)))
    assert paths.image("cam0") == frame / "images" / "cam0.png"  # a local file wins


def test_no_sources_and_malformed_sources(tmp_path):
    assert read_sources(tmp_path) == {}
    (tmp_path / "sources.json").write_text(json.dumps({"images": {"cam0": 3}}))
    with pytest.raises(ValueError, match=r"sources.json: 'images' must map view names"):
        read_sources(tmp_path)
