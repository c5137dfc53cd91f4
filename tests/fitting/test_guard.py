"""The image fit's geometry guard and shape priors on closed forms: pieces and areas of spheres,
the principal subspace of hand-made codes, the hand size of a known skeleton; then the guard
inside :func:`fit_images` (pass, fallback to a pose-and-colour fit, and the last resort)."""

from __future__ import annotations

import dataclasses
import json
import math

import numpy as np
import pytest
import torch
import trimesh

from lisa_hand.fitting.images.config import FitImagesConfig
from lisa_hand.fitting.images.fit import fit_images
from lisa_hand.fitting.images.guard import (
    MIN_PIECE_FRACTION,
    GuardReport,
    guard_mesh,
    surface_guard,
    surface_pieces,
)
from lisa_hand.fitting.images.keypoint_stage import fit_keypoints
from lisa_hand.fitting.images.shape_prior import HandSizePrior, ShapeSpace, hand_size
from lisa_hand.skeleton.tree import PARENTS
from tests.fitting.image_scene import FAST_RENDER, load_float_template, make_scene, tiny_model

RADIUS = 0.05


def sphere(radius: float = RADIUS, centre=(0.0, 0.0, 0.0), subdivisions: int = 3):
    mesh = trimesh.creation.icosphere(subdivisions, radius)
    mesh.apply_translation(centre)
    return mesh


def joined(*meshes):
    return trimesh.util.concatenate(list(meshes))


def test_pieces_and_area_of_spheres():
    one = sphere()
    areas, total = surface_pieces(one)
    assert len(areas) == 1 and total == pytest.approx(4 * math.pi * RADIUS**2, rel=0.01)
    two = joined(sphere(), sphere(0.02, (0.2, 0.0, 0.0)))
    areas, total = surface_pieces(two)
    assert len(areas) == 2 and areas[0] > areas[1]
    assert areas[1] == pytest.approx(4 * math.pi * 0.02**2, rel=0.01)
    # Triangles written with their own vertices (nothing shared) are still one piece.
    soup = trimesh.Trimesh(one.vertices[one.faces].reshape(-1, 3),
                           np.arange(3 * len(one.faces)).reshape(-1, 3), process=False)
    assert len(surface_pieces(soup)[0]) == 1
    assert surface_pieces(trimesh.Trimesh(np.zeros((0, 3)), np.zeros((0, 3), int)))[1] == 0.0


def test_guard_passes_a_similar_surface_and_fails_a_grown_one():
    reference = sphere()
    same = surface_guard(reference, sphere(RADIUS * 1.04))  # area x 1.0816
    assert same.passed and same.pieces == 1
    assert same.area_ratio == pytest.approx(1.04**2, rel=1e-3)
    grown = surface_guard(reference, sphere(RADIUS * 1.06))  # area x 1.1236
    assert not grown.passed and grown.pieces == 1
    assert any("the area changed by +12.4 % (allowed: 10 %)" in note for note in grown.notes)
    assert surface_guard(reference, sphere(RADIUS * 1.06), max_area_change=0.2).passed


def test_floaters_fail_and_specks_are_ignored():
    reference = sphere()
    floater = surface_guard(reference, joined(sphere(RADIUS * 0.97), sphere(0.01, (0.2, 0, 0))))
    # 4 % of the area in a second piece: the area is fine, the piece is not.
    assert floater.pieces == 2 and not floater.passed
    assert any("1 floating piece(s) more" in note for note in floater.notes)
    speck_radius = 0.5 * RADIUS * math.sqrt(MIN_PIECE_FRACTION)  # a quarter of the threshold
    speck = surface_guard(reference, joined(sphere(), sphere(speck_radius, (0.2, 0, 0), 1)))
    assert speck.passed and speck.pieces == 1
    assert any(note.startswith("1 speck(s) below 0.1 % of the area ignored")
               for note in speck.notes)
    # A reference in two pieces allows two.
    pair = joined(sphere(), sphere(RADIUS, (0.2, 0, 0)))
    assert surface_guard(pair, pair).passed and surface_guard(pair, pair).pieces == 2


