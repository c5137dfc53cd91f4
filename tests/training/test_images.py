"""``train_images`` on the tiny dataset: it learns colours, starts from a prior's geometry, keeps
the poses fixed for the first 10% of the steps, resumes exactly and refuses bad settings."""

from __future__ import annotations

import dataclasses
import json
import os
import signal

import pytest
import torch

from lisa_hand.data.datasets import RayFrames, read_frame_table
from lisa_hand.fields.config import FieldConfig
from lisa_hand.model.checkpoint import IMAGE_KIND, load_checkpoint
from lisa_hand.model.lisa import LisaModel, region_bounds
from lisa_hand.render.renderer import calibrate
from lisa_hand.skeleton import forward_kinematics
from lisa_hand.training.image_model import select_frame
from lisa_hand.training.images import (
    ImageTrainConfig,
    build_image_model,
    load_image_data,
    load_image_model,
    pose_refine_step,
    resolve_prior,
    train_images,
)
from lisa_hand.training.prior import load_prior, train_prior

from .conftest import TINY_FIELD, tiny_image_config, tiny_prior_config, tiny_trainer


def _log(run) -> list[dict]:
    return [json.loads(line) for line in (run / "log.jsonl").read_text().splitlines()]


def _mean(entries: list[dict], key: str) -> float:
    return sum(entry["losses"][key] for entry in entries) / len(entries)


@pytest.fixture(scope="module")
def prior_run(tiny_data, tmp_path_factory):
    run = tmp_path_factory.mktemp("prior")
    train_prior(tiny_data, run, tiny_prior_config(trainer=tiny_trainer(steps=6)))
    return run


def test_tiny_image_run_lowers_the_colour_loss(tiny_data, tmp_path):
    config = tiny_image_config(trainer=tiny_trainer(steps=40))
    result = train_images(tiny_data, tmp_path, config)
    assert result.status == "completed"
    log = _log(tmp_path)
    assert set(log[0]["losses"]) == {"total", "col", "eik", "w", "reg", "beta"}
    assert _mean(log[-5:], "col") < 0.75 * _mean(log[:5], "col")
    assert _mean(log[-5:], "total") < 0.8 * _mean(log[:5], "total")

    ckpt = load_checkpoint(tmp_path / "last.pt")
    assert ckpt.extra["kind"] == IMAGE_KIND and ckpt.extra["prior"] is None
    assert ckpt.extra["camera_names"] == ["cam000", "cam001", "cam002"]
    model = load_image_model(tmp_path)
    assert model.frame_keys == ["s000/f000", "s000/f001", "s001/f000", "s001/f001"]
    for key, value in model.state_dict().items():
        assert torch.equal(value, ckpt.model[key]), key
    gain, bias = model.mean_calibration()
    assert torch.allclose(gain, model.gain.mean(0)) and torch.allclose(bias, model.bias.mean(0))
    assert not torch.equal(model.gain, torch.ones_like(model.gain))  # the calibration is learned


def _probe(frame: int, table, model: LisaModel, shape_code: torch.Tensor) -> torch.Tensor:
    generator = torch.Generator().manual_seed(5)
    points = torch.rand(1, 200, 3, generator=generator) * torch.tensor([0.16, 0.06, 0.1]) \
        + torch.tensor([0.0, -0.03, -0.05])
    subject = table.frame_subject[frame : frame + 1]
    with torch.no_grad():
        state = model.prepare(table.pose[frame : frame + 1], table.translation[frame : frame + 1],
                              table.rest_joints[subject], shape_code[None],
                              torch.zeros(1, model.config.color_dim) if model.config.use_color
                              else None)
        return model.field(state, points, with_color=False).sdf


def test_image_model_starts_from_the_prior_geometry(tiny_data, prior_run):
    prior = load_prior(prior_run)
    # field_from_prior: the image run takes the prior's geometry settings (sdf_hidden 32).
    config = tiny_image_config(field=FieldConfig(**{**TINY_FIELD, "sdf_hidden": 16}))
    resolved, prior_model, _ = resolve_prior(config, prior_run)
    assert resolved.field.sdf_hidden == 32 and resolved.field.color_hidden == 16
    assert resolved.field.use_color
    rays = RayFrames(tiny_data, "train", max_band_px=2)
    model, unseen = build_image_model(rays, resolved, prior_model)
    assert unseen == []
    table = read_frame_table(tiny_data, "train")
    for frame in (0, 3):
        subject = int(table.frame_subject[frame])
        sdf_prior = _probe(frame, table, prior.field, prior.shape_codes.weight[subject])
        sdf_image = _probe(frame, table, model.field, model.shape_codes.weight[subject])
        assert torch.equal(sdf_image, sdf_prior)
    # A subject the prior has not seen starts from the prior's mean code.
    val = RayFrames(tiny_data, "val", max_band_px=2)
    model_val, unseen = build_image_model(val, resolved, prior_model)
    assert unseen == ["s002"]
    assert torch.allclose(model_val.shape_codes.weight[0], prior.shape_codes.weight.mean(0))
    # Without a prior the geometry is the fresh initialisation, not the prior's.
    fresh, _ = build_image_model(rays, resolved, None)
    assert not torch.equal(_probe(0, table, fresh.field, fresh.shape_codes.weight[0]),
                           _probe(0, table, prior.field, prior.shape_codes.weight[0]))


