"""The free space of a one-view scan (``lisa_hand.fitting.points.free_space``), checked on a
sphere scanned from one side against its closed-form distances."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import torch
import trimesh

from lisa_hand.data.scans import ScanConfig, simulate_scan
from lisa_hand.fitting.points.free_space import DepthImage, free_space_points

RADIUS = 0.05
CENTRE = np.array([0.02, -0.01, 0.4])
VIEWPOINT = np.array([0.0, 0.0, 0.0])


@pytest.fixture(scope="module")
def sphere_scan():
    sphere = trimesh.creation.icosphere(subdivisions=5, radius=RADIUS)
    vertices = sphere.vertices + CENTRE
    scan = simulate_scan(vertices, sphere.faces,
                         ScanConfig(num_points=4000, partial=True, viewpoint=tuple(VIEWPOINT)),
                         seed=3)
    return torch.from_numpy(scan.points).double(), torch.from_numpy(VIEWPOINT).double()


def _sphere_sdf(points: torch.Tensor) -> torch.Tensor:
    return (points - torch.from_numpy(CENTRE)).norm(dim=-1) - RADIUS


def test_free_points_lie_outside_the_scanned_object_and_before_it(sphere_scan):
    points, viewpoint = sphere_scan
    free = free_space_points(DepthImage(points, viewpoint), points, 2000,
                             torch.Generator().manual_seed(0))
    assert free.shape == (2000, 3)
    # every sample is outside the sphere (the icosphere's facets are within 0.1 mm of it)
    assert float(_sphere_sdf(free).min()) > -1e-4
    # half in front of scan points: 3-20 mm before a point along its ray, so 3 mm or more out
    # (on the sphere's near side the ray meets the surface at the point itself)
    front = free[:1000]
    assert float(_sphere_sdf(front).min()) > 0.0
    assert float((front - viewpoint).norm(dim=-1).max()) < float(
        (points - viewpoint).norm(dim=-1).max())
    again = free_space_points(DepthImage(points, viewpoint), points, 2000,
                             torch.Generator().manual_seed(0))
    assert torch.equal(free, again)


def test_the_depth_image_measures_how_far_a_point_lies_in_front_of_the_surface(sphere_scan):
    points, viewpoint = sphere_scan
    image = DepthImage(points, viewpoint)
    # the scanned (near) side of the sphere: no violation; its far side is hidden: none either
    sphere = trimesh.creation.icosphere(subdivisions=4, radius=RADIUS)
    surface = torch.from_numpy(sphere.vertices + CENTRE)
    assert float(image.violation(surface).max()) == 0.0
    # the ray through the sphere's centre meets it at range |c| - r; a point 15 mm before it
    # lies 15 mm - margin in the free space (to the pixel's nearest return, within a pixel)
    direction = torch.from_numpy(CENTRE / np.linalg.norm(CENTRE))
    near = float(np.linalg.norm(CENTRE)) - RADIUS
    probe = viewpoint + direction * (near - 0.015)
    violation = float(image.violation(probe[None])[0])
    assert violation == pytest.approx(0.015 - image.margin, abs=5e-4)
    # beside the sphere, on an empty pixel: at least the margin plus the gap to the silhouette
    side = torch.tensor([CENTRE[0] + RADIUS + 0.02, CENTRE[1], CENTRE[2]])
    gap = float(image.violation(side[None])[0])
    assert 0.02 - 0.005 < gap - image.margin < 0.02 + 0.002


def test_the_sensor_could_see_the_near_side_only(sphere_scan):
    points, viewpoint = sphere_scan
    image = DepthImage(points, viewpoint)
    sphere = trimesh.creation.icosphere(subdivisions=4, radius=RADIUS)
    surface = torch.from_numpy(sphere.vertices + CENTRE)
    normals = torch.from_numpy(np.array(sphere.vertex_normals))
    seen = image.could_see(surface, normals)
    # closed form: a sphere point faces the sensor where (v - p) . n > 0
    rays = viewpoint - surface
    cosine = (rays * normals).sum(-1) / rays.norm(dim=-1)
    facing = cosine > 0
    assert not bool((seen.bool() & ~facing).any())
    # facing it squarely: seen; at grazing angles the (dilated) depth image's nearer pixels may
    # hide a point behind the silhouette's edge
    assert float(seen[cosine > 0.3].min()) == 1.0
    assert 0.4 < float(seen.mean()) < 0.5  # a little under half: the sensor is 0.4 m away
    # without normals the far side is still hidden, by the near side in front of it (all but
    # the points within the 5 mm tolerance of the silhouette, where the two sides meet)
    hidden = image.could_see(surface, None)[~facing]
    back = (surface - torch.from_numpy(CENTRE)) @ torch.from_numpy(
        CENTRE / np.linalg.norm(CENTRE))
    deep = back[~facing] > 0.01  # more than 1 cm behind the sphere's centre plane
    assert float(hidden[deep].max()) == 0.0
    # a point beside the sphere, on an empty pixel, could be seen
    side = torch.tensor([[CENTRE[0] + RADIUS + 0.02, CENTRE[1], CENTRE[2]]], dtype=surface.dtype)
    assert float(image.could_see(side, None)[0]) == 1.0


def test_the_violation_pulls_a_point_back_towards_the_scan(sphere_scan):
    points, viewpoint = sphere_scan
    image = DepthImage(points, viewpoint)
    probe = torch.tensor([[CENTRE[0] + RADIUS + 0.02, CENTRE[1], CENTRE[2]]],
                         requires_grad=True)
    image.violation(probe).sum().backward()
    # moving along -x (towards the sphere) lowers the violation: central differences agree
    step = torch.tensor([[1e-3, 0.0, 0.0]], dtype=probe.dtype)
    with torch.no_grad():
        slope = float(image.violation(probe + step) - image.violation(probe - step)) / 2e-3
    assert float(probe.grad[0, 0]) > 0.5 and slope > 0.5
    assert float(probe.grad[0, 0]) == pytest.approx(slope, rel=0.25)


def test_a_viewpoint_inside_the_scan_is_refused(sphere_scan):
    points, _ = sphere_scan
    with pytest.raises(ValueError, match="viewpoint"):
        DepthImage(points, points.mean(0))


@pytest.fixture(scope="module")
def curled_index():
    """A one-view scan of the shipped geometry's own hand with the index curled under the palm,
    seen from above the back of the hand: the true hand, the same hand with the index straight,
    the sensor position, the cloud without and with its free space, the fit's config and the
    proxy of the model's mean hand."""
    from types import SimpleNamespace

    from lisa_hand.fitting.points.cloud import target_cloud
    from lisa_hand.fitting.points.config import FitPointsConfig
    from lisa_hand.fitting.points.fit import start_hand, with_free_space
    from lisa_hand.fitting.points.proxy import build_surface_proxy
    from lisa_hand.inference import MeshConfig, mesh_hand
    from lisa_hand.model.trained import load_trained

    model = load_trained("geometry", "cpu")
    placeholder = target_cloud(torch.zeros(30, 3), None, seed=0)
    _, rest_hand, (rest, code, color) = start_hand(model, placeholder, None)
    pose = torch.zeros(16, 3)
    pose[0] = torch.tensor([0.0, 0.0, 0.0])  # palm towards -y, fingers along -x
    pose[1:4, 2] = torch.tensor([1.3, 1.5, 0.9])  # the index curled under the palm
    truth = rest_hand.with_pose(pose.reshape(48), torch.tensor([0.0, 0.0, 0.3]))
    straight_pose = pose.clone()
    straight_pose[1:4] = 0.0
    straight = truth.with_pose(straight_pose.reshape(48), truth.translation)
    mesh = mesh_hand(model, truth, 64, MeshConfig(colors=False, skin_weights=False))
    viewpoint = np.array([0.0, 0.5, 0.3])  # above the back of the hand
    scan = simulate_scan(mesh.vertices, mesh.faces,
                         ScanConfig(num_points=3000, partial=True, viewpoint=tuple(viewpoint)),
                         seed=0)
    config = FitPointsConfig(seed=0)
    plain = target_cloud(scan.points, None, seed=0)
    cloud = with_free_space(plain, viewpoint, "right", config)
    proxy = build_surface_proxy(model, rest, code, color, 1000, torch.Generator().manual_seed(0))
    return SimpleNamespace(model=model, truth=truth, straight=straight, viewpoint=viewpoint,
                           plain=plain, cloud=cloud, config=config, proxy=proxy)


