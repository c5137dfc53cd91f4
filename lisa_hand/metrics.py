"""Evaluation metrics: mesh distances (LISA, Table 1) and image metrics (PSNR, SSIM, LPIPS).

``lisa metrics RECON GT`` prints :func:`compare_mesh_files` for two meshes (or point sets) and
:func:`image_metrics` for two images.

Pure functions: numpy arrays or torch tensors in, Python numbers out. Everything is computed in
float64 on the CPU (evaluation, not a training hot path).
"""

from __future__ import annotations

import importlib.util
import math
import os
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np

__all__ = [
    "MeshData",
    "MeshDistances",
    "MeshComparison",
    "mesh_distances",
    "load_mesh",
    "detect_length_unit",
    "compare_mesh_files",
    "psnr",
    "ssim",
    "lpips_distance",
    "lpips_unavailable_reason",
    "ImageMetrics",
    "image_metrics",
]

# A hand's bounding-box diagonal is ~0.15-0.3 m; in millimetres it is ~150-300. Anything over
# this many units cannot be a hand in metres.
_MM_DIAGONAL_THRESHOLD = 2.0
_MESH_SUFFIXES = (".ply", ".obj", ".glb", ".gltf", ".stl", ".off")
_POINT_SUFFIXES = (".npy", ".npz", ".xyz")


def _to_numpy(value: Any, name: str) -> np.ndarray:
    """Tensors (any device, with grad or not) and array-likes to a numpy array."""
    if hasattr(value, "detach") and hasattr(value, "cpu"):
        value = value.detach().cpu().numpy()
    try:
        return np.asarray(value)
    except (TypeError, ValueError) as exc:
        raise TypeError(f"{name} must be an array, got {type(value).__name__} ({exc})") from None


# ---------------------------------------------------------------------------------------------
# Meshes
# ---------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class MeshData:
    """A triangle mesh, or a point set when ``faces`` is None (as read by :func:`load_mesh`)."""

    vertices: np.ndarray
    """[V, 3] float64 vertex positions (the file's units)."""
    faces: np.ndarray | None
    """[F, 3] int64 triangle vertex indices, or None for a point set."""


@dataclass(frozen=True)
class MeshDistances:
    """The four distances of the LISA paper's Table 1, in ``unit_scale`` units (mm by default).

    A field is NaN where it is undefined: the vertex-to-surface distance towards a point set.
    """

    v2v_recon_to_scan_mm: float
    """Mean distance from each reconstruction vertex to the nearest scan vertex."""
    v2s_recon_to_scan_mm: float
    """Mean distance from each reconstruction vertex to the scan surface (NaN: scan is points)."""
    v2v_scan_to_recon_mm: float
    """Mean distance from each scan vertex to the nearest reconstruction vertex."""
    v2s_scan_to_recon_mm: float
    """Mean distance from each scan vertex to the reconstruction surface."""

    def to_dict(self) -> dict[str, float]:
        """``{field name: value}`` with exactly the four field names as keys."""
        return asdict(self)


def _check_vertices(vertices: Any, name: str) -> np.ndarray:
    array = _to_numpy(vertices, name).astype(np.float64, copy=False)
    if array.ndim != 2 or array.shape[1] != 3 or array.shape[0] == 0:
        raise ValueError(f"{name} must have shape [V, 3] with V > 0, got {list(array.shape)}")
    if not np.isfinite(array).all():
        raise ValueError(f"{name} has non-finite entries")
    return np.ascontiguousarray(array)


def _check_faces(faces: Any, name: str, num_vertices: int) -> np.ndarray | None:
    if faces is None:
        return None
    array = _to_numpy(faces, name)
    if array.size == 0:
        return None
    if array.ndim != 2 or array.shape[1] != 3:
        raise ValueError(f"{name} must have shape [F, 3], got {list(array.shape)}")
    if not np.issubdtype(array.dtype, np.integer):
        raise TypeError(f"{name} must hold integer vertex indices, got dtype {array.dtype}")
    if array.min() < 0 or array.max() >= num_vertices:
        raise ValueError(f"{name} indexes vertices outside [0, {num_vertices}): "
                         f"min {array.min()}, max {array.max()}")
    return np.ascontiguousarray(array, dtype=np.int64)


