"""Novel views of a hand: :func:`prepare_render` / :func:`render_hand`, folders of views.

Views are rendered with :func:`lisa_hand.render.image.render_image` (rays that miss the
occupancy grid cost nothing, samples gather in a band around the surface), one grid shared by
all views of a frame; :func:`orbit_views` places a turntable around the hand's own finger axis.
Nothing here is differentiable (normals use autograd through the SDF inside the renderer).
"""

from __future__ import annotations

import dataclasses
import math
import os
import re
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import torch

from ..geometry.cameras import Camera, pixel_rays
from ..model.trained import TrainedModel
from ..render.density import LaplaceDensity
from ..render.image import ImageOutput, ImageRenderConfig, render_image
from ..render.occupancy import OccupancyGrid
from ..render.shading import shade_foreground
from ..render.turntable import orbit_cameras, shared_grid
from ..skeleton import forward_kinematics
from ..skeleton.params import HandParams
from .bounds import grid_surface_box, hand_bounds, skeleton_box
from .hand_field import HandField, hand_field

__all__ = [
    "hand_render_config",
    "HandScene",
    "prepare_render",
    "render_hand",
    "orbit_views",
    "RenderResult",
    "mp4_available",
    "render_to_folder",
    "scale_camera",
    "file_stem",
]


def hand_render_config(model: TrainedModel, **overrides) -> ImageRenderConfig:
    """The image settings for a trained hand: volume mode with the model's ``beta``, autograd
    normals, Lipschitz allowance 1.5 for a learned SDF; ``overrides`` replace any field."""
    values = dict(beta=float(model.beta), lipschitz=1.5, normals="autograd")
    values.update(overrides)
    return ImageRenderConfig(**values)


@dataclass
class HandScene:
    """A hand ready to be rendered from any camera (:func:`prepare_render`).

    hand: the hand's prepared field. config: image settings. density: VolSDF density (the
    model's beta). center [3], radius: metres, the bounding sphere (:func:`hand_bounds`).
    grid: the occupancy grid shared by all views (None with sphere culling).
    """

    hand: HandField
    config: ImageRenderConfig
    density: LaplaceDensity
    center: torch.Tensor
    radius: float
    grid: OccupancyGrid | None

    def render(self, camera: Camera, progress: bool = False) -> ImageOutput:
        """Render one camera (its width x height pixels) -> :class:`ImageOutput`."""
        model, config = self.hand.model, self.config
        camera = camera.to(device=model.field.device, dtype=model.field.dtype)
        if model.shading is not None and config.normals == "none":
            config = dataclasses.replace(config, normals="autograd")  # the shading needs them
        output = render_image(
            self.hand.field_fn(), self.hand.sdf_fn(), camera, self.center, self.radius,
            config, self.density, progress=progress, grid=self.grid,
        )  # fmt: skip
        if model.shading is None:
            return output
        return _shaded(output, model, camera, config)

    def framing_sphere(self) -> tuple[torch.Tensor, float]:
        """A tight sphere around the surface (the occupied grid cells' box): where to aim and
        how far to stand. -> (center [3] float64 CPU metres, radius metres)"""
        if self.grid is not None:
            low, high = grid_surface_box(self.grid)
        else:
            low, high = skeleton_box(self.hand.params, self.hand.model.config)
        low64, high64 = torch.from_numpy(low), torch.from_numpy(high)
        return 0.5 * (low64 + high64), 0.5 * float((high64 - low64).norm())

    def hand_axes(self) -> tuple[torch.Tensor, torch.Tensor]:
        """The posed hand's finger direction (wrist to middle-finger base) and palm normal
        (MANO rest palm faces -y, either side), unit [3] float64 world vectors."""
        params = self.hand.params
        rest = params.rest_joints.double()
        kinematics = forward_kinematics(params.pose[None].double(), rest[None])
        root = kinematics.transforms[0, 0, :3, :3]
        fingers = root @ (rest[4] - rest[0])
        palm = root @ torch.tensor([0.0, -1.0, 0.0], dtype=torch.float64)
        return fingers / fingers.norm(), palm


