"""The LISA field against an independent float64 per-bone reference, and its properties."""

from __future__ import annotations

import dataclasses

import pytest
import torch
import torch.nn.functional as F

from lisa_hand.fields import FieldConfig, LatentTable, unpose_points
from lisa_hand.model.lisa import FieldOutput, LisaModel, build_model
from lisa_hand.model.losses import eikonal_loss
from lisa_hand.skeleton import forward_kinematics
from tests.fields.helpers import frame_inputs, perturb_, rest_joints, sample_points, tiny_config

COMPOSITIONS = ("lisa", "nasa", "narf", "single")
LEAVES = (3, 6, 9, 12, 15)
PALM = (1, 4, 7, 10, 13)
PARENT = (-1, 0, 1, 2, 0, 4, 5, 0, 7, 8, 0, 10, 11, 0, 13, 14)


def make_model(composition: str = "lisa", seed: int = 0, **overrides) -> LisaModel:
    torch.manual_seed(seed)
    model = LisaModel(tiny_config(composition=composition, **overrides)).double()
    perturb_(model, seed + 1)
    return model


# --------------------------------------------------------------------------------------------
# Independent float64 reference: plain torch ops, an explicit loop over frames and bones.


def _segments(rest: torch.Tensor, bone: int, tip: float) -> list[tuple[torch.Tensor, torch.Tensor]]:
    if bone == 0:
        return [(rest[0], rest[c]) for c in PALM]
    if bone in LEAVES:
        return [(rest[bone], rest[bone] + tip * (rest[bone] - rest[PARENT[bone]]))]
    return [(rest[bone], rest[bone + 1])]


