"""Image files of the dataset layout: one-line errors for what is not a readable image."""

import numpy as np
import pytest

from lisa_hand.data.layout import read_image, read_mask, read_npz, write_image


def test_unreadable_images_are_one_line_naming_the_file(tmp_path):
    write_image(tmp_path / "good.png", np.zeros((8, 8, 3), dtype=np.uint8))
    good = (tmp_path / "good.png").read_bytes()
    (tmp_path / "text.png").write_text("hello, not an image\n")
    (tmp_path / "empty.png").write_bytes(b"")
    (tmp_path / "cut.png").write_bytes(good[:40])
    for name in ("text.png", "empty.png", "cut.png"):
        for reader in (read_image, read_mask):
            with pytest.raises(ValueError) as info:
                reader(tmp_path / name)
            message = str(info.value)
            assert message.startswith(f"{tmp_path / name}: not a readable image"), message
            assert "\n" not in message and "pip install" not in message


def test_a_folder_is_not_a_missing_image(tmp_path):
    (tmp_path / "cam000.png").mkdir()
    (tmp_path / "scan.npz").mkdir()
    with pytest.raises(IsADirectoryError, match=r"cam000\.png: is a directory, expected a file"):
        read_image(tmp_path / "cam000.png")
    with pytest.raises(IsADirectoryError, match=r"scan\.npz: is a directory, expected a file"):
        read_npz(tmp_path / "scan.npz")
    with pytest.raises(FileNotFoundError, match=r"cam001\.png: no such file"):
        read_mask(tmp_path / "cam001.png")
