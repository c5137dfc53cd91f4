"""The files of ``lisa fit-video`` (:func:`video_artefacts`, written by
:func:`lisa_hand.fitting.outputs.write_fit`, all or nothing).

Per hand (in ``DIR`` for one hand, ``DIR/handN`` for several, N its identity): ``params.json``
(the hand at its keyframe: side, skeleton, shape and colour codes; ``lisa mesh`` and ``lisa
render`` read it; ``extra.video`` the clip and the keyframe), ``mesh.ply`` (its surface at the
keyframe, with colours and skinning weights) and ``hand.glb`` (that surface in the rest pose,
skinned to the skeleton, with the clip's motion as an animation: :mod:`lisa_hand.data.gltf`).
In ``DIR``: ``track.json`` (:func:`track_record`), ``overlay.mp4`` (the clip, at the size the
fit worked at, with each hand's mesh posed by skinning in every frame and rendered over it:
:class:`lisa_hand.inference.skinned.SkinnedMesh`,
:func:`lisa_hand.inference.mesh_render.render_mesh`), ``report.html`` and ``metrics.json``
(:mod:`lisa_hand.fitting.video.report`); with several hands ``hands.json``
(:func:`hands_record`). The overlay draws the mesh decimated to
``overlay_faces`` faces (the same picture, a quarter of the time).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from ...inference.mesh_render import render_meshes_over
from ...inference.skinned import SkinnedMesh
from ..outputs import Artefact, json_artefact, mesh_artefact, params_artefact

__all__ = ["VIDEO_FILES", "VIDEO_DESCRIBED", "hand_folder", "track_record", "hands_record",
           "video_artefacts", "video_entry"]

VIDEO_FILES = ("params.json", "mesh.ply", "hand.glb", "track.json", "hands.json",
               "overlay.mp4", "report.html", "metrics.json")
"""The files a video fit writes (per hand or at the top)."""


def hand_folder(fit: Any, hand: Any) -> str:
    """"" for a clip of one hand, else "handN"."""
    return "" if len(fit.hands) == 1 else f"hand{hand.track.identity}"


def _rows(values: np.ndarray, digits: int) -> list:
    return np.round(np.asarray(values, np.float64), digits).tolist()


def _moment(fit: Any, row: int) -> dict[str, Any]:
    """A frame's ``index`` in the clip and ``time_s``."""
    return {"index": int(fit.indices[row]), "time_s": round(float(fit.times[row]), 4)}


def track_record(fit: Any) -> dict[str, Any]:
    """What ``track.json`` holds: the clip (``video``, ``fps``, ``width``, ``height``, original
    pixels), the camera (``K`` original pixels, its ``source``), ``hands`` (each one's
    ``identity``, ``side``, ``folder``, keyframe) and ``frames``: per frame its ``index`` in the
    file, ``time_s`` and ``hands``, each fitted hand's ``identity``, ``side``, ``detected``,
    ``bridged``, ``pose`` [48] radians, ``translation`` [3] metres, ``keypoints_3d`` [21, 3]
    metres in the camera frame, ``keypoints_2d`` [21, 2] pixels of the clip."""
    info = fit.video.info
    K = fit.camera.K.double().cpu().numpy().copy()
    K[:2] /= fit.scale
    frames = []
    for row, (index, time_s) in enumerate(zip(fit.indices.tolist(), fit.times.tolist(),
                                              strict=True)):
        hands = []
        for hand in fit.hands:
            if not np.isfinite(hand.motion.pose[row]).all():
                continue
            hands.append({"identity": hand.track.identity, "side": hand.side,
                          "detected": bool(hand.track.detected[row]),
                          "bridged": bool(hand.track.bridged[row]),
                          "pose": _rows(hand.motion.pose[row], 6),
                          "translation": _rows(hand.motion.translation[row], 6),
                          "keypoints_3d": _rows(hand.motion.keypoints_3d[row], 5),
                          "keypoints_2d": _rows(hand.keypoints_2d[row], 2)})
        frames.append({"index": int(index), "time_s": round(float(time_s), 4), "hands": hands})
    return {"video": str(info.path), "fps": round(float(info.fps), 4), "width": info.width,
            "height": info.height, "independent": fit.independent,
            "camera": {"K": K.tolist(), "source": fit.camera_source},
            "units": {"keypoints_3d": "m", "translation": "m", "pose": "rad (axis-angle, MANO "
                      "order)", "keypoints_2d": "px of the clip"},
            "hands": [{"identity": hand.track.identity, "side": hand.side,
                       "folder": hand_folder(fit, hand),
                       "keyframe": _moment(fit, hand.keyframe_row),
                       "keyframes": [_moment(fit, row) for row in sorted(hand.keyframe.rows)]}
                      for hand in fit.hands],
            "frames": frames}


def hands_record(fit: Any) -> dict[str, Any]:
    """What ``hands.json`` holds for a clip of several hands (``fit.contact``): ``hands`` (each
    one's ``identity``, ``side`` and ``folder``), ``frame`` ("camera"), ``penetration_mm`` (the
    deepest point of any hand inside another over the clip, by the hands' own fields) and
    ``frames``: per frame its ``index``, ``time_s``, ``right_to_left_m`` ([3] metres, the left
    wrist keypoint minus the right one; null unless one right and one left hand are both
    there) and ``penetration_mm`` (null with fewer than two hands there)."""
    contact = fit.contact

    def value(values: np.ndarray, digits: int) -> Any:
        return None if not np.isfinite(values).all() else _rows(values, digits)

    frames = [{**_moment(fit, row), "right_to_left_m": value(contact.right_to_left_m[row], 6),
               "penetration_mm": value(contact.penetration_mm[row], 3)}
              for row in range(len(fit.indices))]
    return {"hands": [{"identity": hand.track.identity, "side": hand.side,
                       "folder": hand_folder(fit, hand)} for hand in fit.hands],
            "frame": "camera", "penetration_mm": round(contact.deepest_mm, 3),
            "frames": frames}


