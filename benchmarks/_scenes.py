"""The scenes of the render benchmark (``python -m benchmarks render``): a field, its
callbacks and the palm camera (see :mod:`benchmarks.render` for what each scene is).

The leading underscore keeps this module out of :func:`benchmarks.benchmark_names`.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import torch

from lisa_hand.geometry.cameras import Camera, intrinsics_from_fov, look_at

__all__ = [
    "BenchScene",
    "lisa_scene",
    "capsule_scene",
    "lisa_capsule_scene",
    "trained_scene",
    "SCENES",
    "make_scene",
]

_CAMERA_DISTANCE = 0.6
_FOV_DEG = 40.0
# Capsule radii of the analytic hand, metres: palm segments and finger segments.
_PALM_RADIUS = 0.013
_FINGER_RADIUS = 0.0085


@dataclass
class BenchScene:
    """A field and a camera to render it with.

    field_fn: points [N, 3] metres, directions [N, 3] -> (sdf [N] metres, rgb [N, 3]).
    sdf_fn: points [N, 3] metres -> sdf [N] metres. camera: the view.
    center: [3] metres and radius (metres) of a sphere holding the surface.
    lipschitz: bound on the SDF's overestimation (1 for an exact SDF).
    description: one line for the log.
    beta: the field's own Laplace scale, metres (a trained model's), or None.
    """

    field_fn: Callable
    sdf_fn: Callable
    camera: Camera
    center: torch.Tensor
    radius: float
    lipschitz: float
    description: str
    beta: float | None = None


def _posed_segments(pose: torch.Tensor, rest_joints: torch.Tensor, tip_extension: float):
    """World segments of the posed hand: (start [20, 3], end [20, 3], owner bone ids, rotation of
    the root [3, 3]). pose: [1, 48] radians; rest_joints: [16, 3] metres."""
    from lisa_hand.fields.bones import SEGMENT_BONES, bone_segments
    from lisa_hand.skeleton import forward_kinematics

    kinematics = forward_kinematics(pose, rest_joints[None])
    start, end = bone_segments(rest_joints[None], tip_extension)
    transforms = kinematics.transforms[0, list(SEGMENT_BONES)]
    rot, trans = transforms[:, :3, :3], transforms[:, :3, 3]
    start = (rot @ start[0, :, :, None])[..., 0] + trans
    end = (rot @ end[0, :, :, None])[..., 0] + trans
    return start, end, list(SEGMENT_BONES), kinematics.transforms[0, 0, :3, :3]


def _palm_camera(
    center: torch.Tensor, root_rotation: torch.Tensor, width: int, height: int
) -> Camera:
    """A camera 0.6 m in front of the palm (rest palm normal -y), fingers (rest -x) up."""
    palm_normal = root_rotation @ torch.tensor([0.0, -1.0, 0.0])
    fingers = root_rotation @ torch.tensor([-1.0, 0.0, 0.0])
    eye = center + _CAMERA_DISTANCE * palm_normal
    rotation, translation = look_at(eye, center, fingers)
    K = intrinsics_from_fov(_FOV_DEG, width, height)
    return Camera(K=K, R=rotation, t=translation, width=width, height=height, name="bench")


def _bounding_sphere(start, end, radii) -> tuple[torch.Tensor, float]:
    ends = torch.cat([start, end])
    center = 0.5 * (ends.amin(dim=0) + ends.amax(dim=0))
    reach = torch.maximum((start - center).norm(dim=-1), (end - center).norm(dim=-1)) + radii
    return center, float(reach.max()) * 1.02


def lisa_scene(
    width: int,
    height: int,
    seed: int = 0,
    *,
    model=None,
    pose: torch.Tensor | None = None,
    rest_joints: torch.Tensor | None = None,
    shape_code: torch.Tensor | None = None,
    color_code: torch.Tensor | None = None,
    lipschitz: float = 1.2,
) -> BenchScene:
    """The LISA field of ``model`` (default: a fresh ``LisaModel()`` at its geometric
    initialisation) for one frame, with the palm camera.

    model: a :class:`lisa_hand.model.LisaModel` (a trained one for real renders).
    pose: [1, 48] radians (default :func:`benchmarks.field.bench_pose`). rest_joints: [16, 3]
    metres (default ``AVERAGE_REST_JOINTS``). shape_code: [1, shape_dim] (default zeros);
    color_code: [1, color_dim] (default 0.5 N(0, 1), seeded).
    lipschitz: allowance for the learned SDF overestimating distances.
    """
    from lisa_hand.fields import FieldConfig
    from lisa_hand.model.lisa import LisaModel
    from lisa_hand.skeleton import AVERAGE_REST_JOINTS

    from .field import bench_pose

    generator = torch.Generator().manual_seed(seed)
    rest_joints = torch.tensor(AVERAGE_REST_JOINTS) if rest_joints is None else rest_joints
    if model is None:
        model = LisaModel(FieldConfig(), init_rest_joints=rest_joints).eval()
    config = model.config
    pose = bench_pose(generator) if pose is None else pose
    if shape_code is None:
        shape_code = torch.zeros(1, config.shape_dim)
    if color_code is None:
        color_code = 0.5 * torch.randn(1, config.color_dim, generator=generator)
    with torch.no_grad():
        state = model.prepare(pose, None, rest_joints[None], shape_code, color_code)
    start, end, owners, root = _posed_segments(pose, rest_joints, config.tip_extension)
    radii = torch.tensor(
        [config.palm_region_radius if o == 0 else config.finger_region_radius for o in owners]
    )
    center, radius = _bounding_sphere(start, end, radii)
    return BenchScene(
        field_fn=model.field_fn(state),
        sdf_fn=model.sdf_fn(state),
        camera=_palm_camera(center, root, width, height),
        center=center,
        radius=radius,
        lipschitz=lipschitz,
        description=f"LISA field ({config.composition}, geometric init), bone regions as bounds",
    )


def _capsule_sdf_fn(pose: torch.Tensor, rest_joints: torch.Tensor):
    """The union of the posed bone capsules: (sdf_fn, start [20, 3], end [20, 3], radii [20])."""
    start, end, owners, root = _posed_segments(pose, rest_joints, tip_extension=0.8)
    radii = torch.tensor([_PALM_RADIUS if o == 0 else _FINGER_RADIUS for o in owners])
    axis = end - start
    length = axis.norm(dim=-1)
    axis = axis / length[:, None]

    def sdf_fn(points: torch.Tensor) -> torch.Tensor:
        dtype = points.dtype
        rel = points[:, None, :] - start.to(dtype)
        along = (rel * axis.to(dtype)).sum(-1).clamp(min=0.0)
        along = torch.minimum(along, length.to(dtype))
        offset = rel - along[..., None] * axis.to(dtype)
        return (offset.norm(dim=-1) - radii.to(dtype)).amin(dim=-1)

    return sdf_fn, start, end, radii, root


def _capsule_colour(points: torch.Tensor) -> torch.Tensor:
    """Skin tone with a smooth pattern (a few mm wavelength), [N, 3] in [0, 1]."""
    skin = torch.tensor([0.85, 0.62, 0.5], dtype=points.dtype)
    pattern = 0.12 * torch.sin(150.0 * points) * torch.cos(90.0 * points.roll(1, dims=-1))
    return (skin + pattern).clamp(0.0, 1.0)


def capsule_scene(width: int, height: int, seed: int = 0) -> BenchScene:
    """The union of the posed skeleton's bone capsules (an exact SDF) with a colour pattern."""
    from lisa_hand.skeleton import AVERAGE_REST_JOINTS

    from .field import bench_pose

    generator = torch.Generator().manual_seed(seed)
    rest_joints = torch.tensor(AVERAGE_REST_JOINTS)
    pose = bench_pose(generator)
    sdf_fn, start, end, radii, root = _capsule_sdf_fn(pose, rest_joints)

    def field_fn(points: torch.Tensor, directions: torch.Tensor):
        return sdf_fn(points), _capsule_colour(points)

    center, radius = _bounding_sphere(start, end, radii)
    return BenchScene(
        field_fn=field_fn,
        sdf_fn=sdf_fn,
        camera=_palm_camera(center, root, width, height),
        center=center,
        radius=radius,
        lipschitz=1.0,
        description="union of 20 bone capsules (exact SDF), patterned colour",
    )


