"""The point fit's stages one by one, through their public functions: each takes and returns
HandParams; the candidate parametrisation round-trips; the prior keeps its old numbers; a left
hand fits as well as the right one it mirrors."""

from __future__ import annotations

import math
import re

import numpy as np
import pytest
import torch

from lisa_hand.data.scans import ScanConfig
from lisa_hand.fitting.points.candidates import CandidateBatch
from lisa_hand.fitting.points.cloud import point_spacing, target_cloud
from lisa_hand.fitting.points.config import FitPointsConfig
from lisa_hand.fitting.points.fit import fit_points
from lisa_hand.fitting.points.global_pose import search_global_pose
from lisa_hand.fitting.points.monitor import FitMonitor
from lisa_hand.fitting.points.proxy import build_surface_proxy, fit_proxy_pose
from lisa_hand.fitting.points.surface_stage import fit_surface, surface_residuals
from lisa_hand.fitting.priors import prior_mean_fingers
from lisa_hand.fitting.sides import mirror_hand
from lisa_hand.fitting.stages import StageReport
from lisa_hand.fitting.terms import hand_prior
from lisa_hand.geometry import axis_angle_to_matrix
from lisa_hand.inference import hand_field
from lisa_hand.skeleton import mirror_points
from lisa_hand.skeleton.params import HandParams

from .test_points import FAST, rotation_error_deg, scan_of, sdf_at, tiny_model, true_hand

pytestmark = pytest.mark.usefixtures("one_thread")


def _hand(seed: int = 0) -> HandParams:
    generator = torch.Generator().manual_seed(seed)
    pose = 0.4 * torch.randn(48, generator=generator)
    pose[:3] = torch.tensor([2.0, -1.0, 0.5])
    return HandParams(pose=pose, translation=torch.tensor([0.1, -0.05, 0.3]),
                      rest_joints=0.05 * torch.randn(16, 3, generator=generator),
                      shape_code=torch.randn(8, generator=generator), side="right")


def test_candidate_batch_round_trips_hand_params():
    hands = [_hand(0), _hand(1)]
    pivot = torch.tensor([0.01, 0.02, -0.03])
    batch = CandidateBatch.from_hands(hands, pivot)
    assert batch.count == 2 and batch.rest_joints.shape == (2, 16, 3)
    for index, hand in enumerate(hands):
        back = batch.hand(index, hand)
        assert torch.allclose(axis_angle_to_matrix(back.pose[:3]),
                              axis_angle_to_matrix(hand.pose[:3]), atol=1e-6)
        assert torch.allclose(back.pose[3:], hand.pose[3:])
        assert torch.allclose(back.translation, hand.translation, atol=1e-6)
        assert torch.equal(back.rest_joints, hand.rest_joints) and back.side == "right"
        assert back.extra == {} and back.extra is not hand.extra


def test_the_point_prior_is_the_weighted_mean_square_of_the_finger_values():
    hands = [_hand(2)]
    batch = CandidateBatch.from_hands(hands, torch.zeros(3))
    config = FitPointsConfig(limit_weight=0.0)
    prior = hand_prior(config, prior_mean_fingers("flat"))(batch.terms())
    expected = config.pose_weight * hands[0].pose[3:].square().mean()
    assert float(prior[0].detach()) == pytest.approx(float(expected), rel=1e-5)


