"""The artist-made WebXR hand (``shared/data/webxr_hand``, MIT, Amazon): a hand the project did
not make, posed with its own rig, scanned whole or from one side, with its forearm stub as it is,
run on into a forearm, or cut short at the wrist (``python -m lisa_hand.bench fit --webxr``).

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

from ..utils.threads import cpu_threads

__all__ = ["WEBXR_POSES", "WEBXR_WRISTS", "pose_webxr_hand", "outer_surface", "webxr_side",
           "webxr_wrist", "reshape_webxr_rig", "extend_forearm", "webxr_wrist_variant",
           "run_webxr_fits"]

WEBXR_WRISTS = ("as-is", "forearm", "cut")
"""What the scans do beyond the wrist (see the module docstring)."""
FOREARM_START_M = 0.015
FOREARM_LENGTH_M = 0.12

WEBXR_POSES = {
    "rest": {},
    "bent_index": {"index-finger": (0.9, 1.2, 0.7)},
    "fist": {**{finger: (1.3, 1.5, 0.9) for finger in ("index-finger", "middle-finger",
                                                        "ring-finger", "pinky-finger")},
             "thumb": (0.3, 0.5, 0.5)},
}
"""Flexion (radians) of each finger's three joints (MCP, PIP, DIP; thumb CMC, MCP, IP)."""


def reshape_webxr_rig(vertices: np.ndarray, joints: np.ndarray, names: list[str],
                      proportions: tuple[float, float, float]) -> tuple[np.ndarray, np.ndarray]:
    """The WebXR hand in other proportions, in its bind pose: a hand unlike the artist's for
    checks beyond one mesh, made by a map that keeps the wrist joint where it is.

    vertices: [V, 3] metres; joints: [25, 3] metres, in the rig's order ``names``.
    proportions: (breadth, thickness, fingers): the palm's breadth across the knuckles and its
    thickness along the knuckle plane's normal scaled about the wrist joint, and everything
    beyond the knuckle line (the mean of the four fingers' proximal joints along the wrist ->
    middle knuckle axis) stretched along that axis, the fingers that many times longer (the
    thumb's tip, which reaches past the line, a little longer too).
    -> (vertices [V, 3], joints [25, 3]) metres, the same map applied to both.
    """
    breadth, thickness, fingers = (float(f) for f in proportions)
    wrist = joints[names.index("wrist")]
    along = joints[names.index("middle-finger-phalanx-proximal")] - wrist
    along /= np.linalg.norm(along)
    normal = _palm_normal(joints, names)
    normal = normal - along * (normal @ along)
    normal /= np.linalg.norm(normal)
    frame = np.stack([along, np.cross(normal, along), normal])  # rows: fingers, breadth, normal
    knuckles = np.mean([(joints[names.index(f"{finger}-phalanx-proximal")] - wrist) @ along
                        for finger in ("index-finger", "middle-finger", "ring-finger",
                                       "pinky-finger")])

    def reshape(points):
        local = (points - wrist) @ frame.T
        local[:, 0] += (fingers - 1.0) * np.maximum(local[:, 0] - knuckles, 0.0)
        local[:, 1] *= breadth
        local[:, 2] *= thickness
        return wrist + local @ frame

    return reshape(vertices), reshape(joints)


def _load_rig(path: str | Path, proportions=None) -> dict:
    """The WebXR rig in metres (vertices, faces, weights, joints, parents, names), reshaped by
    :func:`reshape_webxr_rig` when ``proportions`` is given."""
    with np.load(path, allow_pickle=False) as data:
        rig = {"vertices": data["vertices"] * 1e-3, "faces": data["faces"],
               "weights": data["weights"], "joints": data["joints"].astype(np.float64) * 1e-3,
               "parents": data["parents"], "names": [str(n) for n in data["joint_names"]]}
    if proportions is not None and tuple(proportions) != (1.0, 1.0, 1.0):
        rig["vertices"], rig["joints"] = reshape_webxr_rig(rig["vertices"], rig["joints"],
                                                           rig["names"], proportions)
    return rig


