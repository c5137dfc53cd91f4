"""Point fits of the artist-made WebXR hand (``tests/assets/webxr_hand``, MIT, Amazon; read and
posed by :mod:`lisa_hand.data.webxr_hand`): a hand the project did not make, posed with its own
rig, scanned whole or from one side, with its forearm stub as it is, run on into a forearm, or
cut short at the wrist (``python -m benchmarks fit --webxr``).

Wrist variants: ``as-is`` (the artist's 2.2 cm stub beyond the wrist joint),
``forearm`` (the stub cut 1.5 cm beyond the wrist joint and its cut rim extruded 12 cm along the
forearm axis, the far end closed), ``cut`` (scan points beyond the wrist joint dropped: a scan
that stops exactly at the wrist). The fit leaves out what lies beyond its wrist cut
(:attr:`lisa_hand.fitting.points.config.FitPointsConfig.wrist_clip_m`), and the distances are
taken with both meshes cut at the fit's plane (``FitResult.wrist_plane``), as ``lisa
fit-points --gt`` does; the ground truth of ``cut`` is the artist's mesh cut at the wrist joint.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

from lisa_hand.data.webxr_hand import (
    WEBXR_POSES,
    WEBXR_WRISTS,
    outer_surface,
    pose_webxr_hand,
    webxr_side,
    webxr_wrist,
    webxr_wrist_variant,
)
from lisa_hand.utils.threads import cpu_threads

__all__ = ["run_webxr_fits", "measured_fit", "refined_row"]


def refined_row(model, fit, points: np.ndarray, vertices: np.ndarray, faces: np.ndarray,
                 refine, threads: int) -> dict:
    """The distances of ``fit`` refined on ``points`` (``refined_`` + the four keys) and the
    refinement's seconds."""
    from lisa_hand.fitting.points.refine import refine_surface
    from lisa_hand.fitting.sides import mirror_cloud, mirror_hand
    from lisa_hand.inference import MeshConfig, mesh_hand
    from lisa_hand.metrics import mesh_distances

    keep = fit.wrist_plane.keeps(points) if fit.wrist_plane is not None else slice(None)
    side = fit.params.side  # LISA is a right hand: a left one is refined mirrored
    hand = mirror_hand(fit.params) if side == "left" else fit.params
    with cpu_threads(threads):
        refined, report = refine_surface(
            model, hand, mirror_cloud(torch.as_tensor(points[keep], dtype=torch.float32), side),
            None, refine)
        mesh = mesh_hand(refined, fit.params, 128, MeshConfig(colors=False, skin_weights=False),
                         clip=fit.wrist_plane)
    distances = mesh_distances(mesh.vertices, mesh.faces, vertices, faces, clip=fit.wrist_plane)
    return {"refine_seconds": report.seconds,
            **{f"refined_{key}": value for key, value in distances.to_dict().items()},
            "refined_scan_points_to_recon_mm": _points_to_mesh_mm(points, mesh, fit.wrist_plane)}


def _points_to_mesh_mm(points: np.ndarray, mesh, plane) -> float:
    """Mean distance (mm) from the scan's own points on the hand's side of the wrist cut to the
    fitted surface: scan->recon over what the scanner saw (for a one-sided scan, its seen side;
    the V2S keys count the artist's whole mesh)."""
    import point_cloud_utils as pcu

    kept = points if plane is None else points[plane.keeps(points)]
    distances, _, _ = pcu.closest_points_on_mesh(np.asarray(kept, np.float64),
                                                 np.asarray(mesh.vertices, np.float64),
                                                 np.asarray(mesh.faces, np.int64))
    return float(np.mean(distances) * 1000.0)


def _check_webxr_args(viewpoints: str, wrists: tuple[str, ...], scale: float,
                      proportions=None) -> None:
    if viewpoints not in ("none", "true", "auto"):
        raise ValueError(f"viewpoints must be 'none', 'true' or 'auto', got {viewpoints!r}")
    if not 0.5 <= scale <= 2.0:
        raise ValueError(f"scale must be in [0.5, 2], got {scale!r}")
    if proportions is not None and (len(proportions) != 3
                                    or not all(0.7 <= f <= 1.4 for f in proportions)):
        raise ValueError("proportions must be three factors (breadth, thickness, fingers) in "
                         f"[0.7, 1.4], got {proportions!r}")
    for variant in wrists:
        if variant not in WEBXR_WRISTS:
            raise ValueError(f"unknown wrist variant {variant!r}: one of {WEBXR_WRISTS}")


def measured_fit(model, points: np.ndarray, vertices: np.ndarray, faces: np.ndarray, config,
                  side: str, viewpoint, threads: int) -> tuple[object, dict]:
    """One WebXR fit on ``threads`` threads, its 128^3 mesh measured against the truth
    (vertices [V, 3] metres, faces [F, 3]), both cut at the fit's wrist plane.
    points: [N, 3] metres, the scan. -> (the ``FitResult``, its row's numbers: seconds, points
    beyond the wrist, the four distances, ``scan_points_to_recon_mm``)."""
    from lisa_hand.fitting.points.fit import fit_points
    from lisa_hand.inference import MeshConfig, mesh_hand
    from lisa_hand.metrics import mesh_distances

    with cpu_threads(threads):  # the fit and its mesh on ``threads`` threads
        fit = fit_points(model, points, None, config, side=side, viewpoint=viewpoint)
        mesh = mesh_hand(model, fit.params, 128, MeshConfig(colors=False, skin_weights=False),
                         clip=fit.wrist_plane)
    distances = mesh_distances(mesh.vertices, mesh.faces, vertices, faces, clip=fit.wrist_plane)
    return fit, {"seconds": fit.seconds, "beyond_wrist_points": fit.beyond_wrist_points,
                 **distances.to_dict(),
                 "scan_points_to_recon_mm": _points_to_mesh_mm(points, mesh, fit.wrist_plane)}


