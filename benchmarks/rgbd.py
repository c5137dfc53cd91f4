"""RGB-D benchmark: ``lisa fit-points depth.png --camera cam.json --rgb colour.png`` against the
same depth image without its colour image, on frames where something touches the hand.

``python -m benchmarks rgbd [--frames 4] [--threads 2] [--out DIR] [--json FILE]``

Each frame: a held-out hand of the shipped geometric prior (the k-th test subject of its split of
hand model v2's 290 subjects, relaxed fingers, palm towards the camera, turned at random by about
17 degrees) 42 cm before a 640 x 480 depth camera (580 px focal length), a cup (a 3.5 cm cylinder,
blue) touching its thumb's side, a wall 75 cm away; rendered by ray casting into an aligned colour
image (the hand's true albedo, half ambient, half diffuse light from the camera) and a 16-bit
depth image in millimetres (:func:`lisa_hand.data.images.render_views`). Both fits run as the
command does (:func:`lisa_hand.fitting.points.io.fit_point_file`, defaults; with the colour image,
MediaPipe finds the hand in it: the ``[photo]`` extra). Printed: V2S both ways against the true
hand (mm, cut at the fit's wrist) and the share of the mesh coloured from the colour image.
"""

from __future__ import annotations

import argparse
import dataclasses
import tempfile
import time
from pathlib import Path

import numpy as np

from lisa_hand.utils.threads import cpu_threads

from . import write_results

__all__ = ["rgbd_frame", "run_rgbd_benchmark", "main"]

_SIZE = (640, 480)
_FOCAL_PX = 580.0
_HAND_DEPTH_M, _WALL_DEPTH_M = 0.42, 0.75


def rgbd_frame(index: int, folder: Path) -> dict[str, Path]:
    """Frame ``index`` (see the module docstring) written to ``folder`` -> its files ("depth",
    "colour", "camera", "truth")."""
    import imageio.v3 as iio
    import torch
    import trimesh

    from lisa_hand.data.images import render_views
    from lisa_hand.data.shading import ShadingConfig
    from lisa_hand.data.synth import SynthConfig, make_subject, split_subjects
    from lisa_hand.geometry.cameras import Camera, save_cameras
    from lisa_hand.geometry.meshing import colors_to_uint8
    from lisa_hand.handmodel import named_pose

    subject = split_subjects(290, seed=0)["test"][index]
    record = make_subject(SynthConfig(seed=0, hand_model="v2"), int(subject[1:]),
                          fit_template=False)
    pose = named_pose("relaxed").double().reshape(48).clone()
    turn = torch.randn(3, generator=torch.Generator().manual_seed(index), dtype=torch.float64)
    pose[:3] = torch.tensor([np.pi / 2, 0.0, 0.0], dtype=torch.float64) + 0.3 * turn
    hand = record.hand.posed(pose).mesh(colors=True)
    vertices = np.asarray(hand.vertices, np.float64)
    vertices = vertices - vertices.mean(0) + [0.0, 0.0, _HAND_DEPTH_M]
    cup = trimesh.creation.cylinder(radius=0.035, height=0.10, sections=48)
    cup.apply_translation([vertices[:, 0].max() + 0.034, vertices[:, 1].mean(), 0.40])
    wall = trimesh.Trimesh([[-1, -1, _WALL_DEPTH_M], [1, -1, _WALL_DEPTH_M],
                            [1, 1, _WALL_DEPTH_M], [-1, 1, _WALL_DEPTH_M]], [[0, 2, 1], [0, 3, 2]])
    scene = [(vertices, hand.faces, hand.colors / 255.0),
             (cup.vertices, cup.faces, np.tile([0.2, 0.35, 0.8], (len(cup.vertices), 1))),
             (wall.vertices, wall.faces, np.tile([0.85, 0.85, 0.8], (4, 1)))]
    offsets = np.cumsum([0] + [len(part[0]) for part in scene[:-1]])
    K = torch.tensor([[_FOCAL_PX, 0, _SIZE[0] / 2], [0, _FOCAL_PX, _SIZE[1] / 2], [0, 0, 1.0]],
                     dtype=torch.float64)
    camera = Camera(K=K, R=torch.eye(3, dtype=torch.float64),
                    t=torch.zeros(3, dtype=torch.float64), width=_SIZE[0], height=_SIZE[1])
    view = render_views(np.concatenate([p[0] for p in scene]),
                        np.concatenate([p[1] + o for p, o in zip(scene, offsets, strict=True)]),
                        [camera], np.concatenate([p[2] for p in scene]).astype(np.float32),
                        ShadingConfig(ambient=0.5, diffuse=0.5))[0]
    files = {name: folder / f"frame{index}_{name}{suffix}" for name, suffix in
             (("depth", ".png"), ("colour", ".png"), ("camera", ".json"), ("truth", ".ply"))}
    iio.imwrite(files["colour"], colors_to_uint8(view.rgb))
    iio.imwrite(files["depth"], np.where(view.mask, np.round(view.depth * 1000), 0)
                .astype(np.uint16))
    save_cameras(files["camera"], [camera])
    trimesh.Trimesh(vertices, hand.faces, process=False).export(files["truth"])
    return files


