"""Video clips and folders of frames as a stream of RGB frames with times, and MP4 writing.

``lisa fit-video`` fits a hand through a clip. :func:`open_video` reads a video file (MP4, MOV,
WebM, AVI, MKV: whatever OpenCV's FFmpeg opens) or a folder of images and returns a
:class:`Video`, whose :meth:`Video.frames` decodes the selected frames lazily, each time it is
called (the fit reads the clip once to detect the hand and once more to draw its overlay).

A video file is scanned once at open with ``VideoCapture.grab()`` (decoded, never converted to
RGB), recording every frame's timestamp (``CAP_PROP_POS_MSEC``). The scan is fast (a fraction of
a second for a few hundred frames) and tells, before any work: the true number of readable frames
(a truncated file's header promises more), whether the frame rate varies (phone clips often do:
then frame times come from the timestamps, not from ``index / fps``) and which frames a
``start_s``/``end_s``/``stride`` selection holds, so that an empty selection is an error at once.

Large clips are downscaled to ``max_side`` pixels for detection and fitting
(:attr:`VideoInfo.scale`); callers report results in original pixels by dividing by the scale.
OpenCV (the ``[photo]`` extra) is imported lazily. Bad input raises :class:`VideoError`, one line
naming the file.
"""

from __future__ import annotations

import math
import os
import re
from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ..utils.stderr import native_stderr_captured

__all__ = ["VideoError", "VideoInfo", "VideoFrame", "Video", "open_video", "write_video",
           "FRAME_SUFFIXES", "DEFAULT_FPS"]

FRAME_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".webp")
"""Image suffixes (case-insensitive) read from a folder of frames, and refused as a video."""
DEFAULT_FPS = 30.0
"""Frames a second assumed where neither the file nor the caller gives a rate."""
_VARIABLE_TOLERANCE = 0.10
"""An interval further than this fraction from the median interval makes the rate variable."""


class VideoError(ValueError):
    """One line naming the file and the problem."""


@dataclass(frozen=True)
class VideoInfo:
    """What :func:`open_video` learnt about a clip before decoding any frame for work."""

    path: Path
    """The video file or the folder of frames."""
    kind: str
    """``"video"`` (a file) or ``"frames"`` (a folder of images)."""
    width: int
    """Original frame width, pixels."""
    height: int
    """Original frame height, pixels."""
    fps: float
    """Frames a second: 1000 / the median timestamp interval (ms); a folder: the given fps."""
    num_frames: int
    """Frames in the file: those actually readable (counted at open), or images in the folder."""
    scale: float
    """Processing pixels = original pixels * scale (<= 1; 1 unless downscaled)."""
    variable_rate: bool
    """True when timestamp intervals differ from the median by more than 10 %."""
    notes: tuple[str, ...] = ()
    """One line each: downscaled, variable frame rate, truncated, frame rate assumed."""

    @property
    def size(self) -> tuple[int, int]:
        """Processing (width, height), pixels: the size of :attr:`VideoFrame.rgb`."""
        return round(self.width * self.scale), round(self.height * self.scale)


@dataclass(frozen=True)
class VideoFrame:
    """One decoded frame."""

    index: int
    """Index in the file (0-based, counting every frame, before ``start_s`` and ``stride``)."""
    time_s: float
    """Seconds from the file's start: the frame's timestamp (a folder: ``index / fps``)."""
    rgb: np.ndarray
    """[H, W, 3] uint8 RGB at the processing size :attr:`VideoInfo.size`."""


