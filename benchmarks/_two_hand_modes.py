"""The two-hand scenes as a scan and as calibrated views, for ``python -m benchmarks two_hands
--modes photo,scan,views`` (the photo mode is :mod:`benchmarks.two_hands`' own).

* **scan**: a full scan of both posed meshes joined
  (:func:`lisa_hand.data.scans.simulate_scan`: 8000 points, 0.5 mm of noise along the normal),
  in the scene's camera frame (the truth compares directly), written as a PLY and fitted by
  :func:`lisa_hand.fitting.points.io.fit_hands_file` as a user runs it (two hands, their sides
  found by the fit, the support search on: it must find none): together (the default) and alone
  (``FitPointsConfig(hands=ScanHandsConfig(joint=JointConfig(iters=0)))``).
* **views**: 4 calibrated views round the pair (:func:`lisa_hand.geometry.cameras.make_rig`:
  0.45 m away, 320x240, 45 degrees, the image's up the scene's), both meshes rendered as one
  (:func:`lisa_hand.data.images.render_views`, the scene's colours); per hand a frame folder
  with those images, its mask (its visible pixels: where its own depth, rendered alone, is the
  pair's) and its true keypoints projected (visible: the depth test of
  :func:`lisa_hand.data.images.project_keypoints`). Fitted by
  :func:`lisa_hand.fitting.images.hands.fit_image_folders` with the photo fit's settings
  (:func:`lisa_hand.fitting.photo.config.photo_fit_defaults`: 300 keypoint-stage iterations,
  40 colour-stage ones of 256 rays), the sides given: together and alone (``joint.iters=0``).

Both write ``hands.json`` and ``handN/keypoints.json`` (``keypoints_3d``, world frame: the
scene's camera frame). The fitted hands are matched to the true ones in 3D
(:func:`match_hands_3d`: by side, else the nearest wrist), then scored as the photos are.
"""

from __future__ import annotations

import math
import time
from pathlib import Path

import numpy as np

from ._two_hand_scenes import _meshed

__all__ = ["INPUT_MODES", "parse_modes", "match_hands_3d", "write_scan", "write_views",
           "fit_scene_input", "mode_notes", "picture_sheet"]

INPUT_MODES = ("photo", "scan", "views")
"""What the scenes are fitted from (``--modes``)."""
SCAN_POINTS = 8000
SCAN_NOISE_M = 0.0005
NUM_VIEWS = 4
VIEW_RADIUS_M = 0.45
VIEW_SIZE = (320, 240)
VIEW_FOV_DEG = 45.0
_STREAM_SCAN, _STREAM_VIEWS = 12, 13
_SIDE_MISMATCH_M = 1.0
"""Added to the wrist distance of a fitted hand of the other side: sides match first."""


def parse_modes(text: str) -> tuple[str, ...]:
    """``--modes`` ("photo,scan,views", any order or subset) -> the modes, in that order."""
    modes = [part.strip() for part in text.split(",") if part.strip()]
    unknown = [mode for mode in modes if mode not in INPUT_MODES]
    if unknown or not modes:
        raise ValueError(f"--modes: a comma-separated subset of {','.join(INPUT_MODES)}, got "
                         f"{text!r}")
    return tuple(dict.fromkeys(modes))


def mode_notes(modes: tuple[str, ...]) -> list[str]:
    """What the scan and views modes give the fits (the benchmark's printed notes)."""
    from lisa_hand.fitting.photo.config import photo_fit_defaults

    config = photo_fit_defaults()
    notes = []
    if "scan" in modes:
        notes.append(f"scan: a full scan of both hands ({SCAN_POINTS} points, "
                     f"{SCAN_NOISE_M * 1000:g} mm noise), camera frame, fitted by "
                     "fit_hands_file (2 hands, their sides found by the fit, the support "
                     "search on)")
    if "views" in modes:
        notes.append(f"views: {NUM_VIEWS} calibrated views, {VIEW_SIZE[0]}x{VIEW_SIZE[1]}, "
                     f"{VIEW_FOV_DEG:g} degrees, {VIEW_RADIUS_M} m away, each hand's true "
                     "keypoints (visible: depth test), mask (its visible pixels) and side "
                     f"given; fit_image_folders with keypoint_iters={config.keypoint_iters}, "
                     f"color_iters={config.color_iters}, num_rays={config.num_rays}")
    return notes


