"""Quick-look renders of hand meshes: ray-cast, Lambert-shaded, per-vertex colours.

For looking at the open hand model (and contact sheets); the dataset's images come from the
renderer in :mod:`lisa_hand.render`, not from here.
"""

from __future__ import annotations

import numpy as np

__all__ = ["VIEWS", "render_preview", "contact_sheet"]

# Named views of a right hand in its rest frame (fingers along -x, palm -y, thumb +z):
# (direction the camera looks along, image up direction).
VIEWS: dict[str, tuple[tuple[float, float, float], tuple[float, float, float]]] = {
    "dorsal": ((0.0, -1.0, 0.0), (-1.0, 0.0, 0.0)),
    "palmar": ((0.0, 1.0, 0.0), (-1.0, 0.0, 0.0)),
    "radial": ((0.0, 0.0, -1.0), (-1.0, 0.0, 0.0)),
    "ulnar": ((0.0, 0.0, 1.0), (-1.0, 0.0, 0.0)),
    "oblique": ((-0.35, -0.75, -0.55), (-1.0, 0.0, 0.0)),
    "oblique_palmar": ((-0.3, 0.75, -0.55), (-1.0, 0.0, 0.0)),
}


def _vertex_normals(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    corners = vertices[faces]
    face_normals = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    normals = np.zeros_like(vertices)
    for k in range(3):
        np.add.at(normals, faces[:, k], face_normals)
    return normals / np.maximum(np.linalg.norm(normals, axis=1, keepdims=True), 1e-20)


def render_preview(
    vertices: np.ndarray,
    faces: np.ndarray,
    colors: np.ndarray | None = None,
    view: str | tuple = "oblique",
    size: int = 400,
    background: tuple[float, float, float] = (1.0, 1.0, 1.0),
    margin: float = 0.05,
) -> np.ndarray:
    """Render a mesh with an orthographic camera fitted to it.

    vertices: [V, 3] metres; faces: [F, 3] int; colors: [V, 3] uint8 or float in [0, 1] (None:
        light grey). view: a name in :data:`VIEWS` or a (look direction [3], up [3]) pair.
    size: image height and width in pixels. background: RGB in [0, 1].
    -> [size, size, 3] uint8 image.
    """
    import point_cloud_utils as pcu

    vertices = np.asarray(vertices, dtype=np.float64)
    faces = np.asarray(faces, dtype=np.int64)
    if isinstance(view, str):
        if view not in VIEWS:
            raise ValueError(f"unknown view {view!r}: known views are {', '.join(VIEWS)}")
        look, up = VIEWS[view]
    else:
        look, up = view
    look = np.asarray(look, dtype=np.float64)
    look /= np.linalg.norm(look)
    right = np.cross(look, np.asarray(up, dtype=np.float64))
    right /= np.linalg.norm(right)
    up = np.cross(right, look)
    if colors is None:
        colors_f = np.full(vertices.shape, 0.8)
    else:
        colors_f = np.asarray(colors, dtype=np.float64)
        if colors_f.max() > 1.0:
            colors_f = colors_f / 255.0

    center = 0.5 * (vertices.min(0) + vertices.max(0))
    rel = vertices - center
    half = max(np.abs(rel @ right).max(), np.abs(rel @ up).max()) * (1.0 + margin)
    depth = np.abs(rel @ look).max() + 1.0
    coords = (np.arange(size) + 0.5) / size * 2.0 - 1.0
    grid_x, grid_y = np.meshgrid(coords * half, -coords * half)
    origins = center + grid_x[..., None] * right + grid_y[..., None] * up - depth * look
    origins = origins.reshape(-1, 3)
    directions = np.broadcast_to(look, origins.shape).copy()
    face_id, bary, _ = pcu.ray_mesh_intersection(
        vertices.astype(np.float32), faces.astype(np.int32), origins.astype(np.float32),
        directions.astype(np.float32),
    )  # fmt: skip
    hit = face_id >= 0
    image = np.empty((origins.shape[0], 3))
    image[:] = background
    if hit.any():
        normals = _vertex_normals(vertices, faces)
        tri = faces[face_id[hit]]
        weights = bary[hit][..., None]
        normal = (normals[tri] * weights).sum(1)
        normal /= np.maximum(np.linalg.norm(normal, axis=1, keepdims=True), 1e-20)
        albedo = (colors_f[tri] * weights).sum(1)
        # Key light from the upper left of the camera, a fill light, and ambient.
        key = -look + 0.6 * up - 0.5 * right
        fill = -look - 0.3 * up + 0.8 * right
        key, fill = key / np.linalg.norm(key), fill / np.linalg.norm(fill)
        diffuse = 0.7 * np.clip(normal @ key, 0, None) + 0.25 * np.clip(normal @ fill, 0, None)
        half_vector = key - look
        half_vector /= np.linalg.norm(half_vector)
        specular = 0.08 * np.clip(normal @ half_vector, 0, None) ** 30
        shade = 0.22 + diffuse
        image[hit] = np.clip(albedo * shade[:, None] + specular[:, None], 0.0, 1.0)
    return (image.reshape(size, size, 3) * 255.0 + 0.5).astype(np.uint8)


def contact_sheet(images: list[np.ndarray], columns: int, gap: int = 4) -> np.ndarray:
    """Tile equally sized images [H, W, 3] uint8 into a grid with white gaps."""
    if not images:
        raise ValueError("images is empty")
    height, width = images[0].shape[:2]
    rows = -(-len(images) // columns)
    sheet = np.full(
        (rows * height + (rows - 1) * gap, columns * width + (columns - 1) * gap, 3), 255, np.uint8
    )
    for k, image in enumerate(images):
        r, c = divmod(k, columns)
        sheet[r * (height + gap) : r * (height + gap) + height,
              c * (width + gap) : c * (width + gap) + width] = image  # fmt: skip
    return sheet