def test_train_images_with_a_prior_records_it(tiny_data, prior_run, tmp_path):
    config = tiny_image_config(trainer=tiny_trainer(steps=2))
    train_images(tiny_data, tmp_path, config, prior=prior_run)
    ckpt = load_checkpoint(tmp_path / "last.pt")
    assert ckpt.extra["prior"] == str(prior_run)
    strict = dataclasses.replace(config, field_from_prior=False,
                                 field=FieldConfig(**{**TINY_FIELD, "sdf_hidden": 16}))
    with pytest.raises(ValueError, match=r"its field differs in \['sdf_hidden'\]"):
        train_images(tiny_data, tmp_path / "strict", strict, prior=prior_run)


def test_pose_refinement_starts_after_ten_percent_of_the_steps(tiny_data, tmp_path):
    config = tiny_image_config(trainer=tiny_trainer(steps=20))
    assert pose_refine_step(config) == 2
    assert pose_refine_step(tiny_image_config(trainer=tiny_trainer(steps=25))) == 3
    offsets = []

    def record(info):
        model = info.trainer.model
        offsets.append((float(model.pose_offsets.detach().abs().max()),
                        float(model.translation_offsets.detach().abs().max())))

    train_images(tiny_data, tmp_path, config, hooks=[record])
    assert offsets[0] == offsets[1] == (0.0, 0.0)  # steps 0 and 1: the given poses
    assert all(pose > 0 and translation > 0 for pose, translation in offsets[2:])
    assert load_checkpoint(tmp_path / "last.pt").model["pose_offsets"].abs().max() > 0

    fixed = []
    no_translation = tiny_image_config(trainer=tiny_trainer(steps=4), refine_translation=False,
                                       pose_refine_start=0.5)
    train_images(tiny_data, tmp_path / "pose_only", no_translation, hooks=[
        lambda info: fixed.append(info.trainer.model.translation_offsets.detach().abs().max())])
    assert all(value == 0 for value in fixed)


def _stop_at(step: int):
    def hook(info):
        if info.step == step:
            os.kill(os.getpid(), signal.SIGINT)

    return hook


def test_resume_equals_an_uninterrupted_run(tiny_data, tmp_path):
    config = tiny_image_config(trainer=tiny_trainer(steps=10, lr_schedule="cosine",
                                                    checkpoint_every=3))
    train_images(tiny_data, tmp_path / "whole", config)
    first = train_images(tiny_data, tmp_path / "part", config, hooks=[_stop_at(4)])
    assert first.status == "interrupted" and first.steps_done == 5
    train_images(tiny_data, tmp_path / "part", config)
    whole = load_checkpoint(tmp_path / "whole/last.pt").model
    part = load_checkpoint(tmp_path / "part/last.pt").model
    for key in whole:
        assert torch.allclose(whole[key], part[key], atol=1e-6, rtol=0), key
    assert float(whole["pose_offsets"].abs().max()) > 0


def test_calibration_changes_the_hand_only():
    rgb = torch.tensor([[0.2, 0.4, 0.6], [0.0, 0.0, 0.0], [0.3, 0.3, 0.3]])
    opacity = torch.tensor([0.5, 0.0, 1.0])
    gain = torch.tensor([2.0, 1.0, 0.5])
    bias = torch.tensor([0.1, 0.0, -0.1])
    background = torch.tensor([0.0, 0.0, 1.0])
    out = calibrate(rgb, opacity, gain, bias, background)
    expected = torch.tensor([[0.45, 0.4, 0.75], [0.0, 0.0, 1.0], [0.7, 0.3, 0.05]])
    assert torch.allclose(out, expected, atol=1e-6)