def test_the_point_prior_adds_the_unseen_fingers_terms_by_their_weights():
    """coupling [5]: the four fingers' coupling (finger_coupling of the first four weights)
    and the unseen thumb's pull to the mean pose (thumb_pose_prior times the fifth)."""
    from lisa_hand.fitting.priors import finger_coupling, thumb_pose_prior

    batch = CandidateBatch.from_hands([_hand(3), _hand(4)], torch.zeros(3))
    config = FitPointsConfig(limit_weight=0.0, coupling_weight=2e-4, unseen_thumb_weight=5e-4)
    mean = prior_mean_fingers(config.prior_pose)
    plain = hand_prior(config, mean)(batch.terms())
    weights = torch.tensor([0.0, 0.5, 0.0, 1.0, 0.8])
    both = hand_prior(config, mean, coupling=weights)(batch.terms())
    expected = (2e-4 * finger_coupling(batch.finger_pose, weights[:4])
                + 5e-4 * 0.8 * thumb_pose_prior(batch.finger_pose, mean))
    assert torch.allclose(both - plain, expected, rtol=1e-5)
    assert float(expected.detach().min()) > 0.0
    off = FitPointsConfig(limit_weight=0.0, coupling_weight=2e-4, unseen_thumb_weight=0.0)
    thumbless = hand_prior(off, mean, coupling=weights)(batch.terms())
    assert torch.allclose(thumbless - plain,
                          2e-4 * finger_coupling(batch.finger_pose, weights[:4]), rtol=1e-5)


def test_stages_take_and_return_hand_params():
    model = tiny_model()
    truth = true_hand(model, seed=0)
    points, normals, _ = scan_of(model, truth, ScanConfig(num_points=1000), seed=0)
    config = FitPointsConfig(**FAST)
    cloud = target_cloud(points, normals, seed=config.seed)
    start = truth.with_pose(torch.zeros(48), torch.zeros(3))
    proxy = build_surface_proxy(model, truth.rest_joints, truth.shape_code, None,
                                config.proxy_points, cloud.generator)
    assert proxy.num_points == config.proxy_points and proxy.weights.shape[1] == 16
    monitor = FitMonitor()
    candidates, search = search_global_pose(proxy, cloud, config, start, monitor=monitor)
    assert 1 <= len(candidates) <= config.restarts
    assert all(isinstance(hand, HandParams) for hand in candidates)
    assert len(search.screened_energies) == 24 and search.energies == sorted(search.energies)
    assert isinstance(search, StageReport) and search.stage == "align"
    assert search.loss == search.energies[0] and len(search.energies) == len(candidates)
    assert [step["stage"] for step in search.history] == ["align"] * config.align_iters
    posed, stage = fit_proxy_pose(proxy, cloud, candidates, config, monitor=monitor)
    assert len(posed) == len(candidates) and len(stage.history) == config.pose_iters
    assert stage.stage == "pose" and len(stage.energies) == len(posed)
    assert stage.loss == min(stage.energies)
    hand, surface = fit_surface(model, cloud, posed, config, pivot=proxy.pivot,
                                monitor=monitor)
    assert isinstance(hand, HandParams) and math.isfinite(surface.energies[0])
    assert surface.stage == "field" and surface.energies == [surface.loss]
    assert len(monitor.history) == config.align_iters + config.pose_iters + config.field_iters
    # (fit_points adds the finger restarts between the articulated and the surface stages)
    assert rotation_error_deg(hand.pose, truth.pose) < 5.0
    residual = surface_residuals(model, hand, cloud.points)
    assert float(residual.mean()) < 0.0005
    # The surface stage alone, started at the truth, stays there.
    again, _ = fit_surface(model, cloud, [truth], config)
    assert float(sdf_at(model, again, points).abs().mean()) < 0.0005