def lisa_capsule_scene(width: int, height: int, seed: int = 0) -> BenchScene:
    """The capsule hand with LISA's cost: every SDF and colour query also runs the LISA model of
    the same skeleton and pose (geometric initialisation), whose output perturbs the surface by
    at most 0.5 mm and gives 40 % of the colour. A trained LISA's surface covers the fingers like
    the capsules do, which the initialised model alone does not."""
    from lisa_hand.skeleton import AVERAGE_REST_JOINTS

    from .field import bench_pose

    lisa = lisa_scene(width, height, seed)
    generator = torch.Generator().manual_seed(seed)
    pose = bench_pose(generator)
    capsule_sdf, start, end, radii, root = _capsule_sdf_fn(pose, torch.tensor(AVERAGE_REST_JOINTS))
    perturbation = 5e-4  # metres; tanh(s / 5 cm) keeps its gradient below ~0.013

    def sdf_fn(points: torch.Tensor) -> torch.Tensor:
        return capsule_sdf(points) + perturbation * torch.tanh(lisa.sdf_fn(points) / 0.05)

    def field_fn(points: torch.Tensor, directions: torch.Tensor):
        lisa_sdf, lisa_rgb = lisa.field_fn(points, directions)
        sdf = capsule_sdf(points) + perturbation * torch.tanh(lisa_sdf / 0.05)
        return sdf, 0.6 * _capsule_colour(points) + 0.4 * lisa_rgb

    center, radius = _bounding_sphere(start, end, radii + perturbation)
    return BenchScene(
        field_fn=field_fn,
        sdf_fn=sdf_fn,
        camera=_palm_camera(center, root, width, height),
        center=center,
        radius=radius,
        lipschitz=1.05,
        description="capsule hand + LISA model evaluated at every query (LISA's cost)",
    )