def test_select_frame_and_region_bounds(tiny_data):
    table = read_frame_table(tiny_data, "train")
    model = LisaModel(FieldConfig(**TINY_FIELD))
    codes = torch.randn(2, 8, generator=torch.Generator().manual_seed(0)) * 0.1
    state = model.prepare(table.pose[:2], table.translation[:2], table.rest_joints[[0, 0]],
                          codes, codes)
    points = torch.rand(2, 50, 3, generator=torch.Generator().manual_seed(1)) * 0.15 - 0.02
    with torch.no_grad():
        both = model.field(state, points)
        second = model.field(select_frame(state, 1), points[1:])
    assert torch.allclose(second.sdf, both.sdf[1:], atol=1e-6)
    assert torch.allclose(second.rgb, both.rgb[1:], atol=1e-6)
    low, high = region_bounds(state, model)
    joints = forward_kinematics(table.pose[:2], table.rest_joints[0], table.translation[:2]).joints
    margin = model.config.palm_region_radius
    assert bool((joints >= low[:, None] + margin - 1e-6).all())
    assert bool((joints <= high[:, None] - margin + 1e-6).all())
    # Points outside the box are outside every region.
    outside = torch.cat([low[:, None] - 1e-3, high[:, None] + 1e-3], dim=1)
    with torch.no_grad():
        assert not bool(model.field(state, outside).region_mask.any())


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        (dict(num_rays=100, num_frames=3), "num_rays .* must be a multiple of num_frames"),
        (dict(band_px=5, max_band_px=4), "band_px .* must not exceed max_band_px"),
        (dict(field=FieldConfig(use_color=False)), "use_color must be true"),
        (dict(beta_init=1e-4, beta_min=1e-4), "beta_init .* must be > beta_min"),
        (dict(background=(0.0, 2.0, 0.0)), "background must be 3 values in"),
        (dict(pose_refine_start=1.5), "pose_refine_start must be in"),
        (dict(lambda_col=-1.0), "lambda_col must be a finite number >= 0"),
        (dict(skinning_points=0), "lambda_w > 0 needs skinning_points"),
        (dict(skinning_points=0, lambda_w=0.0, lambda_surface=1.0),
         "lambda_surface > 0 needs skinning_points"),
        (dict(lambda_surface=-1.0), "lambda_surface must be a finite number >= 0"),
        (dict(trainer=tiny_trainer(grad_sync="ddp")), "needs trainer.find_unused_parameters"),
    ],
)
def test_bad_config_values(kwargs, message):
    with pytest.raises(ValueError, match=message):
        ImageTrainConfig(**kwargs)


def test_missing_dataset(tmp_path):
    with pytest.raises(FileNotFoundError, match="no such dataset folder"):
        train_images(tmp_path / "nowhere", tmp_path / "run", tiny_image_config())
    with pytest.raises(FileNotFoundError, match="no checkpoint in this run folder"):
        train_images(tmp_path, tmp_path / "run", tiny_image_config(), prior=tmp_path)


@pytest.mark.parametrize("shading", ["none", "headlight", "camera_light"])
def test_batched_step_computes_the_per_frame_losses(tiny_data, shading):
    # One pass for every frame (grouped callbacks, skinning points without the gradient pass)
    # against frame after frame: the same loss terms and gradients (deterministic samples);
    # with headlight shading, the normals from the grouped SDF too.
    from lisa_hand.render import RenderConfig
    from lisa_hand.training.images import sample_image_batch

    render = RenderConfig(sampler="sphere_traced", num_samples=12, num_samples_extra=4)
    config = tiny_image_config(render=render, num_frames=2, shading=shading)
    rays, scans = load_image_data(tiny_data, config)
    model, _ = build_image_model(rays, config)
    model = model.double()
    batch = sample_image_batch(rays, scans, config, torch.Generator().manual_seed(1))
    batch = batch.to("cpu", torch.float64)
    results = {}
    for batched in (False, True):
        model.zero_grad()
        terms = model(batch, render=render, batched=batched)
        sum(terms[name] for name in ("col", "eik", "w", "surf")).backward()
        results[batched] = ({k: v.detach() for k, v in terms.items()},
                            {n: p.grad.clone() for n, p in model.named_parameters()
                             if p.grad is not None})
    (terms_a, grads_a), (terms_b, grads_b) = results[False], results[True]
    assert float(terms_a["col"]) > 0 and float(terms_a["w"]) > 0 and float(terms_a["surf"]) > 0
    if shading != "none":  # the colour loss reaches the shading's parameters
        assert float(grads_a["shading.diffuse_raw"].abs().sum()) > 0
    if shading == "camera_light":  # and the light's direction, through the rays' rotations
        assert float(grads_a["shading.light_raw"].abs().sum()) > 0
    for name in terms_a:
        torch.testing.assert_close(terms_b[name], terms_a[name], rtol=1e-9, atol=1e-12, msg=name)
    assert grads_a.keys() == grads_b.keys()
    for name in grads_a:
        torch.testing.assert_close(grads_b[name], grads_a[name], rtol=1e-7, atol=1e-12, msg=name)


