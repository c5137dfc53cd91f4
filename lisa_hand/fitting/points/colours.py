"""A coloured scan's colours on the fitted hand's mesh (``lisa fit-points`` on a scan with colour).

Phone scanning apps, photogrammetry and depth cameras with a colour sensor give every point a
colour; the point fit itself uses only positions. :func:`transfer_colours` gives each vertex of
the fitted mesh the colour of the scan near it: the inverse-distance mean of its
:data:`NEIGHBOURS` nearest scan points within ``radius`` (:func:`colour_radius`: three times the
scan's median point spacing, at least 2 mm). The surface the scan did not show (the hidden side
of a one-view scan, between curled fingers) takes colours interpolated from what it did show:
harmonic over the mesh's edges (:func:`harmonic_fill`: every such vertex the mean of its
neighbours, the seen vertices fixed), so colours run on smoothly instead of stopping at a seam;
a piece of the mesh that touches no seen vertex gets the seen vertices' mean colour. With a
model that has colour (LISA-full: ``--model default``), its colour code is first
fitted to the scan's colours (:func:`fit_colour_code`) and the model's colour guesses the unseen
surface instead, corrected by the scan's difference from it interpolated the same way (a palm
the scan did not see comes out lighter than the back it saw, as the model learnt).

Read colours (:func:`read_point_colours`, aligned with
:func:`lisa_hand.fitting.points.inputs.read_point_cloud`'s points):

* ``.ply``: the vertex element's ``red green blue`` (or ``r g b``; ``diffuse_red`` ...), 8-bit
  or 16-bit integers or floats in [0, 1];
* ``.obj``: ``v x y z r g b`` lines (floats in [0, 1]; the common vertex-colour extension);
* ``.npz``: ``colors`` or ``colours`` ``[N, 3]`` (uint8, or floats in [0, 1]);
* ``.glb``, ``.gltf``, ``.off``: the meshes' vertex colours, or their texture sampled at each
  vertex (trimesh's ``to_color``);
* a depth image with its registered colour image (``--rgb``): the colour image's pixel under
  each point (:func:`depth_point_colours`).

``.xyz`` and ``.npy`` files hold points (and normals) only.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch

from ...utils.io import read_numpy

__all__ = ["NEIGHBOURS", "MIN_RADIUS_M", "ScanColours", "read_point_colours",
           "as_unit_colours", "depth_point_colours", "colour_radius", "harmonic_fill",
           "transfer_colours", "fit_colour_code"]

NEIGHBOURS = 8
"""Scan points averaged for a vertex's colour (those within the radius)."""
MIN_RADIUS_M = 0.002
"""The smallest radius within which a scan point colours a vertex, metres."""
_SPACINGS = 3.0  # the radius in median point spacings
_PLY_CHANNELS = (("red", "green", "blue"), ("r", "g", "b"),
                 ("diffuse_red", "diffuse_green", "diffuse_blue"))


@dataclass(frozen=True, eq=False)
class ScanColours:
    """The colours a scan gives a mesh (:func:`transfer_colours`)."""

    colors: np.ndarray
    """[V, 3] uint8 RGB, one per mesh vertex."""
    seen: np.ndarray
    """[V] bool: coloured by scan points (the rest interpolated)."""
    radius_m: float
    """The radius used, metres."""

    @property
    def seen_share(self) -> float:
        """Share of the vertices coloured by scan points."""
        return float(self.seen.mean()) if self.seen.size else 0.0

    def note(self, path: Any, by_model: bool = False) -> str:
        """One sentence for the command line (``by_model``: the unseen surface is the colour
        model's, fitted to the scan)."""
        rest = ("the model's colour, fitted to the scan's" if by_model
                else "interpolated over the surface")
        return (f"{path}: coloured from the scan's colours ({100 * self.seen_share:.0f}% of the "
                f"vertices within {1000 * self.radius_m:.1f} mm of a scan point; the rest "
                f"{rest})")


