"""Fitting a hand the project did not make: the artist-made WebXR hand (``tests/assets/
webxr_hand``, MIT, Amazon), an OBJ in millimetres, and its own rig (the benchmark's poses).

A tiny untrained model (a blob hand on the template's skeleton) cannot fit its shape, so these
tests check what does not depend on a trained model: the real file goes through ``lisa
fit-points``' path (millimetres detected and converted, the three files, finite metrics against
the artist's mesh) and the global pose estimate points the fingers the right way. The accuracy
on this hand is measured with the trained model by ``python -m benchmarks fit --webxr
tests/assets/webxr_hand/right_hand.npz`` (from the repository root). The rig itself (posing,
its outer surface, other proportions) is tested in ``tests/data/test_webxr_hand.py``.
"""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from lisa_hand.data.webxr_hand import pose_webxr_hand
from lisa_hand.fitting.points.fit import FitPointsConfig
from lisa_hand.fitting.points.io import fit_point_file, prepare_point_cloud, read_point_cloud
from lisa_hand.model.trained import export_trained
from lisa_hand.skeleton import forward_kinematics
from lisa_hand.skeleton.params import read_params
from tests.assets import WEBXR_HAND as WEBXR

from .test_points import tiny_model

METRICS = ("v2v_recon_to_scan_mm", "v2s_recon_to_scan_mm", "v2v_scan_to_recon_mm",
           "v2s_scan_to_recon_mm")

pytestmark = pytest.mark.usefixtures("one_thread")


def _joints_mm() -> dict[str, np.ndarray]:
    """The WebXR bind-pose joints by OpenXR name, millimetres."""
    with np.load(WEBXR / "right_hand.npz", allow_pickle=False) as data:
        return {str(name): joint.astype(np.float64)
                for name, joint in zip(data["joint_names"], data["joints"], strict=True)}


def test_the_obj_is_read_as_millimetres():
    points, normals = read_point_cloud(WEBXR / "right_hand.obj")
    assert points.shape == (1159, 3) and normals is None
    cloud = prepare_point_cloud(points, name="right_hand.obj")
    assert cloud.unit == "mm" and cloud.unit_detected
    assert any("read as millimetres" in note for note in cloud.notes)
    np.testing.assert_allclose(cloud.points, points * 1e-3)
    # Wrist to middle fingertip 177.8 mm (the data's README), in metres now.
    joints = _joints_mm()
    reach = np.linalg.norm(joints["middle-finger-tip"] - joints["wrist"]) * 1e-3
    assert reach == pytest.approx(0.1778, abs=0.002)
    with pytest.raises(ValueError, match="right_hand.obj: .*looks like millimetres"):
        prepare_point_cloud(points, units="m", name="right_hand.obj")


def test_fit_points_on_the_real_obj(tmp_path):
    model_path, _ = export_trained(tiny_model(), tmp_path / "tiny.pt")
    out = tmp_path / "fit"
    notes: list[str] = []
    config = FitPointsConfig(field_iters=60, points_per_iteration=256, fit_betas=False)
    report = fit_point_file(WEBXR / "right_hand.obj", out, model_path=model_path,
                            gt_path=WEBXR / "right_hand.obj", resolution=32, config=config,
                            device="cpu", log=notes.append)
    # Both the cloud and the ground truth are millimetres, and each says so.
    assert sum("read as millimetres" in note for note in notes) == 2
    assert sorted(p.name for p in out.iterdir()) == ["keypoints.json", "mesh.ply", "metrics.json",
                                                     "params.json", "preview.png"]
    metrics = json.loads((out / "metrics.json").read_text())
    assert list(metrics) == list(METRICS)
    assert all(math.isfinite(metrics[key]) and 0 < metrics[key] < 100 for key in METRICS)
    params = read_params(out / "params.json")
    assert params.extra["input"]["unit"] == "mm"
    # The global pose from scratch: the fitted wrist -> middle knuckle runs along the artist's
    # wrist -> middle proximal joint (an untrained blob hand: measured 15 degrees).
    fitted = forward_kinematics(params.pose[None], params.rest_joints,
                                params.translation[None]).joints[0].double().numpy()
    joints = _joints_mm()
    truth = joints["middle-finger-phalanx-proximal"] - joints["wrist"]
    along = fitted[4] - fitted[0]  # MANO joints: 0 wrist, 4 middle1
    cosine = along @ truth / (np.linalg.norm(along) * np.linalg.norm(truth))
    assert math.degrees(math.acos(min(1.0, cosine))) < 30.0
    assert report.fit.residual_median_mm < 10.0


