"""Video and frame-folder reading, frame selection, errors, and atomic MP4 writing."""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
import pytest

cv2 = pytest.importorskip("cv2")

from lisa_hand.data.video import (  # noqa: E402
    VideoError,
    _frame_times,
    open_video,
    write_video,
)

REAL_CLIP = Path("/work/shared/data/videos/hand_landmarker_test_video.mp4")
NUM_FRAMES = 30
FPS = 25.0


def gray(index: int) -> int:
    """The gray level frame ``index`` of a test clip is filled with."""
    return 8 * index % 256


def make_clip(path: Path, fourcc: str = "mp4v", size: tuple[int, int] = (64, 48),
              num_frames: int = NUM_FRAMES) -> Path:
    """Write a clip whose frame i is uniformly gray(i); size is (width, height)."""
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*fourcc), FPS, size)
    assert writer.isOpened()
    for i in range(num_frames):
        writer.write(np.full((size[1], size[0], 3), gray(i), np.uint8))
    writer.release()
    return path


def frame_number(rgb: np.ndarray) -> int:
    """The index a decoded test frame encodes, within codec error."""
    return int(round(float(rgb.mean()) / 8))


@pytest.fixture(scope="module")
def clips(tmp_path_factory) -> dict[str, Path]:
    folder = tmp_path_factory.mktemp("clips")
    return {"mp4": make_clip(folder / "clip.mp4"),
            "avi": make_clip(folder / "clip.avi", "MJPG")}


@pytest.mark.parametrize("kind", ["mp4", "avi"])
def test_count_rate_times_and_content(clips, kind):
    video = open_video(clips[kind])
    info = video.info
    assert (info.kind, info.width, info.height, info.size) == ("video", 64, 48, (64, 48))
    assert info.num_frames == len(video) == NUM_FRAMES
    assert info.fps == pytest.approx(FPS, rel=1e-3)
    assert info.scale == 1.0 and not info.variable_rate and info.notes == ()
    frames = list(video.frames())
    assert [f.index for f in frames] == list(range(NUM_FRAMES))
    for f in frames:
        assert f.time_s == pytest.approx(f.index / FPS, abs=1e-3)
        assert f.rgb.shape == (48, 64, 3) and f.rgb.dtype == np.uint8
        assert frame_number(f.rgb) == f.index


def test_selection_start_end_stride(clips):
    video = open_video(clips["mp4"], start_s=0.2, end_s=0.8, stride=3)
    expected = [5, 8, 11, 14, 17]  # times 0.20 .. 0.76 s: indices 5..19, every third
    assert list(video.indices) == expected and len(video) == len(expected)
    frames = list(video.frames())
    assert [f.index for f in frames] == expected
    assert [frame_number(f.rgb) for f in frames] == expected
    assert [f.index for f in open_video(clips["mp4"], end_s=0.1).frames()] == [0, 1, 2]
    assert list(open_video(clips["mp4"], start_s=1.1).indices) == list(range(28, 30))


def test_frames_can_be_iterated_twice(clips):
    video = open_video(clips["mp4"], stride=4)
    first, second = list(video.frames()), list(video.frames())
    assert [f.index for f in first] == [f.index for f in second] == list(range(0, 30, 4))
    for a, b in zip(first, second, strict=True):
        assert a.time_s == b.time_s and np.array_equal(a.rgb, b.rgb)


def test_downscale(tmp_path):
    path = make_clip(tmp_path / "wide.mp4", size=(200, 100), num_frames=3)
    video = open_video(path, max_side=100)
    info = video.info
    assert (info.width, info.height, info.scale, info.size) == (200, 100, 0.5, (100, 50))
    assert any("downscaled from 200x100 to 100x50" in note for note in info.notes)
    frames = list(video.frames())
    assert all(f.rgb.shape == (50, 100, 3) for f in frames)
    assert [frame_number(f.rgb) for f in frames] == [0, 1, 2]