def test_surface_term_is_the_mean_abs_sdf_at_the_scan_points(tiny_data, prior_run):
    # L_surf of a batch against the model's SDF evaluated afresh (LisaModel.forward, float64)
    # at the batch's scan points, each frame with its own pose, skeleton and shape code.
    from lisa_hand.training.images import sample_image_batch

    config = tiny_image_config(lambda_w=0.0, lambda_surface=100.0)
    resolved, prior_model, _ = resolve_prior(config, prior_run)
    rays, scans = load_image_data(tiny_data, resolved)
    assert scans is not None  # read for L_surf although L_w is off
    model, _ = build_image_model(rays, resolved, prior_model)
    model = model.double()
    batch = sample_image_batch(rays, scans, resolved, torch.Generator().manual_seed(2))
    batch = batch.to("cpu", torch.float64)
    terms = model(batch, render=resolved.render, batched=True)
    r = batch.rays
    shape_codes, color_codes = model.shape_codes(r.subject_index), model.color_codes(
        r.subject_index)
    with torch.no_grad():
        sdf = torch.cat([model.field(batch.skin_points[f:f + 1], r.pose[f:f + 1],
                                     r.translation[f:f + 1], r.rest_joints[f:f + 1],
                                     shape_codes[f:f + 1], color_codes[f:f + 1],
                                     with_color=False).sdf[0]
                         for f in range(r.num_frames)])
    assert sdf.shape == (batch.skin_points.shape[0] * batch.skin_points.shape[1],)
    expected = sdf.abs().mean()
    assert float(expected) > 1e-4  # a prior of 6 steps: the scan is not yet its zero level
    torch.testing.assert_close(terms["surf"].detach(), expected, rtol=1e-10, atol=0.0)


def test_surface_term_keeps_the_surface_on_the_scans(tiny_data, prior_run, tmp_path):
    # From the same prior and the same seed, 30 steps with L_surf end with the scan points
    # nearer the zero level (the logged term) than 30 steps with the paper's losses.
    ends = {}
    for weight in (0.0, 100.0):
        config = tiny_image_config(trainer=tiny_trainer(steps=30), lambda_surface=weight)
        run = tmp_path / f"surf{weight:g}"
        train_images(tiny_data, run, config, prior=prior_run)
        log = _log(run)
        assert ("surf" in log[0]["losses"]) == (weight > 0)
        ends[weight] = _surface_error(load_image_model(run), tiny_data, config)
    assert ends[100.0] < 0.7 * ends[0.0], ends


def _surface_error(model, data, config) -> float:
    """Mean |SDF| of ``model`` at 4 batches of scan points of ``data``'s training frames."""
    from lisa_hand.training.images import sample_image_batch

    config = dataclasses.replace(config, lambda_surface=1.0)
    rays, scans = load_image_data(data, config)
    generator = torch.Generator().manual_seed(11)
    errors = []
    for _ in range(4):
        batch = sample_image_batch(rays, scans, config, generator)
        with torch.no_grad():
            terms = model(batch, render=config.render, batched=True)
        errors.append(float(terms["surf"]))
    return sum(errors) / len(errors)


def test_freeze_geometry_keeps_the_priors_mlps(tiny_data, prior_run, tmp_path):
    """With ``freeze_geometry`` a run leaves the prior's SDF and skinning MLPs bit for bit and
    still trains the colour MLP and the codes; without a prior it is refused."""
    prior = load_prior(prior_run)
    config = tiny_image_config(trainer=tiny_trainer(steps=4), freeze_geometry=True)
    train_images(tiny_data, tmp_path / "frozen", config, prior=prior_run)
    model = load_image_model(tmp_path / "frozen")
    for name in ("sdf_mlp", "skinning_mlp"):
        for (key, value), (_, before) in zip(getattr(model.field, name).state_dict().items(),
                                             getattr(prior.field, name).state_dict().items(),
                                             strict=True):
            assert torch.equal(value, before), f"{name}.{key}"
    start, _ = build_image_model(RayFrames(tiny_data, "train", max_band_px=2),
                                 resolve_prior(config, prior_run)[0], prior)
    assert not all(torch.equal(a, b) for a, b in zip(model.field.color_mlp.parameters(),
                                                     start.field.color_mlp.parameters(),
                                                     strict=True))
    assert not torch.equal(model.shape_codes.weight, start.shape_codes.weight)
    with pytest.raises(ValueError, match="freeze_geometry keeps a prior's geometry"):
        train_images(tiny_data, tmp_path / "none", config)
