"""The pictures of ``lisa eval``: each method's fitted mesh beside the truth (Table 1) and each
method's novel view beside the true image (Tables 2 and 3), cropped to the hand and labelled."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from .methods import METHODS

__all__ = ["make_pictures"]


def _crop(images: list[np.ndarray], background: int, margin: int = 8) -> list[np.ndarray]:
    """The images (same size) cropped to the box around every pixel that is not the
    background colour in any of them, plus a margin."""
    content = np.zeros(images[0].shape[:2], bool)
    for image in images:
        content |= np.abs(image.astype(np.int16) - background).max(axis=-1) > 8
    if not content.any():
        return images
    rows, cols = np.nonzero(content.any(axis=1))[0], np.nonzero(content.any(axis=0))[0]
    top, bottom = max(rows[0] - margin, 0), min(rows[-1] + margin + 1, content.shape[0])
    left, right = max(cols[0] - margin, 0), min(cols[-1] + margin + 1, content.shape[1])
    return [image[top:bottom, left:right] for image in images]


def _tile(images: list[np.ndarray], labels: list[str], background: int) -> np.ndarray:
    """Images side by side (cropped to the hand), each with its label written above it."""
    from PIL import Image, ImageDraw

    if len({image.shape for image in images}) == 1:
        images = _crop(images, background)
    height = max(image.shape[0] for image in images)
    strip = 18
    tiles = []
    for image, label in zip(images, labels, strict=True):
        canvas = Image.new("RGB", (image.shape[1], height + strip), (255, 255, 255))
        canvas.paste(Image.fromarray(image), (0, strip))
        ImageDraw.Draw(canvas).text((4, 3), label, fill=(0, 0, 0))
        tiles.append(np.asarray(canvas))
    return np.concatenate(tiles, axis=1)


def _mesh_picture(vertices: np.ndarray, faces: np.ndarray, camera) -> np.ndarray:
    from ..data.images import render_views
    from ..data.shading import ShadingConfig

    image = render_views(vertices, faces, [camera], np.array([0.75, 0.72, 0.70]),
                         ShadingConfig(background=(1.0, 1.0, 1.0)))[0]
    return (np.clip(image.rgb, 0, 1) * 255 + 0.5).astype(np.uint8)


def make_pictures(out: Path, point_rows: list[dict], image_rows: list[dict], order: list[str],
                  count: int = 2) -> list[Path]:
    """``pictures/points_FRAME.png``: each method's fitted mesh and the truth, from the
    frame's first camera; ``pictures/images4_FRAME.png``: each method's first novel view after
    the 4-view fit, and the true image. For the first ``count`` frames of Table 1's 'subjects'
    set and of the image tables."""
    from ..data.layout import FramePaths, read_image, write_image
    from ..geometry.cameras import load_cameras
    from ..metrics import load_mesh

    def as_uint8(image: np.ndarray) -> np.ndarray:
        return (image * 255 + 0.5).astype(np.uint8)

    written = []
    frames = dict.fromkeys((r["frame_name"], r["frame"]) for r in point_rows
                           if r["set"] == "subjects")
    for name, frame_dir in list(frames)[:count]:
        frame = FramePaths(Path(frame_dir))
        camera = load_cameras(frame.cameras)[0]
        images, labels = [], []
        for method in order:
            path = out / "fits" / "points" / "subjects" / name / method / "mesh.ply"
            if path.is_file():
                mesh = load_mesh(path)
                images.append(_mesh_picture(mesh.vertices, mesh.faces, camera))
                labels.append(METHODS[method].label)
        truth = load_mesh(frame.mesh)
        images.append(_mesh_picture(truth.vertices, truth.faces, camera))
        labels.append("ground truth")
        target = out / "pictures" / f"points_{name}.png"
        target.parent.mkdir(parents=True, exist_ok=True)
        write_image(target, _tile(images, labels, background=255))
        written.append(target)
    frames = dict.fromkeys((r["frame_name"], r["frame"], r["novel_view"]) for r in image_rows
                           if r["num_views"] == 4)
    for name, frame_dir, novel in list(frames)[:count]:
        folder = out / "fits" / "images_4" / name
        images, labels = [], []
        for method in order:
            path = folder / method / "novel.png"
            if path.is_file():
                images.append(as_uint8(read_image(path)))
                labels.append(METHODS[method].label)
        if images:
            images.append(as_uint8(read_image(FramePaths(Path(frame_dir)).image(novel))))
            labels.append("ground truth")
            target = out / "pictures" / f"images4_{name}.png"
            target.parent.mkdir(parents=True, exist_ok=True)
            write_image(target, _tile(images, labels, background=0))
            written.append(target)
    return written