@pytest.mark.slow
def test_a_scan_running_on_into_a_forearm_is_cut_at_the_wrist():
    """The shipped model on the WebXR hand whose scan runs 12 cm on into a forearm (about 30%
    of its points): the fit leaves the forearm out and fits the hand as without it; the mesh
    ends at the fit's wrist cut, where the distances are taken (``python -m benchmarks fit
    --webxr ... --webxr-wrists as-is,forearm,cut`` measures every pose)."""
    from lisa_hand.data.scans import ScanConfig, simulate_scan
    from lisa_hand.data.webxr_hand import webxr_wrist, webxr_wrist_variant
    from lisa_hand.fitting.points.fit import fit_points
    from lisa_hand.inference import MeshConfig, mesh_hand
    from lisa_hand.metrics import mesh_distances
    from lisa_hand.model.trained import load_trained

    model = load_trained(None, "cpu")
    path = WEBXR / "right_hand.npz"
    posed, faces = pose_webxr_hand(path, "rest")
    wrist, forearm = webxr_wrist(path)
    vertices, arm_faces = webxr_wrist_variant(posed, faces, wrist, forearm, "forearm")
    scan = simulate_scan(vertices, arm_faces, ScanConfig(num_points=3000), seed=0)
    on_arm = (scan.points - wrist) @ forearm > 0.02  # surely beyond any wrist cut
    config = FitPointsConfig(field_iters=120)
    with_cut = fit_points(model, scan.points, None, config)
    assert with_cut.beyond_wrist_points >= on_arm.sum()
    plane = with_cut.wrist_plane
    assert not plane.keeps(scan.points[on_arm]).any()
    # The cut lies 1 cm beyond the fitted wrist joint, within 1.5 cm of the artist's wrist.
    assert abs(plane.signed_distance(wrist[None])[0]) < 0.025
    mesh = mesh_hand(model, with_cut.params, 96, MeshConfig(colors=False, skin_weights=False),
                     clip=plane)
    assert plane.keeps(mesh.vertices, margin=1e-6).all()
    cut = mesh_distances(mesh.vertices, mesh.faces, vertices, arm_faces, clip=plane)
    # Measured 2.2 mm / 2.7 mm (the same as the scan without a forearm, bench above).
    assert cut.v2s_scan_to_recon_mm < 3.5 and cut.v2s_recon_to_scan_mm < 3.5
    # Without the cut the forearm counts: the scan -> recon distance is several times larger.
    whole = mesh_distances(mesh.vertices, mesh.faces, vertices, arm_faces)
    assert whole.v2s_scan_to_recon_mm > 2.0 * cut.v2s_scan_to_recon_mm


def test_the_shipped_geometric_prior_fits_the_webxr_hand():
    """The point fit's default model (the shipped geometric prior of hand models v1-v3, 644
    subjects) on the artist's hand in its rest pose, a full 5000-point scan with 0.3 mm noise in
    a random placement: the first row of ``python -m benchmarks fit --only-webxr`` (measured
    here V2S 0.90 mm scan->recon, 0.93 mm recon->scan; the v1 prior: 1.28 / 1.44; the shipped
    LISA-full: 2.10 / 2.62). The target without ``--refine`` is 1.5 mm; the bound here, 1.1 mm,
    is one the v1 prior does not meet."""
    import torch

    from lisa_hand.data.scans import ScanConfig, simulate_scan
    from lisa_hand.fitting.points.fit import fit_points
    from lisa_hand.fitting.points.io import default_point_model
    from lisa_hand.geometry import axis_angle_to_matrix
    from lisa_hand.inference import MeshConfig, mesh_hand
    from lisa_hand.metrics import mesh_distances
    from lisa_hand.model.trained import load_trained

    assert default_point_model() == "geometry_v3"
    model = load_trained("geometry_v3", "cpu")
    posed, faces = pose_webxr_hand(WEBXR / "right_hand.npz", "rest")
    turn = 3.0 * torch.rand(3, generator=torch.Generator().manual_seed(0), dtype=torch.float64)
    rotation = axis_angle_to_matrix(turn).numpy()
    placed = (posed - posed.mean(0)) @ rotation.T + np.array([0.0, 0.0, 0.3])
    scan = simulate_scan(placed, faces, ScanConfig(num_points=5000, noise_normal_std=3e-4),
                         seed=0)
    fit = fit_points(model, scan.points, None, FitPointsConfig(num_threads=1, seed=0))
    mesh = mesh_hand(model, fit.params, 128, MeshConfig(colors=False, skin_weights=False),
                     clip=fit.wrist_plane)
    distances = mesh_distances(mesh.vertices, mesh.faces, placed, faces, clip=fit.wrist_plane)
    assert distances.v2s_scan_to_recon_mm < 1.1 and distances.v2s_recon_to_scan_mm < 1.1