@dataclass(frozen=True)
class Video:
    """A clip opened by :func:`open_video`: its info and the frames a selection holds."""

    info: VideoInfo
    indices: tuple[int, ...]
    """File indices of the frames :meth:`frames` yields, increasing."""
    times_s: tuple[float, ...]
    """Their times, seconds from the file's start."""
    _files: tuple[Path, ...] = field(default=(), repr=False)

    def __len__(self) -> int:
        """Number of frames :meth:`frames` yields."""
        return len(self.indices)

    def frames(self) -> Iterator[VideoFrame]:
        """Decode the selected frames in order, lazily; a fresh pass on each call."""
        cv2 = _cv2(self.info.path)
        size = self.info.size
        reader = self._read_folder(cv2) if self.info.kind == "frames" else self._read_file(cv2)
        for index, time_s, bgr in zip(self.indices, self.times_s, reader, strict=True):
            if (bgr.shape[1], bgr.shape[0]) != size:
                bgr = cv2.resize(bgr, size, interpolation=cv2.INTER_AREA)
            rgb = np.ascontiguousarray(bgr[:, :, ::-1])
            yield VideoFrame(index=index, time_s=time_s, rgb=rgb)

    def _read_file(self, cv2: Any) -> Iterator[np.ndarray]:
        cap = cv2.VideoCapture(str(self.info.path))
        try:
            wanted = iter(self.indices)
            target = next(wanted, None)
            index = 0
            while target is not None and cap.grab():
                if index == target:
                    ok, bgr = cap.retrieve()
                    if not ok:
                        raise VideoError(f"{self.info.path}: frame {index} cannot be decoded")
                    yield _check_shape(bgr, self.info)
                    target = next(wanted, None)
                index += 1
            if target is not None:
                raise VideoError(f"{self.info.path}: ends after {index} frames on a second "
                                 f"reading (it had {self.info.num_frames}); has it changed?")
        finally:
            cap.release()

    def _read_folder(self, cv2: Any) -> Iterator[np.ndarray]:
        for index in self.indices:
            path = self._files[index]
            bgr = cv2.imread(str(path), cv2.IMREAD_COLOR)
            if bgr is None:
                raise VideoError(f"{path}: not an image OpenCV can read (truncated or corrupt?)")
            yield _check_shape(bgr, self.info, path)


def _check_shape(bgr: np.ndarray, info: VideoInfo, path: Path | None = None) -> np.ndarray:
    if (bgr.shape[1], bgr.shape[0]) != (info.width, info.height):
        raise VideoError(f"{path or info.path}: a frame of {bgr.shape[1]}x{bgr.shape[0]} pixels "
                         f"in a clip of {info.width}x{info.height}")
    return bgr


def _cv2(path: Path, verb: str = "reading") -> Any:
    try:
        import cv2
    except ImportError:
        raise VideoError(f"{path}: {verb} videos needs OpenCV: pip install -e '.[photo]'") from None
    return cv2


def open_video(path: str | os.PathLike, *, start_s: float | None = None,
               end_s: float | None = None, stride: int = 1, max_side: int = 1280,
               fps: float | None = None) -> Video:
    """Open a video file or a folder of frames and select frames ``start_s <= t < end_s``.

    Of the frames in the time range, every ``stride``-th is kept (the first always). Frames are
    downscaled (area interpolation) so that their longer side is at most ``max_side`` pixels.
    ``fps`` is a folder's frame rate; for a file it is used only where the file gives none.
    Raises :class:`VideoError` (one line naming ``path``) for a missing or unreadable file, a
    folder without images or with frames of two sizes, and an empty or invalid selection.
    """
    path = Path(path)
    if isinstance(stride, bool) or not isinstance(stride, int) or stride < 1:
        raise VideoError(f"{path}: stride must be an integer >= 1, got {stride!r}")
    if isinstance(max_side, bool) or not isinstance(max_side, int) or max_side < 1:
        raise VideoError(f"{path}: max_side must be an integer >= 1 (pixels), got {max_side!r}")
    if fps is not None and not (isinstance(fps, (int, float)) and math.isfinite(fps) and fps > 0):
        raise VideoError(f"{path}: fps must be a positive number, got {fps!r}")
    start = 0.0 if start_s is None else float(start_s)
    end = math.inf if end_s is None else float(end_s)
    if not start >= 0:
        raise VideoError(f"{path}: start_s must be >= 0 seconds, got {start_s!r}")
    if not end > start:
        raise VideoError(f"{path}: end_s ({end_s!r} s) must be after start_s ({start:g} s)")
    if path.is_dir():
        info, times, files = _scan_folder(path, fps)
    elif path.is_file():
        (info, times), files = _scan_file(path, fps), ()
    else:
        raise VideoError(f"{path}: no such file or folder")
    scale = min(1.0, max_side / max(info.width, info.height))
    notes = list(info.notes)
    if scale < 1:
        size = round(info.width * scale), round(info.height * scale)
        notes.insert(0, f"downscaled from {info.width}x{info.height} to {size[0]}x{size[1]} for "
                        "detection and fitting; results in original pixels")
    info = VideoInfo(**{**info.__dict__, "scale": scale, "notes": tuple(notes)})
    chosen = [i for i, t in enumerate(times) if start <= t < end][::stride]
    if not chosen:
        span = f"after {start:g} s" if end == math.inf else f"between {start:g} s and {end:g} s"
        raise VideoError(f"{path}: no frame {span} (its {len(times)} frames run from "
                         f"{times[0]:.2f} s to {times[-1]:.2f} s)")
    return Video(info=info, indices=tuple(chosen), times_s=tuple(times[i] for i in chosen),
                 _files=files)


