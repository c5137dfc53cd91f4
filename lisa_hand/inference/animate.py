"""Re-pose a hand along a pose sequence: :func:`animate_hand` writes a mesh and a frame per pose
from one fixed camera, then a GIF (the pose sequences themselves: :mod:`.sequences`)."""

from __future__ import annotations

import os
import time
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from pathlib import Path

import torch

from ..geometry.cameras import Camera
from ..geometry.meshing import Mesh
from ..model.trained import TrainedModel
from ..render.image import ImageRenderConfig
from ..skeleton import POSE_DIM
from ..skeleton.params import HandParams
from .bounds import union_sphere
from .mesh import MeshConfig, check_resolution, mesh_hand, repose_mesh
from .render import HandScene, hand_render_config, orbit_views, prepare_render

__all__ = ["MESH_MODES", "AnimationResult", "animate_hand"]

MESH_MODES = ("field", "skinning")
"""How :func:`animate_hand` makes each frame's mesh: marching cubes of the field in that pose,
or the first pose's mesh re-posed by linear blend skinning (same vertices and faces)."""


@dataclass
class AnimationResult:
    """What :func:`animate_hand` wrote.

    mesh_paths, frame_paths: one per pose (empty when not asked). gif_path: the animation (or
    None). camera: the fixed camera of the frames (or None). poses [T, 48], translations [T, 3].
    seconds: wall time.
    """

    mesh_paths: list[Path]
    frame_paths: list[Path]
    gif_path: Path | None
    camera: Camera | None
    poses: torch.Tensor
    translations: torch.Tensor
    seconds: float = 0.0
    extra: dict = field(default_factory=dict)


def _checked_motion(
    params: HandParams, poses: torch.Tensor, translations: torch.Tensor | None
) -> tuple[torch.Tensor, torch.Tensor]:
    """The poses [T, 48] and translations [T, 3] (default the hand's) as float32 tensors."""
    poses = torch.as_tensor(poses, dtype=torch.float32)
    if poses.dim() != 2 or poses.shape[1] != POSE_DIM or poses.shape[0] < 1:
        raise ValueError(f"poses must have shape [T, 48] with T >= 1, got {list(poses.shape)}")
    num = poses.shape[0]
    if translations is None:
        translations = params.translation.expand(num, 3).clone()
    translations = torch.as_tensor(translations, dtype=torch.float32)
    if translations.shape != (num, 3):
        raise ValueError(f"translations must have shape [T, 3] = [{num}, 3], got "
                         f"{list(translations.shape)}")
    return poses, translations


def _checked_outputs(
    mesh_resolution: int | None, mesh_suffix: str, mesh_mode: str, frames: bool, fps: float
) -> int | None:
    """Check what :func:`animate_hand` is asked to write. -> the mesh resolution (or None)."""
    from ..data.meshio import MESH_SUFFIXES

    if mesh_mode not in MESH_MODES:
        raise ValueError(f"mesh_mode must be one of {MESH_MODES}, got {mesh_mode!r}")
    if mesh_suffix not in MESH_SUFFIXES:
        raise ValueError(f"mesh_suffix must be one of {MESH_SUFFIXES}, got {mesh_suffix!r}")
    if mesh_resolution is not None:
        mesh_resolution = check_resolution(mesh_resolution)
    if mesh_resolution is None and not frames:
        raise ValueError("nothing to write: no meshes (mesh_resolution None) and no frames")
    if not fps > 0:
        raise ValueError(f"fps must be > 0, got {fps!r}")
    return mesh_resolution


def _write_meshes(
    model: TrainedModel,
    frame_params: list[HandParams],
    out_dir: Path,
    resolution: int,
    suffix: str,
    mode: str,
    config: MeshConfig,
    log: Callable[[str], None],
) -> list[Path]:
    """One mesh per pose, ``out_dir/meshes/frame_000{suffix}``...; 'skinning' mode re-poses the
    first pose's mesh. -> the paths"""
    from ..data.meshio import save_mesh

    paths: list[Path] = []
    first = None
    for index, frame in enumerate(frame_params):
        if mode == "skinning" and first is not None:
            mesh = repose_mesh(first, params=frame_params[0], pose=frame.pose,
                               translation=frame.translation)
        else:
            mesh = mesh_hand(model, frame, resolution, config)
            first = mesh
        if suffix != ".ply" and mesh.skin_weights is not None:
            mesh = Mesh(vertices=mesh.vertices, faces=mesh.faces, colors=mesh.colors)
        path = save_mesh(out_dir / "meshes" / f"frame_{index:03d}{suffix}", mesh)
        paths.append(path)
        log(f"mesh {index + 1}/{len(frame_params)}: {path} ({mesh.num_vertices} vertices)")
    return paths