def test_a_straight_finger_where_the_sensor_saw_nothing_costs_the_fit(curled_index):
    """In the sensor's free space the true hand has no surface, the same hand with the index
    straight has (its finger sticks out where the sensor saw nothing), and the proxy energy's
    free-space term costs the straight finger and not the truth."""
    from lisa_hand.fitting.points.candidates import CandidateBatch
    from lisa_hand.fitting.points.proxy import proxy_energy
    from lisa_hand.inference import MeshConfig, mesh_hand

    model, truth, straight = curled_index.model, curled_index.truth, curled_index.straight
    plain, cloud, config = curled_index.plain, curled_index.cloud, curled_index.config
    proxy = curled_index.proxy
    assert cloud.free.shape == (config.free_space_points, 3) and cloud.depth is not None
    for name, hand, expected in (("truth", truth, 0.0), ("straight", straight, 0.01)):
        other = mesh_hand(model, hand, 64, MeshConfig(colors=False, skin_weights=False))
        seen = cloud.depth.violation(torch.from_numpy(np.asarray(other.vertices)).float())
        fraction = float((seen > 1e-3).float().mean())
        assert (fraction < 0.002) if expected == 0.0 else (fraction > expected), (name, fraction)
    batch = CandidateBatch.from_hands([truth, straight], proxy.pivot)

    def energies(target, seen_only=False):
        target.generator.manual_seed(0)
        settings = dataclasses.replace(config, coverage_seen_only=seen_only)
        return proxy_energy(proxy, target, batch, settings, 0.004, num_points=3000)

    with torch.no_grad():
        without, with_free = energies(plain), energies(cloud)
        seen_only = energies(cloud, seen_only=True)
    gain = with_free - without
    assert float(gain[0]) == 0.0 and float(gain[1]) > 0.0, gain.tolist()
    # measured: without, the straight finger costs 3% more than the truth; with, 35% more
    margin, plain_margin = (float(e[1] - e[0]) for e in (with_free, without))
    assert margin > 5.0 * plain_margin, (with_free.tolist(), without.tolist())
    # coverage asked only of what the sensor could see: the truth's hidden side (the palm's
    # front, the curled index) no longer costs it, and the straight finger costs more than the
    # truth by more (measured: truth 0.44e-3 against 1.95e-3, straight 2.9x the truth
    # against 1.35x)
    assert float(seen_only[0]) < 0.5 * float(with_free[0]), (seen_only, with_free)
    assert float(seen_only[1] - seen_only[0]) > margin, (seen_only, with_free)
    assert float(seen_only[1]) > 2.0 * float(seen_only[0]), seen_only


