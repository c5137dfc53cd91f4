"""A scan analysed once (``lisa_hand.fitting.points.analysis``): on a simulated one-view scan of
a hand before a wall with a block beside it, the analysis finds the wall, the block and the
sensor, keeps the hand's points only, and the fit takes it instead of looking again."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch

from lisa_hand.data.scans import ScanConfig, simulate_scan
from lisa_hand.fitting.points.analysis import AnalysisConfig, analyse_scan
from lisa_hand.fitting.points.fit import FitPointsConfig, fit_points
from lisa_hand.fitting.points.others import OthersConfig
from tests.fitting.test_points import FAST, tiny_model
from tests.fitting.test_support import hand_at, with_wall


def _block(centre, size: float):
    """A cube ``size`` metres across at ``centre`` -> (vertices [8, 3], faces [12, 3])."""
    import trimesh

    box = trimesh.creation.box(extents=(size, size, size))
    return np.asarray(box.vertices) + np.asarray(centre), np.asarray(box.faces)


@pytest.fixture(scope="module")
def scene():
    vertices, faces = hand_at(0.3)
    block_vertices, block_faces = _block(vertices.mean(0) + [0.2, 0.0, 0.0], 0.03)
    vertices, faces, wall, is_wall = with_wall(
        np.concatenate([vertices, block_vertices]),
        np.concatenate([faces, block_faces + len(vertices)]), side=0.3)
    scan = simulate_scan(vertices, faces, ScanConfig(num_points=20000, partial=True,
                                                     viewpoint=(0.0, 0.0, 0.0),
                                                     noise_normal_std=0.0005,
                                                     outlier_fraction=0.0), seed=0)
    hand_count = len(hand_at(0.3)[1])
    face = np.asarray(scan.face_ids)
    kind = np.where(is_wall[face], "wall", np.where(face >= hand_count, "block", "hand"))
    return scan.points, kind, wall


def test_the_analysis_finds_the_wall_the_block_and_the_sensor(scene):
    points, kind, wall = scene
    analysis = analyse_scan(points, viewpoint="auto", support="auto", others="auto", seed=0)
    assert analysis.num_points == len(points)
    assert analysis.support is not None and analysis.others is not None
    assert abs(float(np.dot(analysis.support.plane.normal, wall.normal))) > 0.99
    assert analysis.one_view and analysis.sensor is not None
    assert float(np.linalg.norm(analysis.sensor)) < 0.05  # the origin, within 5 cm
    # the hand's points kept, the wall's and the block's left out
    assert analysis.keep[kind == "hand"].mean() > 0.9  # a few within 2.5 mm of the wall
    assert analysis.keep[kind == "wall"].mean() < 0.02
    assert analysis.keep[kind == "block"].mean() < 0.02
    assert analysis.hand(points).shape == (analysis.hand_points, 3)
    assert analysis.coverage is None and analysis.with_coverage(0.5).coverage == 0.5
    assert analysis.coverage is None  # immutable
    assert analysis.hands == 1  # the block is too small to be a hand
    record = json.loads(json.dumps(analysis.to_dict()))
    assert record["hand_points"] == analysis.hand_points and record["one_view"]
    assert record["hands"] == 1


def test_the_analysis_counts_the_hands_apart(scene):
    points, kind, _ = scene
    hand = points[kind == "hand"]
    two = np.concatenate([hand, hand + np.array([0.0, 0.25, 0.0])])  # another hand, 25 cm away
    assert analyse_scan(two).hands == 2
    assert analyse_scan(hand).hands == 1


def test_the_analysis_settings_reach_the_searches(scene):
    points, _, _ = scene
    strict = AnalysisConfig(others=OthersConfig(min_share=0.9))  # the block counts as noise
    assert analyse_scan(points, others="auto", config=strict).others is None
    given = analyse_scan(points, viewpoint=np.array([0.0, 0.0, 0.0]))
    assert given.one_view and given.viewpoint is None and np.all(given.sensor == 0.0)
    assert not analyse_scan(points).one_view  # nobody asked (no viewpoint), nothing looked for
    with pytest.raises(ValueError, match="support must be 'auto' or None"):
        analyse_scan(points, support="yes")


def test_the_fit_takes_the_analysis_and_records_it(scene):
    points, kind, _ = scene
    model = tiny_model()
    analysis = analyse_scan(points, support="auto", others="auto", seed=0)
    config = FitPointsConfig(**FAST)
    fit = fit_points(model, points, None, config, analysis=analysis)
    recorded = fit.params.extra["fit"]["analysis"]
    assert recorded["hand_points"] == analysis.hand_points
    assert recorded["coverage"] == pytest.approx(fit.coverage)
    assert fit.support is analysis.support and fit.others is analysis.others
    with pytest.raises(ValueError, match="not both"):
        fit_points(model, points, None, config, analysis=analysis, support="auto")
    with pytest.raises(ValueError, match="analysis is of"):
        fit_points(model, torch.as_tensor(points[:100]), None, config, analysis=analysis)


def test_the_default_model_is_the_first_shipped_prior(monkeypatch):
    """default_point_model: the prior of hand models v1-v3 ('geometry_v3') for every scan, one
    view or all round; without its file the v1 prior, without both LISA-full ('default')."""
    from lisa_hand.fitting.points import io
    from lisa_hand.model import trained

    assert io.default_point_model() == "geometry_v3"
    shipped = dict(trained.SHIPPED_MODELS)
    monkeypatch.setitem(trained.SHIPPED_MODELS, "geometry_v3", "missing_v3.pt")
    assert io.default_point_model() == "geometry"
    monkeypatch.setitem(trained.SHIPPED_MODELS, "geometry", "missing.pt")
    assert io.default_point_model() == "default"
    assert shipped["geometry_v3"] == "lisa_geometry_v3.pt"
