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
    fitted, _ = template_mesh(template, fit.pose, fit.betas, fit.translation)
    distances = mesh_distances(fitted, faces, vertices, faces)
    assert distances.v2s_scan_to_recon_mm < 1.0 and distances.v2s_recon_to_scan_mm < 1.0
    rotation = axis_angle_to_matrix(fit.pose[:3].double())
    truth = axis_angle_to_matrix(pose[:3].double())
    angle = torch.arccos(((rotation.T @ truth).trace() - 1).clamp(-2, 2) / 2)
    assert float(angle) < np.radians(5.0)
    assert fit.seconds > 0 and np.isfinite(fit.energy)


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