def test_the_curled_index_hidden_from_the_sensor_is_unseen(curled_index):
    """unseen_fingers: the true hand's index, curled under the palm away from a sensor above
    the back of the hand, could hardly be seen (weight > 0); the other fingers' backs face the
    sensor (weight 0); the same hand with the index straight shows it (it sticks out where the
    sensor saw nothing: the free-space term's business, not the coupling's)."""
    from lisa_hand.fitting.points.proxy import unseen_fingers

    proxy, cloud = curled_index.proxy, curled_index.cloud
    truth = unseen_fingers(proxy, cloud, curled_index.truth, 0.2)
    straight = unseen_fingers(proxy, cloud, curled_index.straight, 0.2)
    assert truth.shape == (5,)  # index, middle, ring, pinky, thumb
    # measured 0.40: its knuckle shows (12% of its surface could be seen, against 20%)
    assert float(truth[0]) > 0.3 and float(truth[1:4].max()) == 0.0, truth.tolist()
    assert float(straight.max()) == 0.0, straight.tolist()
    assert unseen_fingers(proxy, curled_index.plain, curled_index.truth, 0.2) is None
    # a copy of the cloud keeps its depth image, distance grid and generator
    grid = cloud.distance_grid
    copied = cloud.replace(free=cloud.free)
    assert copied.depth is cloud.depth
    assert copied.distance_grid is grid and copied.generator is cloud.generator
    with pytest.raises(TypeError, match="no colour"):
        cloud.replace(colour=None)


def test_a_left_hands_viewpoint_is_mirrored_with_its_cloud(sphere_scan):
    """fit_points mirrors a left hand's cloud into a right one; its sensor position must follow,
    so the free space is the mirror image of the left world's (here: equal to the right's)."""
    from lisa_hand.fitting.points.cloud import target_cloud
    from lisa_hand.fitting.points.config import FitPointsConfig
    from lisa_hand.fitting.points.fit import with_free_space
    from lisa_hand.fitting.sides import mirror_cloud

    points, viewpoint = sphere_scan
    config = FitPointsConfig(free_space_points=256)
    right = with_free_space(target_cloud(points, None, seed=0), viewpoint.numpy(), "right",
                            config)
    left_view = mirror_cloud(viewpoint[None], "left")[0].numpy()
    left = with_free_space(target_cloud(points, None, seed=0), left_view, "left", config)
    assert torch.allclose(left.free, right.free, atol=1e-6)
    with pytest.raises(ValueError, match="viewpoint must be 3 finite numbers"):
        with_free_space(target_cloud(points, None, seed=0), np.array([0.0, np.nan, 0.0]),
                        "right", config)


def test_the_second_pass_weighs_the_unseen_fingers_of_the_hand_it_is_given(curled_index):
    """second_finger_pass judges which fingers the sensor could not see on the field stage's
    hand (not on the proxy stages' best candidate): the curled index of the truth is unseen,
    the straight hand's index is not."""
    from lisa_hand.fitting.points.config import FitPointsConfig
    from lisa_hand.fitting.points.stages import second_finger_pass

    # unseen_share 0.3: the curled index's knuckle shows (about 12% of it), the straight
    # index's back (about 40%); the proxy's random points move these by a few percent
    config = FitPointsConfig(seed=0, finger_iters=2, second_pass_iters=2, unseen_share=0.3)
    weights = {}
    for name in ("truth", "straight"):
        hand = getattr(curled_index, name)
        _, report = second_finger_pass(curled_index.model, curled_index.cloud, hand, config,
                                       1.0)
        (line,) = [line for line in report.notes if line.startswith("unseen fingers: ")]
        listed = line.removeprefix("unseen fingers: ")
        weights[name] = {} if listed == "none" else {
            finger: float(value) for finger, value in (item.split() for item in listed.split(", "))}
    assert weights["truth"].get("index", 0.0) >= 0.3, weights
    assert weights["straight"].get("index", 0.0) <= 0.1, weights
