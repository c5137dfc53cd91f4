"""The point fit's size search (lisa_hand.fitting.points.size_search)."""

from __future__ import annotations

import dataclasses

import pytest
import torch

from lisa_hand.fitting.points.candidates import CandidateBatch
from lisa_hand.fitting.points.cloud import target_cloud
from lisa_hand.fitting.points.config import FitPointsConfig
from lisa_hand.fitting.points.proxy import SurfaceProxy, build_surface_proxy
from lisa_hand.fitting.points.size_search import betas_for_size, scaled_proxy, search_size
from lisa_hand.handmodel.template import load_template

from .test_points import FAST

pytestmark = pytest.mark.usefixtures("one_thread")


@pytest.mark.parametrize("size", [0.85, 1.0, 1.12, 1.2])
def test_the_betas_for_a_size_scale_the_mean_skeleton_about_its_wrist(size):
    template = load_template()
    mean = template.rest_joints(torch.zeros(1, template.num_betas))[0].double()
    skeleton = template.rest_joints(betas_for_size(template, size)[None])[0].double()
    wanted = mean[0] + size * (mean - mean[0])  # the mean skeleton, scaled
    error = (skeleton - wanted).norm(dim=-1)
    assert float(error.max()) < 1e-3, error  # metres: within 1 mm at every joint (the ridge)
    lengths = (skeleton[1:] - skeleton[0]).norm(dim=-1) / (mean[1:] - mean[0]).norm(dim=-1)
    assert float(lengths.mean()) == pytest.approx(size, abs=0.005)


def test_a_scaled_proxy_keeps_its_shape_at_its_size():
    generator = torch.Generator().manual_seed(0)
    joints = torch.randn(16, 3, generator=generator, dtype=torch.float64) * 0.03
    points = torch.randn(50, 3, generator=generator, dtype=torch.float64) * 0.04
    weights = torch.softmax(torch.randn(50, 16, generator=generator, dtype=torch.float64), -1)
    proxy = SurfaceProxy(points, weights, joints, points.mean(0), None)
    moved_joints = joints * 1.3 + torch.tensor([0.01, 0.0, -0.02], dtype=torch.float64)
    sized = scaled_proxy(proxy, 1.3, moved_joints)
    assert torch.allclose(torch.cdist(sized.points_rest, sized.points_rest),
                          1.3 * torch.cdist(points, points), atol=1e-6)
    assert torch.allclose(sized.points_rest[0] - moved_joints[0], 1.3 * (points[0] - joints[0]),
                          atol=1e-7)
    assert torch.allclose(sized.pivot, sized.points_rest.mean(0), atol=1e-6)
    assert sized.weights is weights and sized.rest_joints is moved_joints


def _scan_at_size(model, size: float):
    """A full scan of the shipped model's mean hand, posed, turned and moved, then made
    ``size`` times larger about its wrist (a larger hand, not a longer skeleton) -> (its cloud,
    the hand's pose on the mean skeleton, the proxy of the mean hand, the template, a config)."""
    from lisa_hand.data.scans import ScanConfig, simulate_scan
    from lisa_hand.fitting.points.fit import start_hand
    from lisa_hand.inference import MeshConfig, mesh_hand

    config = FitPointsConfig(**{**FAST, "fit_betas": True})
    placeholder = target_cloud(torch.zeros(30, 3), None, seed=0)
    template, rest_hand, (rest, code, color) = start_hand(model, placeholder, None)
    pose = torch.zeros(16, 3)
    pose[0] = torch.tensor([0.4, -2.0, 0.9])
    pose[1:, 2] = 0.3
    start = rest_hand.with_pose(pose.reshape(48), torch.tensor([0.02, -0.01, 0.35]))
    mesh = mesh_hand(model, start, 64, MeshConfig(colors=False, skin_weights=False))
    wrist = (start.rest_joints[0] + start.translation).numpy()  # the wrist turns in place
    vertices = wrist + size * (mesh.vertices - wrist)
    scan = simulate_scan(vertices, mesh.faces, ScanConfig(num_points=4000), seed=0)
    cloud = target_cloud(scan.points, None, seed=0)
    proxy = build_surface_proxy(model, rest, code, color, config.proxy_points, cloud.generator)
    return cloud, start, proxy, template, config


@pytest.mark.parametrize("size", [0.9, 1.0, 1.15])
def test_the_size_search_finds_the_size_of_the_hand(size):
    """The model's own hand made ``size`` times larger, started on the mean skeleton: the
    search's size is the true one (within one step of its grid) and the candidates come back
    on the template's skeleton for it."""
    from lisa_hand.model.trained import load_trained

    model = load_trained(None, "cpu")
    cloud, start, proxy, template, config = _scan_at_size(model, size)
    other_pose = start.pose.clone()
    other_pose[3:] += 0.2  # a second candidate, its fingers curled farther
    other = start.with_pose(other_pose, start.translation + torch.tensor([0.0, 0.01, 0.0]))
    sized, hands, report = search_size(proxy, cloud, [start, other], template, config)
    sizes = config.sizes
    chosen = sizes[min(range(len(sizes)), key=report.screened_energies.__getitem__)]
    assert abs(chosen - size) <= 0.051, (chosen, report.screened_energies)
    assert report.stage == "size" and f"{chosen:g} times" in report.notes[0]
    assert len(hands) == 2 and all(hand.betas is not None for hand in hands)
    assert torch.allclose(hands[1].rest_joints, template.rest_joints(hands[1].betas[None])[0],
                          atol=1e-6)
    assert torch.equal(sized.rest_joints, hands[1].rest_joints)
    if chosen == 1.0:  # the mean size: the candidates and the proxy as they came
        assert sized is proxy and hands == [start, other]
    else:  # the second candidate keeps its pose, and where it puts the proxy's centroid
        assert torch.allclose(hands[1].pose, other.pose, atol=1e-5)
        before = CandidateBatch.from_hands([other], proxy.pivot).position
        after = CandidateBatch.from_hands([hands[1]], sized.pivot).position
        assert torch.allclose(before, after, atol=1e-6)
    # Off: the candidates come back as they were.
    for off_config in (dataclasses.replace(config, sizes=(1.0,)),
                       dataclasses.replace(config, fit_betas=False)):  # the mean skeleton kept
        kept_proxy, kept, off = search_size(proxy, cloud, [start], template, off_config)
        assert kept_proxy is proxy and kept == [start] and off.screened_energies == []


def test_sizes_are_checked():
    with pytest.raises(ValueError, match="sizes"):
        FitPointsConfig(sizes=())
    with pytest.raises(ValueError, match="sizes"):
        FitPointsConfig(sizes=(1.0, 3.0))