def _framing_camera(scenes: list[HandScene], width: int, height: int) -> Camera:
    """A palm-side camera ``animation`` framing the hand in every pose."""
    camera = orbit_views(scenes[0], 1, width, height, elevation_deg=10.0,
                         framing=union_sphere([s.framing_sphere() for s in scenes]))[0]
    return Camera(K=camera.K, R=camera.R, t=camera.t, width=camera.width,
                  height=camera.height, name="animation")


def _write_frames(
    scenes: list[HandScene],
    camera: Camera,
    out_dir: Path,
    fps: float,
    log: Callable[[str], None],
) -> tuple[list[Path], Path]:
    """One frame per scene from ``camera``, ``out_dir/frames/frame_000.png``..., then
    ``animation.gif`` and ``camera.json``. -> (frame paths, GIF path)"""
    import imageio.v3 as iio

    from ..geometry.cameras import save_cameras
    from ..render.saving import image_to_uint8
    from ..render.turntable import save_gif
    from ..utils.io import atomic_path

    images, paths = [], []
    for index, scene in enumerate(scenes):
        output = scene.render(camera)
        image = image_to_uint8(output.rgb[..., :3])
        path = out_dir / "frames" / f"frame_{index:03d}.png"
        with atomic_path(path) as tmp:
            iio.imwrite(tmp, image, extension=".png")
        images.append(image)
        paths.append(path)
        log(f"frame {index + 1}/{len(scenes)}: {path}")
    gif_path = save_gif(out_dir / "animation.gif", images, fps)
    save_cameras(out_dir / "camera.json", [camera])
    return paths, gif_path


def animate_hand(
    model: TrainedModel,
    params: HandParams,
    poses: torch.Tensor,
    translations: torch.Tensor | None,
    out_dir: str | os.PathLike,
    *,
    mesh_resolution: int | None = 128,
    mesh_suffix: str = ".ply",
    mesh_mode: str = "field",
    mesh_config: MeshConfig | None = None,
    frames: bool = True,
    camera: Camera | None = None,
    width: int = 512,
    height: int = 512,
    render_config: ImageRenderConfig | None = None,
    fps: float = 12.0,
    log: Callable[[str], None] | None = None,
) -> AnimationResult:
    """Re-pose a hand along ``poses``; write its meshes, frames and a GIF into ``out_dir``.

    Files: ``meshes/frame_000.ply`` ... (``mesh_suffix``), ``frames/frame_000.png`` ...,
    ``animation.gif``, ``camera.json`` (the fixed camera) and ``poses.json`` (``{"poses",
    "translations"}``, readable by :func:`read_pose_sequence`). Every file is written atomically.

    poses: [T, 48] radians (the hand's side). translations: [T, 3] metres or None (the hand's).
    mesh_resolution: grid samples per side, or None for no meshes. mesh_mode: 'field' (marching
    cubes of the field in each pose) or 'skinning' (the first pose's mesh re-posed by
    :func:`repose_mesh`: same vertices and faces in every frame).
    frames: render the frames (from ``camera``, default a palm-side view framing every pose,
    ``width`` x ``height``). The shape and colour codes stay those of ``params``.
    """
    from ..utils.io import write_json

    start = time.perf_counter()
    log = log or (lambda message: None)
    poses, translations = _checked_motion(params, poses, translations)
    mesh_resolution = _checked_outputs(mesh_resolution, mesh_suffix, mesh_mode, frames, fps)
    mesh_config = MeshConfig() if mesh_config is None else mesh_config
    if mesh_suffix != ".ply":  # only PLY stores weights; skinning mode still needs them
        mesh_config = replace(mesh_config, skin_weights=mesh_mode == "skinning")
    out_dir = Path(out_dir)
    frame_params = [params.with_pose(poses[i], translations[i]) for i in range(poses.shape[0])]

    mesh_paths: list[Path] = []
    if mesh_resolution is not None:
        mesh_paths = _write_meshes(model, frame_params, out_dir, mesh_resolution, mesh_suffix,
                                   mesh_mode, mesh_config, log)
    frame_paths: list[Path] = []
    gif_path = None
    if frames:
        render_config = hand_render_config(model) if render_config is None else render_config
        scenes = [prepare_render(model, frame, render_config) for frame in frame_params]
        if camera is None:
            camera = _framing_camera(scenes, width, height)
        frame_paths, gif_path = _write_frames(scenes, camera, out_dir, fps, log)
    write_json(out_dir / "poses.json",
               {"poses": poses.tolist(), "translations": translations.tolist()})
    return AnimationResult(
        mesh_paths=mesh_paths, frame_paths=frame_paths, gif_path=gif_path, camera=camera,
        poses=poses, translations=translations, seconds=time.perf_counter() - start,
    )  # fmt: skip