def _scan_file(path: Path, fps_arg: float | None) -> tuple[VideoInfo, list[float]]:
    """Grab every frame once: timestamps, the readable count and the decoded frame size."""
    cv2 = _cv2(path)
    if path.suffix.lower() in FRAME_SUFFIXES or cv2.haveImageReader(str(path)):
        raise VideoError(f"{path}: is an image, not a video; give a folder of frames or a video")
    with native_stderr_captured():  # FFmpeg's own complaint ("moov atom not found"): ours below
        cap = cv2.VideoCapture(str(path))
    try:
        if not cap.isOpened():
            raise VideoError(f"{path}: not a video OpenCV can read (truncated or not a video)")
        header_count = cap.get(cv2.CAP_PROP_FRAME_COUNT)
        header_fps = cap.get(cv2.CAP_PROP_FPS)
        stamps_ms: list[float] = []
        shape = None
        while cap.grab():
            stamps_ms.append(cap.get(cv2.CAP_PROP_POS_MSEC))
            if shape is None:  # the decoded size (rotation metadata applied), not the header's
                ok, bgr = cap.retrieve()
                shape = bgr.shape if ok and bgr is not None else None
                if shape is None:
                    break
    finally:
        cap.release()
    if not stamps_ms or shape is None:
        raise VideoError(f"{path}: not a video OpenCV can read (no decodable frame)")
    count = len(stamps_ms)
    notes = []
    if math.isfinite(header_count) and header_count > count + 1:
        notes.append(f"the file ends after {count} of {int(header_count)} frames "
                     f"(truncated?): using the {count}")
    fps, times, variable, rate_notes = _frame_times(stamps_ms, header_fps, fps_arg)
    notes.extend(rate_notes)
    info = VideoInfo(path=path, kind="video", width=int(shape[1]), height=int(shape[0]), fps=fps,
                     num_frames=count, scale=1.0, variable_rate=variable, notes=tuple(notes))
    return info, times


def _frame_times(stamps_ms: list[float], header_fps: float, fps_arg: float | None
                 ) -> tuple[float, list[float], bool, list[str]]:
    """(fps, frame times in s, variable rate, notes) from the frames' timestamps in ms.

    The rate is 1000 / the median interval; the last interval (often cut short) is left out of
    the median and the variability test. Timestamps that do not increase are replaced by
    ``index / fps``, fps from the header, else ``fps_arg``, else :data:`DEFAULT_FPS`.
    """
    notes: list[str] = []
    count = len(stamps_ms)
    intervals = np.diff(np.asarray(stamps_ms, dtype=np.float64))
    if count > 1 and np.all(np.isfinite(intervals)) and np.all(intervals > 0):
        body = intervals[:-1] if len(intervals) > 1 else intervals
        median = float(np.median(body))
        low, high = float(body.min()), float(body.max())
        variable = max(high - median, median - low) > _VARIABLE_TOLERANCE * median
        if variable:
            notes.append(f"variable frame rate (intervals {low:.1f}-{high:.1f} ms): frame times "
                         "from the file's timestamps")
        return 1000.0 / median, [ms / 1000.0 for ms in stamps_ms], variable, notes
    if math.isfinite(header_fps) and header_fps > 0:
        fps = float(header_fps)
    elif fps_arg is not None:
        fps = float(fps_arg)
    else:
        fps = DEFAULT_FPS
        notes.append(f"the file gives no frame rate: {fps:g} assumed (--fps to set it)")
    if count > 1:
        notes.append(f"the file's timestamps do not increase: frame times are index / {fps:g}")
    return fps, [i / fps for i in range(count)], False, notes


def _natural_key(path: Path) -> list[Any]:
    return [int(part) if part.isdigit() else part.lower()
            for part in re.split(r"(\d+)", path.name)]


