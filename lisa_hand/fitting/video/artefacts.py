"""The files of ``lisa fit-video`` (:func:`video_artefacts`, written by
:func:`lisa_hand.fitting.outputs.write_fit`, all or nothing).

Per hand (in ``DIR`` for one hand, ``DIR/handN`` for several, N its identity): ``params.json``
(the hand at its keyframe: side, skeleton, shape and colour codes; ``lisa mesh`` and ``lisa
render`` read it; ``extra.video`` the clip and the keyframe), ``mesh.ply`` (its surface at the
keyframe, with colours and skinning weights) and ``hand.glb`` (that surface in the rest pose,
skinned to the skeleton, with the clip's motion as an animation: :mod:`lisa_hand.data.gltf`).
In ``DIR``: ``track.json`` (:func:`track_record`), ``overlay.mp4`` (the clip, at the size the
fit worked at, with each hand's mesh posed by skinning in every frame and rendered over it:
:class:`HandPoser`, :func:`lisa_hand.inference.mesh_render.render_mesh`), ``report.html`` and
``metrics.json`` (:mod:`lisa_hand.fitting.video.report`). The overlay draws the mesh decimated
to ``overlay_faces`` faces (the same picture, a quarter of the time).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import torch

from ...geometry.meshing import Mesh
from ...skeleton.params import HandParams
from ..outputs import Artefact, json_artefact, mesh_artefact, params_artefact

__all__ = ["VIDEO_FILES", "VIDEO_DESCRIBED", "HandPoser", "hand_folder", "track_record",
           "render_frame", "video_artefacts", "video_entry"]

VIDEO_FILES = ("params.json", "mesh.ply", "hand.glb", "track.json", "overlay.mp4",
               "report.html", "metrics.json")
"""The files a video fit writes (per hand or at the top)."""


class HandPoser:
    """A fitted hand's mesh moved to any pose by linear blend skinning: the mesh unposed once
    (:func:`lisa_hand.inference.mesh.repose_mesh` to the zero pose), each pose then a forward
    kinematics and a skinning. params: the hand the mesh was made from (either side).
    max_faces: the mesh decimated to at most this many faces first
    (:func:`lisa_hand.geometry.decimation.decimate_mesh`; None: as it is)."""

    def __init__(self, mesh: Mesh, params: HandParams, max_faces: int | None = None) -> None:
        from ...geometry.decimation import decimate_mesh
        from ...inference.mesh import repose_mesh

        self.params = params
        if max_faces is not None:
            mesh = decimate_mesh(mesh, max_faces)
        self.rest = repose_mesh(mesh, params, torch.zeros(48), torch.zeros(3))
        self._vertices = torch.from_numpy(self.rest.vertices).double()
        self._weights = torch.from_numpy(self.rest.skin_weights).double()

    def posed(self, pose: np.ndarray, translation: np.ndarray) -> Mesh:
        """pose [48] radians, translation [3] metres -> the mesh in that pose."""
        from ...skeleton import forward_kinematics, linear_blend_skinning

        kinematics = forward_kinematics(torch.as_tensor(pose, dtype=torch.float64)[None],
                                        self.params.rest_joints.double()[None],
                                        torch.as_tensor(translation, dtype=torch.float64)[None])
        vertices = linear_blend_skinning(self._vertices[None], self._weights,
                                         kinematics.transforms)[0]
        return Mesh(vertices=vertices.float().numpy(), faces=self.rest.faces,
                    colors=self.rest.colors)


def hand_folder(fit: Any, hand: Any) -> str:
    """"" for a clip of one hand, else "handN"."""
    return "" if len(fit.hands) == 1 else f"hand{hand.track.identity}"


def _rows(values: np.ndarray, digits: int) -> list:
    return np.round(np.asarray(values, np.float64), digits).tolist()


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
                       "keyframe": {"index": int(fit.indices[hand.keyframe_row]),
                                    "time_s": round(float(fit.times[hand.keyframe_row]), 4)}}
                      for hand in fit.hands],
            "frames": frames}


def _crop_camera(camera: Any, box: tuple[int, int, int, int]) -> Any:
    """``camera`` restricted to the pixel box (x0, y0, x1, y1)."""
    from ...geometry.cameras import Camera

    x0, y0, x1, y1 = box
    K = camera.K.clone()
    K[0, 2] -= x0
    K[1, 2] -= y0
    return Camera(K=K, R=camera.R, t=camera.t, width=int(x1 - x0), height=int(y1 - y0))


def render_frame(model: Any, rgb: np.ndarray, camera: Any, meshes: list[Mesh], alpha: float,
                 supersample: int = 1, max_side: int | None = None) -> np.ndarray:
    """``rgb`` [H, W, 3] uint8 with ``meshes`` (camera frame) rendered over it at opacity
    ``alpha``, each only in the box its vertices project to, at most ``max_side`` pixels a side
    there (then resized: a hand filling a 4K frame costs what a small one does; None: at the
    frame's resolution) -> [H, W, 3] uint8."""
    from PIL import Image

    from ...inference.mesh_render import render_mesh
    from ...inference.render import scale_camera

    out = rgb.copy()  # only the boxes around the hands are blended, in floats
    height, width = rgb.shape[:2]
    K = camera.K.double().cpu().numpy()
    for mesh in meshes:
        points = mesh.vertices.astype(np.float64)
        in_front = points[:, 2] > 1e-3
        if not in_front.any():
            continue
        pixels = (points[in_front] @ K.T)[:, :2] / points[in_front, 2:]
        x0, y0 = np.floor(pixels.min(0)).astype(int) - 2
        x1, y1 = np.ceil(pixels.max(0)).astype(int) + 2
        x0, y0, x1, y1 = max(x0, 0), max(y0, 0), min(x1, width), min(y1, height)
        if x1 - x0 < 2 or y1 - y0 < 2:
            continue
        box = _crop_camera(camera, (x0, y0, x1, y1))
        factor = 1.0 if max_side is None else min(1.0, max_side / max(x1 - x0, y1 - y0))
        small = scale_camera(box, max(int(round((x1 - x0) * factor)), 1),
                             max(int(round((y1 - y0) * factor)), 1))
        shown = render_mesh(model, mesh, small, supersample)
        colour, cover = shown.rgb, shown.alpha
        if small is not box:
            colour = np.stack([np.asarray(Image.fromarray(colour[..., c]).resize(
                (x1 - x0, y1 - y0), Image.BILINEAR)) for c in range(3)], -1)
            cover = np.asarray(Image.fromarray(cover).resize((x1 - x0, y1 - y0),
                                                             Image.BILINEAR))
        region = out[y0:y1, x0:x1].astype(np.float32) / 255.0
        blended = region * (1.0 - alpha * cover[..., None]) + colour * alpha
        out[y0:y1, x0:x1] = np.clip(blended * 255.0 + 0.5, 0, 255).astype(np.uint8)
    return out


class OverlayFrames:
    """The frames of ``overlay.mp4``, rendered once: iterating reads the clip again and yields
    each frame with the fitted hands over it (:func:`render_frame`), keeping those of the rows
    ``keep`` (the report's pictures); :meth:`frame` gives a kept one (or renders it alone)."""

    def __init__(self, fit: Any, model: Any, config: Any, keep: set[int],
                 progress: bool = False) -> None:
        self.fit, self.model, self.config, self.keep = fit, model, config, set(keep)
        self.progress = progress
        self.posers = [HandPoser(hand.keyframe.mesh, hand.params, config.overlay_faces)
                       for hand in fit.hands]
        self.kept: dict[int, np.ndarray] = {}

    def render(self, row: int, rgb: np.ndarray) -> np.ndarray:
        """The processed frame ``rgb`` of ``row`` with the hands fitted there over it."""
        meshes = [poser.posed(hand.motion.pose[row], hand.motion.translation[row])
                  for hand, poser in zip(self.fit.hands, self.posers, strict=True)
                  if np.isfinite(hand.motion.pose[row]).all()]
        return render_frame(self.model, rgb, self.fit.camera, meshes, self.config.overlay_alpha,
                            self.config.overlay_supersample, self.config.overlay_max_side)

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


def _glb_artefact(name: str, poser: HandPoser, hand: Any, times: np.ndarray) -> Artefact:
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
                      _glb_artefact(prefix + "hand.glb", HandPoser(hand.keyframe.mesh,
                                                                    hand.params), hand, fit.times)]
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