def _shaded(output: ImageOutput, model: TrainedModel, camera: Camera,
            config: ImageRenderConfig) -> ImageOutput:
    """``output`` lit by the model's headlight shading (:mod:`lisa_hand.render.shading`): the
    hand's calibrated colour ``g * albedo`` times the Lambert factor at each pixel's normal
    (pixels without a normal, where the opacity is at most 0.5, get the ambient part 1 - k)."""
    height, width = camera.height, camera.width
    _, directions = pixel_rays(camera, device=output.rgb.device, dtype=output.rgb.dtype)
    with torch.no_grad():
        factor = model.shading.factor(output.normals.reshape(-1, 3), directions, camera.R)
        background = torch.tensor(config.background, dtype=output.rgb.dtype,
                                  device=output.rgb.device)
        rgb = shade_foreground(output.rgb.reshape(-1, 3), output.opacity.reshape(-1),
                               background, factor.to(output.rgb.dtype),
                               model.bias.to(output.rgb))
    return dataclasses.replace(output, rgb=rgb.clamp(0.0, 1.0).reshape(height, width, 3))


def prepare_render(
    model: TrainedModel,
    params: HandParams,
    config: ImageRenderConfig | None = None,
    *,
    hand: HandField | None = None,
) -> HandScene:
    """Prepare a hand for rendering: its field, bounding sphere, density and the occupancy grid
    shared by every view. config: default :func:`hand_render_config`. hand: a prepared
    :func:`hand_field` of the same model and params (reused)."""
    config = hand_render_config(model) if config is None else config
    hand = hand_field(model, params) if hand is None else hand
    field = model.field
    center, radius = hand_bounds(params, model.config)
    center = center.to(field.device, field.dtype)
    density = LaplaceDensity(beta_init=float(model.beta), beta_min=0.0).to(field.device)
    grid = shared_grid(hand.sdf_fn(), center, radius, config, density)
    return HandScene(hand=hand, config=config, density=density, center=center, radius=radius,
                     grid=grid)


def render_hand(
    model: TrainedModel,
    params: HandParams,
    cameras: Sequence[Camera],
    config: ImageRenderConfig | None = None,
    *,
    progress: bool = False,
) -> list[ImageOutput]:
    """Render a hand from every camera (one occupancy grid shared by all).

    Colours are calibrated with the model's mean gain and bias; ``config`` defaults to
    :func:`hand_render_config` (volume rendering, normals). -> one :class:`ImageOutput` per
    camera (rgb [H, W, 3], opacity, depth metres, normals, mask).
    """
    cameras = list(cameras)
    if not cameras:
        raise ValueError("cameras must not be empty")
    scene = prepare_render(model, params, config)
    return [scene.render(camera, progress=progress) for camera in cameras]


def _fit_distance(radius: float, width: int, height: int, fov_deg: float) -> float:
    """Camera distance at which a sphere of ``radius`` fills the smaller image side (5 % margin)."""
    focal = 0.5 * width / math.tan(math.radians(fov_deg) / 2.0)
    half_angle = math.atan(0.5 * min(width, height) / focal)
    return 1.05 * radius / math.sin(half_angle)


def orbit_views(
    scene: HandScene,
    num_views: int,
    width: int = 512,
    height: int = 512,
    *,
    elevation_deg: float = 15.0,
    fov_deg: float = 30.0,
    framing: tuple[torch.Tensor, float] | None = None,
) -> list[Camera]:
    """``num_views`` cameras on a circle around the hand's finger axis (image up = fingers),
    the first one facing the palm, all framing the hand's surface.

    framing: (center [3], radius) metres of the sphere to frame (default the scene's
    :meth:`HandScene.framing_sphere`). -> cameras ``orbit000``... in the model's dtype.
    """
    center, radius = scene.framing_sphere() if framing is None else framing
    fingers, palm = scene.hand_axes()
    distance = _fit_distance(radius, width, height, fov_deg)
    cameras = orbit_cameras(
        num_views, center, distance, elevation_deg, width, height, fov_deg, up=fingers,
        front=palm, dtype=scene.hand.model.field.dtype,
    )  # fmt: skip
    return cameras