def trained_scene(
    width: int, height: int, seed: int = 0, model_path: str | None = None,
    device: torch.device | str = "cpu",
) -> BenchScene:
    """A trained model (``model_path``, default the shipped one) as ``lisa render`` renders it:
    the benchmark pose on the average skeleton, the model's mean codes, calibrated colours; the
    field, camera and bound on ``device``."""
    from lisa_hand.inference import hand_bounds, hand_field, hand_render_config
    from lisa_hand.skeleton import forward_kinematics

    from .mesh import bench_hand

    if model_path is None:
        from lisa_hand.model.trained import default_model_path

        if not default_model_path().is_file():
            raise FileNotFoundError(f"{default_model_path()}: no shipped model; pass --model")
        model_path = str(default_model_path())
    model, params, description = bench_hand(model_path, seed)
    model = model.to(device)
    hand = hand_field(model, params)
    center, radius = hand_bounds(params, model.config)
    root = forward_kinematics(params.pose[None], params.rest_joints[None]).transforms[0, 0, :3, :3]
    return BenchScene(
        field_fn=hand.field_fn(),
        sdf_fn=hand.sdf_fn(),
        camera=_palm_camera(center, root, width, height).to(device),
        center=center.to(device),
        radius=radius,
        lipschitz=hand_render_config(model).lipschitz,
        description=description + " (lisa render's fields)",
        beta=float(model.beta),
    )


SCENES = ("auto", "trained", "lisa-capsules", "lisa", "capsules")


def make_scene(
    kind: str, width: int, height: int, seed: int = 0, model_path: str | None = None,
    device: torch.device | str = "cpu",
) -> BenchScene:
    """One of :data:`SCENES` (see the module docstring); ``model_path``: the trained model;
    ``device``: where it renders (a GPU for the trained scene only)."""
    if kind == "auto":
        from lisa_hand.model.trained import default_model_path

        trained = model_path is not None or default_model_path().is_file()
        kind = "trained" if trained else "lisa-capsules"
    if kind == "trained":
        return trained_scene(width, height, seed, model_path, device)
    if torch.device(device).type != "cpu":
        raise ValueError(f"the {kind!r} scene renders on the CPU only; a GPU renders the "
                         "trained field (--field trained)")
    if kind == "lisa-capsules":
        return lisa_capsule_scene(width, height, seed)
    if kind == "lisa":
        return lisa_scene(width, height, seed)
    if kind == "capsules":
        return capsule_scene(width, height, seed)
    raise ValueError(f"field must be one of {SCENES}, got {kind!r}")