def _mean_distance_to_surface(points: np.ndarray, vertices: np.ndarray,
                              faces: np.ndarray) -> float:
    import point_cloud_utils as pcu

    distances, _, _ = pcu.closest_points_on_mesh(points, vertices, faces)
    return float(np.mean(distances))


def mesh_distances(recon_vertices: Any, recon_faces: Any | None, scan_vertices: Any,
                   scan_faces: Any | None = None, unit_scale: float = 1000.0) -> MeshDistances:
    """Vertex-to-vertex (V2V) and vertex-to-surface (V2S) distances, both directions.

    As in the LISA paper (Table 1): V2V from A to B is the mean over A's vertices of the distance
    to the nearest VERTEX of B (``scipy.spatial.cKDTree``); V2S from A to B is the mean over A's
    vertices of the distance to B's SURFACE, i.e. the closest point on any triangle
    (``point_cloud_utils.closest_points_on_mesh``). Since a vertex is a point of the surface,
    V2V >= V2S. All vertices count, referenced by a face or not; V2S only sees B's triangles.

    recon_vertices: [V, 3], recon_faces: [F, 3] or None, scan_vertices: [V', 3],
    scan_faces: [F', 3] or None (a scan that is only points). Lengths in metres with the default
    ``unit_scale=1000`` give millimetres; pass ``unit_scale=1`` to keep the inputs' units.

    A scan without faces has no surface, so ``v2s_recon_to_scan_mm`` is NaN (likewise
    ``v2s_scan_to_recon_mm`` for a reconstruction without faces).
    """
    recon_v = _check_vertices(recon_vertices, "recon_vertices")
    scan_v = _check_vertices(scan_vertices, "scan_vertices")
    recon_f = _check_faces(recon_faces, "recon_faces", len(recon_v))
    scan_f = _check_faces(scan_faces, "scan_faces", len(scan_v))
    if not unit_scale > 0:
        raise ValueError(f"unit_scale must be positive, got {unit_scale}")
    from scipy.spatial import cKDTree

    v2v_recon_to_scan = float(np.mean(cKDTree(scan_v).query(recon_v)[0]))
    v2v_scan_to_recon = float(np.mean(cKDTree(recon_v).query(scan_v)[0]))
    v2s_recon_to_scan = (math.nan if scan_f is None
                         else _mean_distance_to_surface(recon_v, scan_v, scan_f))
    v2s_scan_to_recon = (math.nan if recon_f is None
                         else _mean_distance_to_surface(scan_v, recon_v, recon_f))
    return MeshDistances(
        v2v_recon_to_scan_mm=unit_scale * v2v_recon_to_scan,
        v2s_recon_to_scan_mm=unit_scale * v2s_recon_to_scan,
        v2v_scan_to_recon_mm=unit_scale * v2v_scan_to_recon,
        v2s_scan_to_recon_mm=unit_scale * v2s_scan_to_recon,
    )


def _points_from_array(array: np.ndarray, path: Path, what: str) -> np.ndarray:
    if array.ndim != 2 or array.shape[1] < 3 or array.shape[0] == 0:
        raise ValueError(f"{path}: {what} must have shape [N, 3] (extra columns such as normals "
                         f"are ignored), got {list(array.shape)}")
    return np.ascontiguousarray(array[:, :3], dtype=np.float64)