def test_the_point_fit_curls_the_webxr_hands_bent_index():
    """The artist's hand with its index curled 160 degrees (MCP 52, PIP 69, DIP 40) about its
    knuckles' hinge axes, the full scan of ``python -m benchmarks fit --only-webxr`` (its
    placement: the second random turn), fitted with the default prior: measured flexion 65 /
    49 / 41 degrees (156 in all: the rig's knuckles are not the skeleton's, so the curl is
    shared out differently: checked within 25 degrees a joint, 10 in all), V2S 0.95 / 1.02 mm
    scan->recon / recon->scan (the target without ``--refine``: 1.5 mm; the v1 prior: 51 / 64 /
    31 degrees, 1.31 / 1.38 mm)."""
    import torch

    from lisa_hand.data.scans import ScanConfig, simulate_scan
    from lisa_hand.fitting.points.fit import fit_points
    from lisa_hand.geometry import axis_angle_to_matrix
    from lisa_hand.handmodel.poses import pose_to_angles
    from lisa_hand.inference import MeshConfig, mesh_hand
    from lisa_hand.metrics import mesh_distances
    from lisa_hand.model.trained import load_trained

    model = load_trained("geometry_v3", "cpu")
    posed, faces = pose_webxr_hand(WEBXR / "right_hand.npz", "bent_index")
    generator = torch.Generator().manual_seed(0)
    turn = 3.0 * torch.rand(3, generator=generator, dtype=torch.float64)  # the rest pose's
    turn = 3.0 * torch.rand(3, generator=generator, dtype=torch.float64)
    rotation = axis_angle_to_matrix(turn).numpy()
    placed = (posed - posed.mean(0)) @ rotation.T + np.array([0.0, 0.0, 0.3])
    scan = simulate_scan(placed, faces, ScanConfig(num_points=5000, noise_normal_std=3e-4),
                         seed=0)
    fit = fit_points(model, scan.points, None, FitPointsConfig(num_threads=1, seed=0))
    flexion = np.degrees(pose_to_angles(fit.params.pose[None].double())[0, :3, 0].numpy())
    mesh = mesh_hand(model, fit.params, 128, MeshConfig(colors=False, skin_weights=False),
                     clip=fit.wrist_plane)
    distances = mesh_distances(mesh.vertices, mesh.faces, placed, faces, clip=fit.wrist_plane)
    np.testing.assert_allclose(flexion, np.degrees([0.9, 1.2, 0.7]), atol=25.0)
    assert abs(flexion.sum() - np.degrees(2.8)) < 10.0, flexion  # the whole curl
    assert distances.v2s_scan_to_recon_mm < 1.2 and distances.v2s_recon_to_scan_mm < 1.2, \
        distances.to_dict()


