"""Photos in (lisa_hand.data.photo): every kind of file a user may hand over, written by the test,
and the camera of an uncalibrated photo checked against closed forms."""

from __future__ import annotations

import json
import math
import struct
import zlib
from pathlib import Path

import numpy as np
import pytest
import torch
from PIL import Image

from lisa_hand.data.photo import (
    DEFAULT_FOV_DEG,
    FILM_DIAGONAL_MM,
    Photo,
    exif_focal_35mm,
    photo_camera,
    read_photo,
    save_camera,
)
from lisa_hand.geometry.cameras import load_cameras
from tests.assets import PHOTOS


def gradient(width: int, height: int) -> np.ndarray:
    """[H, W, 3] uint8: red grows to the right, green downwards, blue constant 64."""
    pixels = np.empty((height, width, 3), np.uint8)
    pixels[..., 0] = np.linspace(0, 255, width).round().astype(np.uint8)[None, :]
    pixels[..., 1] = np.linspace(0, 255, height).round().astype(np.uint8)[:, None]
    pixels[..., 2] = 64
    return pixels


def png16(path: Path, pixels: np.ndarray) -> Path:
    """Write [H, W, 3 or 4] uint16 as a 16-bit PNG by hand (Pillow cannot write 48-bit RGB)."""
    height, width, channels = pixels.shape
    rows = b"".join(b"\x00" + pixels[y].astype(">u2").tobytes() for y in range(height))

    def chunk(kind: bytes, data: bytes) -> bytes:
        crc = zlib.crc32(kind + data) & 0xFFFFFFFF
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", crc)

    color_type = 2 if channels == 3 else 6
    header = struct.pack(">IIBBBBB", width, height, 16, color_type, 0, 0, 0)
    path.write_bytes(b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", header)
                     + chunk(b"IDAT", zlib.compress(rows)) + chunk(b"IEND", b""))
    return path


def jpeg_with_exif(path: Path, size: tuple[int, int], **tags) -> Path:
    """A JPEG whose EXIF holds ``orientation`` (IFD0) and the given Exif sub-IFD tags."""
    exif = Image.Exif()
    if "orientation" in tags:
        exif[0x0112] = tags.pop("orientation")
    sub_ifd = exif.get_ifd(0x8769)
    for tag, value in tags.items():
        sub_ifd[int(tag.lstrip("t"))] = value
    Image.fromarray(gradient(*size)).save(path, quality=95, exif=exif.tobytes())
    return path


# --- reading --------------------------------------------------------------------------------


def test_plain_rgb_jpeg(tmp_path):
    pixels = gradient(64, 48)
    Image.fromarray(pixels).save(tmp_path / "hand.jpg", quality=98)
    photo = read_photo(tmp_path / "hand.jpg")
    assert isinstance(photo, Photo)
    assert photo.image.shape == (48, 64, 3) and photo.image.dtype == np.float32
    assert photo.original_size == (64, 48) and photo.size == (64, 48)
    assert photo.scale == 1.0 and photo.focal_35mm is None and photo.notes == ()
    # JPEG at quality 98 on a smooth gradient: within a few grey levels.
    assert np.abs(photo.image * 255 - pixels).max() < 6


def test_png_exact_values(tmp_path):
    pixels = gradient(30, 20)
    Image.fromarray(pixels).save(tmp_path / "hand.png")
    photo = read_photo(tmp_path / "hand.png")
    np.testing.assert_array_equal(photo.image, pixels.astype(np.float32) / 255.0)
    assert photo.notes == ()


def test_not_an_image(tmp_path):
    path = tmp_path / "hand.jpg"
    path.write_text("this is a text file, not a photo\n")
    with pytest.raises(ValueError, match=r"hand\.jpg: not an image file") as info:
        read_photo(path)
    assert "\n" not in str(info.value)


def test_heic_photo_named(tmp_path):
    path = tmp_path / "IMG_0001.HEIC"
    path.write_bytes(b"\x00\x00\x00\x18ftypheic\x00\x00\x00\x00mif1heic" + bytes(64))
    with pytest.raises(ValueError, match=r"IMG_0001\.HEIC: an HEIC/HEIF photo \(heic\), which "
                                         r"Pillow cannot read; export it as JPEG or PNG"):
        read_photo(path)