def _scan_folder(path: Path, fps_arg: float | None
                 ) -> tuple[VideoInfo, list[float], tuple[Path, ...]]:
    """List a folder's images in natural order and check their sizes from their headers."""
    from PIL import Image

    files = sorted((p for p in path.iterdir()
                    if p.is_file() and p.suffix.lower() in FRAME_SUFFIXES), key=_natural_key)
    if not files:
        raise VideoError(f"{path}: a folder with no frame images "
                         f"({', '.join(FRAME_SUFFIXES)})")
    size = None
    for file in files:  # headers only: a few ms for hundreds of frames
        try:
            with Image.open(file) as image:
                file_size = image.size
        except (OSError, SyntaxError, ValueError) as exc:
            raise VideoError(f"{file}: not an image that can be read ({exc})") from None
        size = size or file_size
        if file_size != size:
            raise VideoError(f"{file}: {file_size[0]}x{file_size[1]} pixels, but the folder's "
                             f"first frame {files[0].name} is {size[0]}x{size[1]}")
    notes = []
    if fps_arg is None:
        notes.append(f"a folder of frames has no frame rate: {DEFAULT_FPS:g} assumed "
                     "(--fps to set it)")
    fps = float(fps_arg) if fps_arg is not None else DEFAULT_FPS
    info = VideoInfo(path=path, kind="frames", width=size[0], height=size[1], fps=fps,
                     num_frames=len(files), scale=1.0, variable_rate=False, notes=tuple(notes))
    return info, [i / fps for i in range(len(files))], tuple(files)


def write_video(path: str | os.PathLike, frames: Iterable[np.ndarray], fps: float) -> Path:
    """Write [H, W, 3] uint8 RGB frames (all one size) as an MP4 at ``fps``; return the path.

    The codec is MPEG-4 Part 2 (``mp4v``): OpenCV's pip wheels have no H.264 encoder. Odd sizes
    are padded by one pixel (edge replicated) to even, which some codecs need. The file is
    written beside ``path`` under a temporary name and moved onto ``path`` only when complete:
    a failure (a bad frame, an exception from ``frames``, which propagates) leaves neither. Raises
    :class:`VideoError` for zero frames, a frame of another size or type, or a writer OpenCV
    cannot open.
    """
    path = Path(path)
    cv2 = _cv2(path, "writing")
    if not (isinstance(fps, (int, float)) and math.isfinite(fps) and fps > 0):
        raise VideoError(f"{path}: fps must be a positive number, got {fps!r}")
    if path.is_dir():
        raise VideoError(f"{path}: is a folder, expected a video file name")
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise VideoError(f"{path}: cannot write here ({exc.strerror or exc})") from None
    tmp = path.with_name(f".{path.name}.tmp-{os.getpid()}{path.suffix or '.mp4'}")
    writer = None
    try:
        size = None
        for number, rgb in enumerate(frames):
            if not (isinstance(rgb, np.ndarray) and rgb.dtype == np.uint8 and rgb.ndim == 3
                    and rgb.shape[2] == 3):
                raise VideoError(f"{path}: frame {number} must be an [H, W, 3] uint8 RGB array, "
                                 f"got {getattr(rgb, 'dtype', type(rgb).__name__)} "
                                 f"{getattr(rgb, 'shape', '')}")
            if size is None:
                size = rgb.shape[:2]
                even = (size[1] + size[1] % 2, size[0] + size[0] % 2)
                writer = cv2.VideoWriter(str(tmp), cv2.VideoWriter_fourcc(*"mp4v"),
                                         float(fps), even)
                if not writer.isOpened():
                    raise VideoError(f"{path}: OpenCV cannot write an mp4v video here")
            elif rgb.shape[:2] != size:
                raise VideoError(f"{path}: frame {number} is {rgb.shape[1]}x{rgb.shape[0]} "
                                 f"pixels, the first {size[1]}x{size[0]}")
            pad = ((0, size[0] % 2), (0, size[1] % 2), (0, 0))
            writer.write(np.ascontiguousarray(np.pad(rgb, pad, mode="edge")[:, :, ::-1]))
        if writer is None:
            raise VideoError(f"{path}: no frames to write")
        writer.release()
        writer = None
        if not tmp.is_file() or tmp.stat().st_size == 0:
            raise VideoError(f"{path}: OpenCV wrote nothing")
        try:
            os.replace(tmp, path)
        except OSError as exc:
            raise VideoError(f"{path}: cannot write ({exc.strerror or exc})") from None
    finally:
        if writer is not None:
            writer.release()
        tmp.unlink(missing_ok=True)
    return path