def test_frame_times_from_timestamps():
    fps, times, variable, notes = _frame_times([0.0, 40.0, 80.0, 120.0, 150.0], 25.0, None)
    assert fps == pytest.approx(25.0) and not variable and notes == []  # last interval ignored
    assert times == pytest.approx([0.0, 0.04, 0.08, 0.12, 0.15])
    fps, times, variable, notes = _frame_times([0, 40, 80, 100, 140, 180, 220], 0.0, None)
    assert variable and fps == pytest.approx(25.0) and times[3] == pytest.approx(0.1)
    assert notes == ["variable frame rate (intervals 20.0-40.0 ms): frame times from the "
                     "file's timestamps"]
    fps, times, variable, notes = _frame_times([0.0, 0.0, 0.0], 24.0, None)
    assert fps == 24.0 and times == pytest.approx([0, 1 / 24, 2 / 24]) and not variable
    assert "do not increase" in notes[0]
    fps, times, _, notes = _frame_times([0.0, 0.0], float("nan"), None)
    assert fps == 30.0 and "30 assumed" in notes[0]
    assert _frame_times([0.0, 0.0], 0.0, 12.0)[0] == 12.0


def write_png(path: Path, level: int, size: tuple[int, int] = (32, 24)) -> None:
    assert cv2.imwrite(str(path), np.full((size[1], size[0], 3), level, np.uint8))


def test_folder_of_frames_natural_order(tmp_path):
    for number in (2, 10, 1):
        write_png(tmp_path / f"frame_{number}.png", 20 * number)
    (tmp_path / "notes.txt").write_text("not a frame")
    video = open_video(tmp_path, fps=10)
    info = video.info
    assert (info.kind, info.size, info.num_frames, info.fps, info.notes) == (
        "frames", (32, 24), 3, 10.0, ())
    frames = list(video.frames())
    assert [int(f.rgb[0, 0, 0]) for f in frames] == [20, 40, 200]  # frame_1, frame_2, frame_10
    assert [f.time_s for f in frames] == pytest.approx([0.0, 0.1, 0.2])
    default = open_video(tmp_path, start_s=1 / 30)
    assert default.info.fps == 30.0 and list(default.indices) == [1, 2]
    assert "no frame rate: 30 assumed" in default.info.notes[0]


def test_folder_errors(tmp_path):
    with pytest.raises(VideoError, match="no frame images"):
        open_video(tmp_path)
    write_png(tmp_path / "a1.png", 0)
    write_png(tmp_path / "a2.jpg", 0, size=(30, 24))
    with pytest.raises(VideoError, match=r"a2\.jpg: 30x24 pixels.*a1\.png is 32x24"):
        open_video(tmp_path)
    (tmp_path / "a2.jpg").write_bytes(b"not a jpeg")
    with pytest.raises(VideoError, match=r"a2\.jpg: not an image"):
        open_video(tmp_path)


def one_line(exc: pytest.ExceptionInfo, path: Path) -> str:
    message = str(exc.value)
    assert "\n" not in message and str(path) in message
    return message


def test_bad_files(tmp_path):
    missing = tmp_path / "missing.mp4"
    with pytest.raises(VideoError) as exc:
        open_video(missing)
    assert one_line(exc, missing).endswith("no such file or folder")
    text = tmp_path / "text.mp4"
    text.write_text("hello, not a video\n" * 10)
    with pytest.raises(VideoError) as exc:
        open_video(text)
    assert "not a video OpenCV can read" in one_line(exc, text)
    image = tmp_path / "still.png"
    write_png(image, 100)
    with pytest.raises(VideoError) as exc:
        open_video(image)
    assert "is an image, not a video" in one_line(exc, image)