def _seed(seed: int, stream: int, index: int) -> int:
    return int(np.random.SeedSequence([seed, stream, index]).generate_state(1)[0])


def match_hands_3d(fitted: list, truths: list) -> list[int | None]:
    """Per true hand (:class:`benchmarks._two_hand_scenes.TrueHand`), the index of the fitted
    hand (:class:`benchmarks._two_hand_scores.FittedHand`) matched to it: the assignment of
    least total wrist distance, a fitted hand of the other side costing 1 m more (so by side,
    else the nearest wrist); None: unmatched, or its wrist farther than half the true hand's
    size (the longest side of its keypoints' box)."""
    from scipy.optimize import linear_sum_assignment

    matched: list[int | None] = [None] * len(truths)
    if not fitted or not truths:
        return matched
    distance = np.array([[np.linalg.norm(hand.keypoints_3d[0] - truth.keypoints_3d[0])
                          if hand.keypoints_3d is not None
                          and np.isfinite(hand.keypoints_3d[0]).all() else math.inf
                          for hand in fitted] for truth in truths])
    sides = np.array([[0.0 if hand.side == truth.side else _SIDE_MISMATCH_M for hand in fitted]
                      for truth in truths])
    cost = np.where(np.isfinite(distance), distance + sides, 1e12)
    rows, columns = linear_sum_assignment(cost)
    for row, column in zip(rows, columns, strict=True):
        size = np.ptp(truths[row].keypoints_3d, axis=0).max()
        if distance[row, column] <= 0.5 * size:
            matched[row] = int(column)
    return matched


# ------------------------------------------------------------------------------------------------
# The inputs


def write_scan(photo, path: Path, seed: int) -> Path:
    """A full scan of ``photo``'s two meshes joined (camera frame) -> ``path`` (PLY points)."""
    import trimesh

    from lisa_hand.data.scans import ScanConfig, simulate_scan

    both = _meshed(photo.meshes).mesh()
    scan = simulate_scan(both.vertices, both.faces,
                         ScanConfig(num_points=SCAN_POINTS, noise_normal_std=SCAN_NOISE_M), seed)
    path.parent.mkdir(parents=True, exist_ok=True)
    trimesh.PointCloud(np.asarray(scan.points, np.float64)).export(path)
    return path


def write_views(photo, folder: Path, seed: int) -> list[Path]:
    """``photo``'s pair seen by :data:`NUM_VIEWS` calibrated cameras (module docstring) ->
    [the right hand's frame folder, the left hand's]."""
    from lisa_hand.data.images import project_keypoints, render_views
    from lisa_hand.data.keypoints import write_keypoints
    from lisa_hand.data.layout import FramePaths, write_image, write_mask
    from lisa_hand.geometry.cameras import make_rig, save_cameras

    both = _meshed(photo.meshes).mesh()
    centre = 0.5 * (both.vertices.min(0) + both.vertices.max(0))
    cameras = make_rig(NUM_VIEWS, target=centre.tolist(), radius=VIEW_RADIUS_M,
                       width=VIEW_SIZE[0], height=VIEW_SIZE[1], fov_deg=VIEW_FOV_DEG, seed=seed,
                       up=(0.0, -1.0, 0.0))
    views = render_views(both.vertices, both.faces, cameras, both.colors / 255.0,
                         generator=seed)
    folders = []
    for truth in (photo.right, photo.left):
        mesh = photo.meshes[truth.side]
        alone = render_views(mesh.vertices, mesh.faces, cameras, mesh.colors / 255.0,
                             generator=seed)
        paths = FramePaths(Path(folder) / truth.side)
        save_cameras(paths.cameras, cameras)
        keypoints = {}
        for camera, view, own in zip(cameras, views, alone, strict=True):
            write_image(paths.image(camera.name), view.rgb)
            write_mask(paths.mask(camera.name),
                       own.mask & view.mask & (np.abs(own.depth - view.depth) < 1e-4))
            projection = project_keypoints(truth.keypoints_3d, camera, depth=view.depth)
            keypoints[camera.name] = {"keypoints": projection.pixels,
                                      "visible": (projection.visible
                                                  & projection.in_image).tolist()}
        write_keypoints(paths.keypoints, keypoints)
        folders.append(paths.root)
    return folders


# ------------------------------------------------------------------------------------------------
# The fits