def test_a_left_hand_fits_as_well_as_the_right_one_it_mirrors():
    model = tiny_model()
    truth = true_hand(model, seed=0)
    points, normals, _ = scan_of(model, truth, ScanConfig(num_points=1000), seed=0)
    config = FitPointsConfig(**FAST)
    right = fit_points(model, points, normals, config, rest_joints=truth.rest_joints)
    assert list(right.reports) == ["align", "pose", "size", "unseen", "fingers", "coverage",
                                   "field", "second"]
    assert right.energy == right.reports["second"].loss
    assert right.candidate_energies == right.reports["align"].screened_energies
    assert right.history == [record for report in right.reports.values()
                             for record in report.history]
    left_points = mirror_points(torch.from_numpy(points)).numpy()
    left_normals = mirror_points(torch.from_numpy(normals)).numpy()
    sides = []
    left = fit_points(model, left_points, left_normals, config,
                      rest_joints=mirror_points(truth.rest_joints), side="left",
                      callback=lambda step: sides.append(step.params().side))
    assert left.params.side == "left" and set(sides) == {"left"}
    assert left.residual_mean_mm == pytest.approx(right.residual_mean_mm, rel=1e-4)
    assert left.inlier_fraction == right.inlier_fraction
    # The left hand's field (mirrored by the renderer and the mesher) is on the left cloud.
    with torch.no_grad():
        sdf = hand_field(model, left.params).sdf_fn()(torch.from_numpy(left_points))
    assert float(sdf.abs().mean()) == pytest.approx(right.residual_mean_mm * 1e-3, rel=1e-3)
    # ... and it is the mirror image of the right fit.
    mirrored = mirror_hand(left.params)
    assert torch.allclose(mirrored.pose, right.params.pose, atol=1e-6)
    assert torch.allclose(mirrored.translation, right.params.translation, atol=1e-7)
    with pytest.raises(ValueError, match="side"):
        fit_points(model, points, side="middle")



def _curled_index_scan(model, config: FitPointsConfig, curl: tuple[float, float, float]):
    """A scan of ``model``'s own mean hand (template skeleton) with the index curled by
    ``curl`` (radians about z at MANO joints 1-3) -> (the true hand, the same hand with the
    index straight, the scan's cloud, the template, start_hand's (rest joints, shape code,
    colour code))."""
    from lisa_hand.data.scans import simulate_scan
    from lisa_hand.fitting.points.fit import start_hand
    from lisa_hand.inference import MeshConfig, mesh_hand

    cloud = target_cloud(torch.zeros(30, 3), None, seed=0)  # a placeholder for start_hand
    template, rest_hand, codes = start_hand(model, cloud, None)
    pose = torch.zeros(16, 3)
    pose[0] = torch.tensor([0.4, -2.0, 0.9])
    pose[1:4, 2] = torch.tensor(curl)
    truth = rest_hand.with_pose(pose.reshape(48), torch.tensor([0.02, -0.01, 0.35]))
    mesh = mesh_hand(model, truth, 64, MeshConfig(colors=False, skin_weights=False))
    scan = simulate_scan(mesh.vertices, mesh.faces, ScanConfig(num_points=4000), seed=0)
    straight = pose.clone()
    straight[1:4] = 0.0
    start = truth.with_pose(straight.reshape(48), truth.translation)
    return truth, start, target_cloud(scan.points, None, seed=config.seed), template, codes


def test_a_finger_left_straight_is_restarted_bent():
    """The shipped model's own surface with the index curled, the candidate with it straight
    (a local minimum of the articulated stage): the restart finds the curl. (The tiny blob
    model's proxy cannot tell a bent finger from a straight one: 2% of energy.)"""
    from lisa_hand.fitting.points.finger_search import restart_fingers
    from lisa_hand.model.trained import load_trained

    model = load_trained(None, "cpu")
    config = FitPointsConfig(**FAST)
    truth, start, cloud, _, (rest, code, color) = _curled_index_scan(model, config,
                                                                     (1.1, 1.2, 0.8))
    proxy = build_surface_proxy(model, rest, code, color, config.proxy_points, cloud.generator)
    hands, report = restart_fingers(proxy, cloud, [start, start], config)
    index = slice(3 * 1, 3 * 4)
    error = float((hands[0].pose[index] - truth.pose[index]).abs().max())
    assert error < 0.35, (error, report.notes)
    assert "index" in report.notes[0] and report.stage == "fingers"
    assert report.energies[1] < report.energies[0] and len(hands) == 2
    # Off: the candidates come back as they were.
    same, off = restart_fingers(proxy, cloud, [start], FitPointsConfig(**FAST, finger_iters=0))
    assert same == [start] and off.energies == []


def test_refine_config_refuses_bad_values():
    from lisa_hand.fitting.points.refine import RefineConfig

    for bad in ({"iters": 0}, {"lr": 0.0}, {"anchor_weight": -1.0}, {"eikonal_offset_mm": 0}):
        with pytest.raises(ValueError):
            RefineConfig(**bad)