def test_extra_specks_that_add_no_floating_area_pass():
    # An untrained field's noise: the reference has two pieces of 0.2 %, the fit four of 0.105 %
    # (0.40 % and 0.42 % of the area outside the largest piece, +0.02 % within 10 % of 0.40 %):
    # more pieces, the same floaters.
    def noisy(fraction, count):
        radius = RADIUS * math.sqrt(fraction)
        return joined(sphere(), *[sphere(radius, (0.2, 0.05 * index, 0), 2)
                                  for index in range(count)])

    report = surface_guard(noisy(0.002, 2), noisy(0.00105, 4))
    assert report.pieces == 5 and report.passed
    assert any("2 piece(s) more than the keypoint-stage hand, but no more area outside the "
               "largest piece" in note for note in report.notes)
    grown = surface_guard(noisy(0.002, 2), noisy(0.004, 4))  # 1.6 %: the floaters grew
    assert grown.pieces == 5 and not grown.passed
    # A clean reference (specks of 0.03 % only) allows no counted floater at all.
    clean = noisy(0.0001, 3)
    assert not surface_guard(clean, joined(noisy(0.0001, 3), sphere(0.002, (0, 0.2, 0)))).passed


def test_an_empty_fit_fails_and_the_report_is_json():
    empty = trimesh.Trimesh(np.zeros((0, 3)), np.zeros((0, 3), int))
    report = surface_guard(sphere(), empty)
    assert report.pieces == 0 and report.area_ratio == 0.0 and not report.passed
    assert "the fitted surface is empty" in report.notes
    values = json.loads(json.dumps(report.to_dict()))
    assert values["pieces"] == 0 and values["passed"] is False and values["notes"][0]
    assert isinstance(report, GuardReport) and isinstance(report.notes, tuple)
    with pytest.raises(ValueError, match="max_area_change must be >= 0"):
        surface_guard(sphere(), sphere(), max_area_change=-0.1)
    with pytest.raises(TypeError, match="fitted_mesh must be a mesh"):
        surface_guard(sphere(), object())


def test_shape_space_of_hand_made_codes():
    # Four codes: the mean plus or minus 3 along e0 and plus or minus 1 along e1 (D = 5).
    mean = torch.tensor([0.1, 0.2, 0.0, -0.1, 0.3])
    axes = torch.eye(5)
    codes = torch.stack([mean + 3 * axes[0], mean - 3 * axes[0], mean + axes[1], mean - axes[1]])
    space = ShapeSpace.from_codes(codes)
    assert space.num_dims == 2  # four codes: at most three directions, two with any spread
    assert torch.allclose(space.mean, mean)
    assert torch.allclose(space.std, torch.tensor([math.sqrt(18 / 3), math.sqrt(2 / 3)]))
    assert torch.allclose(space.directions.abs(), axes[:2], atol=1e-6)
    # Every code is 1.2247 std from the mean along its direction: that is the range.
    edge = 3 / math.sqrt(6)
    assert torch.allclose(space.low, torch.full((2,), -edge), atol=1e-5)
    assert torch.allclose(space.high, torch.full((2,), edge), atol=1e-5)
    assert torch.allclose(space.clamp(torch.tensor([5.0, -0.5])), torch.tensor([edge, -0.5]))
    assert torch.allclose(space.clamp(torch.tensor([5.0, -9.0]), margin=1.0),
                          torch.tensor([edge + 1, -edge - 1]))
    coefficients, offset = space.split(codes[0])
    assert torch.allclose(coefficients.abs(), torch.tensor([3 / math.sqrt(6), 0.0]), atol=1e-6)
    assert offset.abs().max() < 1e-6
    outside = mean + 0.5 * axes[3]
    coefficients, offset = space.split(outside)
    assert torch.allclose(offset, 0.5 * axes[3]) and coefficients.abs().max() < 1e-6
    assert torch.allclose(space.code(coefficients, offset), outside, atol=1e-6)
    assert space.mahalanobis(codes[2]) == pytest.approx(math.sqrt(1.5), rel=1e-5)
    assert ShapeSpace.from_codes(codes, max_dims=1).num_dims == 1
    with pytest.raises(ValueError, match="needs >= 2 training codes"):
        ShapeSpace.from_codes(codes[:1])


def test_hand_size_and_its_prior():
    # Every bone of a skeleton along x, 1 cm long: 15 bones, 0.15 m.
    joints = torch.zeros(1, 16, 3)
    for joint, parent in enumerate(PARENTS):
        if parent >= 0:
            joints[0, joint] = joints[0, parent] + torch.tensor([0.01, 0.0, 0.0])
    assert float(hand_size(joints)[0]) == pytest.approx(0.15, rel=1e-6)
    template = load_float_template()
    prior = HandSizePrior.from_template(template)
    at_mean = float(hand_size(template.rest_joints(torch.zeros(1, 10)))[0])
    assert prior.mean_m == pytest.approx(at_mean, abs=0.003)  # size is linear in the betas
    assert 0.70 < prior.mean_m < 0.75 and 0.055 < prior.std_m / prior.mean_m < 0.067
    bigger = joints * (prior.mean_m + 2 * prior.std_m) / 0.15
    assert float(prior.energy(bigger)[0]) == pytest.approx(4.0, rel=1e-4)


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    from lisa_hand.utils.threads import cpu_threads

    with cpu_threads(1):
        yield make_scene(tmp_path_factory)


