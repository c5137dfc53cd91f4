"""Loading trained runs for inference and exporting them (lisa_hand.model.trained)."""

from __future__ import annotations

import dataclasses

import pytest
import torch

from lisa_hand.model.trained import DEFAULT_BETA, export_trained, load_trained
from lisa_hand.training.images import load_image_model, train_images
from lisa_hand.training.prior import train_prior

from .conftest import tiny_image_config, tiny_prior_config, tiny_trainer


def _sdf(model, points):
    codes = model.shape_codes[:1]
    color = None if model.color_codes is None else model.color_codes[:1]
    rest = torch.tensor([[0.0, 0.0, 0.0]]).repeat(16, 1) + torch.linspace(0, 0.1, 16)[:, None]
    state = model.field.prepare(torch.zeros(1, 48), None, rest, codes, color)
    out = model.field.field(state, points[None])
    return out.sdf[0], None if out.rgb is None else out.rgb[0]


def _sdf_of(field, model, points):
    """The SDF of ``field`` with ``model``'s first codes, as :func:`_sdf`."""
    codes = model.shape_codes[:1]
    color = None if model.color_codes is None else model.color_codes[:1]
    rest = torch.tensor([[0.0, 0.0, 0.0]]).repeat(16, 1) + torch.linspace(0, 0.1, 16)[:, None]
    state = field.prepare(torch.zeros(1, 48), None, rest, codes, color)
    return field.field(state, points[None]).sdf[0]


def test_image_run_loads_exports_and_reloads(tiny_data, tmp_path):
    config = tiny_image_config(trainer=tiny_trainer(steps=2))
    train_images(tiny_data, tmp_path / "run", config)
    model = load_trained(tmp_path / "run")
    assert model.has_color and model.beta > 0
    assert model.shape_codes.shape == (2, 8) and model.gain.shape == (3,)
    points = torch.randn(200, 3, generator=torch.Generator().manual_seed(0)) * 0.05
    sdf, rgb = _sdf(model, points)
    # model/ reads the run without the training code: the same numbers as the training model
    # (beta restates render.LaplaceDensity's parameterisation).
    trained = load_image_model(tmp_path / "run")
    gain, bias = trained.mean_calibration()
    assert model.beta == float(trained.density.beta.detach())
    assert torch.equal(model.gain, gain.detach()) and torch.equal(model.bias, bias.detach())
    assert torch.equal(model.shape_codes, trained.shape_codes.weight.detach())
    assert torch.equal(model.color_codes, trained.color_codes.weight.detach())
    assert torch.equal(_sdf(model, points)[0], _sdf_of(trained.field, model, points))

    path, worst = export_trained(model, tmp_path / "model.pt")
    assert worst == 0.0
    again = load_trained(path)
    sdf2, rgb2 = _sdf(again, points)
    assert torch.equal(sdf, sdf2) and torch.equal(rgb, rgb2)
    assert again.subject_ids == model.subject_ids and again.beta == pytest.approx(model.beta)

    half_path, worst = export_trained(model, tmp_path / "half.pt", half=True)
    assert 0.0 < worst < 1e-2
    assert half_path.stat().st_size < path.stat().st_size
    sdf3, _ = _sdf(load_trained(half_path), points)
    assert (sdf3 - sdf).abs().max() < 1e-3  # metres


def test_prior_run_is_geometry_only(tiny_data, tmp_path):
    train_prior(tiny_data, tmp_path / "prior", tiny_prior_config(trainer=tiny_trainer(steps=2)))
    model = load_trained(tmp_path / "prior" / "last.pt")
    assert not model.has_color and model.color_codes is None
    assert model.beta == DEFAULT_BETA and torch.equal(model.gain, torch.ones(3))
    assert model.mean_color_code() is None and model.mean_shape_code().shape == (8,)


def test_bad_model_files_get_clear_errors(tmp_path):
    with pytest.raises(FileNotFoundError, match="no such model"):
        load_trained(tmp_path / "missing.pt")
    corrupt = tmp_path / "corrupt.pt"
    corrupt.write_bytes(b"not a torch file")
    with pytest.raises(ValueError, match="corrupt.pt: not a LISA model file"):
        load_trained(corrupt)
    other = tmp_path / "other.pt"
    torch.save({"format": "something"}, other)
    with pytest.raises(ValueError, match="other.pt: not a LISA model"):
        load_trained(other)
    with pytest.raises(FileNotFoundError, match="no checkpoint"):
        load_trained(tmp_path)