def test_nearest_distance_counts_the_tangent_offset_by_its_weight():
    """A cloud point ``a`` along its nearest proxy point's normal and ``b`` across it is
    ``sqrt(a^2 + w b^2)`` away (closed form): w = 1 the Euclidean distance, 0 point-to-plane."""
    from lisa_hand.fitting.points.cloud import nearest_distance

    proxy = torch.tensor([[[0.0, 0.0, 0.0], [1.0, 0.0, 0.0]]], dtype=torch.float64)
    normals = torch.tensor([[[0.0, 0.0, 1.0], [1.0, 0.0, 0.0]]], dtype=torch.float64)
    cloud = torch.tensor([[[0.003, 0.004, 0.012]]], dtype=torch.float64)  # nearest: the first
    for weight in (1.0, 0.1, 0.0):
        got = float(nearest_distance(cloud, proxy, normals, weight)[0, 0])
        assert got == pytest.approx(math.sqrt(0.012**2 + weight * 0.005**2), abs=1e-6)
    assert float(nearest_distance(cloud, proxy)[0, 0]) == pytest.approx(0.013, abs=1e-6)


def test_the_proxy_normals_turn_with_the_pose():
    """Posed by a random hand pose, every proxy normal stays perpendicular to the posed
    surface: a short step along the rest tangent plane, posed by ``world``, is at right angles
    to the normal ``world_normals`` gives (points bound to one bone each)."""
    from lisa_hand.fitting.points.proxy import SurfaceProxy
    from lisa_hand.skeleton import NUM_JOINTS

    generator = torch.Generator().manual_seed(3)
    hand = _hand(1)
    count = 64
    points = 0.05 * torch.randn(count, 3, generator=generator, dtype=torch.float64)
    normals = torch.nn.functional.normalize(
        torch.randn(count, 3, generator=generator, dtype=torch.float64), dim=-1)
    tangent = torch.nn.functional.normalize(torch.linalg.cross(
        normals, torch.randn(count, 3, generator=generator, dtype=torch.float64)), dim=-1)
    bones = torch.randint(0, NUM_JOINTS, (count,), generator=generator)
    weights = torch.nn.functional.one_hot(bones, NUM_JOINTS).double()
    rest = hand.rest_joints.double()
    proxy = SurfaceProxy(torch.cat([points, points + 1e-4 * tangent]),
                         torch.cat([weights, weights]), rest, points.mean(0),
                         torch.cat([normals, normals]))
    batch = CandidateBatch.from_hands([hand.with_pose(hand.pose.double(), hand.translation)],
                                      proxy.pivot)
    with torch.no_grad():
        world = proxy.world(batch)[0]
        posed_normals = proxy.world_normals(batch)[0][:count]
    step = world[count:] - world[:count]
    assert torch.allclose(posed_normals.norm(dim=-1), torch.ones(count, dtype=torch.float64))
    assert float(((step * posed_normals).sum(-1) / step.norm(dim=-1)).abs().max()) < 1e-6


def test_the_second_pass_curls_a_finger_the_field_stage_left_straight():
    """The shipped geometric prior's own hand with the index curled, fitted except for the
    index (left straight, as the field stage left the WebXR hand's): the second pass curls
    it."""
    from lisa_hand.fitting.points.stages import second_finger_pass
    from lisa_hand.model.trained import load_trained

    model = load_trained("geometry", "cpu")
    config = FitPointsConfig(**FAST)
    truth, start, cloud, template, _ = _curled_index_scan(model, config, (0.9, 1.2, 0.7))
    index = slice(3 * 1, 3 * 4)
    before = float((start.pose[index] - truth.pose[index]).abs().max())
    hand, report = second_finger_pass(model, cloud, start, config, math.nan, template=template)
    error = float((hand.pose[index] - truth.pose[index]).abs().max())
    assert before > 1.0 and error < 0.35, (error, report.notes)
    assert report.stage == "second" and "index" in report.notes[0]
    assert math.isfinite(report.loss)