def test_a_full_scan_of_the_webxr_fist_fits_within_the_target():
    """The artist's fist, a full 5000-point scan with 0.3 mm noise in the third random
    placement (as ``python -m benchmarks fit --only-webxr``), fitted with the default prior:
    the scan covers 80% of the fitted hand within 4 mm, so the surface stage uses the weaker
    shape prior of a scan from all sides (``FitPointsConfig.covered_shape_weight``). Measured
    V2S 1.37 / 1.14 mm scan->recon / recon->scan, within the 1.5 mm target without
    ``--refine``."""
    import torch

    from lisa_hand.data.scans import ScanConfig, simulate_scan
    from lisa_hand.fitting.points.fit import fit_points
    from lisa_hand.geometry import axis_angle_to_matrix
    from lisa_hand.inference import MeshConfig, mesh_hand
    from lisa_hand.metrics import mesh_distances
    from lisa_hand.model.trained import load_trained

    model = load_trained("geometry_v3", "cpu")
    posed, faces = pose_webxr_hand(WEBXR / "right_hand.npz", "fist")
    generator = torch.Generator().manual_seed(0)
    for _ in range(3):  # the rest pose's and the bent index's turns, then the fist's
        turn = 3.0 * torch.rand(3, generator=generator, dtype=torch.float64)
    placed = (posed - posed.mean(0)) @ axis_angle_to_matrix(turn).numpy().T \
        + np.array([0.0, 0.0, 0.3])
    scan = simulate_scan(placed, faces, ScanConfig(num_points=5000, noise_normal_std=3e-4),
                         seed=0)
    fit = fit_points(model, scan.points, None, FitPointsConfig(num_threads=1, seed=0))
    assert any("shape prior 3e-06" in note for note in fit.reports["coverage"].notes)
    mesh = mesh_hand(model, fit.params, 128, MeshConfig(colors=False, skin_weights=False),
                     clip=fit.wrist_plane)
    distances = mesh_distances(mesh.vertices, mesh.faces, placed, faces, clip=fit.wrist_plane)
    assert distances.v2s_scan_to_recon_mm < 1.5 and distances.v2s_recon_to_scan_mm < 1.5, \
        distances.to_dict()


def test_a_one_view_scan_fits_closer_with_its_sensor_position():
    """The one-view scan of the WebXR fist of ``python -m benchmarks fit --only-webxr``
    (third random turn, the sensor 0.5 m off in a random direction): given where the sensor was,
    the fit keeps the fingers out of the space it saw empty. Measured with the v1 prior
    (``geometry``, where it shows most): the mesh's share of vertices in the free space falls
    from 6.0% to 0% and V2S scan->recon / recon->scan from 3.35 / 3.13 to 2.45 / 2.34 mm (the
    default prior: 2.8% -> 1.7%, 2.49 / 2.93 -> 2.36 / 2.72 mm)."""
    import torch

    from lisa_hand.data.scans import ScanConfig, simulate_scan
    from lisa_hand.fitting.points.fit import fit_points
    from lisa_hand.fitting.points.free_space import DepthImage
    from lisa_hand.geometry import axis_angle_to_matrix
    from lisa_hand.inference import MeshConfig, mesh_hand
    from lisa_hand.metrics import mesh_distances
    from lisa_hand.model.trained import load_trained

    model = load_trained("geometry", "cpu")
    posed, faces = pose_webxr_hand(WEBXR / "right_hand.npz", "fist")
    generator = torch.Generator().manual_seed(0)
    for _ in range(3):  # the rest's and the bent index's turns, then the fist's
        turn = 3.0 * torch.rand(3, generator=generator, dtype=torch.float64)
    rotation = axis_angle_to_matrix(turn).numpy()
    placed = (posed - posed.mean(0)) @ rotation.T + np.array([0.0, 0.0, 0.3])
    scan = simulate_scan(placed, faces, ScanConfig(num_points=5000, partial=True,
                                                   noise_normal_std=3e-4), seed=0)
    depth = DepthImage(torch.from_numpy(scan.points).float(),
                       torch.from_numpy(scan.viewpoint).float())
    results = {}
    for name, viewpoint in (("without", None), ("with", scan.viewpoint)):
        fit = fit_points(model, scan.points, None, FitPointsConfig(num_threads=1, seed=0),
                         viewpoint=viewpoint)
        mesh = mesh_hand(model, fit.params, 128, MeshConfig(colors=False, skin_weights=False),
                         clip=fit.wrist_plane)
        distances = mesh_distances(mesh.vertices, mesh.faces, placed, faces,
                                   clip=fit.wrist_plane)
        seen = depth.violation(torch.from_numpy(np.asarray(mesh.vertices)).float())
        results[name] = (distances.v2s_scan_to_recon_mm, distances.v2s_recon_to_scan_mm,
                         float((seen > 1e-3).float().mean()))
    without, with_view = results["without"], results["with"]
    assert with_view[1] < without[1] - 0.3, results  # no surface where the sensor saw none
    assert with_view[0] < without[0] + 0.1, results
    assert with_view[2] < 0.5 * without[2], results
    assert with_view[0] < 3.0 and with_view[1] < 3.0, results


