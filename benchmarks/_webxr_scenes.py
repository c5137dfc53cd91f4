"""Point fits of the WebXR hand in scenes with more than the hand in them (``python -m benchmarks
fit --webxr ... --webxr-table / --webxr-wall / --webxr-person``): lying on a table, held before a
wall in a depth camera's whole frame, held out by a person (the scans:
:mod:`lisa_hand.data.webxr_scenes`).
"""

from __future__ import annotations

from pathlib import Path

from lisa_hand.data.webxr_hand import WEBXR_POSES, webxr_side
from lisa_hand.data.webxr_scenes import person_scan, table_scan, wall_scan
from lisa_hand.utils.threads import cpu_threads

__all__ = ["run_scene_fits"]


def _scenes(path: str | Path, scene: str, seed: int):
    """(pose, label, points, (vertices, faces), sensor) of each scan of :func:`run_scene_fits`."""
    for pose in WEBXR_POSES:
        if scene == "wall":
            yield (pose, "depth frame, wall", *wall_scan(path, pose, seed))
            continue
        if scene == "person":
            yield (pose, "depth frame, person", *person_scan(path, pose, seed))
            continue
        for down in ("palm", "back"):
            yield (pose, f"table, {down} down", *table_scan(path, pose, down, seed))


def run_scene_fits(model, path: str | Path, *, scene: str = "table", seed: int = 0,
                   threads: int = 1, support: str | None = "auto", viewpoints: str = "auto",
                   others: str | None = "auto", config=None, log=None) -> list[dict]:
    """Fit ``model`` to scans of the WebXR hand in each pose with more than the hand in them:
    ``scene`` "table" (:func:`table_scan`, palm and back down), "wall" (:func:`wall_scan`, a
    depth camera's whole frame) or "person" (:func:`person_scan`, a depth camera's frame of a
    person holding the hand out), with ``support`` ("auto": the table or the wall found and left
    out, the hand kept on its side; None: every point fitted) and ``viewpoints`` ("none", "true":
    the simulated sensor's, "auto"). ``others`` ("auto", as ``lisa fit-points`` by default:
    pieces apart from the hand left out, the part nearest the sensor kept of a scan larger than
    a hand; None: not).
    -> one dict per fit: pose, scan ("table, palm down" ...), seconds, the support found (share
    of the points on it, or None), and the four distances (mm) against the hand, both cut at
    the fit's wrist plane (inf when that cut leaves none of the hand: a fit far off)."""
    import dataclasses

    from lisa_hand.fitting.points.fit import FitPointsConfig, fit_points
    from lisa_hand.inference import MeshConfig, mesh_hand
    from lisa_hand.metrics import mesh_distances

    config = FitPointsConfig(num_threads=threads, seed=seed) if config is None else \
        dataclasses.replace(config, num_threads=threads)
    side = webxr_side(path)
    if scene not in ("table", "wall", "person"):
        raise ValueError(f"scene must be 'table', 'wall' or 'person', got {scene!r}")
    rows = []
    for pose, label, points, (vertices, faces), sensor in _scenes(path, scene, seed):
        view = {"none": None, "true": sensor, "auto": "auto"}[viewpoints]
        with cpu_threads(threads):
            fit = fit_points(model, points, None, config, side=side, viewpoint=view,
                             support=support, others=others)
            mesh = mesh_hand(model, fit.params, 128, MeshConfig(colors=False,
                                                                skin_weights=False),
                             clip=fit.wrist_plane)
        try:
            distances = mesh_distances(mesh.vertices, mesh.faces, vertices, faces,
                                       clip=fit.wrist_plane).to_dict()
        except ValueError:  # a fit far off (with support=None: on the wall) cuts the hand away
            distances = dict.fromkeys(("v2v_recon_to_scan_mm", "v2s_recon_to_scan_mm",
                                       "v2v_scan_to_recon_mm", "v2s_scan_to_recon_mm"),
                                      float("inf"))
        rows.append({"pose": pose, "wrist": "as-is", "scan": label,
                     "support": None if fit.support is None else fit.support.fraction,
                     "viewpoint": viewpoints, "seconds": fit.seconds,
                     "beyond_wrist_points": fit.beyond_wrist_points, **distances,
                     "scan_points_to_recon_mm": float("nan")})
        if log is not None:
            log(rows[-1])
    return rows