def test_covered_fraction_counts_the_proxy_points_near_the_cloud():
    """covered_fraction: the share of the posed proxy within the distance of the cloud. A proxy
    of two blobs of random points 8 cm apart, bound to the root and posed by a random hand: a
    cloud of all the posed points covers all of it, a cloud of one blob that blob's share, and
    the whole cloud moved 20 cm off none, at 4 mm (the cloud's distance grid is good to about a
    2 mm cell); fit_points records the share in the coverage stage's notes."""
    from lisa_hand.fitting.points.proxy import SurfaceProxy, covered_fraction
    from lisa_hand.skeleton import NUM_JOINTS

    generator = torch.Generator().manual_seed(5)
    hand = _hand(2)
    blob = torch.tensor([0.04, 0.0, 0.0])
    points = 0.01 * torch.randn(300, 3, generator=generator)
    points[:120] += blob
    points[120:] -= blob
    weights = torch.zeros(300, NUM_JOINTS)
    weights[:, 0] = 1.0
    proxy = SurfaceProxy(points, weights, hand.rest_joints.float(), points.mean(0))
    with torch.no_grad():
        world = proxy.world(CandidateBatch.from_hands([hand], proxy.pivot))[0]
    assert covered_fraction(proxy, target_cloud(world), hand, 0.004) == 1.0
    assert covered_fraction(proxy, target_cloud(world[:120]), hand, 0.004) == pytest.approx(0.4)
    moved = target_cloud(world + torch.tensor([0.0, 0.0, 0.2]))
    assert covered_fraction(proxy, moved, hand, 0.004) == 0.0

    model = tiny_model()
    truth = true_hand(model, seed=0)
    scan, normals, _ = scan_of(model, truth, ScanConfig(num_points=1000), seed=0)
    result = fit_points(model, scan, normals, FitPointsConfig(**FAST))
    # within 4 mm, or twice the point spacing of this sparse 1000-point scan
    found = [re.search(r"of the hand within ([0-9.]+) mm: shape prior", note)
             for note in result.reports["coverage"].notes]
    within = [float(match.group(1)) for match in found if match]
    spacing = 2e3 * point_spacing(torch.as_tensor(scan))
    assert len(within) == 1 and within[0] >= 4.0
    assert within[0] == pytest.approx(max(4.0, spacing), rel=0.1)


def test_each_candidate_keeps_the_points_on_its_own_side_of_its_wrist():
    # hand_side against a second implementation: the numpy wrist plane of each candidate.
    from lisa_hand.fitting.points.surface_stage import _FieldEnergy
    from lisa_hand.skeleton.wrist import wrist_plane

    model = tiny_model()
    hands = [true_hand(model, seed=0), true_hand(model, seed=3)]
    cloud = target_cloud(torch.randn(600, 3) * 0.08 + hands[0].translation, None, seed=0)
    config = FitPointsConfig(**FAST)
    energy = _FieldEnergy(model, cloud, config, hands, None)
    batch = CandidateBatch.from_hands(hands, torch.tensor([0.01, -0.02, 0.03]))
    for offset in (0.0, 0.01):
        keep = energy.hand_side(batch, cloud.points, offset)
        assert keep.shape == (2, 600)
        for index, hand in enumerate(hands):
            expected = wrist_plane(hand, offset).keeps(cloud.points.double().numpy())
            assert 50 < expected.sum() < 550  # both sides hold points
            assert torch.equal(keep[index].bool(), torch.from_numpy(expected))
    assert _FieldEnergy(model, cloud, FitPointsConfig(**FAST, wrist_clip_m=None), hands,
                        None).hand_side(batch, cloud.points, 0.0) is None


