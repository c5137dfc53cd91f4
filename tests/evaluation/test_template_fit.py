"""The MANO-like baseline's fit: the template recovers a hand made by the template itself
(known pose, shape, orientation and position), and its subdivision to about 100k vertices."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from lisa_hand.evaluation.template_fit import (
    TemplateFitConfig,
    fit_template_points,
    subdivide_to,
    template_mesh,
)
from lisa_hand.geometry import axis_angle_to_matrix
from lisa_hand.handmodel.poses import named_pose
from lisa_hand.handmodel.template import load_template
from lisa_hand.metrics import mesh_distances

pytestmark = pytest.mark.usefixtures("one_thread")


def test_fit_recovers_a_template_hand():
    import trimesh

    template = load_template()
    generator = torch.Generator().manual_seed(4)
    pose = named_pose("relaxed").clone()
    pose[:3] = torch.tensor([1.9, -0.7, 0.4])  # far from any axis-aligned start
    betas = 0.5 * torch.randn(template.num_betas, generator=generator)
    translation = torch.tensor([0.03, -0.05, 0.4])
    vertices, faces = template_mesh(template, pose, betas, translation)
    points = trimesh.Trimesh(vertices, faces, process=False).sample(8000, seed=5)

    fit = fit_template_points(points, template, TemplateFitConfig(seed=1))
    hand = fit.params
    fitted, _ = template_mesh(template, hand.pose, hand.betas, hand.translation)
    distances = mesh_distances(fitted, faces, vertices, faces)
    assert distances.v2s_scan_to_recon_mm < 1.0 and distances.v2s_recon_to_scan_mm < 1.0
    rotation = axis_angle_to_matrix(hand.pose[:3].double())
    truth = axis_angle_to_matrix(pose[:3].double())
    angle = torch.arccos(((rotation.T @ truth).trace() - 1).clamp(-2, 2) / 2)
    assert float(angle) < np.radians(5.0)
    assert fit.seconds > 0 and np.isfinite(fit.energy)
    # The one hand state: the template's skeleton for the fitted betas, no LISA codes.
    assert hand.side == "right" and hand.model == "template" and hand.shape_code.numel() == 0
    rest_joints = template.to(dtype=torch.float32).rest_joints(hand.betas[None])[0]
    assert torch.allclose(hand.rest_joints, rest_joints)
    assert hand.extra["fit"]["energy"] == fit.energy


def test_a_left_hand_fits_as_the_mirror_of_the_right_one():
    import trimesh

    from lisa_hand.skeleton import mirror_points

    template = load_template()
    pose = named_pose("relaxed").clone()
    pose[:3] = torch.tensor([0.3, 1.2, -0.4])
    translation = torch.tensor([0.01, 0.02, 0.3])
    vertices, faces = template_mesh(template, pose, torch.zeros(template.num_betas), translation)
    points = trimesh.Trimesh(vertices, faces, process=False).sample(3000, seed=2)
    config = TemplateFitConfig(rigid_iters=40, full_iters=60, seed=1)
    right = fit_template_points(points, template, config)
    left_points = mirror_points(torch.from_numpy(points)).numpy()
    left = fit_template_points(left_points, template, config, side="left")
    assert left.params.side == "left" and left.energy == pytest.approx(right.energy, rel=1e-5)
    # The left mesh is the mirror of the right one, its faces still turned outwards.
    left_mesh = trimesh.Trimesh(*template_mesh(template, left.params.pose, left.params.betas,
                                               left.params.translation, side="left"),
                                process=False)
    right_mesh = trimesh.Trimesh(*template_mesh(template, right.params.pose,
                                                right.params.betas, right.params.translation),
                                 process=False)
    assert np.allclose(left_mesh.vertices, right_mesh.vertices * [-1.0, 1.0, 1.0], atol=1e-5)
    assert left_mesh.volume > 0 and left_mesh.volume == pytest.approx(right_mesh.volume,
                                                                      rel=1e-4)
    with pytest.raises(ValueError, match="side"):
        fit_template_points(points, template, config, side="up")


def test_fit_rejects_bad_points():
    with pytest.raises(ValueError, match=r"shape \[N, 3\]"):
        fit_template_points(np.zeros((5, 3)))
    with pytest.raises(ValueError, match="non-finite"):
        fit_template_points(np.full((50, 3), np.nan))
    with pytest.raises(ValueError, match="keep must be"):
        TemplateFitConfig(keep=0)


def test_subdivision_to_about_100k_vertices():
    template = load_template()
    vertices, faces = template_mesh(template, torch.zeros(48), torch.zeros(template.num_betas),
                                    torch.zeros(3))
    dense, dense_faces = subdivide_to(vertices, faces, 100_000)
    # Each loop subdivision about quadruples the count: 800 -> ~51k or ~205k; 51k is closer.
    assert 40_000 < len(dense) < 60_000 and len(dense_faces) == 4**3 * len(faces)
    # The subdivided surface stays on the template's (loop subdivision smooths by < 1 mm).
    distances = mesh_distances(dense, dense_faces, vertices, faces)
    assert distances.v2s_recon_to_scan_mm < 1.0
    small, _ = subdivide_to(vertices, faces, 3_000)
    assert len(small) == 4 * len(vertices) - 6 or 3_000 < len(small) < 3_300
    unchanged, _ = subdivide_to(vertices, faces, 500)
    assert len(unchanged) == len(vertices)
