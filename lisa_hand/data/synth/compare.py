"""A contact sheet of hand model v1 beside v2: the generator's subjects, rest pose and one pose.

``python -m lisa_hand.data.synth.compare docs/hand_model_v1_v2.png`` writes the sheet of the
docs: ``num_subjects`` columns (the dataset subjects s000, s001, ... of ``SynthConfig(seed)``
with ``hand_model="v1"`` and ``"v2"``) and four rows: v1 at rest (back of the hand, oblique
view), v1 in the subject's first dataset pose (palm side), v2 at rest, v2 in the same pose (the
frame's pose does not depend on the hand model). Meshes and tiles as ``lisa synth --preview``
(:func:`lisa_hand.handmodel.render_preview`, white background, global rotation removed).
"""

from __future__ import annotations

import argparse
import dataclasses
import os
from pathlib import Path

from ...utils.threads import cpu_threads
from ..layout import write_image
from .config import SynthConfig, check_integer
from .scene import frame_setup, make_subject

__all__ = ["write_model_comparison", "main"]

_ROW_VIEWS = ("oblique", "oblique_palmar")


def _tiles(config: SynthConfig, num_subjects: int, tile_size: int, voxels_per_length: int):
    """Two rows of tiles (rest, posed) of the first ``num_subjects`` subjects of ``config``."""
    from ...handmodel import VIEWS, render_preview

    rows: list[list] = [[], []]
    for index in range(num_subjects):
        subject = make_subject(config, index, fit_template=False)
        pose = frame_setup(config, subject, 0).pose.clone()
        pose[:3] = 0.0
        for row, posed_pose in enumerate((None, pose)):
            hand = subject.hand
            mesh = hand.posed(posed_pose).mesh(
                voxel_size=hand.shape.hand_length / voxels_per_length, skin_weights=False)
            look, up = VIEWS[_ROW_VIEWS[row]]
            if hand.side == "left":
                look, up = (-look[0], look[1], look[2]), (-up[0], up[1], up[2])
            rows[row].append(render_preview(mesh.vertices, mesh.faces, mesh.colors,
                                            view=(look, up), size=tile_size))
    return rows


def write_model_comparison(path: str | os.PathLike, num_subjects: int = 8, seed: int = 0,
                           tile_size: int = 240, voxels_per_length: int = 160,
                           progress: bool = True) -> Path:
    """Write the v1-beside-v2 contact sheet PNG (rows: v1 rest, v1 posed, v2 rest, v2 posed;
    one column per subject). -> the path written.

    num_subjects: columns (>= 1). seed: the datasets' seed. tile_size: pixels per tile side.
    voxels_per_length: marching-cubes voxels per hand length (160: 1.2 mm, quick; the dataset
    uses 255).
    """
    from tqdm.auto import tqdm

    from ...handmodel import contact_sheet

    num_subjects = check_integer(num_subjects, "num_subjects", 1)
    tile_size = check_integer(tile_size, "tile_size", 32)
    voxels_per_length = check_integer(voxels_per_length, "voxels_per_length", 16)
    path = Path(path)
    if path.suffix.lower() != ".png":
        raise ValueError(f"{path}: the comparison sheet is a PNG file (name it *.png)")
    path.parent.mkdir(parents=True, exist_ok=True)
    tiles = []
    with cpu_threads(1):
        for model in tqdm(("v1", "v2"), desc="compare", disable=not progress):
            config = dataclasses.replace(SynthConfig(seed=seed), hand_model=model)
            for row in _tiles(config, num_subjects, tile_size, voxels_per_length):
                tiles.extend(row)
    return write_image(path, contact_sheet(tiles, columns=num_subjects))


def main(argv: list[str] | None = None) -> int:
    """``python -m lisa_hand.data.synth.compare OUT.png [--subjects N] [--seed S]``."""
    parser = argparse.ArgumentParser(
        prog="python -m lisa_hand.data.synth.compare",
        description="Contact sheet of the open hand model v1 beside v2 (rows: v1 rest, v1 "
                    "posed, v2 rest, v2 posed; one column per generator subject).")
    parser.add_argument("out", type=Path, help="PNG file to write.")
    parser.add_argument("--subjects", type=int, default=8, help="Subjects (columns).")
    parser.add_argument("--seed", type=int, default=0, help="Seed of the generator's datasets.")
    parser.add_argument("--tile-size", type=int, default=240, help="Pixels per tile side.")
    parser.add_argument("--mesh-resolution", type=int, default=160,
                        help="Marching-cubes voxels per hand length.")
    args = parser.parse_args(argv)
    try:
        path = write_model_comparison(args.out, args.subjects, args.seed, args.tile_size,
                                      args.mesh_resolution)
    except (ValueError, OSError) as exc:
        parser.exit(2, f"error: {exc}\n")
    print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