def pose_webxr_hand(path: str | Path, pose: str = "rest",
                    proportions: tuple[float, float, float] | None = None
                    ) -> tuple[np.ndarray, np.ndarray]:
    """The WebXR hand (``right_hand.npz``: millimetres, 25 OpenXR joints, its own skinning
    weights) posed by linear blend skinning, in metres.

    Each joint of :data:`WEBXR_POSES` turns about the axis ``bone x palm normal``, so positive
    angles curl the finger towards the palm, of a right hand (``right_hand.npz``) or a left one
    (``left_hand.npz``): for the four fingers the palm normal is the normal of the knuckle plane
    (wrist, index and little-finger proximal joints) on the thumb's side, so that they curl as
    hinges in their own plane; for the thumb it is the normal of the plane of the thumb's
    proximal joint and the middle finger, on the same side. (The plane of the thumb and the
    fingers would not do for the four fingers: the thumb's proximal joint lies well in front of
    the palm, so that axis is about 45 degrees off the knuckle plane's normal and would curl them
    diagonally across the palm, sideways at their PIP and DIP hinges, which a hand cannot do.)
    proportions: the hand reshaped first
    (:func:`reshape_webxr_rig`; None: as the artist made it).
    -> (vertices [V, 3] metres, faces [F, 3]).
    """
    from ..geometry import axis_angle_to_matrix

    if pose not in WEBXR_POSES:
        raise ValueError(f"unknown WebXR pose {pose!r}: one of {', '.join(WEBXR_POSES)}")
    rig = _load_rig(path, proportions)
    vertices, faces, weights = rig["vertices"], rig["faces"], rig["weights"]
    joints, parents, names = rig["joints"], rig["parents"], rig["names"]
    index = {name: number for number, name in enumerate(names)}
    fingers = joints[index["middle-finger-phalanx-proximal"]] - joints[0]
    fingers /= np.linalg.norm(fingers)
    thumb = joints[index["thumb-phalanx-proximal"]] - joints[0]
    thumb -= fingers * (thumb @ fingers)
    palm_normal = _palm_normal(joints, names)
    thumb_normal = np.cross(thumb / np.linalg.norm(thumb), fingers)
    thumb_normal = thumb_normal if thumb_normal @ palm_normal > 0 else -thumb_normal
    local = np.tile(np.eye(4), (len(names), 1, 1))
    for finger, angles in WEBXR_POSES[pose].items():
        chain = (["thumb-metacarpal", "thumb-phalanx-proximal", "thumb-phalanx-distal"]
                 if finger == "thumb" else
                 [f"{finger}-phalanx-{part}" for part in ("proximal", "intermediate", "distal")])
        ends = chain[1:] + [f"{finger}-tip"]
        for joint_name, end_name, angle in zip(chain, ends, angles, strict=True):
            joint, end = index[joint_name], index[end_name]
            normal = thumb_normal if finger == "thumb" else palm_normal
            axis = np.cross(joints[end] - joints[joint], normal)
            axis_angle = torch.from_numpy(angle * axis / np.linalg.norm(axis))
            rotation = axis_angle_to_matrix(axis_angle).numpy()
            local[joint, :3, :3] = rotation
            local[joint, :3, 3] = joints[joint] - rotation @ joints[joint]
    world = np.empty_like(local)
    for joint in range(len(names)):  # parents come first in the OpenXR order
        world[joint] = local[joint] if parents[joint] < 0 else world[parents[joint]] @ local[joint]
    blended = np.einsum("vj,jab->vab", weights, world)
    posed = np.einsum("vab,vb->va", blended[:, :3, :3], vertices) + blended[:, :3, 3]
    return posed, faces


def outer_surface(vertices: np.ndarray, faces: np.ndarray, offset: float = 2e-4
                  ) -> tuple[np.ndarray, np.ndarray]:
    """The outside of a posed mesh: (vertices [V', 3], faces [F', 3]), without the faces (and
    the vertices only they use) that linear blend skinning pushed inside the hand (a fist's
    fingertips sink into the palm: 2.6% of the WebXR fist's area), which no scanner sees and
    no surface can reach.

    A face is inside when the point ``offset`` metres out along its normal from its centroid
    has a winding number above one half (point-cloud-utils' fast winding numbers; an open cut
    at the wrist leaves faces far from it unaffected). vertices: [V, 3] metres; faces: [F, 3]
    outward.
    """
    import point_cloud_utils as pcu
    import trimesh

    mesh = trimesh.Trimesh(vertices, faces, process=False)
    probes = mesh.triangles_center + offset * mesh.face_normals
    winding = pcu.triangle_soup_fast_winding_number(
        np.ascontiguousarray(vertices, np.float64), np.ascontiguousarray(faces, np.int64),
        np.ascontiguousarray(probes, np.float64))
    kept = faces[winding <= 0.5]
    used, compact = np.unique(kept, return_inverse=True)
    return vertices[used], compact.reshape(kept.shape).astype(np.int64)


