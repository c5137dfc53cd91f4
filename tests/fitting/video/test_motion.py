"""The motion fit of ``lisa fit-video`` (lisa_hand.fitting.video.motion) on a synthetic clip:
the template's right hand moving along a smooth pose and translation trajectory 0.5 m in front
of a pinhole camera, its true keypoints projected (with seeded Gaussian pixel noise) as the
detections; the energy's motion terms against closed forms."""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np
import pytest
import torch

from lisa_hand.fitting.outputs.records import posed_keypoints
from lisa_hand.fitting.priors import prior_mean_fingers
from lisa_hand.fitting.stages import template_on
from lisa_hand.fitting.video.config import MotionConfig
from lisa_hand.fitting.video.motion import (
    MotionData,
    MotionEnergy,
    MotionResult,
    _planned_steps,
    fit_motion,
)
from lisa_hand.fitting.video.quality import jitter_mm
from lisa_hand.handmodel.template import load_template

FRAMES, FPS = 30, 25.0
K = torch.tensor([[500.0, 0.0, 320.0], [0.0, 500.0, 240.0], [0.0, 0.0, 1.0]])  # 640 x 480
FAST = MotionConfig(window=12, overlap=3, window_iters=40, refine_iters=80)


pytestmark = pytest.mark.usefixtures("one_thread_per_module")  # the CPU is shared


def trajectory(times: torch.Tensor, dtype: torch.dtype = torch.float32
               ) -> tuple[torch.Tensor, torch.Tensor]:
    """A smooth motion: the palm toward the camera (the template's hand lies in its x-z plane),
    rocking and turning, the fingers curling and opening around the relaxed pose, the wrist
    drifting left, bobbing and receding. -> pose [N, 48], translation [N, 3] metres."""
    relaxed = prior_mean_fingers("relaxed", dtype=dtype)
    pose = torch.zeros(len(times), 48, dtype=dtype)
    translation = torch.zeros(len(times), 3, dtype=dtype)
    for row, t in enumerate(times.tolist()):
        pose[row, :3] = torch.tensor([math.pi / 2 + 0.2 * math.sin(math.pi * t),
                                      0.15 * math.sin(0.8 * math.pi * t), 0.1 * t])
        pose[row, 3:] = relaxed * (1.0 + 0.4 * math.sin(1.2 * math.pi * t))
        translation[row] = torch.tensor([0.09 - 0.05 * t, 0.02 * math.sin(math.pi * t),
                                         0.5 + 0.03 * t])
    return pose, translation


def project(points: torch.Tensor | np.ndarray) -> torch.Tensor:
    points = torch.as_tensor(points, dtype=torch.float32)
    return (points @ K.T)[..., :2] / points[..., 2:]


@dataclass
class Clip:
    template: object
    rest_joints: torch.Tensor  # [16, 3]
    times: torch.Tensor  # [N]
    pose: torch.Tensor  # [N, 48]
    translation: torch.Tensor  # [N, 3]
    keypoints_3d: torch.Tensor  # [N, 21, 3]
    pixels: torch.Tensor  # [N, 21, 2]
    size_px: float

    def data(self, noise_px: float = 0.0, weights: torch.Tensor | None = None) -> MotionData:
        noise = torch.randn(self.pixels.shape, generator=torch.Generator().manual_seed(1))
        return MotionData(K=K, keypoints=self.pixels + noise_px * noise,
                          weights=torch.ones(FRAMES) if weights is None else weights,
                          times=self.times, size_px=self.size_px)

    def fit(self, data: MotionData, temporal: bool = True,
            segments: list | None = None) -> MotionResult:
        segments = [(0, FRAMES, 0, self.pose[0], self.translation[0])] if segments is None \
            else segments
        return fit_motion(self.template, self.rest_joints, None, data, segments, FAST,
                          temporal=temporal)

    def pixel_error(self, result: MotionResult) -> np.ndarray:
        """[N, 21] px between the fitted and the true keypoints, projected."""
        return (project(result.keypoints_3d) - self.pixels).norm(dim=-1).numpy()

    def mpjpe_mm(self, result: MotionResult) -> np.ndarray:
        """[N] root-aligned mean keypoint error, mm."""
        fitted = result.keypoints_3d - result.keypoints_3d[:, :1]
        true = (self.keypoints_3d - self.keypoints_3d[:, :1]).numpy()
        return 1000.0 * np.linalg.norm(fitted - true, axis=-1).mean(-1)