def test_a_forearm_in_the_scan_weighs_on_no_candidate():
    # Points beyond a candidate's wrist cut leave its data term as it is without them, while a
    # fit with no cut (wrist_clip_m None) pays for them.
    from lisa_hand.fitting.points.surface_stage import _FieldEnergy
    from lisa_hand.skeleton.wrist import wrist_plane

    model = tiny_model()
    truth = true_hand(model, seed=0)
    points, _, _ = scan_of(model, truth, ScanConfig(num_points=800), seed=0)
    points = torch.as_tensor(points, dtype=torch.float32)
    plane = wrist_plane(truth, 0.01)
    hand = points[torch.from_numpy(plane.keeps(points.double().numpy()))]
    normal = torch.as_tensor(plane.normal, dtype=torch.float32)
    base = torch.as_tensor(plane.point, dtype=torch.float32)
    generator = torch.Generator().manual_seed(1)
    spread = 0.02 * torch.randn(300, 3, generator=generator)
    spread = spread - (spread @ normal)[:, None] * normal  # across the forearm's axis
    forearm = base - normal * (0.005 + 0.05 * torch.rand(300, 1, generator=generator)) + spread
    for clip, same in ((0.01, True), (None, False)):
        config = FitPointsConfig(**FAST, wrist_clip_m=clip)
        values = []
        for cloud_points in (hand, torch.cat([hand, forearm])):
            cloud = target_cloud(cloud_points, None, seed=0)
            energy = _FieldEnergy(model, cloud, config, [truth], None)
            batch = CandidateBatch.from_hands([truth], truth.rest_joints.mean(0))
            with torch.no_grad():
                values.append(float(energy.data(batch, torch.arange(cloud.num_points), 0.004)))
        assert (values[0] == pytest.approx(values[1], rel=1e-5)) == same
    assert values[1] > 2.0 * values[0]


def test_the_surface_stage_draws_free_points_near_its_candidates_again():
    from lisa_hand.fitting.points.free_space import DepthImage

    model = tiny_model()
    truth = true_hand(model, seed=0)
    points, _, _ = scan_of(model, truth, ScanConfig(num_points=500), seed=0)
    cloud = target_cloud(points, None, seed=0)
    cloud = cloud.replace(depth=DepthImage(cloud.points, cloud.points.mean(0) +
                                           torch.tensor([0.0, 0.0, -0.4])))
    config = FitPointsConfig(**{**FAST, "field_iters": 20}, free_near_every=8,
                             prune_after=(0.25, 0.5))
    calls = []

    def near(batch):
        calls.append(batch.count)
        return cloud.points[:4] + 0.05

    fit_surface(model, cloud, [truth, truth], config, free_near=near)
    # steps 0, 8, 16 and the prunings at 5 and 10 (2 -> 1 candidate at the first)
    assert calls == [2, 2, 1, 1, 1]


def test_side_auto_keeps_the_side_the_scan_shows():
    """``side="auto"`` fits both sides and keeps the one nearer the scan: the shipped v3 prior's
    own hand (a natural pose) is kept as a right hand, its mirror image as a left one, each by
    a clear margin; the distances are the mean capped ``|G|`` at the points both fits keep
    (checked through ``hand_field``, which mirrors a left hand itself); the kept fit is the
    one-side fit exactly, though the two sides ran side by side in two threads."""
    from lisa_hand.data.scans import simulate_scan
    from lisa_hand.fitting.points.fit import start_hand
    from lisa_hand.inference import MeshConfig, mesh_hand
    from lisa_hand.model.trained import load_trained

    model = load_trained("geometry_v3", "cpu")
    config = FitPointsConfig(**FAST)
    _, rest_hand, _ = start_hand(model, target_cloud(torch.zeros(30, 3), None), None)
    pose = torch.zeros(16, 3)
    pose[0] = torch.tensor([1.2, 0.3, -0.6])
    pose[1:16, 2] = 0.25  # every finger joint a little bent
    truth = rest_hand.with_pose(pose.reshape(48), torch.tensor([0.01, 0.02, 0.3]))
    mesh = mesh_hand(model, truth, 64, MeshConfig(colors=False, skin_weights=False))
    points = simulate_scan(mesh.vertices, mesh.faces, ScanConfig(num_points=2000), seed=1).points
    threads = torch.get_num_threads()
    for side, cloud in (("right", points), ("left", mirror_points(torch.as_tensor(points)))):
        fit = fit_points(model, cloud, None, config, side="auto")  # both sides in two threads
        assert torch.get_num_threads() == threads
        alone = fit_points(model, cloud, None, config, side=side)  # the same fit, on its own
        assert alone.energy == fit.energy and torch.equal(alone.params.pose, fit.params.pose)
        other = "left" if side == "right" else "right"
        distances = fit.side_distances_mm
        assert fit.params.side == side, distances
        assert distances[other] > 1.2 * distances[side], distances
        assert fit.params.extra["fit"]["side_distances_mm"] == distances
        cloud = torch.as_tensor(cloud, dtype=torch.float32)
        keep = torch.from_numpy(fit.wrist_plane.keeps(cloud.double().numpy()))
        with torch.no_grad():
            sdf = hand_field(model, fit.params).sdf_fn()(cloud)
        own = float(sdf.abs().clamp_max(0.01)[keep].mean()) * 1e3  # this fit's cut only
        assert own == pytest.approx(distances[side], rel=0.05, abs=0.02)


