"""Several hands in one photo (``lisa fit-photo`` without ``--hand``): their masks split
between them before each is fitted alone (:func:`split_coarse_masks`), then all refined
together (:func:`fit_together`: :func:`lisa_hand.fitting.pair.joint.fit_hands_together`, each
hand's field at the others' surfaces, depth order from the split masks), and the files of all
of them beside each hand's folder (:func:`several_artefacts`): ``hands.json``
(:func:`lisa_hand.fitting.pair.record.hands_record`), ``hands.ply`` (every hand's mesh in one,
the photo's camera frame) and ``overlay.png`` (every hand over the photo).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch

__all__ = ["Together", "split_coarse_masks", "fit_together", "several_artefacts"]


@dataclass
class Together:
    """The joint fit of a photo's hands: each hand's (mesh, specks) as written, their
    penetration [K, K] mm on those meshes, the joint stage's report (None when it did not run:
    ``joint.iters`` 0) and notes."""

    meshes: list[tuple[Any, Any]]
    penetration_mm: np.ndarray
    report: Any
    notes: list[str]


def split_coarse_masks(inputs: list[Any], targets: list[tuple[str, list[Any]]]
                       ) -> list[list[np.ndarray]]:
    """One photo's hands (``targets``, one hand each): their coarse masks
    (:func:`lisa_hand.fitting.photo.mask.coarse_mask`) with every pixel given to one hand
    (:func:`lisa_hand.fitting.photo.mask.split_masks`) -> per target [its mask]."""
    from .mask import coarse_mask, split_masks

    photo = inputs[0].photo
    keypoints = [hands[0].keypoints for _, hands in targets]
    masks = split_masks([coarse_mask(photo.image, points) for points in keypoints], keypoints)
    return [[mask] for mask in masks]


def _notes(alones: list[Any]) -> list[str]:
    sides = [alone.side for alone in alones]
    notes = []
    if len(alones) > 2:
        notes.append(f"{len(alones)} hands found: each fitted, then all together")
    for side in ("right", "left"):
        if sides.count(side) > 1:
            notes.append(f"{sides.count(side)} {side} hands in one photo: fitted as found "
                         "(two people's hands, or a side the detector got wrong: fit one with "
                         "--hand N --side)")
    return notes


def fit_together(model: Any, alones: list[Any], config: Any, progress: bool,
                 log: Callable[[str], None]) -> Together:
    """Refine a photo's hands fitted alone (``alones``, the photo fit's) together; their
    results are replaced in place by the joint fit's -> :class:`Together`."""
    from ...utils.threads import cpu_threads
    from ..pair.contact import HandBody, penetration_depths
    from ..pair.joint import HandView, JointHand, fit_hands_together
    from ..stages import template_on
    from .fit import alone_mesh

    notes = _notes(alones)
    with cpu_threads(config.fit.num_threads):
        meshes = [alone_mesh(model, alone, config) for alone in alones]
        report = None
        if config.fit.joint.iters > 0:
            K = alones[0].inputs[0].camera.K
            hands = [JointHand(params=alone.result.params, mesh=mesh, views=(HandView(
                K=K, keypoints=alone.hands[0].keypoints, visible=alone.hands[0].visible,
                mask=alone.coarse[0]),)) for alone, (mesh, _) in zip(alones, meshes, strict=True)]
            template = template_on(None, torch.device("cpu"))
            fitted, report = fit_hands_together(model, hands, template, config.fit.joint,
                                                progress)
            for alone, params in zip(alones, fitted, strict=True):
                params.extra["joint"] = report.to_dict()
                if report.iters > 0:  # moved: its surface is meshed again
                    alone.result = dataclasses.replace(alone.result, params=params,
                                                       surface_meshes={})
            if report.iters > 0:
                meshes = [alone_mesh(model, alone, config) for alone in alones]
        bodies = [HandBody.of(model, alone.result.params, mesh, 1, 0)
                  for alone, (mesh, _) in zip(alones, meshes, strict=True)]
        depths = penetration_depths(model, bodies)
    if report is not None and report.iters > 0:
        log(f"hands fitted together: deepest penetration {report.penetration_start_mm.max():.1f}"
            f" -> {depths.max():.1f} mm ({report.seconds:.1f} s)")
    elif report is not None:
        log("the hands do not meet: each kept as fitted alone")
    for note in notes:
        log(note)
    return Together(meshes=meshes, penetration_mm=depths, report=report, notes=notes)


def several_artefacts(model: Any, together: Together, alones: list[Any]) -> list[Any]:
    """``hands.json``, ``hands.ply`` and ``overlay.png`` of a photo's hands."""
    from ...inference.mesh_render import render_meshes_over
    from ..outputs import hand_keypoints_3d, image_artefact, json_artefact, mesh_artefact
    from ..pair.record import hands_record, joined_mesh

    params = [alone.result.params for alone in alones]
    roots = np.stack([hand_keypoints_3d(hand)[0] for hand in params])
    record = hands_record(params, [alone.folder for alone in alones], roots,
                          together.penetration_mm, "the photo's camera (OpenCV: x right, y "
                          "down, z forward), metres",
                          None if together.report is None else together.report.to_dict(),
                          together.notes)
    meshes = [mesh for mesh, _ in together.meshes]
    photo = alones[0].inputs[0]
    rgb = np.clip(np.asarray(photo.photo.image) * 255.0 + 0.5, 0, 255).astype(np.uint8)
    overlay = render_meshes_over(model, rgb, photo.camera, meshes, alpha=0.8, supersample=2)
    return [json_artefact("hands.json", record), mesh_artefact(joined_mesh(meshes), "hands.ply"),
            image_artefact("overlay.png", np.concatenate([rgb, overlay], axis=1))]