@pytest.mark.parametrize(("name", "fourcc"), [("cut.mp4", "mp4v"), ("cut.avi", "MJPG")])
def test_truncated_file(tmp_path, name, fourcc):
    path = make_clip(tmp_path / name, fourcc, num_frames=50)
    data = path.read_bytes()
    path.write_bytes(data[: int(len(data) * 0.4)])
    try:
        video = open_video(path)
    except VideoError as exc:  # OpenCV's MP4 has its index at the end: nothing readable
        message = str(exc)
        assert "\n" not in message and str(path) in message
        assert "not a video OpenCV can read" in message
    else:
        assert video.info.num_frames < 50
        assert any("truncated" in note for note in video.info.notes)
        assert len(list(video.frames())) == video.info.num_frames


def test_bad_selection(clips):
    path = clips["mp4"]
    with pytest.raises(VideoError, match=r"no frame between 2 s and 3 s \(its 30 frames run "
                                         r"from 0\.00 s to 1\.16 s\)"):
        open_video(path, start_s=2.0, end_s=3.0)
    with pytest.raises(VideoError, match=r"no frame after 5 s \(its 30 frames"):
        open_video(path, start_s=5)
    for kwargs, match in [({"stride": 0}, "stride must be an integer >= 1"),
                          ({"start_s": -1.0}, "start_s must be >= 0"),
                          ({"start_s": 0.5, "end_s": 0.5}, "must be after start_s"),
                          ({"max_side": 0}, "max_side"),
                          ({"fps": 0}, "fps must be a positive number")]:
        with pytest.raises(VideoError, match=match) as exc:
            open_video(path, **kwargs)
        one_line(exc, path)


def test_write_video_round_trip(tmp_path):
    rng = np.random.default_rng(0)
    levels = rng.integers(10, 240, size=10)
    frames = [np.full((25, 31, 3), (level, 255 - level, 128), np.uint8) for level in levels]
    path = write_video(tmp_path / "out" / "round.mp4", frames, fps=12.0)
    assert path == tmp_path / "out" / "round.mp4"
    video = open_video(path)
    assert video.info.num_frames == 10 and video.info.size == (32, 26)  # padded to even
    assert video.info.fps == pytest.approx(12.0, rel=1e-3)
    for frame, level in zip(video.frames(), levels, strict=True):
        expected = np.array([level, 255 - level, 128], np.float64)
        assert np.abs(frame.rgb.reshape(-1, 3).mean(0) - expected).max() < 6
    assert sorted(p.name for p in path.parent.iterdir()) == ["round.mp4"]


def test_write_video_is_atomic(tmp_path):
    target = tmp_path / "clip.mp4"

    def failing():
        for i in range(5):
            yield np.full((16, 16, 3), 10 * i, np.uint8)
        raise RuntimeError("the renderer failed")

    with pytest.raises(RuntimeError, match="the renderer failed"):
        write_video(target, failing(), fps=10)
    assert list(tmp_path.iterdir()) == []
    bad = [np.zeros((16, 16, 3), np.uint8), np.zeros((16, 18, 3), np.uint8)]
    with pytest.raises(VideoError, match="frame 1 is 18x16 pixels, the first 16x16"):
        write_video(target, bad, fps=10)
    with pytest.raises(VideoError, match="no frames to write"):
        write_video(target, [], fps=10)
    with pytest.raises(VideoError, match=r"frame 0 must be an \[H, W, 3\] uint8"):
        write_video(target, [np.zeros((16, 16, 3), np.float32)], fps=10)
    assert list(tmp_path.iterdir()) == []


@pytest.mark.skipif(not REAL_CLIP.is_file(), reason="the real hand clip is not here")
def test_real_clip():
    begin = time.perf_counter()
    video = open_video(REAL_CLIP)
    seconds = time.perf_counter() - begin
    info = video.info
    assert (info.width, info.height, info.num_frames, len(video)) == (640, 360, 202, 202)
    assert info.fps == pytest.approx(25.0) and not info.variable_rate and info.notes == ()
    assert seconds < 2.0
    first = next(iter(video.frames()))
    assert first.index == 0 and first.rgb.shape == (360, 640, 3)