def webxr_side(path: str | Path) -> str:
    """'right' or 'left': the hand of a WebXR rig file. Looking from the palm's side (the thumb's
    proximal joint's side of the knuckle plane) with the fingers up, a right hand's thumb points
    one way and a left hand's the other: the sign of ``(thumb x fingers) . palm normal``
    (MANO's right-hand convention makes it positive)."""
    with np.load(path, allow_pickle=False) as data:
        joints = data["joints"].astype(np.float64)
        names = [str(n) for n in data["joint_names"]]
    wrist = joints[names.index("wrist")]
    fingers = joints[names.index("middle-finger-phalanx-proximal")] - wrist
    thumb = joints[names.index("thumb-phalanx-proximal")] - wrist
    return "right" if np.cross(thumb, fingers) @ _palm_normal(joints, names) > 0 else "left"


def _palm_normal(joints: np.ndarray, names: list[str]) -> np.ndarray:
    """[3] unit normal of the knuckle plane (wrist, index and little-finger proximal joints;
    joints [25, 3] in the rig's order ``names``) on the palm's side, which is the thumb's: its
    proximal joint lies in front of the palm, in a right hand and a left one alike."""
    wrist = joints[names.index("wrist")]
    knuckles = np.cross(joints[names.index("index-finger-phalanx-proximal")] - wrist,
                        joints[names.index("pinky-finger-phalanx-proximal")] - wrist)
    knuckles /= np.linalg.norm(knuckles)
    thumb = joints[names.index("thumb-phalanx-proximal")] - wrist
    return knuckles if knuckles @ thumb > 0 else -knuckles


def webxr_wrist(path: str | Path, proportions=None) -> tuple[np.ndarray, np.ndarray]:
    """(the wrist joint [3] metres, the unit forearm direction [3]: middle knuckle -> wrist) of
    the WebXR hand (in ``proportions``, :func:`reshape_webxr_rig`); its poses move only the
    fingers, so these hold in every pose."""
    rig = _load_rig(path, proportions)
    joints, names = rig["joints"], rig["names"]
    wrist = joints[names.index("wrist")]
    forearm = wrist - joints[names.index("middle-finger-phalanx-proximal")]
    return wrist, forearm / np.linalg.norm(forearm)


def extend_forearm(vertices: np.ndarray, faces: np.ndarray, wrist: np.ndarray,
                   forearm: np.ndarray, start: float = FOREARM_START_M,
                   length: float = FOREARM_LENGTH_M, rings: int = 12
                   ) -> tuple[np.ndarray, np.ndarray]:
    """A closed hand mesh cut ``start`` metres beyond the wrist joint and its cut rim extruded
    ``length`` metres along ``forearm`` (in ``rings`` rings; the far end closed by a fan).

    vertices: [V, 3] metres; faces: [F, 3] outward; wrist: [3] metres; forearm: [3] unit.
    -> (vertices [V', 3] metres, faces [F', 3]), outward, closed.
    """
    from ..geometry.planes import Plane, clip_mesh

    cut = Plane(wrist + start * forearm, -forearm)
    kept, kept_faces = clip_mesh(vertices, faces, cut)
    edges = np.concatenate([kept_faces[:, [0, 1]], kept_faces[:, [1, 2]], kept_faces[:, [2, 0]]])
    key = np.sort(edges, axis=1)
    _, inverse, counts = np.unique(key, axis=0, return_inverse=True, return_counts=True)
    rim = edges[counts[inverse.reshape(-1)] == 1]  # directed as in their faces
    rim_vertices = np.unique(rim)
    count = len(kept)
    new_vertices = [kept]
    ring_index = {}
    for ring in range(1, rings + 1):
        offset = forearm * (length * ring / rings)
        ring_index[ring] = {v: count + k for k, v in enumerate(rim_vertices)}
        new_vertices.append(kept[rim_vertices] + offset)
        count += len(rim_vertices)
    ring_index[0] = {v: v for v in rim_vertices}
    new_faces = [kept_faces]
    for ring in range(rings):
        low, high = ring_index[ring], ring_index[ring + 1]
        for a, b in rim:  # the face holding a -> b lies on the hand's side
            new_faces.append(np.array([[low[b], low[a], high[a]], [low[b], high[a], high[b]]]))
    centre = kept[rim_vertices].mean(0) + forearm * length
    new_vertices.append(centre[None])
    last = ring_index[rings]
    new_faces.append(np.array([[last[b], last[a], count] for a, b in rim]))
    return np.concatenate(new_vertices), np.concatenate(new_faces).astype(np.int64)