@pytest.fixture(scope="module")
def clip() -> Clip:
    template = template_on(None, torch.device("cpu"))
    rest_joints = template.rest_joints(torch.zeros(1, int(template.num_betas)))[0].float()
    times = torch.arange(FRAMES, dtype=torch.float32) / FPS
    pose, translation = trajectory(times)
    with torch.no_grad():
        keypoints_3d = posed_keypoints(template, rest_joints, None, pose, translation)
    pixels = project(keypoints_3d)
    assert pixels.min() > 100 and pixels[..., 0].max() < 540 and pixels[..., 1].max() < 460
    extent = pixels.amax(1) - pixels.amin(1)
    size = float(extent.norm(dim=-1).median())
    return Clip(template, rest_joints, times, pose, translation, keypoints_3d, pixels, size)


@pytest.fixture(scope="module")
def noisy_fits(clip):
    """The clip with 2 px of noise fitted with and without the motion terms."""
    data = clip.data(noise_px=2.0)
    return clip.fit(data, temporal=True), clip.fit(data, temporal=False)


def test_without_noise_the_fit_reprojects_onto_the_truth(clip):
    result = clip.fit(clip.data())
    error = clip.pixel_error(result)
    assert error.mean(-1).max() < 1.0, error.mean(-1)  # measured 0.40 px
    assert error.max() < 2.0
    # Every frame of the segment fitted: 4 windows of 9 new frames forward from the anchor at
    # row 0, none backward, then the whole segment at once (refine_iters = 2 x window_iters);
    # the progress bar is told as many.
    assert result.iterations == 4 * 40 + 2 * 40
    assert _planned_steps([(0, FRAMES, 0)], FAST) == result.iterations
    assert _planned_steps([(0, FRAMES, 10)], FAST) == (3 + 2) * 40 + 2 * 40  # 19 on, 10 back
    assert np.isfinite(result.pose).all() and np.isfinite(result.translation).all()
    np.testing.assert_allclose(result.translation, clip.translation.numpy(), atol=0.02)


def test_the_motion_terms_steady_a_noisy_track(clip, noisy_fits):
    """2 px of noise: the motion prior cuts the jitter (measured 3.2 against 11.2
    mm/frame^2; the truth's own 0.19) without a worse 3D shape (MPJPE 4.8 against 6.3 mm)."""
    tracked, independent = noisy_fits
    jitter_tracked = np.mean(jitter_mm(tracked.keypoints_3d))
    jitter_independent = np.mean(jitter_mm(independent.keypoints_3d))
    assert jitter_tracked < 0.5 * jitter_independent, (jitter_tracked, jitter_independent)
    assert jitter_independent > 5.0 * np.mean(jitter_mm(clip.keypoints_3d.numpy()))
    error_tracked = clip.mpjpe_mm(tracked).mean()
    error_independent = clip.mpjpe_mm(independent).mean()
    assert error_tracked < error_independent + 0.5, (error_tracked, error_independent)
    assert error_tracked < 8.0
    for result in noisy_fits:  # both still follow the detections
        assert clip.pixel_error(result).mean() < 3.0


def test_frames_without_keypoints_are_carried_by_the_motion_prior(clip):
    gap = slice(13, 17)
    weights = torch.ones(FRAMES)
    weights[gap] = 0.0
    data = clip.data(noise_px=1.0, weights=weights)
    data.keypoints[gap] = 1e4  # what a bridged frame's keypoints are does not matter
    result = clip.fit(data)
    assert np.isfinite(result.pose[gap]).all() and np.isfinite(result.keypoints_3d[gap]).all()
    error = clip.pixel_error(result)[gap].mean(-1)
    assert error.max() < 3.0, error  # measured 1.7 px
    # Holding the last seen frame's pose instead would be further off than that.
    held = (clip.pixels[gap] - clip.pixels[12]).norm(dim=-1).mean(-1).numpy()
    assert held[-1] > 8.0 and (error[1:] < 0.5 * held[1:]).all()
    assert clip.mpjpe_mm(result)[gap].max() < 10.0  # measured 4.5 mm
    np.testing.assert_allclose(result.translation[gap], clip.translation[gap].numpy(),
                               atol=0.015)