class OverlayFrames:
    """The frames of ``overlay.mp4``, rendered once: iterating reads the clip again and yields
    each frame with the fitted hands over it
    (:func:`lisa_hand.inference.mesh_render.render_meshes_over`), keeping those of the rows
    ``keep`` (the report's pictures); :meth:`frame` gives a kept one (or renders it alone)."""

    def __init__(self, fit: Any, model: Any, config: Any, keep: set[int],
                 progress: bool = False) -> None:
        self.fit, self.model, self.config, self.keep = fit, model, config, set(keep)
        self.progress = progress
        self.posers = [SkinnedMesh(hand.keyframe.mesh, hand.params, config.overlay_faces)
                       for hand in fit.hands]
        self.kept: dict[int, np.ndarray] = {}

    def render(self, row: int, rgb: np.ndarray) -> np.ndarray:
        """The processed frame ``rgb`` of ``row`` with the hands fitted there over it."""
        meshes = [poser.posed(hand.motion.pose[row], hand.motion.translation[row])
                  for hand, poser in zip(self.fit.hands, self.posers, strict=True)
                  if np.isfinite(hand.motion.pose[row]).all()]
        return render_meshes_over(self.model, rgb, self.fit.camera, meshes,
                                  self.config.overlay_alpha, self.config.overlay_supersample,
                                  self.config.overlay_max_side)

    def __iter__(self):
        from ..stages import progress_bar

        bar = progress_bar(self.progress, len(self.fit.indices), "overlay")
        for row, frame in enumerate(self.fit.video.frames()):
            image = self.render(row, frame.rgb)
            if row in self.keep:
                self.kept[row] = image
            if bar is not None:
                bar.update(1)
            yield image
        if bar is not None:
            bar.close()

    def frame(self, row: int) -> np.ndarray:
        if row not in self.kept:
            for number, frame in enumerate(self.fit.video.frames()):
                if number == row:
                    self.kept[row] = self.render(row, frame.rgb)
                    break
        return self.kept[row]


def _glb_artefact(name: str, poser: SkinnedMesh, hand: Any, times: np.ndarray) -> Artefact:
    fitted = np.isfinite(hand.motion.pose).all(-1)

    def write(path: Path) -> Path:
        from ...data.gltf import write_animated_glb

        return write_animated_glb(path, poser.rest, poser.params.rest_joints,
                                  hand.motion.pose[fitted], hand.motion.translation[fitted],
                                  times[fitted] - times[0], side=hand.side)

    return Artefact(name, write)


def _overlay_artefact(fit: Any, frames: OverlayFrames) -> Artefact:
    def write(path: Path) -> Path:
        from ...data.video import write_video

        steps = np.diff(fit.times)
        rate = 1.0 / float(np.median(steps)) if len(steps) else fit.video.info.fps
        return write_video(path, frames, rate)

    return Artefact("overlay.mp4", write)


def _report_artefact(fit: Any, frames: OverlayFrames, metrics: dict, config: Any) -> Artefact:
    def write(path: Path) -> Path:
        from .report import video_report_html

        path.write_text(video_report_html(fit, metrics, config, frames.frame), encoding="utf-8")
        return path  # in the staging folder: the folder is swapped in whole

    return Artefact("report.html", write)


def video_artefacts(fit: Any, model: Any, config: Any, metrics: dict, progress: bool = False
                    ) -> list[Artefact]:
    """Every file of the fit (module docstring); metrics: ``metrics.json``'s record. The
    report, written last, shows frames the overlay rendered. progress: a progress bar of the
    overlay's frames."""
    from .report import report_rows

    keep = {row for hand in fit.hands for row in report_rows(hand, config.report_frames)}
    frames = OverlayFrames(fit, model, config, keep, progress)
    artefacts = []
    for hand in fit.hands:
        folder = hand_folder(fit, hand)
        prefix = f"{folder}/" if folder else ""
        artefacts += [params_artefact(hand.params, prefix + "params.json"),
                      mesh_artefact(hand.keyframe.mesh, prefix + "mesh.ply"),
                      _glb_artefact(prefix + "hand.glb", SkinnedMesh(hand.keyframe.mesh,
                                                                    hand.params), hand, fit.times)]
    if fit.contact is not None:
        artefacts.append(json_artefact("hands.json", hands_record(fit)))
    return artefacts + [json_artefact("track.json", track_record(fit)),
                        json_artefact("metrics.json", metrics),
                        _overlay_artefact(fit, frames),
                        _report_artefact(fit, frames, metrics, config)]


def video_entry(path: Path) -> bool:
    """Whether ``path``, an entry of an output folder, is what a video fit writes: a file of
    :data:`VIDEO_FILES`, or a ``handN`` folder holding only such files."""
    import re

    if path.is_symlink():
        return False
    if path.is_file():
        return path.name in VIDEO_FILES
    if path.is_dir() and re.fullmatch(r"hand\d+", path.name):
        return all(entry.is_file() and not entry.is_symlink() and entry.name in VIDEO_FILES
                   for entry in path.iterdir())
    return False


VIDEO_DESCRIBED = ", ".join(VIDEO_FILES) + " and handN folders"
"""How an output-folder error names what a video fit leaves."""
