"""Inference with a trained LISA model: mesh, render, re-pose and mix fitted hands.

What ``lisa mesh``, ``lisa render``, ``lisa animate`` and ``lisa blend`` do, as functions over a
:class:`~lisa_hand.model.trained.TrainedModel` and a :class:`~lisa_hand.skeleton.params.HandParams`
(the one hand state: the ``params.json`` of a fitted hand). One concept per module:

* :mod:`.hand_field`: :func:`hand_field` binds a hand to a model and prepares one frame of the
  field: a :class:`HandField`, whose callbacks (``sdf_fn``, the colour-calibrated ``field_fn``,
  per-point colours and skinning weights) follow the one field protocol, in the world frame.
  :func:`load_hand` reads ``params.json`` and the model it names.
* :mod:`.bounds`: :func:`hand_bounds`, a sphere that holds the zero level set (the posed bone
  regions plus a margin), and :func:`skeleton_box`, the tighter box where a surface is expected.
* :mod:`.mesh`: :func:`mesh_hand`, coarse-to-fine marching cubes with per-vertex colours and
  skinning weights; :func:`repose_mesh` moves a mesh to another pose by skinning.
* :mod:`.render`: :func:`prepare_render` / :func:`render_hand`, novel views sharing one
  occupancy grid; :func:`orbit_views` places a turntable around the hand's finger axis;
  :func:`render_to_folder` writes them.
* :mod:`.sequences`: pose sequences (:func:`read_pose_sequence`, :func:`motion_poses`).
* :mod:`.animate`: :func:`animate_hand` re-poses a hand along a sequence, writing a mesh and a
  frame per pose from one fixed camera.
* :mod:`.blend`: :func:`blend_params` swaps or interpolates the shape (code and skeleton) and
  colour codes of two fitted hands; the field keeps them disentangled.

Nothing here is differentiable: everything runs under ``torch.no_grad`` (normals use autograd
through the SDF inside the renderer).
"""

from .animate import MESH_MODES, AnimationResult, animate_hand
from .blend import blend_params
from .bounds import grid_surface_box, hand_bounds, posed_segments, skeleton_box, union_sphere
from .hand_field import (
    GEOMETRY_ONLY_GREY,
    HandField,
    check_params,
    hand_field,
    load_hand,
    resolve_model_path,
)
from .mesh import (
    HandMesh,
    MeshConfig,
    check_resolution,
    mesh_attributes,
    mesh_hand,
    mesh_hand_with_stats,
    mirror_mesh,
    repose_mesh,
)
from .render import (
    HandScene,
    RenderResult,
    file_stem,
    hand_render_config,
    mp4_available,
    orbit_views,
    prepare_render,
    render_hand,
    render_to_folder,
    scale_camera,
)
from .sequences import PoseSequence, motion_poses, read_pose_sequence, resolve_poses

__all__ = [
    "GEOMETRY_ONLY_GREY",
    "MESH_MODES",
    "HandField",
    "check_params",
    "hand_field",
    "resolve_model_path",
    "load_hand",
    "posed_segments",
    "hand_bounds",
    "skeleton_box",
    "grid_surface_box",
    "union_sphere",
    "MeshConfig",
    "HandMesh",
    "check_resolution",
    "mesh_attributes",
    "mesh_hand",
    "mesh_hand_with_stats",
    "mirror_mesh",
    "repose_mesh",
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
    "PoseSequence",
    "read_pose_sequence",
    "resolve_poses",
    "motion_poses",
    "AnimationResult",
    "animate_hand",
    "blend_params",
]