def test_rows_outside_the_segments_are_nan(clip):
    data = clip.data()
    result = clip.fit(data, segments=[(5, 20, 10, clip.pose[10], clip.translation[10])])
    fitted = np.zeros(FRAMES, bool)
    fitted[5:20] = True
    for values in (result.pose, result.translation, result.keypoints_3d):
        assert np.isnan(values[~fitted]).all() and np.isfinite(values[fitted]).all()
    assert result.pose.shape == (FRAMES, 48) and result.keypoints_3d.shape == (FRAMES, 21, 3)
    # Rows 11-19 forward and 9-5 backward: one window each, then the refinement.
    assert result.iterations == 40 + 40 + 80
    assert clip.pixel_error(result)[fitted].mean(-1).max() < 1.0


@pytest.mark.parametrize("segment", [
    (5, 20, 20), (5, 20, 4), (25, 31, 26), (10, 5, 7),
    (-1, 5, 0),
])
def test_a_segment_must_hold_its_anchor(clip, segment):
    first, end, anchor = segment
    with pytest.raises(ValueError, match="must hold its anchor"):
        clip.fit(clip.data(), segments=[(first, end, anchor, clip.pose[0],
                                         clip.translation[0])])


# --- the energy's motion terms, in float64 --------------------------------------------------


@pytest.fixture(scope="module")
def exact():
    """The template in float64, its rest joints, 10 frame times at 25 fps."""
    template = load_template()
    assert template.dtype == torch.float64
    rest_joints = template.rest_joints(torch.zeros(1, int(template.num_betas),
                                                   dtype=torch.float64))[0]
    return template, rest_joints, torch.arange(10, dtype=torch.float64) / FPS


def energy(exact, pose, translation, config: MotionConfig, temporal: bool) -> float:
    """The energy of all 10 frames, the detections the hand's own projected keypoints."""
    template, rest_joints, times = exact
    K64 = K.double()
    with torch.no_grad():
        points = posed_keypoints(template, rest_joints, None, pose, translation)
        data = MotionData(K=K64, keypoints=(points @ K64.T)[..., :2] / points[..., 2:],
                          weights=torch.ones(len(times), dtype=torch.float64), times=times,
                          size_px=150.0)
        rows = torch.arange(len(times))
        return float(MotionEnergy(template, rest_joints, None, data, config, temporal)(
            rows, pose, translation, torch.ones(len(times), dtype=torch.bool)))


def held_pose(times: torch.Tensor) -> torch.Tensor:
    pose, _ = trajectory(times[:1], torch.float64)
    return pose.expand(len(times), 48).clone()


def test_constant_velocity_has_no_acceleration_energy(exact):
    """A fixed pose translated at a constant velocity v: every keypoint moves at v, so the
    motion terms add exactly velocity_weight x (W - 1) x |v|^2 and no acceleration."""
    times = exact[2]
    velocity = torch.tensor([0.1, -0.05, 0.02], dtype=torch.float64)
    translation = torch.tensor([0.09, 0.0, 0.5], dtype=torch.float64) + times[:, None] * velocity
    pose = held_pose(times)
    config = MotionConfig()
    alone = energy(exact, pose, translation, config, temporal=False)
    tracked = energy(exact, pose, translation, config, temporal=True)
    steady = energy(exact, pose, translation,
                    replace(config, acceleration_weight=0.0, articulation_weight=0.0), True)
    assert tracked == pytest.approx(steady, rel=1e-12, abs=1e-15)
    assert tracked - alone == pytest.approx(config.velocity_weight * 9 * float(velocity @ velocity),
                                            rel=1e-6)