def run_webxr_fits(model, path: str | Path, *, num_points: int = 5000, seed: int = 0,
                   threads: int = 1, wrists: tuple[str, ...] = ("as-is",),
                   config=None, refine=None, viewpoints: str = "none", scale: float = 1.0,
                   proportions: tuple[float, float, float] | None = None,
                   log=None) -> list[dict]:
    """Fit ``model`` (a trained model) to the WebXR hand (``right_hand.npz`` or
    ``left_hand.npz``, its side found by :func:`webxr_side`) in each pose of
    :data:`WEBXR_POSES` and each wrist variant of ``wrists`` (:data:`WEBXR_WRISTS`), from a full
    scan and from a one-view partial scan (noise 0.3 mm), each in a random placement (the same
    for every variant of a pose).

    config: the :class:`~lisa_hand.fitting.points.config.FitPointsConfig` (None: defaults with
    ``num_threads=threads`` and ``seed``). refine: a
    :class:`~lisa_hand.fitting.points.refine.RefineConfig`: each fit is also refined
    (``lisa fit-points --refine``) and measured again (``refined_*`` keys, ``refine_seconds``).
    viewpoints: what each one-view scan's fit is told of its sensor position
    (``fit_points(viewpoint=)``, the free-space term): "none"; "true", the simulated sensor's, as
    a depth camera's points in its own frame give it; "auto", found from the scan (a full scan's
    fit gets "auto" too, which leaves it without one).
    scale: the hand made this many times larger about its wrist joint in every pose (a hand of
    another size: 1.15 is 204 mm from the wrist joint to the middle fingertip, 0.85 is 151).
    proportions: (breadth, thickness, fingers) of :func:`reshape_webxr_rig`, applied before
    ``scale`` (None: the artist's).
    log: called with each row as it is measured.
    -> one dict per fit: pose, wrist, scan kind, seconds, points left out beyond the wrist, the
    four distances (mm, fitted 128^3 mesh against the variant's mesh, both cut at the fit's
    wrist plane) and ``scan_points_to_recon_mm`` (the scan's own points to the fitted surface:
    the seen side of a one-sided scan).
    """
    import dataclasses

    from lisa_hand.data.scans import ScanConfig, simulate_scan
    from lisa_hand.fitting.points.fit import FitPointsConfig
    from lisa_hand.geometry import axis_angle_to_matrix
    from lisa_hand.geometry.planes import Plane

    _check_webxr_args(viewpoints, wrists, scale, proportions)
    config = FitPointsConfig(num_threads=threads, seed=seed) if config is None else \
        dataclasses.replace(config, num_threads=threads)
    generator = torch.Generator().manual_seed(seed)
    wrist, forearm = webxr_wrist(path, proportions)
    side = webxr_side(path)
    rows = []
    for pose in WEBXR_POSES:
        posed, faces = pose_webxr_hand(path, pose, proportions)
        posed = wrist + scale * (posed - wrist)
        outer = outer_surface(posed, faces)  # what a scanner sees of the whole hand
        turn = 3.0 * torch.rand(3, generator=generator, dtype=torch.float64)
        rotation = axis_angle_to_matrix(turn).numpy()
        centre = posed.mean(0)

        def place(points, rotation=rotation, centre=centre):
            return (points - centre) @ rotation.T + 0.3 * np.array([0, 0, 1.0])

        for variant in wrists:
            vertices, variant_faces = outer if variant == "as-is" else outer_surface(
                *webxr_wrist_variant(posed, faces, wrist, forearm, variant))
            placed = place(vertices)
            for partial in (False, True):
                scan_vertices, scan_faces = ((place(outer[0]), outer[1]) if variant == "cut"
                                             else (placed, variant_faces))
                scan = simulate_scan(scan_vertices, scan_faces,
                                     ScanConfig(num_points=num_points, partial=partial,
                                                noise_normal_std=3e-4), seed=seed)
                points = scan.points
                if variant == "cut":  # the scanner stopped at the wrist joint
                    points = points[Plane(place(wrist[None])[0],
                                          -(forearm @ rotation.T)).keeps(points)]
                kind = "partial" if partial else "full"
                viewpoint = {"none": None, "auto": "auto",
                             "true": scan.viewpoint if partial else None}[viewpoints]
                fit, measured = measured_fit(model, points, placed, variant_faces, config,
                                              side, viewpoint, threads)
                rows.append({"pose": pose, "wrist": variant, "scan": kind,
                             "model": str(model.source), "viewpoint": viewpoints,
                             "scale": scale, "proportions": list(proportions or (1.0, 1.0, 1.0)),
                             **measured})
                if refine is not None:
                    rows[-1].update(refined_row(model, fit, points, placed, variant_faces,
                                                 refine, threads))
                if log is not None:
                    log(rows[-1])
    return rows