def _point_segment_distance(x: torch.Tensor, a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    ab = b - a
    t = (((x - a) @ ab) / (ab @ ab)).clamp(0.0, 1.0)
    return (x - a - t[:, None] * ab).norm(dim=-1)


def _mlp(x: torch.Tensor, mlp, group: int, cond: torch.Tensor | None, activation) -> torch.Tensor:
    """One group of a StackedMLP on concat(point, cond), with the full first-layer weight."""
    weight = mlp.point_weight[group]
    if cond is not None:
        weight = torch.cat([weight, mlp.cond_weight[group]], dim=0)
        x = torch.cat([x, cond.expand(x.shape[0], -1)], dim=-1)
    h = activation(x @ weight + mlp.first_bias[group])
    layers = list(zip(mlp.hidden_weights, mlp.hidden_biases, strict=True))
    for w, b in layers:
        h = activation(h @ w[group] + b[group])
    return h @ mlp.out_weight[group] + mlp.out_bias[group]


def _encode(x: torch.Tensor, frequencies: int) -> torch.Tensor:
    parts = [x]
    for k in range(frequencies):
        parts += [torch.sin(2.0**k * x), torch.cos(2.0**k * x)]
    return torch.cat(parts, dim=-1)


def _pose_feature(config, pose, rotmats, bone: int | None) -> torch.Tensor:
    if config.pose_conditioning == "full":
        return pose
    eye = torch.eye(3, dtype=pose.dtype)
    seen = set(range(1, 16)) if bone is None else {bone, PARENT[bone]}
    if bone is not None:
        seen |= {c for c in range(16) if PARENT[c] == bone}
    return torch.cat(
        [(rotmats[k] - eye).reshape(9) if k in seen else pose.new_zeros(9) for k in range(1, 16)]
    )


def reference_field(model: LisaModel, inputs: dict, points: torch.Tensor) -> dict:
    config = model.config
    scale = config.coordinate_scale
    softplus = lambda v: F.softplus(v, beta=config.softplus_beta)  # noqa: E731
    kin = forward_kinematics(inputs["pose"], inputs["rest_joints"], inputs["translation"])
    radius = [config.palm_region_radius] + [config.finger_region_radius] * 15
    result = {key: [] for key in ("sdf", "rgb", "weights", "bone_sdf", "excess", "active")}
    for b in range(points.shape[0]):
        rest, pose = inputs["rest_joints"][b], inputs["pose"][b]
        shape, color = inputs["shape_code"][b], inputs["color_code"][b]
        locals_, excess, bone_sdf, colors = [], [], [], []
        for j in range(16):
            rot, trans = kin.transforms[b, j, :3, :3], kin.transforms[b, j, :3, 3]
            x_rest = (points[b] - trans) @ rot  # R^T (x - t)
            segments = _segments(rest, j, config.tip_extension)
            distance = torch.stack(
                [_point_segment_distance(x_rest, a, e) for a, e in segments], -1
            ).amin(-1)
            excess.append(distance - radius[j])
            if j == 0:
                centre = torch.cat([rest[:1], rest[list(PALM)]]).mean(0)
            else:
                centre = 0.5 * (segments[0][0] + segments[0][1])
            locals_.append((x_rest - centre) / scale)
            if config.composition == "single":
                continue
            encoded = _encode(locals_[j], config.pe_frequencies)
            feature = _pose_feature(config, pose, kin.rotmats[b], j)
            s = _mlp(encoded, model.sdf_mlp, j, torch.cat([feature, shape]), softplus)[:, 0]
            bone_sdf.append(
                torch.where(excess[j] < 0, s * scale, excess[j] + config.outside_margin)
            )
            cond = torch.cat([feature, shape, color])
            c = torch.sigmoid(_mlp(encoded, model.color_mlp, j, cond, torch.relu))
            colors.append(torch.where(excess[j][:, None] < 0, c, torch.full_like(c, 0.5)))
        excess = torch.stack(excess, -1)
        active = excess < 0
        nearest = excess.argmin(-1)
        result["excess"].append(excess)
        result["active"].append(active)
        if config.composition == "single":
            rot, trans = kin.transforms[b, 0, :3, :3], kin.transforms[b, 0, :3, 3]
            x_hand = ((points[b] - trans) @ rot - rest.mean(0)) / scale
            encoded = _encode(x_hand, config.pe_frequencies)
            feature = _pose_feature(config, pose, kin.rotmats[b], None)
            s = _mlp(encoded, model.sdf_mlp, 0, torch.cat([feature, shape]), softplus)[:, 0]
            cond = torch.cat([feature, shape, color])
            c = torch.sigmoid(_mlp(encoded, model.color_mlp, 0, cond, torch.relu))
            inside = active.any(-1)
            outside = (excess + config.outside_margin).amin(-1)
            result["sdf"].append(torch.where(inside, s * scale, outside))
            result["rgb"].append(torch.where(inside[:, None], c, torch.full_like(c, 0.5)))
            continue
        bone_sdf, colors = torch.stack(bone_sdf, -1), torch.stack(colors, -2)
        allowed = active.clone()
        none = ~active.any(-1)
        allowed[none, nearest[none]] = True
        if config.composition == "nasa":
            choice = torch.where(allowed, bone_sdf, torch.inf).argmin(-1)
            weights = F.one_hot(choice, 16).double()
        else:
            skin_in = torch.cat(locals_, -1)
            if config.composition == "lisa":
                skin_in = torch.cat([skin_in, bone_sdf / scale], -1)
            logits = _mlp(skin_in, model.skinning_mlp, 0, None, softplus)
            logits = logits - logits.amax(-1, keepdim=True)
            weights = torch.exp(logits) * allowed
            weights = weights / weights.sum(-1, keepdim=True)
        result["sdf"].append((weights * bone_sdf).sum(-1))
        result["rgb"].append((weights[..., None] * colors).sum(-2))
        result["weights"].append(weights)
        result["bone_sdf"].append(bone_sdf)
    return {k: torch.stack(v) if v else None for k, v in result.items()}


@pytest.mark.parametrize("composition", COMPOSITIONS)
@pytest.mark.parametrize("pose_conditioning", ["local", "full"])
def test_matches_float64_reference(composition, pose_conditioning):
    model = make_model(composition, pose_conditioning=pose_conditioning)
    inputs = frame_inputs(model.config, batch=2, seed=3)
    state = model.prepare(**inputs)
    points = sample_points(state, 300, seed=4)
    with torch.no_grad():
        out = model.field(state, points)
    ref = reference_field(model, inputs, points)
    counts = ref["active"].sum(-1)
    assert (counts == 0).any() and (counts == 1).any() and (counts >= 2).any()
    assert torch.equal(out.region_mask, ref["active"])
    torch.testing.assert_close(out.sdf, ref["sdf"], rtol=0, atol=1e-12)
    torch.testing.assert_close(out.rgb, ref["rgb"], rtol=0, atol=1e-12)
    if composition == "single":
        assert out.weights is None and out.bone_sdf is None
        return
    torch.testing.assert_close(out.bone_sdf, ref["bone_sdf"], rtol=0, atol=1e-12)
    inside = counts > 0
    torch.testing.assert_close(out.weights[inside], ref["weights"][inside], rtol=0, atol=1e-12)
    # Outside every region: one-hot on a nearest region (equidistant regions may tie).
    outside = ~inside
    chosen = out.weights[outside].argmax(-1)
    chosen_excess = ref["excess"][outside].gather(-1, chosen[:, None])[:, 0]
    torch.testing.assert_close(chosen_excess, ref["excess"][outside].amin(-1), rtol=0, atol=1e-12)
    assert torch.equal(out.weights[outside].amax(-1), torch.ones_like(chosen_excess))


# --------------------------------------------------------------------------------------------
# Culling, gradients, compositions


@pytest.mark.parametrize("composition", COMPOSITIONS)
def test_culled_equals_unculled(composition):
    model = make_model(composition, seed=5)
    inputs = frame_inputs(model.config, batch=2, seed=6)
    state = model.prepare(**inputs)
    points = sample_points(state, 256, seed=7)
    culled = model.field(state, points, with_gradient=True)
    dense = model.field(state, points, with_gradient=True, cull=False)
    for name in ("sdf", "rgb", "weights", "bone_sdf", "sdf_grad"):
        a, b = getattr(culled, name), getattr(dense, name)
        if a is None:
            assert b is None
            continue
        torch.testing.assert_close(a, b, rtol=0, atol=1e-12, msg=name)


def test_single_frame_culling_uses_per_bone_bias():
    model = make_model("lisa", seed=8)
    inputs = frame_inputs(model.config, batch=2, seed=9)
    state = model.prepare(**inputs)
    points = sample_points(state, 128, seed=10)
    both = model.field(state, points)
    for b in range(2):
        one = {key: value[b : b + 1] for key, value in inputs.items()}
        single = model.field(model.prepare(**one), points[b : b + 1])
        torch.testing.assert_close(single.sdf, both.sdf[b : b + 1], rtol=0, atol=1e-12)
        torch.testing.assert_close(single.rgb, both.rgb[b : b + 1], rtol=0, atol=1e-12)


@pytest.mark.parametrize("composition", COMPOSITIONS)
def test_gradient_matches_finite_differences(composition):
    model = make_model(composition, seed=11)
    inputs = frame_inputs(model.config, batch=1, seed=12)
    state = model.prepare(**inputs)
    points = sample_points(state, 64, seed=13)
    with torch.no_grad():
        excess = model.region_excess(state, points)
    # Stay away from region boundaries and equidistant fallback ties (kinks of the field).
    sorted_excess = excess.sort(dim=-1).values
    keep = (excess.abs() > 2e-4).all(-1) & (sorted_excess[..., 1] - sorted_excess[..., 0] > 2e-4)
    points = points[:, keep[0]]
    out = model.field(state, points, with_gradient=True)
    step = 1e-6
    numeric = []
    for axis in range(3):
        offset = torch.zeros(3, dtype=points.dtype)
        offset[axis] = step
        with torch.no_grad():
            plus = model.field(state, points + offset, with_color=False).sdf
            minus = model.field(state, points - offset, with_color=False).sdf
        numeric.append((plus - minus) / (2 * step))
    numeric = torch.stack(numeric, -1)
    torch.testing.assert_close(out.sdf_grad, numeric, rtol=0, atol=1e-6)
    # Points in no region get the analytic stand-in: a unit gradient.
    outside = ~out.region_mask.any(-1)
    assert outside.any()
    norms = out.sdf_grad[outside].norm(dim=-1)
    torch.testing.assert_close(norms, torch.ones_like(norms), rtol=0, atol=1e-9)


@pytest.mark.parametrize("composition", ["lisa", "nasa", "narf"])
def test_weights_are_a_partition_of_unity(composition):
    model = make_model(composition, seed=14)
    state = model.prepare(**frame_inputs(model.config, batch=2, seed=15))
    out = model.field(state, sample_points(state, 200, seed=16))
    assert (out.weights >= 0).all()
    torch.testing.assert_close(out.weights.sum(-1), torch.ones_like(out.sdf), rtol=0, atol=1e-12)
    assert (out.weights[~out.region_mask & out.region_mask.any(-1, keepdim=True)] == 0).all()
    assert (out.rgb >= 0).all() and (out.rgb <= 1).all()


def test_nasa_selects_exactly_one_bone():
    model = make_model("nasa", seed=17)
    state = model.prepare(**frame_inputs(model.config, batch=2, seed=18))
    out = model.field(state, sample_points(state, 300, seed=19))
    assert ((out.weights == 0) | (out.weights == 1)).all()
    assert (out.weights.sum(-1) == 1).all()
    inside = out.region_mask.any(-1)
    masked = torch.where(out.region_mask, out.bone_sdf, torch.inf).amin(-1)
    torch.testing.assert_close(out.sdf[inside], masked[inside], rtol=0, atol=0)
    torch.testing.assert_close(out.sdf[~inside], out.bone_sdf[~inside].amin(-1), rtol=0, atol=0)
    chosen = out.weights.argmax(-1, keepdim=True)
    torch.testing.assert_close(out.sdf, out.bone_sdf.gather(-1, chosen)[..., 0], rtol=0, atol=0)


@pytest.mark.parametrize("composition, depends", [("narf", False), ("lisa", True)])
def test_skinning_input_sdf_only_for_lisa(composition, depends):
    model = make_model(composition, seed=20)
    inputs = frame_inputs(model.config, batch=1, seed=21)
    points = sample_points(model.prepare(**inputs), 300, seed=22)
    with torch.no_grad():
        before = model.field(model.prepare(**inputs), points)
        for param in model.sdf_mlp.parameters():
            param.mul_(1.5)
        after = model.field(model.prepare(**inputs), points)
    assert not torch.allclose(before.bone_sdf, after.bone_sdf)
    changed = (before.weights - after.weights).abs().max() > 1e-6
    assert bool(changed) == depends


def test_single_mlp_has_no_per_bone_parameters():
    model = make_model("single")
    assert model.skinning_mlp is None
    for name, param in model.named_parameters():
        assert param.shape[0] != 16, name
    per_bone = make_model("lisa")
    assert any(param.shape[0] == 16 for param in per_bone.parameters())


@pytest.mark.parametrize("composition", COMPOSITIONS)
def test_sdf_does_not_depend_on_color_code(composition):
    model = make_model(composition, seed=23)
    inputs = frame_inputs(model.config, batch=2, seed=24)
    points = sample_points(model.prepare(**inputs), 200, seed=25)
    first = model.field(model.prepare(**inputs), points)
    inputs["color_code"] = inputs["color_code"] + 1.0
    second = model.field(model.prepare(**inputs), points)
    assert torch.equal(first.sdf, second.sdf)
    assert not torch.allclose(first.rgb, second.rgb)
    # And the SDF gradient has no path to the colour code.
    code = inputs["color_code"].clone().requires_grad_(True)
    state = model.prepare(**{**inputs, "color_code": code})
    sdf = model.field(state, points, with_color=False).sdf
    assert (
        not sdf.requires_grad or torch.autograd.grad(sdf.sum(), code, allow_unused=True)[0] is None
    )


def test_unposing_inverts_forward_kinematics():
    gen = torch.Generator().manual_seed(26)
    rest = rest_joints()[None].expand(3, -1, -1)
    pose = 0.5 * torch.randn(3, 48, generator=gen, dtype=torch.float64)
    translation = torch.randn(3, 3, generator=gen, dtype=torch.float64)
    kin = forward_kinematics(pose, rest, translation)
    for bone in range(16):
        attached = rest[:, bone : bone + 1] + 0.02 * torch.randn(3, 10, 3, generator=gen).double()
        rot, trans = kin.transforms[:, bone, :3, :3], kin.transforms[:, bone, :3, 3]
        posed = attached @ rot.transpose(-1, -2) + trans[:, None]
        unposed = unpose_points(kin.transforms, posed)[:, :, bone]
        torch.testing.assert_close(unposed, attached, rtol=0, atol=1e-12)
    # The model's bone-local coordinates are the same points, centred and scaled.
    model = make_model()
    state = model.prepare(
        pose, translation, rest, torch.zeros(3, 4).double(), torch.zeros(3, 3).double()
    )
    points = torch.randn(3, 5, 3, generator=gen, dtype=torch.float64) * 0.1
    local = model.bone_local_points(state, points)
    rest_frame = unpose_points(kin.transforms, points)
    from lisa_hand.fields import bone_centres

    expected = (rest_frame - bone_centres(rest, model.config.tip_extension)[:, None]) / 0.05
    torch.testing.assert_close(local, expected, rtol=0, atol=1e-12)


def test_eikonal_second_order_gradients():
    model = make_model("lisa", seed=27).train()
    inputs = frame_inputs(model.config, batch=1, seed=28)
    code = inputs["shape_code"].clone().requires_grad_(True)
    state = model.prepare(**{**inputs, "shape_code": code})
    out = model.field(state, sample_points(state, 64, seed=29), with_gradient=True)
    assert out.sdf_grad.requires_grad  # create_graph defaults to True when training
    eikonal_loss(out.sdf_grad).backward()
    assert model.sdf_mlp.hidden_weights[0].grad.abs().sum() > 0
    assert model.skinning_mlp.point_weight.grad.abs().sum() > 0
    assert code.grad.abs().sum() > 0
    model.eval()
    out = model.field(state, sample_points(state, 8, seed=30), with_gradient=True)
    assert not out.sdf_grad.requires_grad
    with torch.no_grad():
        out = model.field(state, sample_points(state, 8, seed=30), with_gradient=True)
    assert out.sdf_grad is not None and not out.sdf.requires_grad


# --------------------------------------------------------------------------------------------
# Dtypes, devices, precision, initialisation, validation


def test_float32_matches_float64():
    model64 = make_model("lisa", seed=31)
    model32 = LisaModel(model64.config)
    model32.load_state_dict({k: v.float() for k, v in model64.state_dict().items()})
    inputs = frame_inputs(model64.config, batch=2, seed=32)
    state64 = model64.prepare(**inputs)
    points = sample_points(state64, 200, seed=33)
    with torch.no_grad():
        out64 = model64.field(state64, points)
        inputs32 = {k: v.float() for k, v in inputs.items()}
        out32 = model32.field(model32.prepare(**inputs32), points.float(), with_gradient=True)
    assert out32.sdf.dtype == torch.float32 and out32.sdf_grad.dtype == torch.float32
    torch.testing.assert_close(out32.sdf.double(), out64.sdf, rtol=0, atol=2e-5)
    torch.testing.assert_close(out32.rgb.double(), out64.rgb, rtol=0, atol=2e-5)


def test_bfloat16_inference_precision_is_close():
    base = make_model("lisa", seed=34)
    model = LisaModel(dataclasses.replace(base.config, inference_precision="bfloat16"))
    model.load_state_dict({k: v.float() for k, v in base.state_dict().items()})
    inputs = {k: v.float() for k, v in frame_inputs(base.config, batch=1, seed=35).items()}
    state = model.prepare(**inputs)
    points = sample_points(state, 200, seed=36)
    with torch.no_grad():
        low = model.field(state, points)
        model.config = base.config
        exact = model.field(state, points)
    assert not torch.equal(low.sdf, exact.sdf)
    torch.testing.assert_close(low.sdf, exact.sdf, rtol=0, atol=3e-3)
    torch.testing.assert_close(low.rgb, exact.rgb, rtol=0, atol=3e-2)


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs CUDA")
def test_cuda_matches_cpu():
    model = make_model("lisa", seed=37).float()
    inputs = {k: v.float() for k, v in frame_inputs(model.config, batch=2, seed=38).items()}
    state = model.prepare(**inputs)
    points = sample_points(state, 256, seed=39)
    with torch.no_grad():
        cpu = model.field(state, points)
        gpu_model = model.cuda()
        gpu_state = gpu_model.prepare(**{k: v.cuda() for k, v in inputs.items()})
        gpu = gpu_model.field(gpu_state, points.cuda())
    torch.testing.assert_close(gpu.sdf.cpu(), cpu.sdf, rtol=0, atol=1e-5)
    torch.testing.assert_close(gpu.rgb.cpu(), cpu.rgb, rtol=0, atol=1e-5)


def test_fresh_model_is_a_blobby_hand():
    rest = rest_joints()
    config = FieldConfig(sdf_hidden=64, skinning_hidden=32, shape_dim=8, color_dim=8)
    torch.manual_seed(40)
    model = LisaModel(config, init_rest_joints=rest.float()).double()
    state = model.prepare(
        torch.zeros(1, 48).double(),
        None,
        rest[None],
        torch.zeros(1, 8).double(),
        torch.zeros(1, 8).double(),
    )
    from lisa_hand.fields import bone_centres

    with torch.no_grad():
        inside = model.field(state, bone_centres(rest[None], config.tip_extension)).sdf
        far = (
            rest[None, :1]
            + torch.tensor([[[0.0, 0.08, 0.0], [0.0, -0.08, 0.0], [0.1, 0.0, 0.0]]]).double()
        )
        outside = model.field(state, far).sdf
        finger = model.field(
            state, rest[None, [5]] + torch.tensor([[[0.0, 0.03, 0.0]]]).double()
        ).sdf
    assert (inside < -0.002).all(), inside
    assert (outside > 0.02).all() and (finger > 0.005).all()


def test_build_from_dict_and_state_dict_round_trip():
    config = tiny_config(composition="narf", use_color=False)
    model = build_model(config.to_dict())
    assert model.config == config and model.color_mlp is None
    clone = build_model(FieldConfig.from_dict(config.to_dict()))
    clone.load_state_dict(model.state_dict())
    assert not any("pose_mask" in key for key in model.state_dict())
    inputs = {k: v.float() for k, v in frame_inputs(config, batch=1, seed=41).items()}
    inputs.pop("color_code")
    state = model.prepare(**inputs)
    points = sample_points(state, 32, seed=42)
    out = model.field(state, points)
    assert isinstance(out, FieldOutput) and out.rgb is None
    torch.testing.assert_close(clone.field(clone.prepare(**inputs), points).sdf, out.sdf)
    with pytest.raises(ValueError, match="use_color"):
        model.field(state, points, with_color=True)


def test_field_fn_and_sdf_fn_callbacks():
    model = make_model("lisa", seed=43)
    inputs = frame_inputs(model.config, batch=1, seed=44)
    state = model.prepare(**inputs)
    points = sample_points(state, 16, seed=45)[0]
    sdf, rgb = model.field_fn(state)(points, torch.zeros_like(points))
    torch.testing.assert_close(model.sdf_fn(state)(points), sdf)
    assert sdf.shape == (16,) and rgb.shape == (16, 3)
    two = model.prepare(**frame_inputs(model.config, batch=2, seed=44))
    with pytest.raises(ValueError, match="one frame"):
        model.sdf_fn(two)


def test_latent_codes_feed_the_model():
    config = tiny_config()
    shapes, colors = LatentTable(5, config.shape_dim), LatentTable(5, config.color_dim)
    model = make_model().float()
    ids = torch.tensor([1, 3])
    inputs = {k: v.float() for k, v in frame_inputs(config, batch=2, seed=46).items()}
    state = model.prepare(inputs["pose"], None, inputs["rest_joints"], shapes(ids), colors(ids))
    model.field(state, sample_points(state, 16, seed=47)).sdf.sum().backward()
    assert shapes.weight.grad[ids].abs().sum() > 0 and shapes.weight.grad[0].abs().sum() == 0


def test_input_validation():
    model = make_model()
    inputs = frame_inputs(model.config, batch=2, seed=48)
    with pytest.raises(ValueError, match="pose"):
        model.prepare(**{**inputs, "pose": inputs["pose"][:, :40]})
    with pytest.raises(ValueError, match="shape_code"):
        model.prepare(**{**inputs, "shape_code": inputs["shape_code"][:, :2]})
    with pytest.raises(ValueError, match="rest_joints"):
        model.prepare(**{**inputs, "rest_joints": inputs["rest_joints"][:, :15]})
    with pytest.raises(ValueError, match="color_code"):
        model.prepare(**{**inputs, "color_code": None})
    with pytest.raises(TypeError, match="dtype"):
        model.prepare(**{k: v.float() for k, v in inputs.items()})
    state = model.prepare(**inputs)
    with pytest.raises(ValueError, match="points"):
        model.field(state, torch.zeros(3, 4, 3, dtype=torch.float64))
    with pytest.raises(TypeError, match="state"):
        model.field(inputs, torch.zeros(2, 4, 3, dtype=torch.float64))
    shared = model.prepare(**{**inputs, "rest_joints": inputs["rest_joints"][0]})
    assert shared.rest_joints.shape == (2, 16, 3)


def test_the_straightforward_reference_computes_the_same_field():
    from tests.model.reference_field import ReferenceField

    model = make_model("lisa", seed=49)
    inputs = frame_inputs(model.config, batch=1, seed=50)
    state = model.prepare(**inputs)
    points = sample_points(state, 200, seed=51)
    reference = ReferenceField(model)
    with torch.no_grad():
        out = model.field(state, points)
        ref = reference(
            points,
            inputs["pose"],
            state.kinematics,
            inputs["rest_joints"],
            inputs["shape_code"],
            inputs["color_code"],
            model.pose_mask,
        )
    torch.testing.assert_close(ref.sdf, out.sdf, rtol=0, atol=1e-12)
    torch.testing.assert_close(ref.rgb, out.rgb, rtol=0, atol=1e-12)
    inside = out.region_mask.any(-1)
    torch.testing.assert_close(ref.weights[inside], out.weights[inside], rtol=0, atol=1e-12)


def test_grouped_callbacks_match_per_frame_evaluation():
    # Points of two frames, interleaved and unequal in number, through one grouped call: the
    # same values and gradients as each frame's own callback.
    model = make_model("lisa", seed=46)
    inputs = frame_inputs(model.config, batch=2, seed=47)
    state = model.prepare(**inputs)
    points = sample_points(state, 40, seed=48)
    flat = torch.cat([points[0], points[1, :25]])
    groups = torch.cat([torch.zeros(40, dtype=torch.long), torch.ones(25, dtype=torch.long)])
    order = torch.randperm(65, generator=torch.Generator().manual_seed(0))
    flat, groups = flat[order].clone().requires_grad_(True), groups[order]
    sdf, rgb = model.grouped_field_fn(state)(flat, torch.zeros_like(flat), groups)
    torch.testing.assert_close(model.grouped_sdf_fn(state)(flat, groups), sdf, rtol=0, atol=0)
    (grad,) = torch.autograd.grad(sdf.sum() + rgb.sum(), flat)
    for frame in range(2):
        one = model.prepare(**{key: value[frame : frame + 1] for key, value in inputs.items()})
        rows = (groups == frame).nonzero()[:, 0]
        query = flat.detach()[rows].requires_grad_(True)
        ref_sdf, ref_rgb = model.field_fn(one)(query, torch.zeros_like(query))
        (ref_grad,) = torch.autograd.grad(ref_sdf.sum() + ref_rgb.sum(), query)
        torch.testing.assert_close(sdf[rows], ref_sdf, rtol=0, atol=1e-12)
        torch.testing.assert_close(rgb[rows], ref_rgb, rtol=0, atol=1e-12)
        torch.testing.assert_close(grad[rows], ref_grad, rtol=0, atol=1e-12)
    with pytest.raises(ValueError, match="groups must be in"):
        model.grouped_sdf_fn(state)(flat.detach(), torch.full_like(groups, 2))