@pytest.mark.parametrize("mode", ["headlight", "camera_light"])
def test_headlight_shading_is_trained_exported_and_rendered(tiny_data, tmp_path, mode):
    from lisa_hand.geometry.cameras import pixel_rays
    from lisa_hand.inference.render import orbit_views, prepare_render
    from lisa_hand.render.shading import HeadlightShading
    from lisa_hand.skeleton.params import HandParams

    from .tiny_dataset import base_rest_joints

    config = tiny_image_config(trainer=tiny_trainer(steps=3), shading=mode)
    train_images(tiny_data, tmp_path / "run", config)
    model = load_trained(tmp_path / "run")
    assert isinstance(model.shading, HeadlightShading)
    start = HeadlightShading.for_mode(mode)
    assert model.shading.learns_light == (mode == "camera_light")
    assert not torch.equal(model.shading.diffuse_raw, start.diffuse_raw)  # it was trained
    trained = load_image_model(tmp_path / "run")
    assert torch.equal(model.shading.diffuse, trained.shading.diffuse)
    if mode == "camera_light":  # the light turned away from the camera's axis
        assert not torch.equal(model.shading.light, start.light)
        assert torch.equal(model.shading.light, trained.shading.light)

    path, _ = export_trained(model, tmp_path / "model.pt")
    again = load_trained(path)
    torch.testing.assert_close(again.shading.diffuse, model.shading.diffuse)
    if mode == "camera_light":
        torch.testing.assert_close(again.shading.light, model.shading.light)

    # Rendered: the unshaded model's hand colour times the Lambert factor at each normal.
    params = HandParams(pose=torch.zeros(48), translation=torch.zeros(3),
                        rest_joints=base_rest_joints().float(), shape_code=again.shape_codes[0],
                        color_code=again.color_codes[0])
    plain_model = dataclasses.replace(again, shading=None)
    plain_scene = prepare_render(plain_model, params)
    camera = orbit_views(plain_scene, 1, 24, 20)[0]
    plain = plain_scene.render(camera)
    shaded = prepare_render(again, params).render(camera)
    assert int(plain.mask.sum()) > 20
    assert torch.equal(shaded.opacity, plain.opacity)
    _, directions = pixel_rays(camera)
    factor = again.shading.factor(plain.normals.reshape(-1, 3), directions,
                                  camera.R).reshape(20, 24, 1)
    bias = again.bias * plain.opacity[..., None]
    expected = ((plain.rgb - bias) * factor + bias).clamp(0, 1)  # black background
    torch.testing.assert_close(shaded.rgb, expected, rtol=0, atol=1e-5)
    assert float((shaded.rgb - plain.rgb).abs().max()) > 0.01  # the shading shows


def test_shipped_models_by_name(tmp_path, monkeypatch):
    """'default', 'geometry' and 'geometry_v3' name the three shipped files (LISA-full with
    colour on hand model v1, its geometric prior, the prior of hand models v1-v3); a file or
    folder of that name in the working directory wins; params.json records the name, else the
    absolute path; a name shipped once says where its file went."""
    from lisa_hand.model.trained import SHIPPED_MODELS, model_label, shipped_model_path

    assert set(SHIPPED_MODELS) == {"default", "geometry", "geometry_v3"}
    full = load_trained("default")
    assert full.has_color and full.source == str(shipped_model_path("default"))
    assert len(full.subject_ids) == 51  # the training recipe's 51 subjects
    priors = [load_trained(name) for name in ("geometry", "geometry_v3")]
    for name, geometry in zip(("geometry", "geometry_v3"), priors, strict=True):
        assert not geometry.has_color and geometry.color_codes is None
        assert geometry.source == str(shipped_model_path(name))
        assert len(geometry.subject_ids) >= 200
        assert geometry.config.shape_dim == full.config.shape_dim == 128
    assert not torch.equal(priors[0].shape_codes[:5], priors[1].shape_codes[:5])  # two models
    # geometry_v3: 203 subjects of hand model v2, 105 of v1, 336 of v3 (docs/training.md)
    ids = priors[1].subject_ids
    assert len(ids) == 644
    assert sum(subject.startswith("v1") for subject in ids) == 105
    assert sum(subject.startswith("mh") for subject in ids) == 336
    assert model_label("geometry_v3") == "geometry_v3"
    with pytest.raises(FileNotFoundError, match="geometry_mix: this model is no longer shipped"):
        load_trained("geometry_mix")
    torch.testing.assert_close(load_trained(None).shape_codes, full.shape_codes)
    assert model_label(None) == "default" and model_label("geometry") == "geometry"
    with pytest.raises(ValueError, match="no shipped model named 'colour'"):
        shipped_model_path("colour")
    monkeypatch.chdir(tmp_path)
    (tmp_path / "geometry").mkdir()
    assert model_label("geometry") == str((tmp_path / "geometry").resolve())
    with pytest.raises(FileNotFoundError, match="no checkpoint"):
        load_trained("geometry")  # the local folder, not the shipped file
