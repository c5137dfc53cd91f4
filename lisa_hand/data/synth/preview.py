"""A contact sheet of a synthetic dataset's subjects and poses (``lisa synth --preview``)."""

from __future__ import annotations

import os
from pathlib import Path

import torch

from ...utils.threads import cpu_threads
from ..layout import write_image
from .config import SynthConfig, check_integer
from .scene import SubjectRecord, frame_setup, make_subject, preview_generator

__all__ = ["write_preview"]

# Views of the preview tiles, cycled over the columns (names of lisa_hand.handmodel.VIEWS).
_PREVIEW_VIEWS = ("oblique", "oblique", "oblique_palmar", "palmar", "oblique", "oblique_palmar")
_PREVIEW_NAMED = ("relaxed", "fist", "pinch", "point", "ok")


def write_preview(path: str | os.PathLike, config: SynthConfig | None = None,
                  num_subjects: int = 4, num_poses: int = 6, tile_size: int = 320) -> Path:
    """A contact sheet PNG: ``num_subjects`` rows (the dataset's subjects s000, s001, ...) by
    ``num_poses`` columns (named poses, then the subject's own dataset poses), each hand shown
    without its global rotation from a named view (:func:`lisa_hand.handmodel.render_preview`,
    white background, the dataset's mesh resolution). -> the path written.
    """
    from ...handmodel import VIEWS, contact_sheet, named_pose, render_preview

    config = SynthConfig() if config is None else config
    if not isinstance(config, SynthConfig):
        raise TypeError(f"config must be a SynthConfig, got {type(config).__name__}")
    num_subjects = check_integer(num_subjects, "num_subjects", 1)
    num_poses = check_integer(num_poses, "num_poses", 1)
    tile_size = check_integer(tile_size, "tile_size", 32)
    path = Path(path)
    if path.suffix.lower() != ".png":
        raise ValueError(f"{path}: the preview is a PNG file (name it *.png)")
    path.parent.mkdir(parents=True, exist_ok=True)
    with cpu_threads(1):
        tiles = []
        for index in range(num_subjects):
            subject = make_subject(config, index, fit_template=False)
            side = subject.hand.side
            num_named = min(len(_PREVIEW_NAMED), (num_poses + 1) // 2)
            poses = [named_pose(name, side=side, dtype=torch.float64)
                     for name in _PREVIEW_NAMED[:num_named]]
            sampled = _sampled_preview_poses(config, subject, num_poses - num_named)
            for column, pose in enumerate(poses + sampled):
                pose = pose.clone()
                pose[:3] = 0.0
                mesh = subject.hand.posed(pose).mesh(
                    voxel_size=subject.hand.shape.hand_length / config.voxels_per_length,
                    skin_weights=False)
                look, up = VIEWS[_PREVIEW_VIEWS[column % len(_PREVIEW_VIEWS)]]
                if side == "left":  # the mirror image of the right hand's view
                    look, up = (-look[0], look[1], look[2]), (-up[0], up[1], up[2])
                tiles.append(render_preview(mesh.vertices, mesh.faces, mesh.colors,
                                            view=(look, up), size=tile_size))
        sheet = contact_sheet(tiles, columns=num_poses)
    return write_image(path, sheet)


def _sampled_preview_poses(config: SynthConfig, subject: SubjectRecord,
                           count: int) -> list[torch.Tensor]:
    """``count`` sampled poses: the subject's first dataset poses that are not named ones, then
    (if the dataset has too few, e.g. ``named_pose_fraction = 1``) fresh natural poses."""
    from ...handmodel import sample_pose

    poses: list[torch.Tensor] = []
    frame = 0
    while len(poses) < count and frame < min(config.num_poses, count + 16):
        setup = frame_setup(config, subject, frame)
        if setup.pose_name is None:
            poses.append(setup.pose)
        frame += 1
    if len(poses) < count:
        generator = preview_generator(config, subject.index)
        extra = sample_pose(generator, count - len(poses), noise=config.pose_noise,
                            side=subject.hand.side).double()
        poses.extend(extra.unbind(0))
    return poses