def webxr_wrist_variant(vertices: np.ndarray, faces: np.ndarray, wrist: np.ndarray,
                   forearm: np.ndarray, variant: str) -> tuple[np.ndarray, np.ndarray]:
    """The mesh to scan and to compare against for a wrist variant (module docstring)."""
    from ..geometry.planes import Plane, clip_mesh

    if variant == "forearm":
        return extend_forearm(vertices, faces, wrist, forearm)
    if variant == "cut":
        return clip_mesh(vertices, faces, Plane(wrist, -forearm))
    return vertices, faces


def _refined_row(model, fit, points: np.ndarray, vertices: np.ndarray, faces: np.ndarray,
                 refine, threads: int) -> dict:
    """The distances of ``fit`` refined on ``points`` (``refined_`` + the four keys) and the
    refinement's seconds."""
    from ..fitting.points.refine import refine_surface
    from ..fitting.sides import mirror_cloud, mirror_hand
    from ..inference import MeshConfig, mesh_hand
    from ..metrics import mesh_distances

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


def _measured_fit(model, points: np.ndarray, vertices: np.ndarray, faces: np.ndarray, config,
                  side: str, viewpoint, threads: int) -> tuple[object, dict]:
    """One WebXR fit on ``threads`` threads, its 128^3 mesh measured against the truth
    (vertices [V, 3] metres, faces [F, 3]), both cut at the fit's wrist plane.
    points: [N, 3] metres, the scan. -> (the ``FitResult``, its row's numbers: seconds, points
    beyond the wrist, the four distances, ``scan_points_to_recon_mm``)."""
    from ..fitting.points.fit import fit_points
    from ..inference import MeshConfig, mesh_hand
    from ..metrics import mesh_distances

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
    """Fit ``model`` (a trained model, or {"full": one, "partial": another}: one for each kind
    of scan, as ``lisa fit-points`` chooses by default) to the WebXR hand (``right_hand.npz`` or
    ``left_hand.npz``, its side found
    by :func:`webxr_side`) in each pose of :data:`WEBXR_POSES` and each wrist
    variant of ``wrists`` (:data:`WEBXR_WRISTS`), from a full scan and from a one-view partial
    scan (noise 0.3 mm), each in a random placement (the same for every variant of a pose).

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

    from ..data.scans import ScanConfig, simulate_scan
    from ..fitting.points.fit import FitPointsConfig
    from ..geometry import axis_angle_to_matrix
    from ..geometry.planes import Plane

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
                fit_model = model[kind] if isinstance(model, dict) else model
                viewpoint = {"none": None, "auto": "auto",
                             "true": scan.viewpoint if partial else None}[viewpoints]
                fit, measured = _measured_fit(fit_model, points, placed, variant_faces, config,
                                              side, viewpoint, threads)
                rows.append({"pose": pose, "wrist": variant, "scan": kind,
                             "model": str(fit_model.source), "viewpoint": viewpoints,
                             "scale": scale, "proportions": list(proportions or (1.0, 1.0, 1.0)),
                             **measured})
                if refine is not None:
                    rows[-1].update(_refined_row(fit_model, fit, points, placed, variant_faces,
                                                 refine, threads))
                if log is not None:
                    log(rows[-1])
    return rows