def test_the_person_frame_is_one_piece_whose_nearest_part_is_the_hand():
    """A depth frame of a person holding the hand out (:func:`lisa_hand.data.webxr_scenes.
    person_scan`, as ``benchmarks fit --webxr-person``): hand, arm and body are one piece too
    large for a hand, and what lies within HAND_REACH_M of the nearest point along the surface is
    the hand and a stub of its forearm, not the body."""
    import point_cloud_utils as pcu

    from lisa_hand.data.webxr_scenes import person_scan
    from lisa_hand.fitting.points.others import _pieces, find_others

    for pose in ("rest", "fist"):
        points, (vertices, faces), sensor = person_scan(WEBXR / "right_hand.npz", pose)
        points = points.astype(np.float64)
        _, sizes = _pieces(points, 0.01)
        assert sizes.max() > 0.95 * len(points)  # one piece, but for stray noise
        found = find_others(points, sensor=sensor)
        assert found.oversize > 0.6 and 1500 < (~found.removed).sum() < 0.3 * len(points)
        # the kept points lie on the hand and its forearm (to the depth noise, 1.3 mm at 45 cm),
        # and the hand-and-arm points the camera saw within 20 cm of the nearest kept one are kept
        off, _, _ = pcu.closest_points_on_mesh(points, np.asarray(vertices, np.float64),
                                               np.asarray(faces, np.int64))
        assert np.quantile(off[~found.removed], 0.99) < 0.005
        kept = points[~found.removed]
        near = np.linalg.norm(points - kept[np.argmin(np.linalg.norm(kept, axis=1))], axis=1)
        assert (~found.removed)[(off < 0.005) & (near < 0.2)].mean() > 0.99
        assert found.removed[off > 0.02].all()  # the body


def test_the_size_search_finds_a_larger_webxr_hands_size():
    """The artist's fist made 1.15 times larger about its wrist (204 mm from the wrist joint
    to the middle fingertip, a large adult hand), a full 5000-point scan with 0.3 mm noise:
    the size search finds its size, and the proxy stages pose a hand of that size. With the
    default prior, whose shape codes reach hands this large by themselves, that brings the fit
    no closer here: measured V2S scan->recon without the search (``sizes=(1.0,)``) 1.79 mm,
    with it 1.84 mm (the v1 prior: 2.29 and 2.28 mm, size 1.1 chosen), checked within 0.2 mm of
    each other and 2.1 mm. Over the benchmark's x1.15 scans the search is closer (``python -m
    benchmarks fit --webxr-scale 1.15`` against ``--webxr-sizes 1``)."""
    import torch

    from lisa_hand.data.scans import ScanConfig, simulate_scan
    from lisa_hand.data.webxr_hand import outer_surface, webxr_wrist
    from lisa_hand.fitting.points.fit import fit_points
    from lisa_hand.geometry import axis_angle_to_matrix
    from lisa_hand.inference import MeshConfig, mesh_hand
    from lisa_hand.metrics import mesh_distances
    from lisa_hand.model.trained import load_trained

    model = load_trained("geometry_v3", "cpu")
    wrist, _ = webxr_wrist(WEBXR / "right_hand.npz")
    posed, faces = pose_webxr_hand(WEBXR / "right_hand.npz", "fist")
    posed, faces = outer_surface(wrist + 1.15 * (posed - wrist), faces)
    generator = torch.Generator().manual_seed(1)
    for _ in range(3):  # the third turn of the bench's placements with --seed 1
        turn = 3.0 * torch.rand(3, generator=generator, dtype=torch.float64)
    placed = (posed - posed.mean(0)) @ axis_angle_to_matrix(turn).numpy().T \
        + np.array([0.0, 0.0, 0.3])
    scan = simulate_scan(placed, faces, ScanConfig(num_points=5000, noise_normal_std=3e-4),
                         seed=1)
    errors = {}
    for sizes in ((1.0,), FitPointsConfig().sizes):
        fit = fit_points(model, scan.points, None,
                         FitPointsConfig(num_threads=1, seed=0, sizes=sizes))
        mesh = mesh_hand(model, fit.params, 128, MeshConfig(colors=False, skin_weights=False),
                         clip=fit.wrist_plane)
        errors[len(sizes)] = mesh_distances(mesh.vertices, mesh.faces, placed, faces,
                                            clip=fit.wrist_plane).v2s_scan_to_recon_mm
    assert "1.15 times" in fit.reports["size"].notes[0]
    assert errors[len(sizes)] < min(2.1, errors[1] + 0.2), errors