def run_rgbd_benchmark(frames: int, folder: Path) -> dict:
    """Fit ``frames`` frames with and without their colour image -> {"rows": [...]}."""
    from lisa_hand.data.depth import DepthFrame
    from lisa_hand.fitting.points.io import fit_point_file
    from lisa_hand.fitting.points.rgbd import with_colour_hand
    from lisa_hand.geometry.cameras import load_cameras

    rows = []
    for index in range(frames):
        files = rgbd_frame(index, folder)
        frame = DepthFrame(camera=load_cameras(files["camera"])[0])
        row: dict = {"frame": index}
        for name in ("with_rgb", "depth_only"):
            depth, side = frame, "auto"
            if name == "with_rgb":  # as lisa fit-points --rgb does
                depth, found = with_colour_hand(files["depth"], frame, files["colour"])
                depth, side = dataclasses.replace(depth, colour=files["colour"]), found.side
            start = time.perf_counter()
            report = fit_point_file(files["depth"], folder / f"frame{index}_{name}",
                                    gt_path=files["truth"], depth=depth, side=side,
                                    viewpoint="auto", support="auto", others="auto")
            colours = report.fit.params.extra["input"].get("colours", {})
            row[name] = {"seconds": time.perf_counter() - start,
                         "v2s_scan_to_recon_mm": report.metrics["v2s_scan_to_recon_mm"],
                         "v2s_recon_to_scan_mm": report.metrics["v2s_recon_to_scan_mm"],
                         "coloured_share": colours.get("seen_share")}
        rows.append(row)
        print(f"frame {index}: " + "; ".join(
            f"{name} V2S {row[name]['v2s_scan_to_recon_mm']:.2f} / "
            f"{row[name]['v2s_recon_to_scan_mm']:.2f} mm ({row[name]['seconds']:.0f} s)"
            for name in ("with_rgb", "depth_only")), flush=True)
    return {"rows": rows}


def main(argv: list[str] | None = None) -> dict:
    """Command line: ``python -m benchmarks rgbd [options]``; returns the results."""
    parser = argparse.ArgumentParser(prog="python -m benchmarks rgbd",
                                     description=__doc__.split("\n\n")[0])
    parser.add_argument("--frames", type=int, default=4, help="frames (default 4)")
    parser.add_argument("--out", default=None, metavar="DIR",
                        help="keep the frames and fits here (default: a temporary folder)")
    parser.add_argument("--threads", type=int, default=2, help="torch CPU threads (default 2)")
    parser.add_argument("--json", default=None, metavar="FILE", help="write the results here")
    args = parser.parse_args(argv)
    if not 1 <= args.frames <= 20 or args.threads < 1:
        raise ValueError("--frames must be in 1..20 and --threads >= 1")
    from lisa_hand.data.detect import photo_extra_missing

    hint = photo_extra_missing()
    if hint is not None:
        raise ValueError(hint)
    with cpu_threads(args.threads), tempfile.TemporaryDirectory() as scratch:
        folder = Path(args.out) if args.out is not None else Path(scratch)
        folder.mkdir(parents=True, exist_ok=True)
        results = run_rgbd_benchmark(args.frames, folder)
    for name in ("with_rgb", "depth_only"):
        values = [row[name]["v2s_scan_to_recon_mm"] for row in results["rows"]]
        print(f"{name}: V2S scan->recon mean {np.mean(values):.2f} mm "
              f"({min(values):.2f}-{max(values):.2f})")
    write_results(args.json, results)
    return results


if __name__ == "__main__":
    main()