def test_constant_acceleration_energy(exact):
    """A fixed pose translated with a constant acceleration a: the acceleration term is
    acceleration_weight x (W - 2) x |a|^2, the articulation term (relative to the wrist) 0."""
    times = exact[2]
    accel = torch.tensor([0.8, 0.3, -0.4], dtype=torch.float64)  # m/s^2
    translation = torch.tensor([0.09, 0.0, 0.5], dtype=torch.float64) \
        + 0.5 * times[:, None] ** 2 * accel
    pose = held_pose(times)
    config = MotionConfig(velocity_weight=0.0)
    alone = energy(exact, pose, translation, config, temporal=False)
    tracked = energy(exact, pose, translation, config, temporal=True)
    assert tracked - alone == pytest.approx(config.acceleration_weight * 8 * float(accel @ accel),
                                            rel=1e-6)
    no_articulation = energy(exact, pose, translation, replace(config, articulation_weight=0.0),
                             True)
    assert tracked == pytest.approx(no_articulation, rel=1e-12)


def test_moving_fingers_add_articulation_and_joint_speed(exact):
    """Fingers curling with the wrist still: their acceleration relative to the wrist counts
    (articulation); a joint turning faster than max_joint_speed adds joint_speed_weight x the
    squared excess per step."""
    times = exact[2]
    translation = torch.tensor([0.09, 0.0, 0.5], dtype=torch.float64).expand(10, 3).clone()
    pose, _ = trajectory(times * 3.0, torch.float64)
    pose[:, :3] = pose[0, :3]  # the wrist held, the fingers accelerating
    config = MotionConfig(velocity_weight=0.0, acceleration_weight=0.0, joint_speed_weight=0.0)
    alone = energy(exact, pose, translation, config, temporal=False)
    assert energy(exact, pose, translation, config, True) - alone > 1e-6
    # One finger joint value turning at 30 rad/s, 5 above the limit of 25, nothing else moving.
    spinning = held_pose(times)
    spinning[:, 10] += 30.0 * times
    config = MotionConfig(velocity_weight=0.0, acceleration_weight=0.0, articulation_weight=0.0,
                          depth_articulation_weight=0.0)
    alone = energy(exact, spinning, translation, config, temporal=False)
    tracked = energy(exact, spinning, translation, config, temporal=True)
    assert tracked - alone == pytest.approx(config.joint_speed_weight * 9 * 5.0 ** 2, rel=1e-6)


def test_articulation_splits_along_and_across_the_camera_rays(exact):
    """The fingers curling with the wrist still: the articulation energy is
    articulation_weight x the mean squared wrist-relative acceleration across each keypoint's
    camera ray plus depth_articulation_weight x the same along it (a numpy float64 reference
    from the keypoints' second differences); with equal weights the split sums to the whole."""
    template, rest_joints, times = exact
    translation = torch.tensor([0.09, 0.0, 0.5], dtype=torch.float64).expand(10, 3).clone()
    pose, _ = trajectory(times * 3.0, torch.float64)
    pose[:, :3] = pose[0, :3]
    points = posed_keypoints(template, rest_joints, None, pose, translation).numpy()
    step = 1.0 / FPS
    acceleration = (points[2:] - 2.0 * points[1:-1] + points[:-2]) / step ** 2
    relative = acceleration - acceleration[:, :1]
    ray = points[1:-1] / np.linalg.norm(points[1:-1], axis=-1, keepdims=True)
    along = np.einsum("fkc,fkc->fk", relative, ray) ** 2
    across = (relative ** 2).sum(-1) - along
    assert along.mean() > 0.05 * across.mean() and across.mean() > 0.05 * along.mean()
    quiet = MotionConfig(velocity_weight=0.0, acceleration_weight=0.0, joint_speed_weight=0.0,
                         articulation_weight=0.0, depth_articulation_weight=0.0)
    alone = energy(exact, pose, translation, quiet, temporal=False)
    for w_across, w_along in ((2e-3, 0.0), (0.0, 3e-2), (5e-3, 5e-3)):
        config = replace(quiet, articulation_weight=w_across, depth_articulation_weight=w_along)
        tracked = energy(exact, pose, translation, config, temporal=True)
        expected = w_across * across.mean(-1).sum() + w_along * along.mean(-1).sum()
        assert tracked - alone == pytest.approx(expected, rel=1e-6)