FAST = dict(keypoint_iters=30, color_iters=6, num_rays=64, render=FAST_RENDER, restarts=3,
            rotation_pool=64, guard_resolution=24)


@pytest.mark.usefixtures("one_thread")
def test_fit_images_guard_passes_and_is_recorded(scene):
    result = fit_images(scene["model"], scene["views"], FitImagesConfig(**FAST))
    assert result.guard is not None and result.guard.passed
    assert set(result.guard_attempts) == {"color"} and result.notes == []
    guard = result.params.extra["guard"]
    assert guard["passed"] and guard["fallback"] == "none" and guard["pieces"] >= 1
    assert abs(guard["area_ratio"] - 1.0) <= 0.10 and guard["seconds"] > 0
    off = fit_images(scene["model"], scene["views"], FitImagesConfig(**FAST, guard=False))
    assert off.guard is None and "guard" not in off.params.extra
    assert off.notes and "surface guard is off" in off.notes[0]


def assert_same_surface(reused, fresh, tolerance: float = 1e-5) -> None:
    """Two meshes of one surface (the guard's reused, a fresh extraction): every vertex of
    each on a vertex of the other (within ``tolerance`` metres: a left hand's is the right
    hand's mirrored, its grid rounded differently, ~1 um), the same area (to 1e-3: marching
    cubes may split a mirrored ambiguous cell the other way), the same colours and skinning
    weights at the matched vertices."""
    from scipy.spatial import cKDTree

    distance, match = cKDTree(fresh.vertices).query(reused.vertices)
    assert distance.max() < tolerance
    assert cKDTree(reused.vertices).query(fresh.vertices)[0].max() < tolerance
    assert surface_pieces(reused)[1] == pytest.approx(surface_pieces(fresh)[1], rel=1e-3)
    np.testing.assert_allclose(reused.colors.astype(int), fresh.colors[match].astype(int),
                               atol=1)
    np.testing.assert_allclose(reused.skin_weights, fresh.skin_weights[match], atol=1e-4)


@pytest.mark.usefixtures("one_thread")
@pytest.mark.parametrize("side", ["right", "left"])
def test_the_written_mesh_is_the_guards_mesh(scene, side):
    from lisa_hand.fitting.images.folder import fitted_mesh, output_surface
    from lisa_hand.inference import mesh_hand

    model = scene["model"]
    result = fit_images(model, scene["views"], FitImagesConfig(**FAST), side=side)
    assert set(result.surface_meshes) == {"start", "returned"}
    assert result.surface_resolution == FAST["guard_resolution"] == 24
    reused = fitted_mesh(model, result, 24)
    fresh = mesh_hand(model, result.params, 24)
    assert_same_surface(reused, fresh)
    # Another resolution: extracted, not the guard's.
    other = fitted_mesh(model, result, 20)
    assert_same_surface(other, mesh_hand(model, result.params, 20))
    # The written mesh's figures against the guard's start: as with the start meshed again.
    cached = output_surface(model, result, reused, 24)
    again = output_surface(model, dataclasses.replace(result, surface_meshes={}), fresh, 24)
    assert cached["pieces"] == again["pieces"] and cached["passed"] == again["passed"]
    assert cached["area_ratio"] == pytest.approx(again["area_ratio"], rel=1e-3)
    off = fit_images(model, scene["views"], FitImagesConfig(**FAST, guard=False), side=side)
    assert off.surface_meshes == {} and off.surface_resolution is None


def code_sensitive_model():
    """The tiny model with random weights from the shape code into its SDF MLP (at the
    geometric initialisation they are 0: the code would not change the surface)."""
    model = tiny_model()
    weight = model.field.sdf_mlp.cond_weight
    with torch.no_grad():
        weight[:, -model.config.shape_dim:] = torch.randn(
            weight[:, -model.config.shape_dim:].shape, generator=torch.Generator().manual_seed(0))
    return model