# The camera helper below is pure camera math; its natural home is lisa_hand.geometry.cameras
# (kept here, beside the renders that use it, until that module takes it).
def scale_camera(camera: Camera, width: int, height: int) -> Camera:
    """The camera rendering ``width x height`` pixels of the same view (intrinsics scaled)."""
    for name, value in (("width", width), ("height", height)):
        if isinstance(value, bool) or not isinstance(value, int) or value < 1:
            raise ValueError(f"{name} must be a positive int (pixels), got {value!r}")
    if (width, height) == (camera.width, camera.height):
        return camera
    scale = torch.tensor([width / camera.width, height / camera.height, 1.0],
                         dtype=camera.dtype, device=camera.device)
    return Camera(K=camera.K * scale[:, None], R=camera.R, t=camera.t, width=width,
                  height=height, name=camera.name)


_UNSAFE = re.compile(r"[^A-Za-z0-9_.-]+")


def file_stem(names: Sequence[str | None], default: str = "view") -> list[str]:
    """File-name-safe, unique stems for cameras: the name with unsafe characters replaced by
    ``_`` (``{default}{index:03d}`` when there is none), an index appended to repeats."""
    stems, seen = [], set()
    for index, name in enumerate(names):
        stem = _UNSAFE.sub("_", name).strip("._") if name else ""
        stem = stem or f"{default}{index:03d}"
        if stem in seen:
            stem = f"{stem}_{index:03d}"
        seen.add(stem)
        stems.append(stem)
    return stems


@dataclass
class RenderResult:
    """What :func:`render_to_folder` wrote.

    views: per camera, the paths by kind ('rgb', 'normals', 'mask', 'depth').
    cameras_path: ``cameras.json`` with the cameras used. gif_path, video_path: the turntable
    (None when not asked, or no MP4 backend). seconds: wall time of the renders.
    """

    views: list[dict[str, Path]]
    cameras_path: Path
    gif_path: Path | None
    video_path: Path | None
    seconds: float


def mp4_available() -> bool:
    """Whether imageio can write MP4 here (the ``av`` or ``imageio-ffmpeg`` package)."""
    import importlib.util

    return any(importlib.util.find_spec(name) is not None for name in ("av", "imageio_ffmpeg"))


def render_to_folder(
    scene: HandScene,
    cameras: Sequence[Camera],
    out_dir: str | os.PathLike,
    *,
    turntable: bool = False,
    fps: float = 12.0,
    log: Callable[[str], None] | None = None,
) -> RenderResult:
    """Render every camera of ``scene`` and write, per camera ``NAME``
    (:func:`file_stem`), ``NAME_rgb.png``, ``NAME_normals.png`` (world-frame ``(n + 1) / 2``,
    when the config computes normals), ``NAME_mask.png`` and ``NAME_depth.npy`` (metres along
    the ray), plus ``cameras.json``; with ``turntable``, the RGB views as ``turntable.gif`` and,
    when an MP4 backend is installed, ``turntable.mp4``. All writes are atomic."""
    from ..geometry.cameras import save_cameras
    from ..render.saving import image_to_uint8, save_image_outputs
    from ..render.turntable import save_gif, save_video

    cameras = list(cameras)
    if not cameras:
        raise ValueError("cameras must not be empty")
    if not fps > 0:
        raise ValueError(f"fps must be > 0, got {fps!r}")
    log = log or (lambda message: None)
    out_dir = Path(out_dir)
    start = time.perf_counter()
    views, frames = [], []
    for index, (camera, stem) in enumerate(
        zip(cameras, file_stem([c.name for c in cameras]), strict=True)
    ):
        output = scene.render(camera)
        views.append(save_image_outputs(out_dir, output, stem))
        frames.append(image_to_uint8(output.rgb[..., :3]))
        log(f"view {index + 1}/{len(cameras)}: {views[-1]['rgb']} "
            f"({int(output.mask.sum())} hand pixels)")
    seconds = time.perf_counter() - start
    cameras_path = save_cameras(out_dir / "cameras.json", cameras)
    gif_path = video_path = None
    if turntable:
        gif_path = save_gif(out_dir / "turntable.gif", frames, fps)
        if mp4_available():
            video_path = save_video(out_dir / "turntable.mp4", frames, fps)
    return RenderResult(views=views, cameras_path=cameras_path, gif_path=gif_path,
                        video_path=video_path, seconds=seconds)