def test_truncated_jpeg(tmp_path):
    rng = np.random.default_rng(0)
    full = tmp_path / "full.jpg"
    Image.fromarray(rng.integers(0, 256, (120, 160, 3), dtype=np.uint8)).save(full)
    cut = tmp_path / "cut.jpg"
    cut.write_bytes(full.read_bytes()[: full.stat().st_size // 2])
    with pytest.raises(ValueError, match=r"cut\.jpg: truncated or corrupt image file"):
        read_photo(cut)


def test_truncated_png(tmp_path):
    full = tmp_path / "full.png"
    rng = np.random.default_rng(1)
    Image.fromarray(rng.integers(0, 256, (120, 160, 3), dtype=np.uint8)).save(full)
    cut = tmp_path / "cut.png"
    cut.write_bytes(full.read_bytes()[: full.stat().st_size // 2])
    with pytest.raises(ValueError, match=r"cut\.png: truncated or corrupt image file"):
        read_photo(cut)


def test_missing_file_and_folder(tmp_path):
    with pytest.raises(FileNotFoundError, match=r"nope\.jpg: no such file"):
        read_photo(tmp_path / "nope.jpg")
    (tmp_path / "photos.jpg").mkdir()
    with pytest.raises(IsADirectoryError, match=r"photos\.jpg: is a directory"):
        read_photo(tmp_path / "photos.jpg")


def test_cmyk_jpeg(tmp_path):
    # Pure cyan ink (C = 255) is RGB (0, 255, 255) in Pillow's profile-free conversion.
    Image.new("CMYK", (32, 24), (255, 0, 0, 0)).save(tmp_path / "print.jpg", quality=98)
    photo = read_photo(tmp_path / "print.jpg")
    assert photo.image.shape == (24, 32, 3)
    np.testing.assert_allclose(photo.image.mean(axis=(0, 1)), [0.0, 1.0, 1.0], atol=0.02)
    assert any("CMYK converted to RGB" in note for note in photo.notes)


def test_16bit_grey_png_keeps_16_bits(tmp_path):
    values = np.array([[0, 1, 257, 32768, 65535]], dtype=np.uint16).repeat(3, 0)
    Image.fromarray(values).save(tmp_path / "grey16.png")
    photo = read_photo(tmp_path / "grey16.png")
    expected = values.astype(np.float32) / 65535.0
    for channel in range(3):
        np.testing.assert_allclose(photo.image[..., channel], expected, rtol=0, atol=1e-7)
    assert photo.image[0, 1, 0] > 0  # the value 1 of 65535 survives: 16 bits kept
    assert any("16-bit greyscale" in note for note in photo.notes)
    assert any("greyscale: replicated" in note for note in photo.notes)


def test_16bit_rgb_png(tmp_path):
    pixels = np.zeros((6, 10, 3), np.uint16)
    pixels[..., 0], pixels[..., 1], pixels[..., 2] = 65535, 32896, 0  # 32896 = 128 * 257
    photo = read_photo(png16(tmp_path / "rgb16.png", pixels))
    np.testing.assert_allclose(photo.image[0, 0], [1.0, 128 / 255, 0.0], atol=1e-6)
    assert any("16-bit PNG" in note for note in photo.notes)


def test_16bit_rgba_png(tmp_path):
    pixels = np.zeros((4, 4, 4), np.uint16)
    pixels[..., 1], pixels[..., 3] = 65535, 65535
    pixels[0, 0, 3] = 0  # one transparent pixel of 16
    photo = read_photo(png16(tmp_path / "rgba16.png", pixels))
    np.testing.assert_allclose(photo.image[1, 1], [0.0, 1.0, 0.0], atol=1e-6)
    assert any("alpha channel dropped (6% of the pixels" in note for note in photo.notes)
    assert any("16-bit PNG" in note for note in photo.notes)


def test_rgba_png_drops_alpha_keeps_colours(tmp_path):
    rgba = np.zeros((10, 20, 4), np.uint8)
    rgba[..., :3] = (200, 100, 50)
    rgba[..., 3] = 255
    rgba[:, :5, 3] = 0  # a transparent quarter whose stored colour is black
    rgba[:, :5, :3] = 0
    Image.fromarray(rgba).save(tmp_path / "cutout.png")
    photo = read_photo(tmp_path / "cutout.png")
    assert photo.image.shape == (10, 20, 3)
    np.testing.assert_allclose(photo.image[0, 10], np.array([200, 100, 50]) / 255, atol=1e-7)
    np.testing.assert_array_equal(photo.image[:, :5], 0.0)  # not composited over white
    assert "alpha channel dropped (25% of the pixels not opaque; their stored colour kept)" in \
        photo.notes


def test_palette_png_with_transparency(tmp_path):
    pal = Image.new("P", (8, 8), 1)
    pal.putpalette([0, 0, 0, 10, 200, 30] + [0] * 762)
    pal.info["transparency"] = 0
    pal.save(tmp_path / "palette.png", transparency=0)
    photo = read_photo(tmp_path / "palette.png")
    np.testing.assert_allclose(photo.image[3, 3], np.array([10, 200, 30]) / 255, atol=1e-7)
    assert any("alpha channel dropped (0% of the pixels" in note for note in photo.notes)


@pytest.mark.parametrize("mode", ["L", "LA", "1"])
def test_greyscale_replicated(tmp_path, mode):
    grey = np.tile(np.arange(0, 256, 16, dtype=np.uint8), (4, 1))
    image = Image.fromarray(grey).convert(mode)
    image.save(tmp_path / "grey.png")
    photo = read_photo(tmp_path / "grey.png")
    assert photo.image.shape == (4, 16, 3)
    np.testing.assert_array_equal(photo.image[..., 0], photo.image[..., 2])
    expected = np.asarray(image.convert("L"), np.float32) / 255
    np.testing.assert_allclose(photo.image[..., 1], expected, atol=1e-7)
    assert "greyscale: replicated to RGB" in photo.notes


def test_greyscale_jpeg(tmp_path):
    Image.fromarray(np.full((12, 16), 128, np.uint8)).save(tmp_path / "grey.jpg", quality=98)
    photo = read_photo(tmp_path / "grey.jpg")
    np.testing.assert_allclose(photo.image, 128 / 255, atol=2 / 255)
    assert "greyscale: replicated to RGB" in photo.notes


def test_huge_jpeg_downscaled(tmp_path):
    """A 24 MP photo (6000 x 4000) comes back at 1600 x 1067, original size and scale kept."""
    Image.fromarray(gradient(6000, 4000)).save(tmp_path / "huge.jpg", quality=90)
    photo = read_photo(tmp_path / "huge.jpg")
    assert photo.image.shape == (1067, 1600, 3)
    assert photo.original_size == (6000, 4000)
    assert photo.scale == pytest.approx(1600 / 6000)
    assert "downscaled from 6000x4000 to 1600x1067 (scale 0.2667); reports are in original " \
        "pixels" in photo.notes
    # The gradient survives: red at column u is about 255 * u / W (in original pixels).
    u = np.array([100, 800, 1500])
    expected_red = 255 * ((u + 0.5) / photo.scale - 0.5) / 5999
    np.testing.assert_allclose(photo.image[500, u, 0] * 255, expected_red, atol=3)


def test_max_side_png(tmp_path):
    Image.fromarray(gradient(300, 100)).save(tmp_path / "wide.png")
    photo = read_photo(tmp_path / "wide.png", max_side=60)
    assert photo.image.shape == (20, 60, 3) and photo.scale == pytest.approx(0.2)
    assert photo.original_size == (300, 100)
    with pytest.raises(ValueError, match="max_side"):
        read_photo(tmp_path / "wide.png", max_side=0)


@pytest.mark.parametrize("orientation, shape, corner", [
    (1, (48, 64), (0, 0)),      # as stored: the dark corner (red 0, green 0) stays top left
    (3, (48, 64), (-1, -1)),    # rotated 180: it goes to the bottom right
    (6, (64, 48), (0, -1)),     # shown rotated 90 clockwise: top right
    (8, (64, 48), (-1, 0)),     # 90 counter-clockwise: bottom left
    (2, (48, 64), (0, -1)),     # mirrored: top right
])
def test_exif_orientation_applied(tmp_path, orientation, shape, corner):
    path = jpeg_with_exif(tmp_path / "phone.jpg", (64, 48), orientation=orientation)
    photo = read_photo(path)
    assert photo.image.shape[:2] == shape
    assert photo.original_size == (shape[1], shape[0])
    brightness = photo.image[..., :2].sum(-1)
    darkest = np.unravel_index(np.argmin(brightness), brightness.shape)
    expected = tuple(c % n for c, n in zip(corner, shape, strict=True))
    assert darkest == expected
    if orientation == 1:
        assert photo.notes == ()
    else:
        assert photo.notes[0].startswith(f"EXIF orientation {orientation} applied")


def test_exif_orientation_before_downscale(tmp_path):
    path = jpeg_with_exif(tmp_path / "portrait.jpg", (400, 300), orientation=6)
    photo = read_photo(path, max_side=100)
    assert photo.original_size == (300, 400) and photo.image.shape == (100, 75, 3)


def test_exif_focal_35mm_tag(tmp_path):
    path = jpeg_with_exif(tmp_path / "phone.jpg", (64, 48), t41989=26, t37386=4.25)
    assert read_photo(path).focal_35mm == 26.0


def test_exif_focal_from_sensor(tmp_path):
    """FocalLength 4.25 mm on a phone sensor of 4000 x 3000 pixels of 1.4 um (7142.857 px/cm):
    5.6 x 4.2 mm, diagonal 7 mm -> f35 = 4.25 * 43.27 / 7 = 26.27 mm."""
    path = jpeg_with_exif(tmp_path / "cam.jpg", (64, 48), t37386=4.25, t41486=1e4 / 1.4,
                          t41487=1e4 / 1.4, t41488=3, t40962=4000, t40963=3000)
    assert read_photo(path).focal_35mm == pytest.approx(4.25 * FILM_DIAGONAL_MM / 7.0, rel=1e-5)


def test_exif_focal_sensor_from_image_size():
    # No PixelX/YDimension: the stored size is the sensor's pixel count; inch is the default.
    ifd = {37386: 50.0, 41486: 25.4 * 100}  # 100 px/mm: 3600 x 2400 px is 36 x 24 mm
    assert exif_focal_35mm(ifd, (3600, 2400)) == pytest.approx(50.0)


def test_exif_focal_missing_or_broken():
    assert exif_focal_35mm({}, (64, 48)) is None
    assert exif_focal_35mm({37386: 4.25}, (64, 48)) is None  # no sensor size
    assert exif_focal_35mm({41989: 0, 37386: 4.25}, (64, 48)) is None
    assert exif_focal_35mm({37386: 4.25, 41486: 1000.0, 41488: 1}, (64, 48)) is None  # no unit
    assert exif_focal_35mm({41989: (52, 2)}, (64, 48)) == 26.0


def test_exif_focal_present_but_unusable_noted(tmp_path):
    path = jpeg_with_exif(tmp_path / "cam.jpg", (64, 48), t37386=4.25)
    photo = read_photo(path)
    assert photo.focal_35mm is None
    assert any("EXIF focal length present but unusable" in note for note in photo.notes)


def test_real_photos():
    photo = read_photo(PHOTOS / "thumbs-up.png")
    assert photo.original_size == (1920, 1280) and photo.image.shape == (1067, 1600, 3)
    assert photo.scale == pytest.approx(1600 / 1920)
    assert any(note.startswith("alpha channel dropped") for note in photo.notes)
    small = read_photo(PHOTOS / "hand_thumb_up.jpg")
    assert small.original_size == (640, 521) and small.scale == 1.0 and small.notes == ()


# --- cameras --------------------------------------------------------------------------------


def make_photo(size=(800, 600), original=(4000, 3000), focal_35mm=None) -> Photo:
    image = np.zeros((size[1], size[0], 3), np.float32)
    return Photo(path=Path("/photos/IMG_0001.jpg"), image=image, original_size=original,
                 scale=size[0] / original[0], focal_35mm=focal_35mm)


def test_camera_default_fov():
    camera, source = photo_camera(make_photo())
    assert source == "default"
    focal = 400.0 / math.tan(math.radians(DEFAULT_FOV_DEG) / 2)  # long side 800 px
    np.testing.assert_allclose(camera.K.numpy(), [[focal, 0, 400], [0, focal, 300], [0, 0, 1]],
                               rtol=1e-6)
    assert (camera.width, camera.height, camera.name) == (800, 600, "IMG_0001")
    assert torch.equal(camera.R, torch.eye(3)) and torch.equal(camera.t, torch.zeros(3))
    # A 26 mm equivalent on a 4:3 frame, converted along the diagonal, is within 1% of it.
    exif_camera, _ = photo_camera(make_photo(focal_35mm=26.0))
    assert float(exif_camera.K[0, 0]) == pytest.approx(focal, rel=0.01)


def test_camera_default_portrait_same_focal():
    landscape, _ = photo_camera(make_photo())
    portrait, _ = photo_camera(make_photo(size=(600, 800), original=(3000, 4000)))
    assert float(portrait.K[0, 0]) == pytest.approx(float(landscape.K[0, 0]))
    assert portrait.K[0, 2] == 300 and portrait.K[1, 2] == 400


def test_camera_exif_diagonal():
    camera, source = photo_camera(make_photo(focal_35mm=26.0))
    assert source == "exif"
    # f_px = f35 * hypot(W, H) / 43.27 in original pixels, times the scale 0.2.
    expected = 26.0 * 5000.0 / FILM_DIAGONAL_MM * 0.2
    assert float(camera.K[0, 0]) == pytest.approx(expected, rel=1e-6)
    assert float(camera.K[1, 1]) == pytest.approx(expected, rel=1e-6)
    # 3:2 photo: the same as the width-based f35 / 36 * W.
    camera, _ = photo_camera(make_photo(size=(600, 400), original=(6000, 4000), focal_35mm=50.0))
    assert float(camera.K[0, 0]) == pytest.approx(50.0 / 36.0 * 600, rel=1e-6)


def test_camera_focal_px_in_original_pixels():
    camera, source = photo_camera(make_photo(focal_35mm=26.0), focal_px=3200.0, fov_deg=50.0)
    assert source == "focal-px"
    assert float(camera.K[0, 0]) == pytest.approx(640.0) and float(camera.K[1, 1]) == 640.0
    for bad in (0.0, -5.0, float("nan"), "x"):
        with pytest.raises(ValueError, match="focal_px"):
            photo_camera(make_photo(), focal_px=bad)


def test_camera_fov_long_side():
    camera, source = photo_camera(make_photo(focal_35mm=26.0), fov_deg=90.0)
    assert source == "fov"
    assert float(camera.K[0, 0]) == pytest.approx(400.0)  # tan(45) = 1: half the long side
    portrait, _ = photo_camera(make_photo(size=(600, 800), original=(3000, 4000)), fov_deg=90.0)
    assert float(portrait.K[0, 0]) == pytest.approx(400.0)
    for bad in (0.0, 180.0, 200.0):
        with pytest.raises(ValueError, match="fov_deg"):
            photo_camera(make_photo(), fov_deg=bad)


def test_camera_calibrated_rescaled(tmp_path):
    calibration = [{"name": "phone", "width": 4000, "height": 3000,
                    "K": [[3100.0, 0.0, 2010.0], [0.0, 3090.0, 1490.0], [0.0, 0.0, 1.0]]}]
    path = tmp_path / "cameras.json"
    path.write_text(json.dumps(calibration))
    camera, source = photo_camera(make_photo(focal_35mm=26.0), camera_json=path, focal_px=1.0)
    assert source == "calibrated"
    np.testing.assert_allclose(camera.K.numpy(),
                               [[620.0, 0, 402.0], [0, 618.0, 298.0], [0, 0, 1]], rtol=1e-6)
    assert torch.equal(camera.R, torch.eye(3))
    # The same calibration at half size, as an object with R and t: the same camera.
    half = {**calibration[0], "width": 2000, "height": 1500,
            "K": [[1550.0, 0.0, 1005.0], [0.0, 1545.0, 745.0], [0.0, 0.0, 1.0]],
            "R": np.eye(3).tolist(), "t": [0.1, 0.0, 0.0]}
    path.write_text(json.dumps(half))
    again, _ = photo_camera(make_photo(), camera_json=path)
    torch.testing.assert_close(again.K, camera.K)


def test_camera_calibrated_errors(tmp_path):
    path = tmp_path / "cameras.json"
    path.write_text(json.dumps([{"width": 3000, "height": 4000,
                                 "K": [[3100, 0, 1500], [0, 3100, 2000], [0, 0, 1]]}]))
    with pytest.raises(ValueError, match=r"calibrated for 3000x4000 images but IMG_0001\.jpg is "
                                         r"4000x3000 \(rotated"):
        photo_camera(make_photo(), camera_json=path)
    path.write_text(json.dumps([{"width": 4000, "height": 3000}]))
    with pytest.raises(ValueError, match=r"cameras\.json: camera 0: missing camera field\(s\): K"):
        photo_camera(make_photo(), camera_json=path)
    two = {"width": 4000, "height": 3000, "K": [[3100, 0, 2000], [0, 3100, 1500], [0, 0, 1]]}
    path.write_text(json.dumps([{**two, "name": "a"}, {**two, "name": "b"}]))
    with pytest.raises(ValueError, match="2 cameras and none named 'IMG_0001'"):
        photo_camera(make_photo(), camera_json=path)
    path.write_text(json.dumps([{**two, "name": "a"}, {**two, "name": "IMG_0001",
                                                       "K": [[800, 0, 2000], [0, 800, 1500],
                                                             [0, 0, 1]]}]))
    camera, _ = photo_camera(make_photo(), camera_json=path)
    assert float(camera.K[0, 0]) == pytest.approx(160.0)
    with pytest.raises(FileNotFoundError, match="no such file"):
        photo_camera(make_photo(), camera_json=tmp_path / "missing.json")


def test_save_camera_both_sizes_and_read_back(tmp_path):
    photo = make_photo(focal_35mm=26.0)
    camera, source = photo_camera(photo)
    written = save_camera(tmp_path / "out", camera, source, original_size=photo.original_size)
    assert written == tmp_path / "out" / "camera.json"
    entries = json.loads(written.read_text())
    assert [entry["image"] for entry in entries] == ["fitted", "original"]
    assert all(entry["source"] == "exif" for entry in entries)
    assert (entries[0]["width"], entries[0]["height"]) == (800, 600)
    assert (entries[1]["width"], entries[1]["height"]) == (4000, 3000)
    np.testing.assert_allclose(entries[1]["K"][0][0], 26.0 * 5000 / FILM_DIAGONAL_MM, rtol=1e-6)
    assert entries[1]["K"][0][2] == pytest.approx(2000.0)
    # The cameras.json convention: load_cameras reads it; --camera reads it back unchanged.
    fitted, original = load_cameras(written)
    assert (fitted.width, fitted.height, original.width, original.height) == (800, 600, 4000, 3000)
    again, again_source = photo_camera(photo, camera_json=written)
    assert again_source == "calibrated"
    torch.testing.assert_close(again.K, camera.K)
    assert save_camera(tmp_path / "cam.json", camera, source) == tmp_path / "cam.json"
    with pytest.raises(ValueError, match="source must be one of"):
        save_camera(tmp_path / "x.json", camera, "guess")


def test_a_jpeg_cut_inside_its_header_is_one_line_naming_the_file(tmp_path):
    from PIL import Image

    full = tmp_path / "full.jpg"
    Image.fromarray(np.full((64, 64, 3), 128, np.uint8)).save(full, quality=90)
    cut = tmp_path / "cut.jpg"
    cut.write_bytes(full.read_bytes()[:300])
    with pytest.raises(ValueError, match=r"cut\.jpg: (truncated or corrupt|not an image)"):
        read_photo(cut)
