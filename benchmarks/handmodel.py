"""Hand model v3 benchmark: its population against the anthropometry it is drawn from, the
volume each skinning keeps per pose, and a contact sheet of v3 beside v2 and real photos.

``python -m benchmarks handmodel [--subjects N] [--volume-subjects K] [--sheet PNG]
[--photos DIR] [--json FILE]``

* **population**: ``N`` v3 subjects (:func:`lisa_hand.handmodel.sample_hand`); per sex the mean
  and SD of hand length, breadth and palm thickness as measured on the morphed mesh
  (:func:`lisa_hand.handmodel.makehuman.measure_hand`), their correlations, printed beside the
  published figures of :data:`lisa_hand.handmodel.anthropometry.ANTHROPOMETRIC_TABLE`;
* **volume**: per named pose, the change of the enclosed volume from the rest hand (the points
  whose winding number is above 1/2 on a 1.2 mm grid: folded skin counted once) with linear
  blend skinning, dual quaternion skinning, and dual quaternions with the knuckle corrective
  (the default), mean over ``K`` subjects;
* **sheet** (``--sheet``): v2 hands (top row), v3 hands (middle row) in natural poses, and the
  photos of ``--photos`` (bottom row, cropped square), as ``docs/hand_model_v3.png``.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import torch

from . import write_results

__all__ = ["population", "volume_changes", "write_sheet", "main"]

_SKINNINGS = {"lbs": ("linear", 0.0), "dqs": ("dual_quaternion", 0.0),
              "dqs+corrective": ("dual_quaternion", None)}


def population(num_subjects: int, seed: int = 0) -> dict:
    """Measured v3 sizes per sex: {sex: {measure: (mean, sd)}, correlations}, millimetres."""
    from lisa_hand.handmodel import sample_hand
    from lisa_hand.handmodel.makehuman import measure_hand, morph

    rows = {"female": [], "male": []}
    for index in range(num_subjects):
        hand = sample_hand(torch.Generator().manual_seed(seed * 100003 + index), model="v3")
        vertices, joints = morph(hand.shape)
        size = measure_hand(vertices, joints)
        sex = "female" if hand.shape.gender < 0.5 else "male"
        rows[sex].append([1000 * size["hand_length"], 1000 * size["hand_breadth"],
                          1000 * size["palm_thickness"]])
    result = {}
    for sex, values in rows.items():
        values = np.asarray(values)
        if len(values) < 3:
            continue
        corr = np.corrcoef(values.T)
        result[sex] = {
            "count": len(values),
            "hand_length_mm": [float(values[:, 0].mean()), float(values[:, 0].std())],
            "hand_breadth_mm": [float(values[:, 1].mean()), float(values[:, 1].std())],
            "palm_thickness_mm": [float(values[:, 2].mean()), float(values[:, 2].std())],
            "corr_length_breadth": float(corr[0, 1]),
            "corr_length_thickness": float(corr[0, 2]),
        }
    return result


def _enclosed_volume(vertices: np.ndarray, faces: np.ndarray, step: float = 0.0012) -> float:
    import point_cloud_utils as pcu

    low, high = vertices.min(0) - 0.002, vertices.max(0) + 0.002
    axes = [np.arange(a, b, step) for a, b in zip(low, high, strict=True)]
    grid = np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, 3)
    winding = pcu.triangle_soup_fast_winding_number(vertices, faces, grid)
    return float((winding > 0.5).sum() * step**3)


def volume_changes(num_subjects: int, seed: int = 0) -> dict:
    """{skinning: {pose: mean percent change of the enclosed volume from rest}}."""
    from lisa_hand.handmodel import POSE_NAMES, named_pose, sample_hand
    from lisa_hand.handmodel.mesh_hand import KNUCKLE_BULGE, PosedMeshHand

    changes = {name: {pose: [] for pose in POSE_NAMES} for name in _SKINNINGS}
    for index in range(num_subjects):
        hand = sample_hand(torch.Generator().manual_seed(seed * 100003 + index), model="v3")
        rest = hand.posed(dtype=torch.float64)
        rest_volume = _enclosed_volume(rest.vertices, rest.faces)
        for pose_name in POSE_NAMES:
            pose = named_pose(pose_name, dtype=torch.float64)
            for name, (skinning, corrective) in _SKINNINGS.items():
                posed = PosedMeshHand(hand, pose, None, skinning=skinning,
                                      corrective=KNUCKLE_BULGE if corrective is None
                                      else corrective)
                volume = _enclosed_volume(posed.vertices, posed.faces)
                changes[name][pose_name].append(100.0 * (volume / rest_volume - 1.0))
    return {name: {pose: float(np.mean(values)) for pose, values in poses.items()}
            for name, poses in changes.items()}


def _square(image: np.ndarray, size: int) -> np.ndarray:
    from PIL import Image

    height, width = image.shape[:2]
    side = min(height, width)
    top, left = (height - side) // 2, (width - side) // 2
    crop = Image.fromarray(np.ascontiguousarray(image[top:top + side, left:left + side, :3]))
    return np.asarray(crop.resize((size, size), Image.LANCZOS))


def write_sheet(path: str | Path, photos: str | Path | None, columns: int = 6,
                size: int = 240) -> Path:
    """The contact sheet (see the module docstring) -> its path."""
    import imageio.v3 as iio

    from lisa_hand.handmodel import contact_sheet, render_preview, sample_hand, sample_pose
    from lisa_hand.utils.io import atomic_path

    tiles = []
    for model in ("v2", "v3"):
        for index in range(columns):
            generator = torch.Generator().manual_seed(1000 + index)
            hand = sample_hand(generator, model=model)
            pose = sample_pose(torch.Generator().manual_seed(index), 1)[0].double()
            pose[:3] = 0.0
            posed = hand.posed(pose)
            mesh = posed.mesh(voxel_size=hand.shape.hand_length / 160, skin_weights=False)
            view = "oblique_palmar" if index % 2 else "oblique"
            tiles.append(render_preview(mesh.vertices, mesh.faces, mesh.colors, view=view,
                                        size=size))
    if photos is not None:
        files = sorted((p for p in Path(photos).rglob("*")  # the folder's own photos first
                        if p.suffix.lower() in (".jpg", ".jpeg", ".png")),
                       key=lambda p: (len(p.parts), str(p)))[:columns]
        tiles += [_square(iio.imread(file), size) for file in files]
        tiles += [np.full((size, size, 3), 255, np.uint8)] * (-len(tiles) % columns)
    path = Path(path)
    with atomic_path(path) as staging:
        iio.imwrite(staging, contact_sheet(tiles, columns), extension=path.suffix)
    return path


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(prog="python -m benchmarks handmodel",
                                     description=__doc__.split("\n\n")[0])
    parser.add_argument("--subjects", type=int, default=200, help="subjects of the population")
    parser.add_argument("--volume-subjects", type=int, default=3,
                        help="subjects of the volume table")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--sheet", type=Path, help="write the contact sheet here (PNG)")
    parser.add_argument("--photos", type=Path, help="a folder of real photos for the sheet")
    parser.add_argument("--json", type=Path, help="write the numbers here")
    args = parser.parse_args(argv)
    from lisa_hand.handmodel.anthropometry import ANTHROPOMETRIC_TABLE

    sizes = population(args.subjects, args.seed)
    print(f"v3 population, {args.subjects} subjects (measured on the mesh; published in brackets)")
    print("sex     n    length mm          breadth mm        thickness mm      r(L,B)")
    for sex, row in sizes.items():
        table = ANTHROPOMETRIC_TABLE[sex]
        cells = [f"{row[key][0]:5.1f} ({1000 * table['mean'][i]:5.1f}) sd {row[key][1]:4.1f} "
                 f"({1000 * table['std'][i]:3.1f})" for i, key in enumerate(
                     ("hand_length_mm", "hand_breadth_mm", "palm_thickness_mm"))]
        print(f"{sex:7s} {row['count']:3d}  " + "  ".join(cells)
              + f"  {row['corr_length_breadth']:.2f} (0.65)")
    volumes = volume_changes(args.volume_subjects, args.seed)
    poses = list(next(iter(volumes.values())))
    print(f"\nvolume change from rest, %, mean of {args.volume_subjects} subjects")
    print(f"{'skinning':16s}" + "".join(f"{p:>9s}" for p in poses) + "   mean |.|")
    for name, row in volumes.items():
        mean_abs = np.mean([abs(v) for v in row.values()])
        print(f"{name:16s}" + "".join(f"{row[p]:9.2f}" for p in poses) + f"   {mean_abs:.2f}")
    if args.sheet is not None:
        print(f"wrote {write_sheet(args.sheet, args.photos)}")
    write_results(args.json, {"subjects": args.subjects, "volume_subjects": args.volume_subjects,
                              "seed": args.seed, "population": sizes,
                              "volume_change_percent": volumes})
