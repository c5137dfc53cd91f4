"""``lisa fit-video``: one consistent hand (or two) through a clip (:func:`fit_video`).

1. **Read** the clip (:func:`lisa_hand.data.video.open_video`: a video file or a folder of
   frames; ``start``/``end``/``stride``; frames above ``max_side`` downscaled for the work,
   results given in the clip's own pixels) and choose its camera as a photo's
   (:func:`lisa_hand.data.photo.photo_camera`: ``--camera``, ``--focal-px``, ``--fov``, a
   default field of view).
2. **Detect** the hands of every frame in order with MediaPipe's tracking mode
   (:class:`lisa_hand.data.detect.VideoHandDetector`) and **join** them into tracks
   (:func:`lisa_hand.fitting.video.tracks.build_tracks`: one identity a hand, short dropouts
   bridged, a hand that leaves and comes back picked up again).
3. Per track, **a first skeleton**: the keypoint stage on its best-seen frame
   (:func:`lisa_hand.fitting.video.keyframe.keyframe_start`), whose pose there starts the
   motion.
4. Per track, **the motion**: pose and translation in every frame where the hand is present,
   fitted in windows with a motion prior, then all at once with the skeleton refitted on every
   frame (:func:`lisa_hand.fitting.video.motion.fit_motion`); ``independent``: each frame
   alone with the first skeleton, the reference. Then **one shape and colour**: its
   keyframes (the best-seen frame and the best of other parts of the clip, ``keyframes``)
   fitted as photos of one hand at their fitted poses
   (:func:`lisa_hand.fitting.video.keyframe.fit_keyframe`).
5. With several hands, **where they are from each other** and how deep they meet in every frame
   (:func:`lisa_hand.fitting.video.contact.clip_contact`).
6. The files (:mod:`lisa_hand.fitting.video.artefacts`): written all or nothing.

A left hand is fitted as the mirror image of a right one (its keypoints mirrored about the
principal point), as every fitter does, and mirrored back.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
import torch

from ...skeleton.params import HandParams
from .config import FitVideoConfig
from .keyframe import KeyframeFit
from .motion import MotionResult
from .tracks import HandTrack

__all__ = ["TrackedHand", "VideoFit", "fit_video", "detect_clip"]

SIDES = ("auto", "right", "left")


@dataclass
class TrackedHand:
    """One hand through the clip. params: the hand at its keyframe (shape, skeleton, colour).
    keyframe_row: that frame's row. motion: its pose [N, 48], translation [N, 3] and 3D
    keypoints [N, 21, 3] (camera frame metres, the hand's side; NaN where absent).
    keypoints_2d: [N, 21, 2] the 3D keypoints projected, the clip's own pixels.
    side_source: "detected" or "--side"."""

    track: HandTrack
    params: HandParams
    keyframe_row: int
    keyframe: KeyframeFit
    motion: MotionResult
    keypoints_2d: np.ndarray
    side_source: str

    @property
    def side(self) -> str:
        return self.params.side


@dataclass
class VideoFit:
    """The fit of a clip. video: the :class:`lisa_hand.data.video.Video` (frames re-read for
    the overlay). indices, times: [N] each frame's index in the file and time, seconds.
    camera: the camera in processing pixels (world = camera frame); camera_source: where it
    came from. hands: one :class:`TrackedHand` a track. detections: per frame, the hands the
    detector found. independent: each frame was fitted alone. model: the trained model the
    hands belong to. timings: seconds per step; notes: sentences for the user. contact: with
    two hands or more, where they are from each other and how deep they meet per frame
    (:class:`lisa_hand.fitting.video.contact.ClipContact`; None for one hand)."""

    video: Any
    indices: np.ndarray
    times: np.ndarray
    camera: Any
    camera_source: str
    hands: list[TrackedHand]
    detections: list[list[Any]]
    independent: bool
    model: Any = None
    timings: dict[str, float] = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)
    contact: Any = None

    @property
    def scale(self) -> float:
        """Processing pixels per original pixel."""
        return float(self.video.info.scale)


def detect_clip(video: Any, config: FitVideoConfig, progress: bool
                ) -> tuple[list[list[Any]], np.ndarray, np.ndarray, dict[int, np.ndarray]]:
    """MediaPipe on every frame of ``video`` in order -> (per frame the detected hands,
    indices [N], times [N] seconds, the frames where each side was seen best so far: row ->
    [h, w, 3] uint8, most often the keyframes, which then need not be read again)."""
    from ...data.detect import VideoHandDetector
    from ..stages import progress_bar
    from .keyframe import view_score

    detections, indices, times = [], [], []
    best: dict[str, tuple[tuple[bool, float], int, np.ndarray]] = {}
    bar = progress_bar(progress, len(video), "detect")
    with VideoHandDetector(max_hands=config.max_hands,
                           min_detection_confidence=config.detection_confidence,
                           min_tracking_confidence=config.tracking_confidence,
                           model_complexity=config.model_complexity) as detector:
        for row, frame in enumerate(video.frames()):
            detections.append(detector(frame.rgb))
            for hand in detections[-1]:
                seen = view_score(hand.keypoints, hand.score, *video.info.size)
                if hand.side not in best or seen > best[hand.side][0]:
                    best[hand.side] = (seen, row, frame.rgb)
            indices.append(frame.index)
            times.append(frame.time_s)
            if bar is not None:
                bar.update(1)
    if bar is not None:
        bar.close()
    kept = {row: rgb for _, row, rgb in best.values()}
    return detections, np.asarray(indices, np.int64), np.asarray(times, np.float64), kept


def _frames_at(video: Any, rows: set[int], kept: dict[int, np.ndarray]
               ) -> dict[int, np.ndarray]:
    """The processed frames at ``rows`` (positions in ``video.frames()``): those in ``kept``,
    the others read again."""
    found = {row: kept[row] for row in rows if row in kept}
    if len(found) == len(rows):
        return found
    for row, frame in enumerate(video.frames()):
        if row in rows:
            found[row] = frame.rgb
        if len(found) == len(rows):
            break
    return found


def _motion_data(track: HandTrack, camera: Any, times: np.ndarray, side: str) -> Any:
    """The track's keypoints as :class:`MotionData` of a right hand."""
    from ..images.terms import bone_directions
    from .motion import MotionData

    keypoints = np.nan_to_num(track.keypoints.copy())
    K = camera.K.double().cpu()
    if side == "left":
        keypoints[..., 0] = 2.0 * float(K[0, 2]) - keypoints[..., 0]
    weights = track.scores * track.detected  # bridged frames: the motion prior only
    directions = direction_weights = None
    if track.landmarks_3d is not None:
        landmarks = torch.from_numpy(track.landmarks_3d).float()
        if side == "left":
            landmarks[..., 0] = -landmarks[..., 0]
        found = torch.isfinite(landmarks).all(-1).all(-1) & torch.from_numpy(track.detected)
        directions = bone_directions(torch.nan_to_num(landmarks))
        direction_weights = found.float()
    return MotionData(K=K.float(), keypoints=torch.from_numpy(keypoints).float(),
                      weights=torch.from_numpy(weights).float(),
                      times=torch.from_numpy(times).float(), size_px=max(track.size_px(), 1.0),
                      directions=directions, direction_weights=direction_weights)


def _segments(track: HandTrack, independent: bool) -> list[tuple[int, int]]:
    """Runs of frames to fit: where the hand is present (tracked) or detected (independent)."""
    if not independent:
        return track.segments()
    return replace(track, bridged=np.zeros_like(track.bridged)).segments()


def _right(pose: torch.Tensor, translation: torch.Tensor, side: str
           ) -> tuple[torch.Tensor, torch.Tensor]:
    """A ``side`` hand's pose and translation -> its mirrored right hand's (or as given)."""
    from ...skeleton import mirror_points, mirror_pose

    if side == "left":
        return mirror_pose(pose), mirror_points(translation)
    return pose, translation


def _fit_track(model: Any, video: Any, track: HandTrack, side: str, camera: Any,
               times: np.ndarray, frames: dict[int, np.ndarray], key_rows: list[int],
               config: FitVideoConfig, template: Any, progress: bool) -> tuple[Any, Any]:
    """One track: the first skeleton and pose from the best-seen keyframe (``key_rows[0]``),
    the motion and the clip's skeleton, then the shape and colour from every keyframe at its
    fitted pose with that skeleton ->
    (KeyframeFit, MotionResult of the hand's side)."""
    from ...skeleton import mirror_points, mirror_pose
    from ..sides import mirror_hand
    from .keyframe import (
        choose_keyframe,
        fit_keyframe,
        frame_photo,
        keyframe_start,
        keyframe_views,
        segment_anchor,
    )
    from .motion import fit_motion

    info = video.info
    photo_of = {row: frame_photo(info.path, rgb, (info.width, info.height), info.scale)
                for row, rgb in frames.items()}
    views = keyframe_views(photo_of, camera, track, key_rows, side, config.keyframe,
                           config.min_hand_px)
    start = keyframe_start(views[0], side, config.keyframe, template, progress)
    key_row = key_rows[0]
    right = mirror_hand(start) if side == "left" else start
    segments = []
    for first, end in _segments(track, config.independent):
        if first <= key_row < end:
            segments.append((first, end, key_row, right.pose, right.translation))
            continue
        anchor = choose_keyframe(track, *info.size, range(first, end))
        pose, translation = segment_anchor(photo_of[anchor], camera, track, anchor, side,
                                           config.keyframe, template)
        segments.append((first, end, anchor, *_right(pose, translation, side)))
    data = _motion_data(track, camera, times, side)
    motion = fit_motion(template, right.rest_joints.float(), right.betas, data, segments,
                        config.motion, temporal=not config.independent, progress=progress)
    if side == "left":
        motion = replace(motion,
                         pose=mirror_pose(torch.from_numpy(motion.pose)).numpy(),
                         translation=mirror_points(torch.from_numpy(motion.translation)).numpy(),
                         keypoints_3d=mirror_points(torch.from_numpy(motion.keypoints_3d))
                         .numpy())
    if config.motion.betas_lr > 0 and not config.independent:  # the clip's own skeleton
        rest_joints = motion.rest_joints.to(start.rest_joints)
        start = replace(start, betas=motion.betas.to(start.betas),
                        rest_joints=mirror_points(rest_joints) if side == "left" else rest_joints,
                        pose=torch.from_numpy(motion.pose[key_row]).float(),
                        translation=torch.from_numpy(motion.translation[key_row]).float())
    fitted = [0] + [number for number, row in enumerate(key_rows)
                    if number and np.isfinite(motion.pose[row]).all()]
    starts = [start] + [replace(start, pose=torch.from_numpy(motion.pose[key_rows[n]]).float(),
                                translation=torch.from_numpy(motion.translation[key_rows[n]])
                                .float()) for n in fitted[1:]]
    keyframe = fit_keyframe(model, [views[n] for n in fitted], starts,
                            [key_rows[n] for n in fitted], side, config.keyframe, progress)
    return keyframe, motion


def _project(camera: Any, points: np.ndarray, scale: float) -> np.ndarray:
    """[N, 21, 3] camera-frame metres -> [N, 21, 2] pixels of the clip (original size)."""
    K = camera.K.double().cpu().numpy()
    homogeneous = points @ K.T
    return homogeneous[..., :2] / np.maximum(homogeneous[..., 2:], 1e-6) / scale


def _anchor_rows(tracks: Sequence[HandTrack], size: tuple[int, int], config: FitVideoConfig
                 ) -> dict[int, tuple[list[int], list[int]]]:
    """Per track, the rows whose frames the fit needs: (its keyframes, the best-seen first;
    the anchor of each further segment)."""
    from .keyframe import choose_keyframe, choose_keyframes

    rows = {}
    for track in tracks:
        keys = choose_keyframes(track, *size, config.keyframes)
        others = [choose_keyframe(track, *size, range(first, end))
                  for first, end in _segments(track, config.independent)
                  if not first <= keys[0] < end]
        rows[track.identity] = (keys, others)
    return rows


def _check_arguments(side: str, stride: int) -> None:
    if side not in SIDES:
        raise ValueError(f"side must be one of {', '.join(SIDES)}, got {side!r}")
    if isinstance(stride, bool) or not isinstance(stride, int) or stride < 1:
        raise ValueError(f"stride must be a positive integer, got {stride!r}")


def _kept_tracks(tracks: list[HandTrack], config: FitVideoConfig, notes: list[str]
                 ) -> list[HandTrack]:
    """The tracks detected in at least ``min_frames`` frames (fewer: a false detection)."""
    kept = [track for track in tracks if int(track.detected.sum()) >= config.min_frames]
    if len(kept) < len(tracks):
        notes.append(f"{len(tracks) - len(kept)} hand(s) detected in fewer than "
                     f"{config.min_frames} frames ignored")
    return [replace(track, identity=number) for number, track in enumerate(kept)]


def fit_video(
    video_path: Any,
    *,
    camera_json: Any = None,
    focal_px: float | None = None,
    fov_deg: float | None = None,
    side: str = "auto",
    start_s: float | None = None,
    end_s: float | None = None,
    stride: int = 1,
    fps: float | None = None,
    model_path: Any = None,
    device: str = "auto",
    progress: bool = True,
    log: Callable[[str], None] | None = print,
    config: FitVideoConfig | None = None,
) -> VideoFit:
    """Fit the hands of a clip (module docstring) -> :class:`VideoFit`; nothing is written.

    video_path: a video file (MP4, MOV, WebM, AVI...) or a folder of frames. camera_json,
    focal_px (original pixels), fov_deg (along the long side): the camera, as ``fit-photo``'s.
    side: "auto" (each track's detected side), "right" or "left" (every hand). start_s, end_s:
    the part of the clip, seconds; stride: every n-th frame; fps: a frame folder's rate.
    model_path: a trained model (None: the shipped default). Raises ValueError (one line) for
    bad input and when no frame holds a hand.
    """
    from ...data.photo import photo_camera
    from ...data.video import open_video
    from ...model.trained import load_trained
    from ...utils.device import resolve_device
    from ...utils.threads import cpu_threads
    from .contact import clip_contact
    from .keyframe import frame_photo
    from .tracks import build_tracks

    log = log or (lambda line: None)
    config = FitVideoConfig() if config is None else config
    _check_arguments(side, stride)
    began = time.perf_counter()
    video = open_video(video_path, start_s=start_s, end_s=end_s, stride=stride,
                       max_side=config.max_side, fps=fps)
    info = video.info
    notes = list(info.notes)
    for note in notes:
        log(note)
    first = next(iter(video.frames()))
    camera, camera_source = photo_camera(
        frame_photo(info.path, first.rgb, (info.width, info.height), info.scale),
        camera_json, focal_px, fov_deg)
    timings = {"seconds_open": time.perf_counter() - began}
    with cpu_threads(config.num_threads):
        detections, indices, times, kept = detect_clip(video, config, progress)
        timings["seconds_detect"] = time.perf_counter() - began - timings["seconds_open"]
        bridge = int(round(config.bridge_s * info.fps / stride)) if not \
            config.independent else 0
        tracks = _kept_tracks(build_tracks(detections, max_hands=config.max_hands,
                                           bridge_frames=bridge,
                                           match_fraction=config.match_fraction),
                              config, notes)
        if not tracks:
            raise ValueError(f"{info.path}: no hand found in any of its {len(video)} frames")
        log(f"{len(video)} frames, {len(tracks)} hand(s) followed: "
            + ", ".join(f"{t.side} in {int(t.present.sum())} frames" for t in tracks))
        model = load_trained(model_path, resolve_device(device))
        hands = _fit_hands(model, video, tracks, side, camera, indices, times, kept,
                           model_path, config, progress, log, notes)
        contact = clip_contact(model, hands, config.overlay_faces) if len(hands) > 1 else None
    timings["seconds_fit"] = time.perf_counter() - began - sum(timings.values())
    return VideoFit(video=video, indices=indices, times=times, camera=camera,
                    camera_source=camera_source, hands=hands, detections=detections,
                    independent=config.independent, model=model, timings=timings,
                    notes=notes, contact=contact)


def _fit_hands(model: Any, video: Any, tracks: list[HandTrack], side: str, camera: Any,
               indices: np.ndarray, times: np.ndarray, kept: dict[int, np.ndarray],
               model_path: Any,
               config: FitVideoConfig, progress: bool, log: Callable[[str], None],
               notes: list[str]) -> list[TrackedHand]:
    """Each track's keyframe and motion (module docstring, steps 3 and 4)."""
    from ...utils.config import config_to_dict
    from ..stages import template_on

    info = video.info
    template = template_on(None, torch.device("cpu"))
    anchors = _anchor_rows(tracks, info.size, config)
    frames = _frames_at(video, {row for keys, others in anchors.values()
                                for row in keys + others}, kept)
    hands = []
    for track in tracks:
        chosen = track.side if side == "auto" else side
        keys, others = anchors[track.identity]
        key_row = keys[0]
        log(f"hand {track.identity} ({chosen}): keyframe(s) at "
            + ", ".join(f"{times[row]:.2f}" for row in sorted(keys)) + " s")
        keyframe, motion = _fit_track(model, video, track, chosen, camera, times,
                                      {row: frames[row] for row in keys + others},
                                      keys, config, template, progress)
        notes += keyframe.notes
        params = keyframe.params
        params.model = _model_label(model_path)
        params.extra["video"] = {"path": str(info.path), "identity": track.identity,
                                 "keyframe": {"index": int(indices[key_row]),
                                              "time_s": float(times[key_row])},
                                 "keyframes": [{"index": int(indices[row]),
                                                "time_s": float(times[row])}
                                               for row in sorted(keys)]}
        params.extra["config"] = config_to_dict(config)  # the settings that fitted it
        hands.append(TrackedHand(
            track=track, params=params, keyframe_row=key_row, keyframe=keyframe,
            motion=motion, keypoints_2d=_project(camera, motion.keypoints_3d, info.scale),
            side_source="detected" if side == "auto" else "--side"))
    return hands


def _model_label(model_path: Any) -> str:
    from ...model.trained import model_label

    return model_label(model_path)