def as_unit_colours(values: Any, name: str = "colours") -> np.ndarray:
    """Colours as stored -> [N, 3] float32 in [0, 1]: 8-bit and 16-bit integers are scaled, floats
    above 1 are read as 0-255; a fourth (alpha) column is dropped. ValueError naming ``name``
    for another shape or values outside those ranges."""
    values = np.asarray(values)
    if values.ndim != 2 or values.shape[1] not in (3, 4):
        raise ValueError(f"{name}: colours must have shape [N, 3] (or [N, 4] with alpha), got "
                         f"{list(values.shape)}")
    values = values[:, :3]
    if values.dtype == np.uint8:
        return values.astype(np.float32) / 255.0
    if values.dtype == np.uint16:
        return values.astype(np.float32) / 65535.0
    if not np.issubdtype(values.dtype, np.number):
        raise ValueError(f"{name}: colours must be numbers, got dtype {values.dtype}")
    values = values.astype(np.float64)
    if not np.isfinite(values).all() or values.min(initial=0.0) < 0.0:
        raise ValueError(f"{name}: colours must be finite and not negative")
    top = values.max(initial=0.0)
    if top > 255.0:
        raise ValueError(f"{name}: colours reach {top:g}: expected [0, 1] or [0, 255]")
    return (values / (255.0 if top > 1.0 else 1.0)).astype(np.float32)


def _ply_colours(path: Path) -> np.ndarray | None:
    from ...data.meshio import read_ply_vertices

    vertex = read_ply_vertices(path)
    names = vertex.dtype.names or ()
    for channels in _PLY_CHANNELS:
        if all(channel in names for channel in channels):
            stacked = np.stack([vertex[channel] for channel in channels], axis=1)
            return as_unit_colours(stacked, str(path))
    return None


def _obj_colours(path: Path) -> np.ndarray | None:
    rows = []
    with open(path, encoding="utf-8") as handle:
        for line in handle:
            if line.startswith("v "):
                rows.append(line.split()[1:])
    if not rows or any(len(row) < 6 for row in rows):
        return None  # positions only (or only some vertices coloured: not a coloured scan)
    return as_unit_colours(np.array([row[3:6] for row in rows], dtype=np.float64), str(path))


def _npz_colours(path: Path) -> np.ndarray | None:
    archive = read_numpy(path)
    key = next((k for k in ("colors", "colours") if k in archive), None)
    return None if key is None else as_unit_colours(archive[key], f"{path} '{key}'")


def _mesh_file_colours(path: Path) -> np.ndarray | None:
    from ...metrics import load_mesh

    colours = load_mesh(path).colors  # the same read as the points' (merged vertices)
    return None if colours is None else as_unit_colours(colours, str(path))


def read_point_colours(path: str | os.PathLike, count: int) -> np.ndarray | None:
    """The colours of the ``count`` points that
    :func:`lisa_hand.fitting.points.inputs.read_point_cloud` read from ``path`` -> [count, 3]
    float32 in [0, 1], or None when the file has none, not one per point (a mesh whose vertices
    were merged differently) or one colour for all (a material's, as some GLB files have).
    ValueError naming the file for colours that cannot be read (out of range, a file trimesh
    cannot take apart)."""
    path = Path(path)
    reader = {".ply": _ply_colours, ".obj": _obj_colours, ".npz": _npz_colours,
              ".glb": _mesh_file_colours, ".gltf": _mesh_file_colours,
              ".off": _mesh_file_colours}.get(path.suffix.lower())
    if reader is None:
        return None
    try:
        colours = reader(path)
    except ValueError:
        raise
    except Exception as error:  # trimesh raises many types for files it reads in part
        raise ValueError(f"{path}: cannot read the colours ({type(error).__name__}: "
                         f"{error})") from None
    if colours is None or len(colours) != count or not np.ptp(colours, axis=0).any():
        return None  # none, not one per point, or one colour everywhere (a default material)
    return colours