def test_tries_keep_the_fit_nearest_the_scan():
    """``tries=2`` on a one-view scan with its sensor: fits from seeds 3 and 4, the one nearer
    the scan kept, equal to that seed's fit on its own (the two ran side by side in two
    threads); ``tries=1`` fits once."""
    import dataclasses

    from lisa_hand.data.scans import simulate_scan
    from lisa_hand.fitting.points.fit import start_hand
    from lisa_hand.inference import MeshConfig, mesh_hand
    from lisa_hand.model.trained import load_trained

    model = load_trained("geometry_v3", "cpu")
    config = FitPointsConfig(**{**FAST, "seed": 3, "tries": 2})
    _, rest_hand, _ = start_hand(model, target_cloud(torch.zeros(30, 3), None), None)
    pose = torch.zeros(16, 3)
    pose[0] = torch.tensor([0.3, 0.2, -0.4])
    pose[1:16, 2] = 0.4
    truth = rest_hand.with_pose(pose.reshape(48), torch.tensor([0.0, 0.0, 0.35]))
    mesh = mesh_hand(model, truth, 64, MeshConfig(colors=False, skin_weights=False))
    scan = simulate_scan(mesh.vertices, mesh.faces, ScanConfig(
        num_points=2000, partial=True, viewpoint=(0.0, 0.0, 0.0)), seed=2)
    fit = fit_points(model, scan.points, None, config, side="right", viewpoint=np.zeros(3))
    distances = fit.try_distances_mm
    assert len(distances) == 2 and fit.side_distances_mm is None
    assert fit.params.extra["fit"]["try_distances_mm"] == distances
    seed = 3 + int(np.argmin(distances))
    alone = fit_points(model, scan.points, None, dataclasses.replace(config, seed=seed, tries=1),
                       side="right", viewpoint=np.zeros(3))
    assert alone.energy == fit.energy and torch.equal(alone.params.pose, fit.params.pose)
    assert alone.try_distances_mm is None


def test_a_sparse_cloud_counts_coverage_within_its_point_spacing():
    """point_spacing of a square grid is its step (closed form); the coverage distance is
    ``covered_mm`` for a dense cloud and 2 steps for a sparse one."""
    from lisa_hand.fitting.points.stages import _covered_distance

    def grid(step: float) -> torch.Tensor:  # 12 x 12 points in the z = 0 plane
        axis = torch.arange(12, dtype=torch.float64) * step
        x, y = torch.meshgrid(axis, axis, indexing="ij")
        return torch.stack([x, y, torch.zeros_like(x)], dim=-1).reshape(-1, 3)

    config = FitPointsConfig()
    for step, expected in ((0.005, 0.01), (0.001, 0.004)):
        points = grid(step)
        assert point_spacing(points) == pytest.approx(step, rel=1e-9)
        cloud = target_cloud(points + 0.1, None)
        assert _covered_distance(cloud, config) == pytest.approx(expected, rel=1e-5)
    assert point_spacing(torch.zeros(1, 3)) == 0.0