def load_mesh(path: str | os.PathLike) -> MeshData:
    """Read a mesh (PLY, OBJ, GLB/GLTF, STL, OFF via trimesh) or a point set (.npy, .npz, .xyz).

    Scenes are concatenated into one mesh; a PLY holding only points gives a point set.
    ``.npy``: an [N, 3+] array. ``.npz``: ``vertices`` (or ``points``) [N, 3] and optional
    ``faces`` [F, 3]. ``.xyz``: text, one point a line, the first three columns are x y z.
    Errors name the file.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no such file")
    suffix = path.suffix.lower()
    if suffix in _POINT_SUFFIXES:
        try:
            if suffix == ".npy":
                return MeshData(_points_from_array(np.load(path, allow_pickle=False), path,
                                                   "the array"), None)
            if suffix == ".xyz":
                array = np.loadtxt(path, ndmin=2, comments="#")
                return MeshData(_points_from_array(array, path, "the points"), None)
            with np.load(path, allow_pickle=False) as archive:
                key = next((k for k in ("vertices", "points") if k in archive.files), None)
                if key is None:
                    raise ValueError(f"{path}: expected an array named 'vertices' or 'points', "
                                     f"found {archive.files}")
                vertices = _points_from_array(archive[key], path, f"'{key}'")
                faces = archive["faces"] if "faces" in archive.files else None
        except (OSError, EOFError, ValueError) as exc:
            message = str(exc)
            raise ValueError(message if message.startswith(str(path))
                             else f"{path}: cannot read ({message})") from None
        return MeshData(vertices, _check_faces(faces, f"{path}: faces", len(vertices)))
    if suffix not in _MESH_SUFFIXES:
        raise ValueError(f"{path}: unsupported file type '{suffix}' (expected one of "
                         f"{', '.join(_MESH_SUFFIXES + _POINT_SUFFIXES)})")
    import trimesh

    try:
        # process=True merges vertices at identical positions (STL and UV seams repeat them), so
        # V2V averages over distinct surface points.
        loaded = trimesh.load(path, process=True)
    except Exception as exc:  # trimesh raises many types for corrupt files
        raise ValueError(f"{path}: cannot read ({type(exc).__name__}: {exc})") from None
    if isinstance(loaded, trimesh.Scene):
        geometries = list(loaded.dump()) if loaded.geometry else []
        meshes = [g for g in geometries if isinstance(g, trimesh.Trimesh) and len(g.faces)]
        clouds = [g for g in geometries if isinstance(g, trimesh.PointCloud)]
        if meshes:
            loaded = trimesh.util.concatenate(meshes)
        elif clouds:
            loaded = trimesh.PointCloud(np.concatenate([c.vertices for c in clouds]))
        else:
            raise ValueError(f"{path}: the file holds no mesh or points")
    if isinstance(loaded, trimesh.PointCloud):
        vertices, faces = np.asarray(loaded.vertices, dtype=np.float64), None
    elif isinstance(loaded, trimesh.Trimesh):
        vertices = np.asarray(loaded.vertices, dtype=np.float64)
        faces = np.asarray(loaded.faces, dtype=np.int64) if len(loaded.faces) else None
    else:
        raise ValueError(f"{path}: unsupported content ({type(loaded).__name__})")
    if vertices.ndim != 2 or vertices.shape[1] != 3 or len(vertices) == 0:
        raise ValueError(f"{path}: the file holds no vertices")
    if not np.isfinite(vertices).all():
        raise ValueError(f"{path}: vertices have non-finite entries")
    return MeshData(np.ascontiguousarray(vertices), faces)


def detect_length_unit(vertices: Any) -> str:
    """Guess the unit of a hand's coordinates: ``"mm"`` if its bounding-box diagonal exceeds 2
    units (no hand is 2 m across), else ``"m"``.

    vertices: [V, 3] -> "m" or "mm"
    """
    array = _check_vertices(vertices, "vertices")
    diagonal = float(np.linalg.norm(array.max(axis=0) - array.min(axis=0)))
    return "mm" if diagonal > _MM_DIAGONAL_THRESHOLD else "m"


@dataclass(frozen=True)
class MeshComparison:
    """Result of :func:`compare_mesh_files`."""

    distances: MeshDistances
    """The four distances in millimetres."""
    recon_unit: str
    """Unit the reconstruction file was read in: "m" or "mm"."""
    scan_unit: str
    """Unit the scan file was read in: "m" or "mm"."""
    recon_unit_detected: bool
    """True if ``recon_unit`` was guessed (``units="auto"``)."""
    scan_unit_detected: bool
    """True if ``scan_unit`` was guessed (``units="auto"``)."""


def compare_mesh_files(recon_path: str | os.PathLike, scan_path: str | os.PathLike,
                       units: str = "auto") -> MeshComparison:
    """Load two files with :func:`load_mesh` and return their distances in millimetres.

    units: "m", "mm" (both files), or "auto" (each file on its own: :func:`detect_length_unit`).
    """
    if units not in ("m", "mm", "auto"):
        raise ValueError(f"units must be 'm', 'mm' or 'auto', got {units!r}")
    recon = load_mesh(recon_path)
    scan = load_mesh(scan_path)
    recon_unit = detect_length_unit(recon.vertices) if units == "auto" else units
    scan_unit = detect_length_unit(scan.vertices) if units == "auto" else units
    to_metres = {"m": 1.0, "mm": 1e-3}
    distances = mesh_distances(recon.vertices * to_metres[recon_unit], recon.faces,
                               scan.vertices * to_metres[scan_unit], scan.faces,
                               unit_scale=1000.0)
    return MeshComparison(distances, recon_unit, scan_unit, units == "auto", units == "auto")


# ---------------------------------------------------------------------------------------------
# Images
# ---------------------------------------------------------------------------------------------


def _check_image(image: Any, name: str) -> np.ndarray:
    array = _to_numpy(image, name)
    if array.ndim not in (2, 3) or (array.ndim == 3 and array.shape[2] not in (1, 3)):
        raise ValueError(f"{name} must have shape [H, W, 3] (or [H, W], [H, W, 1]), "
                         f"got {list(array.shape)}")
    if array.dtype == np.uint8:
        return array.astype(np.float64) / 255.0
    if not (np.issubdtype(array.dtype, np.floating) or array.dtype == np.bool_):
        raise TypeError(f"{name} must be float in [0, 1] or uint8, got dtype {array.dtype}")
    return array.astype(np.float64, copy=False)


def _check_pair(pred: Any, target: Any, mask: Any | None
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    pred_array = _check_image(pred, "pred")
    target_array = _check_image(target, "target")
    if pred_array.shape != target_array.shape:
        raise ValueError(f"pred and target must have the same shape, got pred "
                         f"{list(pred_array.shape)} and target {list(target_array.shape)}")
    if mask is None:
        return pred_array, target_array, None
    mask_array = _to_numpy(mask, "mask")
    if mask_array.ndim == 3 and mask_array.shape[2] == 1:
        mask_array = mask_array[..., 0]
    if mask_array.shape != pred_array.shape[:2]:
        raise ValueError(f"mask must have shape [H, W] = {list(pred_array.shape[:2])}, "
                         f"got {list(mask_array.shape)}")
    mask_array = mask_array.astype(bool)
    if not mask_array.any():
        raise ValueError("mask is empty: no pixel to evaluate")
    return pred_array, target_array, mask_array


def psnr(pred: Any, target: Any, mask: Any | None = None, max_value: float = 1.0) -> float:
    """Peak signal-to-noise ratio ``10 log10(max_value^2 / MSE)`` in dB.

    pred, target: [H, W, 3] (or [H, W]) floats in [0, max_value], or uint8 (divided by 255, so
    keep ``max_value=1``); mask: [H, W] bool or None. With a mask the MSE averages only the
    pixels inside it (all channels). Identical images give ``inf``.
    """
    pred_array, target_array, mask_array = _check_pair(pred, target, mask)
    if not max_value > 0:
        raise ValueError(f"max_value must be positive, got {max_value}")
    squared = (pred_array - target_array) ** 2
    mse = float(squared[mask_array].mean() if mask_array is not None else squared.mean())
    if mse == 0.0:
        return math.inf
    return 10.0 * math.log10(max_value**2 / mse)


# Gaussian 11x11 window with sigma 1.5 and population statistics: the SSIM of Wang et al. (2004),
# as used by NeRF-style evaluations (skimage's documented way to match the paper).
_SSIM_SIGMA = 1.5
_SSIM_WINDOW = 11


def ssim(pred: Any, target: Any, mask: Any | None = None, max_value: float = 1.0) -> float:
    """Structural similarity (Wang et al. 2004) via ``skimage.metrics.structural_similarity``.

    Gaussian window (sigma 1.5, 11x11), population covariances, ``data_range=max_value``, colour
    channels averaged. Without a mask: the mean SSIM of skimage (which crops the window's
    half-width at the borders). With a mask: the mean of the full SSIM map over the mask's pixels
    (and channels); windows near the mask's edge still see pixels outside it.

    pred, target: [H, W, 3] (or [H, W]) floats in [0, max_value] or uint8, H and W >= 11;
    mask: [H, W] bool or None.
    """
    pred_array, target_array, mask_array = _check_pair(pred, target, mask)
    if min(pred_array.shape[:2]) < _SSIM_WINDOW:
        raise ValueError(f"ssim needs images of at least {_SSIM_WINDOW}x{_SSIM_WINDOW} pixels, "
                         f"got pred {list(pred_array.shape)}")
    from skimage.metrics import structural_similarity

    channel_axis = -1 if pred_array.ndim == 3 else None
    mean_ssim, ssim_map = structural_similarity(
        pred_array, target_array, data_range=max_value, channel_axis=channel_axis,
        gaussian_weights=True, sigma=_SSIM_SIGMA, use_sample_covariance=False, full=True,
    )
    if mask_array is None:
        return float(mean_ssim)
    return float(ssim_map[mask_array].mean())


# ---------------------------------------------------------------------------------------------
# LPIPS (optional: needs the lpips package, torchvision and the backbone weights on disk)
# ---------------------------------------------------------------------------------------------

# Backbone checkpoints torchvision stores in <torch hub dir>/checkpoints.
_LPIPS_BACKBONES = {"alex": "alexnet-owt-", "vgg": "vgg16-", "squeeze": "squeezenet1_1-"}
_lpips_models: dict[str, Any] = {}
_lpips_failures: dict[str, str] = {}


def lpips_unavailable_reason(net: str = "alex") -> str:
    """Why :func:`lpips_distance` returns None, in one line; "" when LPIPS can run.

    Checks only files and importability, never downloads: the ``lpips`` package, ``torchvision``,
    the package's linear-layer weights ``lpips/weights/v0.1/<net>.pth`` and the backbone
    checkpoint in ``<torch hub dir>/checkpoints``.
    """
    if net in _lpips_failures:
        return _lpips_failures[net]
    if net not in _LPIPS_BACKBONES:
        return f"unknown LPIPS network {net!r} (expected one of {sorted(_LPIPS_BACKBONES)})"
    spec = importlib.util.find_spec("lpips")
    if spec is None or spec.origin is None:
        return "LPIPS unavailable: the 'lpips' package is not installed"
    if importlib.util.find_spec("torchvision") is None:
        return "LPIPS unavailable: 'lpips' needs torchvision, which is not installed"
    linear = Path(spec.origin).parent / "weights" / "v0.1" / f"{net}.pth"
    if not linear.is_file():
        return f"LPIPS unavailable: missing the lpips linear weights {linear}"
    import torch

    checkpoints = Path(torch.hub.get_dir()) / "checkpoints"
    prefix = _LPIPS_BACKBONES[net]
    if not any(checkpoints.glob(f"{prefix}*.pth")):
        return (f"LPIPS unavailable: no '{prefix}*.pth' backbone weights in {checkpoints} "
                f"(they are never downloaded at run time)")
    return ""


@contextmanager
def _downloads_forbidden() -> Iterator[None]:
    """Make any torch.hub download raise instead of reaching the network."""
    import torch.hub

    original = torch.hub.download_url_to_file

    def refuse(url: str, *args: Any, **kwargs: Any) -> None:
        raise RuntimeError(f"LPIPS tried to download {url}; downloads are disabled")

    torch.hub.download_url_to_file = refuse
    try:
        yield
    finally:
        torch.hub.download_url_to_file = original


def lpips_distance(pred: Any, target: Any, net: str = "alex") -> float | None:
    """LPIPS perceptual distance (Zhang et al. 2018; lower is more similar), or None.

    Returns None when the package or its weights are not available locally (see
    :func:`lpips_unavailable_reason`); never downloads anything.

    pred, target: [H, W, 3] floats in [0, 1] or uint8.
    """
    pred_array, target_array, _ = _check_pair(pred, target, None)
    if pred_array.ndim != 3 or pred_array.shape[2] != 3:
        raise ValueError(f"lpips_distance needs [H, W, 3] images, got {list(pred_array.shape)}")
    if lpips_unavailable_reason(net):
        return None
    import torch

    model = _lpips_models.get(net)
    if model is None:
        import lpips

        try:
            with _downloads_forbidden():
                model = lpips.LPIPS(net=net, pretrained=True, verbose=False).eval()
        except (RuntimeError, OSError) as exc:  # refused download, unreadable weights
            _lpips_failures[net] = f"LPIPS unavailable: loading the model failed ({exc})"
            return None
        _lpips_models[net] = model

    def to_tensor(image: np.ndarray) -> torch.Tensor:
        # LPIPS expects [1, 3, H, W] in [-1, 1].
        return torch.from_numpy(image).float().permute(2, 0, 1)[None] * 2.0 - 1.0

    with torch.no_grad():
        return float(model(to_tensor(pred_array), to_tensor(target_array)).item())


# ---------------------------------------------------------------------------------------------
# All image metrics at once
# ---------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class ImageMetrics:
    """PSNR, SSIM and LPIPS of one rendered image against its ground truth (:func:`image_metrics`).

    A field is NaN where it is undefined: the masked metrics without a mask, LPIPS when its
    weights are not installed (``lpips_message`` then says why, in one line).
    """

    psnr_db: float
    """PSNR over the whole image, dB (``inf`` for identical images)."""
    ssim: float
    """Mean SSIM over the whole image (unitless, at most 1)."""
    psnr_mask_db: float
    """PSNR inside the mask, dB (NaN without a mask)."""
    ssim_mask: float
    """Mean SSIM map inside the mask (NaN without a mask)."""
    lpips: float
    """LPIPS over the whole image (lower is more similar; NaN when unavailable)."""
    lpips_message: str
    """Why LPIPS is NaN, one line (:func:`lpips_unavailable_reason`); "" when it was computed."""

    def to_dict(self) -> dict[str, float | None]:
        """The five metrics by field name, NaN as None (JSON's null); no message."""
        return {key: (None if isinstance(value, float) and math.isnan(value) else value)
                for key, value in asdict(self).items() if key != "lpips_message"}


def image_metrics(pred: Any, target: Any, mask: Any | None = None,
                  lpips_net: str = "alex") -> ImageMetrics:
    """:func:`psnr` and :func:`ssim` of the whole image and inside ``mask``, and
    :func:`lpips_distance` of the whole image (never downloads anything).

    pred, target: [H, W, 3] floats in [0, 1] or uint8, H and W >= 11; mask: [H, W] bool or None.
    """
    pred_array, target_array, mask_array = _check_pair(pred, target, mask)
    if mask_array is None:
        psnr_mask_db = ssim_mask = math.nan
    else:
        psnr_mask_db = psnr(pred_array, target_array, mask_array)
        ssim_mask = ssim(pred_array, target_array, mask_array)
    value = lpips_distance(pred_array, target_array, net=lpips_net)
    message = "" if value is not None else (lpips_unavailable_reason(lpips_net)
                                            or "LPIPS unavailable")
    return ImageMetrics(
        psnr_db=psnr(pred_array, target_array),
        ssim=ssim(pred_array, target_array),
        psnr_mask_db=psnr_mask_db,
        ssim_mask=ssim_mask,
        lpips=math.nan if value is None else value,
        lpips_message=message,
    )