def depth_point_colours(points: np.ndarray, frame: Any, colour_path: str | os.PathLike
                        ) -> np.ndarray:
    """The colour under each point of a depth image in its registered colour image.

    points: [N, 3] world metres (:func:`lisa_hand.data.depth.read_depth_cloud`'s). frame: the
    :class:`lisa_hand.data.depth.DepthFrame` they were read with; colour_path: the colour image
    aligned to the depth camera (scaled to the depth image's size when its shape is the same).
    -> [N, 3] float32 in [0, 1]."""
    from PIL import Image

    from ...data.photo import read_photo
    from ...geometry.cameras import project_points

    camera = frame.camera
    size = (int(camera.width), int(camera.height))
    photo = read_photo(colour_path, max_side=max(8192, *size))  # as stored; resized below
    image = photo.image
    if (image.shape[1], image.shape[0]) != size:
        height, width = image.shape[:2]
        if abs(width / height - size[0] / size[1]) > 0.01:
            raise ValueError(f"{colour_path}: the colour image is {width}x{height} pixels, the "
                             f"depth image {size[0]}x{size[1]}: register it to the depth camera")
        pil = Image.fromarray(np.clip(np.round(image * 255.0), 0, 255).astype(np.uint8))
        image = np.asarray(pil.resize(size, Image.BILINEAR), np.float32) / 255.0
    pixels, _ = project_points(camera.K.double().cpu(), camera.R.double().cpu(),
                               camera.t.double().cpu(), torch.as_tensor(points).double())
    pixels = pixels.numpy()
    columns = np.clip(np.floor(pixels[:, 0]).astype(np.int64), 0, size[0] - 1)
    rows = np.clip(np.floor(pixels[:, 1]).astype(np.int64), 0, size[1] - 1)
    return np.ascontiguousarray(image[rows, columns, :3], np.float32)


def colour_radius(points: np.ndarray) -> float:
    """Within how far a scan point colours a vertex: :data:`_SPACINGS` times the median distance
    from a point to its nearest neighbour, at least :data:`MIN_RADIUS_M` (metres)."""
    from .cloud import point_spacing

    return max(MIN_RADIUS_M, _SPACINGS * point_spacing(torch.as_tensor(np.asarray(points))))


def harmonic_fill(faces: np.ndarray, values: np.ndarray, known: np.ndarray) -> np.ndarray:
    """Values at the unknown vertices of a mesh interpolated from the known ones.

    faces: [F, 3] vertex indices; values: [V, C] (the unknown rows are ignored); known: [V] bool.
    -> [V, C] float64: known rows as given, each unknown one the mean of its edge neighbours
    (the graph Laplace equation, Dirichlet at the known vertices); unknown vertices of a piece
    with no known vertex get the known rows' mean. ValueError when no vertex is known.
    """
    from scipy.sparse import coo_matrix, diags
    from scipy.sparse.csgraph import connected_components
    from scipy.sparse.linalg import spsolve

    values = np.asarray(values, np.float64)
    known = np.asarray(known, bool)
    count = len(values)
    filled = values.copy()
    if not known.any():
        raise ValueError("harmonic_fill needs at least one known vertex")
    if known.all():
        return filled
    faces = np.asarray(faces, np.int64).reshape(-1, 3)
    edges = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    edges = np.concatenate([edges, edges[:, ::-1]])
    adjacency = coo_matrix((np.ones(len(edges)), (edges[:, 0], edges[:, 1])),
                           shape=(count, count)).tocsr()
    adjacency.data[:] = 1.0  # an edge shared by two faces counts once
    mean = values[known].mean(axis=0)
    _, labels = connected_components(adjacency, directed=False)
    reached = np.isin(labels, np.unique(labels[known]))
    solve = ~known & reached
    filled[~known & ~reached] = mean
    if solve.any():
        laplacian = (diags(np.asarray(adjacency.sum(axis=1)).ravel()) - adjacency).tocsr()
        system = laplacian[solve][:, solve].tocsc()
        right = -(laplacian[solve][:, known] @ values[known])
        solution = spsolve(system, right)
        filled[solve] = np.asarray(solution).reshape(int(solve.sum()), -1)
    return filled