def test_landmark_term_is_the_weighted_direction_misfit(exact):
    """The detector's 3D landmarks (another hand's bones, here the fingers curled further)
    add landmark_weight x the direction misfit of each frame with landmarks (weight 1), none
    where a frame's weight is 0."""
    from lisa_hand.fitting.images.terms import bone_directions, direction_misfit

    template, rest_joints, times = exact
    translation = torch.tensor([0.09, 0.0, 0.5], dtype=torch.float64).expand(10, 3).clone()
    pose, _ = trajectory(times, torch.float64)
    other, _ = trajectory(times * 3.0 + 0.3, torch.float64)
    with torch.no_grad():
        points = posed_keypoints(template, rest_joints, None, pose, translation)
        landmarks = posed_keypoints(template, rest_joints, None, other, translation)
    K64 = K.double()
    present = torch.tensor([1.0] * 6 + [0.0] * 4, dtype=torch.float64)
    data = MotionData(K=K64, keypoints=(points @ K64.T)[..., :2] / points[..., 2:],
                      weights=torch.ones(10, dtype=torch.float64), times=times, size_px=150.0,
                      directions=bone_directions(landmarks), direction_weights=present)
    rows, every = torch.arange(10), torch.ones(10, dtype=torch.bool)
    quiet = MotionConfig(landmark_weight=0.0)
    weighted = replace(quiet, landmark_weight=30.0)
    with torch.no_grad():
        alone = MotionEnergy(template, rest_joints, None, data, quiet, False)(
            rows, pose, translation, every)
        with_landmarks = MotionEnergy(template, rest_joints, None, data, weighted, False)(
            rows, pose, translation, every)
        misfit = direction_misfit(points, bone_directions(landmarks))
    assert float(misfit[:6].sum()) > 1e-4
    assert float(with_landmarks - alone) == pytest.approx(30.0 * float(misfit[:6].sum()),
                                                          rel=1e-9)


def test_landmarks_set_the_lean_along_the_rays_not_the_pixels(clip):
    """Landmarks whose bones lean the other way along the camera's rays (each true bone
    mirrored through the plane across its ray: the same picture, the other depth): the fitted
    bones lean their way where the pixels alone keep the truth's lean, while the keypoints stay
    within 2 % of the hand's size of the detections (a rigid skeleton cannot turn every bone's
    depth over without moving some pixels)."""
    from lisa_hand.fitting.images.terms import bone_directions

    parents = [0, 1, 2, 3, 0, 5, 6, 7, 0, 9, 10, 11, 0, 13, 14, 15, 0, 17, 18, 19]
    ray = clip.keypoints_3d[:, parents] / clip.keypoints_3d[:, parents].norm(dim=-1,
                                                                            keepdim=True)
    true = bone_directions(clip.keypoints_3d)
    mirrored = true - 2.0 * (true * ray).sum(-1, keepdim=True) * ray

    def lean_gap(result: MotionResult) -> float:
        points = torch.from_numpy(result.keypoints_3d).float()
        return float(((bone_directions(points) - mirrored) * ray).sum(-1).abs().mean())

    plain = clip.data(noise_px=1.0)
    data = replace(plain, directions=mirrored, direction_weights=torch.ones(FRAMES))
    without = clip.fit(plain)
    config = replace(FAST, landmark_weight=30.0)
    with_landmarks = fit_motion(clip.template, clip.rest_joints, None, data,
                                [(0, FRAMES, 0, clip.pose[0], clip.translation[0])], config)
    assert lean_gap(without) > 0.5 and lean_gap(with_landmarks) < 0.3 * lean_gap(without)
    assert clip.pixel_error(without).mean() < 1.5
    assert clip.pixel_error(with_landmarks).mean() < 0.02 * clip.size_px


# --- the clip's one skeleton, fitted on every frame -----------------------------------------


@pytest.fixture(scope="module")
def shaped_clip(clip) -> Clip:
    """The clip's motion by a hand of other template betas (seeded, 1.5 standard deviations
    a coefficient at most): another skeleton than the zero betas' the fit starts from."""
    template = clip.template
    generator = torch.Generator().manual_seed(3)
    betas = (torch.rand(int(template.num_betas), generator=generator) * 3.0 - 1.5)
    rest_joints = template.rest_joints(betas[None])[0].float()
    with torch.no_grad():
        keypoints_3d = posed_keypoints(template, rest_joints, betas, clip.pose,
                                       clip.translation)
    return replace(clip, rest_joints=rest_joints, keypoints_3d=keypoints_3d,
                   pixels=project(keypoints_3d))