def _fit_scan(ply: Path, out_dir: Path, fit: str, options: dict) -> None:
    from lisa_hand.fitting.points.io import fit_hands_file

    config = None
    if fit == "alone":
        from lisa_hand.fitting.pair.config import JointConfig
        from lisa_hand.fitting.points.config import FitPointsConfig, ScanHandsConfig

        config = FitPointsConfig(hands=ScanHandsConfig(joint=JointConfig(iters=0)))
    fit_hands_file(ply, out_dir, 2, config=config, device=options["device"],
                   progress=False, log=None)


def _fit_views(folders: list[Path], out_dir: Path, fit: str, options: dict) -> None:
    import dataclasses

    from lisa_hand.fitting.images.hands import fit_image_folders
    from lisa_hand.fitting.photo.config import photo_fit_defaults

    config = photo_fit_defaults()
    if fit == "alone":
        from lisa_hand.fitting.pair.config import JointConfig

        config = dataclasses.replace(config, joint=JointConfig(iters=0))
    fit_image_folders(folders, out_dir, ["right", "left"], config=config,
                      device=options["device"], progress=False)


def fit_scene_input(mode: str, photo, work_dir: Path, options: dict,
                    seed: int) -> tuple[dict, float]:
    """Make ``photo``'s scene's ``mode`` input ("scan" or "views") in ``work_dir``, fit it
    together and alone, and score both -> ({"together": ModeResult, "alone": ...}, seconds
    making the input)."""
    from ._two_hand_scores import FITS, failed_fit, read_fit_output, score_fit

    start = time.perf_counter()
    stem = photo.path.stem
    if mode == "scan":
        source = write_scan(photo, work_dir / "scans" / f"{stem}.ply",
                            _seed(seed, _STREAM_SCAN, photo.index))
        fit_function = _fit_scan
    elif mode == "views":
        source = write_views(photo, work_dir / "views" / stem,
                             _seed(seed, _STREAM_VIEWS, photo.index))
        fit_function = _fit_views
    else:
        raise ValueError(f"unknown input mode {mode!r} (scan or views here)")
    seconds_input = time.perf_counter() - start
    results = {}
    for fit in FITS:
        out_dir = work_dir / "fits" / mode / stem / fit
        start = time.perf_counter()
        try:
            fit_function(source, out_dir, fit, options)
        except Exception as exc:  # noqa: BLE001 (a benchmark reports a failed fit and goes on)
            results[fit] = failed_fit(time.perf_counter() - start, f"{type(exc).__name__}: {exc}")
            continue
        seconds = time.perf_counter() - start
        output = read_fit_output(out_dir, keypoints_2d=False)
        results[fit] = score_fit(output, photo, seconds,
                                 match_hands_3d(output.hands, [photo.right, photo.left]))
    return results, seconds_input


# ------------------------------------------------------------------------------------------------
# The scenes' pictures


def picture_sheet(photos: list, path: Path, columns: int = 3, tile_width: int = 512) -> Path:
    """Write the two-hand photos side by side, each with its kind, its true penetration (or gap)
    and true 2D keypoints (right hand red, left blue; hidden ones hollow) -> ``path``."""
    from PIL import Image, ImageDraw

    tiles = []
    for photo in photos:
        image = Image.open(photo.path).convert("RGB")
        scale = tile_width / image.width
        image = image.resize((tile_width, round(image.height * scale)), Image.BILINEAR)
        draw = ImageDraw.Draw(image)
        for hand, colour in ((photo.right, (230, 40, 40)), (photo.left, (40, 90, 240))):
            for (x, y), shown in zip(hand.keypoints_2d * scale, hand.visible, strict=True):
                draw.ellipse((x - 2, y - 2, x + 2, y + 2), fill=colour if shown else None,
                             outline=colour)
        label = (f"{photo.index}: {photo.kind} (penetration {photo.penetration_mm:.1f} mm, "
                 f"gap {photo.gap_mm:.1f} mm)")
        draw.rectangle((0, 0, 8 + 6 * len(label), 14), fill=(0, 0, 0))
        draw.text((4, 2), label, fill=(255, 255, 255))
        tiles.append(image)
    height = max(tile.height for tile in tiles)
    sheet = Image.new("RGB", (columns * tile_width, math.ceil(len(tiles) / columns) * height),
                      (255, 255, 255))
    for k, tile in enumerate(tiles):
        sheet.paste(tile, ((k % columns) * tile_width, (k // columns) * height))
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    sheet.save(path)
    return Path(path)