@pytest.fixture(scope="module")
def wreck_start(scene):
    from lisa_hand.utils.threads import cpu_threads

    with cpu_threads(1):  # the start of the scenarios below: fingers restarted only if off
        return fit_keypoints(scene["views"], FitImagesConfig(**FAST, finger_restart_px=2.0))[0]


@pytest.mark.usefixtures("one_thread")
def test_a_grown_colour_fit_is_shrunk_back(scene, wreck_start):
    model, views = code_sensitive_model(), scene["views"]
    # A free shape code at a moderate rate grows the surface by ~25 %; a quarter of the change
    # of pose and shape passes (the shrinking only meshes: no refit).
    result = fit_images(model, views, FitImagesConfig(**FAST, shape_fit="free", code_lr=0.004),
                        start=wreck_start)
    attempts = result.guard_attempts
    assert list(attempts) == ["color", "shrink_0.5", "shrink_0.25"]
    ratios = [attempts[name].area_ratio for name in attempts]
    assert ratios[0] > 1.15 and ratios[0] > ratios[1] > ratios[2] and ratios[2] < 1.1
    assert result.guard is attempts["shrink_0.25"] and result.guard.passed
    assert result.params.extra["guard"]["fallback"] == "shrink_0.25"
    assert "shrunk to 25 %, which passed" in result.notes[0]
    from lisa_hand.fitting.images.folder import fitted_mesh
    from lisa_hand.inference import mesh_hand

    assert_same_surface(fitted_mesh(model, result, 24), mesh_hand(model, result.params, 24))
    # A quarter of the way from the start's shape code, and the skeleton follows the betas.
    assert float((result.params.shape_code - model.mean_shape_code()).norm()) > 0
    template = load_float_template()
    assert torch.allclose(result.params.rest_joints,
                          template.rest_joints(result.params.betas[None])[0], atol=1e-6)


@pytest.mark.usefixtures("one_thread")
def test_a_wrecked_colour_fit_falls_back(scene, wreck_start):
    model, views, start = code_sensitive_model(), scene["views"], wreck_start
    # A free shape code at a high rate makes the surface vanish; shrinking does not save it
    # (guard_shrink=() skips it); the fallback fits pose and colour only, and passes.
    wreck = FitImagesConfig(**FAST, shape_fit="free", code_lr=0.3, guard_shrink=())
    result = fit_images(model, views, wreck, start=start)
    first = result.guard_attempts["color"]
    assert not first.passed and first.pieces == 0 and first.area_ratio == 0.0
    assert list(result.guard_attempts) == ["color", "fixed_shape"]
    assert result.params.extra["guard"]["fallback"] == "fixed_shape"
    assert result.guard is result.guard_attempts["fixed_shape"] and result.guard.passed
    assert abs(result.guard.area_ratio - 1.0) < 0.01 and result.guard.pieces >= 1
    assert result.notes[0].startswith("the colour stage failed the surface guard (the fitted "
                                      "surface is empty; the area changed by -100.0 %")
    assert torch.equal(result.params.shape_code, model.mean_shape_code())
    assert torch.equal(result.params.betas, start.betas)
    assert result.reports["color_fixed_shape"].stage == "color_fixed_shape"
    stages = {record["stage"] for record in result.history}
    assert stages == {"color", "color_fixed_shape"}  # the keypoint stage was given
    assert surface_pieces(guard_mesh(model, result.params, 24))[1] > 0
    # No area change allowed at all: the fallback (its pose moved) fails too, and the start's
    # geometry is kept with the fallback's colour.
    strict = fit_images(model, views, FitImagesConfig(**FAST, shape_fit="free", code_lr=0.3,
                                                      max_area_change=0.0), start=start)
    assert list(strict.guard_attempts) == ["color", "shrink_0.5", "shrink_0.25", "fixed_shape"]
    assert strict.params.extra["guard"]["fallback"] == "start_geometry"
    assert not strict.guard_attempts["fixed_shape"].passed
    assert torch.equal(strict.params.pose, start.pose) and strict.guard.area_ratio == 1.0
    assert strict.guard.passed and len(strict.notes) == 1
    assert "the keypoint stage's geometry is kept" in strict.notes[0]
    assert not torch.equal(strict.params.color_code, model.mean_color_code())
    from lisa_hand.fitting.images.folder import fitted_mesh
    from lisa_hand.inference import mesh_hand

    assert strict.surface_meshes["returned"] is strict.surface_meshes["start"]
    assert_same_surface(fitted_mesh(model, strict, 24), mesh_hand(model, strict.params, 24))