def _bone_lengths(rest_joints: torch.Tensor) -> torch.Tensor:
    from lisa_hand.skeleton import PARENTS

    return (rest_joints[1:] - rest_joints[list(PARENTS[1:])]).norm(dim=-1)


def test_the_skeleton_is_fitted_on_every_frame(shaped_clip):
    """Started from the zero betas' skeleton, the fit with the skeleton free ends with the true
    one's proportions (its bone lengths up to one scale, which pixels cannot tell from depth:
    measured 0.36 mm off against 0.78), nearer the detections (1 px of noise: 0.96 px against
    1.10) and the true keypoints (MPJPE 9.5 against 13.2 mm); the skeleton it returns is its
    betas'."""
    clip = shaped_clip
    template = clip.template
    zeros = torch.zeros(int(template.num_betas))
    start = template.rest_joints(zeros[None])[0].float()
    data = clip.data(noise_px=1.0)
    segments = [(0, FRAMES, 0, clip.pose[0], clip.translation[0])]
    config = replace(FAST, refine_iters=300, betas_weight=0.01)
    fixed = fit_motion(template, start, zeros, data, segments, replace(config, betas_lr=0.0))
    free = fit_motion(template, start, zeros, data, segments, replace(config, betas_lr=0.1))
    torch.testing.assert_close(fixed.betas, zeros)
    torch.testing.assert_close(fixed.rest_joints, start)
    torch.testing.assert_close(free.rest_joints, template.rest_joints(free.betas[None])[0]
                               .float())
    true_bones = _bone_lengths(clip.rest_joints)

    def proportion_error(result: MotionResult) -> float:
        bones = _bone_lengths(result.rest_joints)
        scale = (bones * true_bones).sum() / (bones * bones).sum()  # least squares
        return float((scale * bones - true_bones).abs().mean())

    assert proportion_error(free) < 0.6 * proportion_error(fixed)
    assert clip.pixel_error(free).mean() < 0.92 * clip.pixel_error(fixed).mean()
    assert clip.mpjpe_mm(free).mean() < 0.8 * clip.mpjpe_mm(fixed).mean()
    # Each frame alone (the independent reference) keeps the keyframe's skeleton.
    alone = fit_motion(template, start, zeros, data, segments, replace(config, betas_lr=0.1),
                       temporal=False)
    torch.testing.assert_close(alone.betas, zeros)


def test_segments_share_the_final_pass_and_the_skeleton(clip):
    """Two segments: with the skeleton fixed the final pass over both at once gives what each
    alone gives (they share no term); with it free, one skeleton for both, the final pass
    counted once."""
    data = clip.data(noise_px=1.0)
    template = clip.template
    zeros = torch.zeros(int(template.num_betas))
    first = (0, 14, 3, clip.pose[3], clip.translation[3])
    second = (16, FRAMES, 20, clip.pose[20], clip.translation[20])
    fixed = replace(FAST, betas_lr=0.0)
    both = fit_motion(template, clip.rest_joints, zeros, data, [first, second], fixed)
    for segment in (first, second):
        alone = fit_motion(template, clip.rest_joints, zeros, data, [segment], fixed)
        rows = slice(segment[0], segment[1])
        np.testing.assert_allclose(both.pose[rows], alone.pose[rows], atol=1e-5)
        np.testing.assert_allclose(both.translation[rows], alone.translation[rows], atol=1e-6)
    # Windows: 2 forward and 1 back from row 3, 1 forward and 1 back from row 20.
    assert both.iterations == _planned_steps([first, second], fixed) == (3 + 2) * 40 + 80
    free = fit_motion(template, clip.rest_joints, zeros, data, [first, second],
                      replace(FAST, betas_lr=0.1))
    assert free.iterations == both.iterations
    assert float(free.betas.abs().max()) > 1e-3  # moved, once for both