def transfer_colours(vertices: np.ndarray, faces: np.ndarray, points: np.ndarray,
                     colours: np.ndarray, radius: float | None = None,
                     base: np.ndarray | None = None) -> ScanColours | None:
    """The scan's colours on a mesh (see the module docstring).

    vertices: [V, 3] metres; faces: [F, 3]; points: [N, 3] metres, the scan points that belong
    to the hand; colours: [N, 3] in [0, 1]; radius: metres (None: :func:`colour_radius`);
    base: [V, 3] in [0, 1], a model's colours at the vertices (:func:`fit_colour_code`), or None:
    with it, the unseen vertices take the base plus the seen vertices' difference from it,
    interpolated (the model guesses what the scan did not show, the scan corrects it near what
    it did), instead of the seen colours interpolated.
    -> :class:`ScanColours`, or None when no vertex lies within the radius of a point.
    """
    from scipy.spatial import cKDTree

    from ...geometry.meshing import colors_to_uint8

    vertices = np.asarray(vertices, np.float64)
    points = np.asarray(points, np.float64)
    colours = np.asarray(colours, np.float64)
    if len(points) == 0 or len(vertices) == 0:
        return None
    radius = colour_radius(points) if radius is None else float(radius)
    k = min(NEIGHBOURS, len(points))
    distances, index = cKDTree(points).query(vertices, k=k)
    distances, index = distances.reshape(len(vertices), k), index.reshape(len(vertices), k)
    within = distances <= radius
    seen = within.any(axis=1)
    if not seen.any():
        return None
    weights = within / np.maximum(distances, 1e-2 * radius)
    values = np.zeros((len(vertices), 3))
    values[seen] = (np.einsum("vk,vkc->vc", weights[seen], colours[index[seen]])
                    / weights[seen].sum(axis=1, keepdims=True))
    if base is None:
        filled = harmonic_fill(faces, values, seen)
    else:
        base = np.asarray(base, np.float64)
        filled = base + harmonic_fill(faces, values - base, seen)
    return ScanColours(colors=colors_to_uint8(filled), seen=seen, radius_m=radius)


def fit_colour_code(model: Any, params: Any, points: np.ndarray, colours: np.ndarray, *,
                    iters: int = 100, lr: float = 0.05, batch: int = 2048,
                    code_weight: float = 1e-3, seed: int = 0) -> torch.Tensor:
    """LISA's colour code ``gamma`` of a fitted hand, fitted to a scan's colours: the L1 of the
    model's calibrated colour (its mean gain and bias, as meshes and renders use) at the scan
    points against their colours, plus ``code_weight |gamma|`` (the paper's Eq. 13 and 16 with
    the points in place of rays), Adam from the hand's code (or the training codes' mean), on
    ``batch`` random points a step.

    model: a :class:`lisa_hand.model.trained.TrainedModel` with colour; params: the fitted
    :class:`lisa_hand.skeleton.params.HandParams`; points: [N, 3] world metres near its surface;
    colours: [N, 3] in [0, 1]. -> the code [color_dim] (CPU, float32)."""
    from ...inference.hand_field import field_inputs
    from ...render.renderer import apply_gain_bias
    from ...skeleton import mirror_points
    from .surface_stage import frozen_field

    if not model.has_color:
        raise ValueError("the model has no colour to fit (a geometric prior)")
    field = model.field
    like = {"device": field.device, "dtype": field.dtype}
    *inputs, code = field_inputs(model, params)
    code = code.detach().clone().requires_grad_(True)
    at = torch.as_tensor(points, **like)
    at = mirror_points(at) if params.side == "left" else at  # the right hand the field is
    target = torch.as_tensor(colours, **like)
    gain, bias = model.gain.to(**like), model.bias.to(**like)
    generator = torch.Generator().manual_seed(seed)
    optimiser = torch.optim.Adam([code], lr=lr)
    with frozen_field(model):
        for _ in range(iters):
            pick = torch.randint(0, len(at), (min(batch, len(at)),), generator=generator)
            pick = pick.to(at.device)
            rgb = field.field(field.prepare(*inputs, code), at[pick][None], with_color=True).rgb
            loss = ((apply_gain_bias(rgb[0], gain, bias) - target[pick]).abs().mean()
                    + code_weight * code.norm())
            optimiser.zero_grad()
            loss.backward()
            optimiser.step()
    return code.detach()[0].float().cpu()
