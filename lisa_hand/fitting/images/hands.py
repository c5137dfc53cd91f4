"""Several hands seen by the same calibrated cameras (``lisa fit-images DIR1 DIR2 ...``: one
frame folder a hand, as ``lisa import interhand2.6m`` writes an interacting frame): each hand
fitted alone (:func:`lisa_hand.fitting.images.fit.fit_images`), then all together
(:func:`lisa_hand.fitting.pair.joint.fit_hands_together`: every hand's keypoints in every
view, each hand's field at the other hands' surfaces, depth order from the views' masks split
between the hands), and written as ``OUT/handN/`` (``params.json``, ``mesh.ply``,
``keypoints.json``), ``OUT/hands.json`` and ``OUT/hands.ply``
(:func:`fit_image_folders`).
"""

from __future__ import annotations

import dataclasses
import os
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from ..outputs import releases_output_locks

__all__ = ["fit_image_folders"]


def _joint_views(hands_views: list[list[Any]]) -> list[tuple[Any, ...]]:
    """Each hand's views as the joint fit's :class:`~lisa_hand.fitting.pair.joint.HandView`,
    the masks of each camera split between the hands
    (:func:`lisa_hand.fitting.photo.mask.split_masks`; a camera where some hand has no mask or
    no keypoints keeps none)."""
    from ..pair.joint import HandView
    from ..photo.mask import split_masks

    out: list[list[Any]] = [[] for _ in hands_views]
    for views in zip(*hands_views, strict=True):
        known = all(view.mask is not None and view.keypoints is not None for view in views)
        masks = split_masks([view.mask.cpu().numpy() > 0 for view in views],
                            [view.keypoints.double().cpu().numpy() for view in views]) \
            if known else [None] * len(views)
        for index, (view, mask) in enumerate(zip(views, masks, strict=True)):
            if view.keypoints is None:
                continue
            camera = view.camera
            out[index].append(HandView(
                K=camera.K.double().cpu(), R=camera.R.double().cpu(), t=camera.t.double().cpu(),
                keypoints=view.keypoints.double().cpu().numpy(),
                visible=view.visible.cpu().numpy().astype(bool), mask=mask))
    return [tuple(views) for views in out]


def _same_camera(first: Any, second: Any) -> bool:
    """The same calibration: intrinsics within 0.01 px, pose within 1e-5 (rotation) and 0.01
    mm, the same image size."""
    import torch

    return ((first.width, first.height) == (second.width, second.height)
            and torch.allclose(first.K.double(), second.K.double(), atol=1e-2)
            and torch.allclose(first.R.double(), second.R.double(), atol=1e-5)
            and torch.allclose(first.t.double(), second.t.double(), atol=1e-5))


def _read_folders(frame_dirs: list[Path], sides: Sequence[str], views: Sequence[str] | None
                  ) -> list[list[Any]]:
    """Each folder's views, checked: one side each, the same calibrated cameras."""
    from .views import read_views

    if len(frame_dirs) < 2 or len(sides) != len(frame_dirs):
        raise ValueError(f"{len(frame_dirs)} frame folder(s) and {len(sides)} side(s): give "
                         "one --side per folder, in order (right or left)")
    for side in sides:
        if side not in ("right", "left"):
            raise ValueError(f"side must be 'right' or 'left', got {side!r}")
    hands_views = [read_views(frame, views) for frame in frame_dirs]
    names = [[view.name for view in one] for one in hands_views]
    if any(one != names[0] for one in names):
        raise ValueError(f"the frame folders {', '.join(map(str, frame_dirs))} must hold the "
                         f"same cameras (--views to choose), got {names}")
    for frame, one in zip(frame_dirs[1:], hands_views[1:], strict=True):
        for view, first in zip(one, hands_views[0], strict=True):
            if not _same_camera(view.camera, first.camera):
                raise ValueError(f"{frame}: camera {view.name} is not {frame_dirs[0]}'s "
                                 f"{first.name} (other intrinsics or pose): the hands must be "
                                 "seen by the same calibrated cameras")
    return hands_views


@releases_output_locks
def fit_image_folders(
    frame_dirs: Sequence[str | os.PathLike],
    out_dir: str | os.PathLike,
    sides: Sequence[str],
    *,
    views: Sequence[str] | None = None,
    model_path: str | os.PathLike | None = None,
    resolution: int = 128,
    config: Any = None,
    device: str = "auto",
    progress: bool = False,
    log: Callable[[str], None] | None = None,
) -> list[Path]:
    """Fit one hand per frame folder (the same cameras in each; ``sides``: each one's "right"
    or "left") alone and then together, and write them (module docstring). views, model_path,
    resolution, device: as :func:`lisa_hand.fitting.images.folder.fit_image_folder`'s; config:
    :class:`lisa_hand.fitting.images.config.FitImagesConfig` (its ``joint`` the joint fit's).
    -> the written paths."""
    import torch

    from ...model.trained import load_trained, model_label
    from ...utils.config import config_to_dict
    from ...utils.device import resolve_device
    from ..outputs import (
        fit_artefacts,
        hand_keypoints_3d,
        json_artefact,
        mesh_artefact,
        write_fit,
    )
    from ..outputs.folder import claim_output_folder, hands_entry
    from ..pair.contact import HandBody, penetration_depths
    from ..pair.joint import JointHand, fit_hands_together
    from ..pair.record import hands_record, joined_mesh
    from ..stages import template_on
    from .config import FitImagesConfig
    from .fit import fit_images
    from .folder import fitted_mesh

    log = log or (lambda line: None)
    config = FitImagesConfig() if config is None else config
    frame_dirs = [Path(frame) for frame in frame_dirs]
    hands_views = _read_folders(frame_dirs, sides, views)
    out_dir = claim_output_folder(out_dir, hands_entry, "hands.json, hands.ply and hand0/, "
                                  "hand1/, ... folders")
    model = load_trained(model_path, resolve_device(device))
    fits = []
    for index, (frame, side, image_views) in enumerate(zip(frame_dirs, sides, hands_views,
                                                           strict=True)):
        log(f"hand{index}: {frame} ({side})")
        fits.append(fit_images(model, image_views, config, progress, side=side))
    meshes = [fitted_mesh(model, fit, resolution) for fit in fits]
    joint = [JointHand(params=fit.params, mesh=mesh, views=hand_views)
             for fit, mesh, hand_views in zip(fits, meshes, _joint_views(hands_views),
                                              strict=True)]
    hands, report = fit_hands_together(model, joint, template_on(None, torch.device("cpu")),
                                       config.joint, progress)
    meshes = [fitted_mesh(model, dataclasses.replace(fit, params=hand, surface_meshes={}),
                          resolution) for fit, hand in zip(fits, hands, strict=True)]
    artefacts = []
    for index, (frame, hand, mesh) in enumerate(zip(frame_dirs, hands, meshes, strict=True)):
        hand.model = model_label(model_path)
        hand.extra["input"] = {"path": str(frame), "hands": [str(f) for f in frame_dirs]}
        hand.extra["config"] = config_to_dict(config)
        artefacts += [dataclasses.replace(artefact, name=f"hand{index}/{artefact.name}")
                      for artefact in fit_artefacts(hand, mesh)]
    depths = penetration_depths(model, [HandBody.of(model, hand, mesh, 1, 0)
                                        for hand, mesh in zip(hands, meshes, strict=True)])
    roots = np.stack([hand_keypoints_3d(hand)[0] for hand in hands])
    record = hands_record(hands, [f"hand{k}" for k in range(len(hands))], roots, depths,
                          "the cameras' world (cameras.json), metres", report.to_dict(), [])
    artefacts += [json_artefact("hands.json", record),
                  mesh_artefact(joined_mesh(meshes), "hands.ply")]
    log(f"{len(hands)} hands fitted together: keypoint error "
        + ", ".join(f"{error:.1f}" for error in report.keypoint_error_end_px)
        + f" px; deepest penetration {depths.max():.1f} mm")
    return write_fit(out_dir, artefacts, hands_entry,
                     "hands.json, hands.ply and hand0/, hand1/, ... folders")
