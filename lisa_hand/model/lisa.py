"""The LISA hand field ``G(x, pose, shape, color) -> (sdf, rgb)`` (paper Section 4.1, Eq. 6-9).

The one place that combines bone frames, per-bone predictions and skinning weights:

1. A world point is unposed into every bone's rest frame, ``x_j = R_j^-1 (x - t_j)`` with the
   rest-to-posed transforms ``A_j = [R_j | t_j]`` of forward kinematics, then centred at the
   bone and scaled to network units (``(x_j - centre_j) / coordinate_scale``).
2. Per-bone SDF MLPs ``G^s_j(PE(x_j), pose_j, beta+) -> s_j`` and colour MLPs
   ``G^c_j(PE(x_j), pose_j, beta+, gamma) -> c_j`` (the SDF never sees the colour code, so shape
   and colour stay disentangled). All 16 bones are one stacked module.
3. Skinning weights ``w`` from an MLP on ``concat(x_1..x_16, s_1..s_16)`` and a softmax; then
   ``s = sum_j w_j s_j`` and ``c = sum_j w_j c_j`` (Eq. 9). NASA, NARF and a single MLP (the
   VolSDF baseline) are other compositions of the same parts (:class:`FieldConfig`).

Bone regions are part of the definition, so that culled evaluation is exact: bone ``j`` owns a
capsule region around its segments in its rest frame (:mod:`lisa_hand.fields.bones`). Outside
it, ``w_j = 0`` (its skinning logit is ``-inf``), and ``s_j`` and ``c_j`` are analytic stand-ins
that never enter the blend — ``s_j = dist(x_j, region_j) + outside_margin`` and ``c_j = 0.5`` —
but keep ``bone_sdf`` defined. A point in no region takes its nearest region's bone with weight
one, so its SDF is that stand-in: positive, with a unit gradient. Hence each bone's MLPs only
have to run on the points inside its region, and the skinning MLP only on the points in two or
more regions (a single active bone gives an exact one-hot).

Usage::

    model = LisaModel(FieldConfig())
    state = model.prepare(pose, translation, rest_joints, shape_code, color_code)  # per frame
    out = model.field(state, points_world, with_gradient=True)  # per batch of points
"""

from __future__ import annotations

from collections.abc import Callable

import torch
from torch import nn

from ..fields.bones import (
    PALM_CHILDREN,
    SEGMENT_BONES,
    bone_axes,
    bone_centres,
    bone_segments,
    segment_distances,
)
from ..fields.composition import blend, masked_softmax, nasa_selection, one_hot_weights
from ..fields.config import FieldConfig
from ..fields.encoding import encoding_dim, positional_encoding
from ..fields.mlp import StackedMLP, geometric_init_, soft_min_init_
from ..fields.pose import local_pose_mask, pose_feature_dim, pose_features
from ..skeleton import NUM_JOINTS, POSE_DIM, check_pose, forward_kinematics
from .frame import FieldOutput, FrameState, group_points, region_bounds

__all__ = ["FrameState", "FieldOutput", "LisaModel", "build_model", "region_bounds"]

_STAND_IN_COLOR = 0.5
_NUM_PALM_SEGMENTS = len(PALM_CHILDREN)


class LisaModel(nn.Module):
    """The LISA field and its baseline compositions, built from a :class:`FieldConfig`.

    Parameters (per-bone compositions): ``sdf_mlp`` (16 stacked SDF MLPs), ``color_mlp`` (16
    stacked colour MLPs, if ``use_color``) and ``skinning_mlp`` ('lisa' and 'narf'). The 'single'
    composition holds one SDF MLP and one colour MLP and nothing per bone. Latent codes live
    outside the model (:class:`lisa_hand.fields.LatentTable`).
    """

    def __init__(
        self, config: FieldConfig | None = None, *, init_rest_joints: torch.Tensor | None = None
    ) -> None:
        """
        config: the architecture (defaults to ``FieldConfig()``).
        init_rest_joints: [16, 3] metres, a typical rest skeleton: the geometric initialisation
            then stretches each bone's blob along its bone (see :meth:`geometric_init_`).
        """
        super().__init__()
        config = FieldConfig() if config is None else config
        if not isinstance(config, FieldConfig):
            raise TypeError(f"config must be a FieldConfig, got {type(config).__name__}")
        self.config = config
        groups = NUM_JOINTS if config.per_bone else 1
        self.num_groups = groups
        pose_dim = pose_feature_dim(config.pose_conditioning)
        point_dim = encoding_dim(config.pe_frequencies)
        self.sdf_mlp = StackedMLP(
            groups,
            point_dim,
            pose_dim + config.shape_dim,
            config.sdf_hidden,
            config.sdf_depth,
            1,
            activation="softplus",
            beta=config.softplus_beta,
        )
        self.color_mlp: StackedMLP | None = None
        if config.use_color:
            self.color_mlp = StackedMLP(
                groups,
                point_dim,
                pose_dim + config.shape_dim + config.color_dim,
                config.color_hidden,
                config.color_depth,
                3,
                activation="relu",
            )
        self.skinning_mlp: StackedMLP | None = None
        if config.composition in ("lisa", "narf"):
            skin_in = 3 * NUM_JOINTS + (NUM_JOINTS if config.composition == "lisa" else 0)
            self.skinning_mlp = StackedMLP(
                1,
                skin_in,
                0,
                config.skinning_hidden,
                config.skinning_depth,
                NUM_JOINTS,
                activation="softplus",
                beta=config.softplus_beta,
            )
            self._init_skinning()
        self.register_buffer("pose_mask", local_pose_mask(config.per_bone), persistent=False)
        # Python floats, made into a tensor of the points' dtype at use (a float32 buffer would
        # round the radii for float64 evaluation).
        self.region_radii = (config.palm_region_radius,) + (config.finger_region_radius,) * (
            NUM_JOINTS - 1
        )
        self.geometric_init_(init_rest_joints)

    # ------------------------------------------------------------------------------------------
    # Construction helpers

    @torch.no_grad()
    def geometric_init_(self, rest_joints: torch.Tensor | None = None) -> None:
        """Re-initialise the SDF MLP(s) so that a fresh model is a blobby hand (IGR/SAL init).

        Each bone starts as a blob of radius ``init_finger_radius`` (``init_palm_radius`` for the
        wrist bone) around its centre; with ``rest_joints`` [16, 3] metres each blob is stretched
        along its bone into a capsule-like spheroid. The single MLP starts as one blob around the
        hand's centre.
        """
        config = self.config
        scale = config.coordinate_scale
        axes = half_lengths = None
        if rest_joints is not None:
            if rest_joints.shape != (NUM_JOINTS, 3):
                raise ValueError(
                    f"init_rest_joints must have shape [16, 3], got {tuple(rest_joints.shape)}"
                )
            axes, lengths = bone_axes(rest_joints[None].double(), config.tip_extension)
            axes, lengths = axes[0], lengths[0]
        if config.per_bone:
            radii = [config.init_palm_radius] + [config.init_finger_radius] * (NUM_JOINTS - 1)
            radii = torch.tensor(radii, dtype=torch.float64) / scale
            if axes is not None:
                half_lengths = 0.5 * lengths / scale
        else:
            radii = torch.tensor([config.init_palm_radius], dtype=torch.float64) / scale
            if axes is not None:
                centre = rest_joints.double().mean(dim=0)
                reach = (rest_joints.double() - centre).norm(dim=-1).max()
                axes, half_lengths = axes[:1], (reach / scale).reshape(1)
        geometric_init_(self.sdf_mlp, radii, axes=axes, half_lengths=half_lengths)

    @torch.no_grad()
    def _init_skinning(self) -> None:
        """LISA: logits ``~ -20 s_j`` (a soft minimum of the bone SDFs, so the fresh blobs form
        their union). NARF, or LISA narrower than 16: near-uniform weights over active bones."""
        mlp = self.skinning_mlp
        if self.config.composition == "lisa":
            sdf_inputs = 3 * NUM_JOINTS
            if soft_min_init_(mlp, sdf_inputs, NUM_JOINTS, sharpness=20.0, value_max=2.0):
                return
        mlp.out_weight.mul_(0.01)
        mlp.out_bias.zero_()

    def extra_repr(self) -> str:
        return f"composition={self.config.composition!r}"

    @property
    def dtype(self) -> torch.dtype:
        return self.sdf_mlp.point_weight.dtype

    @property
    def device(self) -> torch.device:
        return self.sdf_mlp.point_weight.device

    # ------------------------------------------------------------------------------------------
    # Per frame

    def _check_tensor(self, value, name: str, shape: tuple) -> torch.Tensor:
        if not isinstance(value, torch.Tensor):
            raise TypeError(f"{name} must be a torch.Tensor, got {type(value).__name__}")
        mismatch = value.dim() != len(shape) or any(
            s is not None and v != s for v, s in zip(value.shape, shape, strict=True)
        )
        if mismatch:
            expected = "[" + ", ".join("*" if s is None else str(s) for s in shape) + "]"
            raise ValueError(f"{name} must have shape {expected}, got {list(value.shape)}")
        if value.dtype != self.dtype:
            raise TypeError(
                f"{name} has dtype {value.dtype} but the model is {self.dtype} (cast the input, "
                "or the model with .to(dtype))"
            )
        if value.device != self.device:
            raise ValueError(f"{name} is on {value.device} but the model is on {self.device}")
        return value

    def prepare(
        self,
        pose: torch.Tensor,
        translation: torch.Tensor | None,
        rest_joints: torch.Tensor,
        shape_code: torch.Tensor,
        color_code: torch.Tensor | None = None,
    ) -> FrameState:
        """Everything per frame, once: bone transforms, regions and conditioning biases.

        pose: [B, 48] axis-angle radians (MANO order); translation: [B, 3] metres or None.
        rest_joints: [B, 16, 3] (or [16, 3] shared) rest-pose joints, metres; subjects differ.
        shape_code: [B, shape_dim] (beta+); color_code: [B, color_dim] (gamma), required when
            the model has colour, ignored otherwise.
        """
        config = self.config
        if not isinstance(pose, torch.Tensor):
            raise TypeError(f"pose must be a torch.Tensor, got {type(pose).__name__}")
        pose = check_pose(pose).reshape(-1, POSE_DIM)
        batch = pose.shape[0]
        self._check_tensor(pose, "pose", (batch, POSE_DIM))
        if translation is not None:
            self._check_tensor(translation, "translation", (batch, 3))
        if isinstance(rest_joints, torch.Tensor) and rest_joints.dim() == 2:
            self._check_tensor(rest_joints, "rest_joints", (NUM_JOINTS, 3))
            rest_joints = rest_joints.expand(batch, NUM_JOINTS, 3)
        self._check_tensor(rest_joints, "rest_joints", (batch, NUM_JOINTS, 3))
        self._check_tensor(shape_code, "shape_code", (batch, config.shape_dim))
        if self.color_mlp is not None:
            if color_code is None:
                raise ValueError("color_code [B, color_dim] is required: the model has colour")
            self._check_tensor(color_code, "color_code", (batch, config.color_dim))

        kinematics = forward_kinematics(pose, rest_joints, translation)
        scale = config.coordinate_scale
        rot_t = kinematics.transforms[..., :3, :3].transpose(-1, -2)  # R_j^T
        trans = kinematics.transforms[..., :3, 3]
        centres = bone_centres(rest_joints, config.tip_extension)  # [B, J, 3]
        world_to_local = rot_t / scale
        local_offset = -((rot_t @ trans[..., None])[..., 0] + centres) / scale

        start, end = bone_segments(rest_joints, config.tip_extension)
        owner_transforms = kinematics.transforms[:, list(SEGMENT_BONES)]
        owner_rot, owner_trans = owner_transforms[..., :3, :3], owner_transforms[..., :3, 3]
        region_origin = kinematics.joints[:, 0]
        posed_start = (owner_rot @ start[..., None])[..., 0] + owner_trans
        segment_start = posed_start - region_origin[:, None]
        segment_vec = (owner_rot @ (end - start)[..., None])[..., 0]
        segment_length = segment_vec.norm(dim=-1)
        segment_dir = segment_vec / segment_length.clamp_min(1e-12)[..., None]

        groups = self.num_groups
        features = pose_features(pose, kinematics.rotmats, config.pose_conditioning, self.pose_mask)
        shape = shape_code[:, None].expand(batch, groups, -1)
        sdf_bias = self.sdf_mlp.condition(torch.cat([features, shape], dim=-1), batch)
        color_bias = None
        if self.color_mlp is not None:
            color = color_code[:, None].expand(batch, groups, -1)
            cond = torch.cat([features, shape, color], dim=-1)
            color_bias = self.color_mlp.condition(cond, batch)

        hand_to_local = hand_offset = None
        if not config.per_bone:
            hand_centre = rest_joints.mean(dim=1)
            hand_to_local = rot_t[:, 0] / scale
            root_rest = (rot_t[:, 0] @ trans[:, 0, :, None])[..., 0]
            hand_offset = -(root_rest + hand_centre) / scale
        return FrameState(
            kinematics=kinematics,
            rest_joints=rest_joints,
            world_to_local=world_to_local,
            local_offset=local_offset,
            region_origin=region_origin,
            segment_start=segment_start,
            segment_dir=segment_dir,
            segment_length=segment_length,
            sdf_bias=sdf_bias,
            color_bias=color_bias,
            hand_to_local=hand_to_local,
            hand_offset=hand_offset,
        )

    # ------------------------------------------------------------------------------------------
    # Per point

    def field(
        self,
        state: FrameState,
        points: torch.Tensor,
        *,
        with_color: bool | None = None,
        with_gradient: bool = False,
        create_graph: bool | None = None,
        cull: bool = True,
    ) -> FieldOutput:
        """Evaluate the field at world points.

        state: from :meth:`prepare`, batch B.
        points: [B, N, 3] world points, metres.
        with_color: evaluate the colour MLPs (default: when the model has colour). False gives
            geometry only (shape prior, meshing).
        with_gradient: also return ``sdf_grad`` [B, N, 3] (Eikonal and normal losses).
        create_graph: keep the graph of the gradient for a second backward pass; default: when
            training (``self.training``) with autograd enabled.
        cull: run each bone's MLPs only inside its region (exact; False runs every point through
            every bone and is for checking).
        """
        if not isinstance(state, FrameState):
            raise TypeError(f"state must be a FrameState (prepare()), got {type(state).__name__}")
        self._check_tensor(points, "points", (state.batch_size, None, 3))
        if with_color is None:
            with_color = self.color_mlp is not None
        elif with_color and self.color_mlp is None:
            raise ValueError("with_color=True but the model was built with use_color=False")
        if not with_gradient:
            precision = self.config.inference_precision
            if points.dtype != torch.float32 or torch.is_grad_enabled():
                precision = "float32"
            return self._evaluate(state, points, with_color, cull, precision)

        outer_grad = torch.is_grad_enabled()
        if create_graph is None:
            create_graph = self.training and outer_grad
        with torch.enable_grad():
            query = points if points.requires_grad else points.detach().requires_grad_(True)
            out = self._evaluate(state, query, with_color, cull, "float32")
            (grad,) = torch.autograd.grad(
                out.sdf,
                query,
                torch.ones_like(out.sdf),
                create_graph=create_graph,
                retain_graph=create_graph or outer_grad,
            )
        out.sdf_grad = grad
        if not outer_grad:
            for name in ("sdf", "rgb", "weights", "bone_sdf", "sdf_grad"):
                value = getattr(out, name)
                if value is not None:
                    setattr(out, name, value.detach())
        return out

    def forward(
        self,
        points: torch.Tensor,
        pose: torch.Tensor,
        translation: torch.Tensor | None,
        rest_joints: torch.Tensor,
        shape_code: torch.Tensor,
        color_code: torch.Tensor | None = None,
        **field_options,
    ) -> FieldOutput:
        """:meth:`prepare` then :meth:`field` (see both for shapes); for one-off evaluations."""
        state = self.prepare(pose, translation, rest_joints, shape_code, color_code)
        return self.field(state, points, **field_options)

    def sdf_fn(self, state: FrameState) -> Callable[[torch.Tensor], torch.Tensor]:
        """``points [N, 3] -> sdf [N]`` for a one-frame state (meshing, sphere tracing)."""
        self._check_single_frame(state)

        def sdf(points: torch.Tensor) -> torch.Tensor:
            return self.field(state, points[None], with_color=False).sdf[0]

        return sdf

    def field_fn(
        self, state: FrameState
    ) -> Callable[[torch.Tensor, torch.Tensor], tuple[torch.Tensor, torch.Tensor]]:
        """``(points [N, 3], directions [N, 3]) -> (sdf [N], rgb [N, 3])`` for a one-frame state
        (the renderer's callback; the field does not depend on the view direction)."""
        self._check_single_frame(state)
        if self.color_mlp is None:
            raise ValueError("field_fn needs colour; the model was built with use_color=False")

        def field(points: torch.Tensor, directions: torch.Tensor):
            out = self.field(state, points[None], with_color=True)
            return out.sdf[0], out.rgb[0]

        return field

    def grouped_sdf_fn(self, state: FrameState) -> Callable[[torch.Tensor, torch.Tensor],
                                                          torch.Tensor]:
        """``(points [N, 3], groups [N]) -> sdf [N]``: every frame of a batched state in one
        evaluation, point ``i`` in frame ``groups[i]`` (a
        :class:`~lisa_hand.geometry.fields.GroupedSdfFn`: sphere tracing several frames at once).
        """

        def sdf(points: torch.Tensor, groups: torch.Tensor) -> torch.Tensor:
            padded, index = group_points(points, groups, state.batch_size)
            return self.field(state, padded, with_color=False).sdf[index]

        return sdf

    def grouped_field_fn(self, state: FrameState) -> Callable[..., tuple[torch.Tensor,
                                                                          torch.Tensor]]:
        """``(points [N, 3], directions [N, 3], groups [N]) -> (sdf [N], rgb [N, 3])`` for every
        frame of a batched state in one evaluation (a
        :class:`~lisa_hand.geometry.fields.GroupedFieldFn`: rendering several frames at once)."""
        if self.color_mlp is None:
            raise ValueError("grouped_field_fn needs colour; the model was built with "
                             "use_color=False")

        def field(points: torch.Tensor, directions: torch.Tensor, groups: torch.Tensor):
            padded, index = group_points(points, groups, state.batch_size)
            out = self.field(state, padded, with_color=True)
            return out.sdf[index], out.rgb[index]

        return field

    @staticmethod
    def _check_single_frame(state: FrameState) -> None:
        if state.batch_size != 1:
            raise ValueError(f"expected a state of one frame, got batch size {state.batch_size}")

    # ------------------------------------------------------------------------------------------
    # Internals

    def bone_local_points(self, state: FrameState, points: torch.Tensor) -> torch.Tensor:
        """Points in every bone's centred local frame, network units.

        points: [B, N, 3] world metres -> [B, N, 16, 3] ``(R_j^T (x - t_j) - centre_j) / scale``
        """
        batch, num = points.shape[:2]
        # One [B, N, 3] @ [B, 3, 48] product instead of 16 small ones.
        stacked = state.world_to_local.permute(0, 3, 1, 2).reshape(batch, 3, 3 * NUM_JOINTS)
        local = torch.bmm(points, stacked).reshape(batch, num, NUM_JOINTS, 3)
        return local + state.local_offset[:, None]

    def region_excess(self, state: FrameState, points: torch.Tensor) -> torch.Tensor:
        """Distance from each point to each bone's region, negative inside.

        points: [B, N, 3] world metres -> [B, N, 16] metres
        """
        relative = points - state.region_origin[:, None]
        distance = segment_distances(
            relative, state.segment_start, state.segment_dir, state.segment_length
        )
        cut = _NUM_PALM_SEGMENTS
        palm = distance[..., :cut].amin(dim=-1, keepdim=True)
        distance = torch.cat([palm, distance[..., cut:]], dim=-1)
        return distance - points.new_tensor(self.region_radii)

    @staticmethod
    def _group_rows(mask: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, list]:
        """The culled rows of a [B, N, G] mask, sorted by group, then frame, then point.

        -> (group index [Q], flat point index [Q] into B * N, sizes: G ints for one frame, else
        G lists of B ints, as :meth:`StackedMLP.forward_grouped` takes them with the bias
        [1, G, H] -> [G, H] or [B, G, H] of :meth:`_first_bias`).
        """
        batch, num, groups = mask.shape
        group_index, point_index = mask.reshape(batch * num, groups).t().nonzero(as_tuple=True)
        counts = mask.sum(dim=1)  # [B, G]
        sizes = counts[0].tolist() if batch == 1 else counts.t().tolist()
        return group_index, point_index, sizes

    @staticmethod
    def _first_bias(bias: torch.Tensor) -> torch.Tensor:
        """The per-frame first-layer bias [B, G, H] as forward_grouped takes it with
        :meth:`_group_rows`' sizes."""
        return bias[0] if bias.shape[0] == 1 else bias

    def _evaluate(
        self,
        state: FrameState,
        points: torch.Tensor,
        with_color: bool,
        cull: bool,
        precision: str,
    ) -> FieldOutput:
        config = self.config
        scale = config.coordinate_scale
        batch, num = points.shape[:2]
        local = self.bone_local_points(state, points)  # [B, N, J, 3] units
        excess = self.region_excess(state, points)  # [B, N, J] metres, < 0 inside
        active = excess < 0
        fallback = excess.detach().argmin(dim=-1)  # nearest region, for points in none
        stand_in = excess + config.outside_margin  # metres
        if not config.per_bone:
            return self._evaluate_single(
                state, points, active, stand_in, with_color, cull, precision
            )

        num_pairs_all = batch * num * NUM_JOINTS
        # 'bfloat16': every MLP; 'mixed': only the colour MLPs. The skinning MLP stays exact in
        # 'mixed': its logits reach tens (a soft minimum of the SDFs), where bfloat16's 8 bits
        # move the weights by ~1e-1.
        mlp_options = {"low_precision": precision == "bfloat16"}
        color_options = {"low_precision": precision != "float32"}
        if cull:
            bone_index, point_index, group_sizes = self._group_rows(active)  # bone-major
            pair_flat = point_index * NUM_JOINTS + bone_index
            encoded = positional_encoding(local.reshape(-1, 3)[pair_flat], config.pe_frequencies)
            sdf_pairs = self.sdf_mlp.forward_grouped(
                encoded, group_sizes, self._first_bias(state.sdf_bias), **mlp_options
            )[:, 0]
            bone_sdf = stand_in.reshape(num_pairs_all).index_put((pair_flat,), sdf_pairs * scale)
            bone_sdf = bone_sdf.reshape(batch, num, NUM_JOINTS)
        else:
            encoded_all = positional_encoding(local, config.pe_frequencies)
            sdf_all = self.sdf_mlp.forward_dense(encoded_all, state.sdf_bias)[..., 0]
            bone_sdf = torch.where(active, sdf_all * scale, stand_in)

        weights = self._weights(local, bone_sdf, active, fallback, cull, mlp_options)
        sdf = blend(weights, bone_sdf)

        rgb = None
        if with_color:
            color_mask = active & (weights > 0)
            if cull:
                if not torch.equal(color_mask, active):  # NASA: only the chosen bone
                    bone_index, point_index, group_sizes = self._group_rows(color_mask)
                    pair_flat = point_index * NUM_JOINTS + bone_index
                    encoded = positional_encoding(
                        local.reshape(-1, 3)[pair_flat], config.pe_frequencies
                    )
                color_pairs = torch.sigmoid(
                    self.color_mlp.forward_grouped(
                        encoded, group_sizes, self._first_bias(state.color_bias), **color_options
                    )
                )
                weight_pairs = weights.reshape(num_pairs_all)[pair_flat]
                rgb = points.new_zeros(batch * num, 3).index_add(
                    0, point_index, weight_pairs[:, None] * color_pairs
                )
                rgb = rgb.reshape(batch, num, 3)
            else:
                color_all = torch.sigmoid(
                    self.color_mlp.forward_dense(encoded_all, state.color_bias)
                )
                color_all = torch.where(color_mask[..., None], color_all, 0.0)
                rgb = blend(weights, color_all)
            # Bones outside their region have the stand-in colour (only fallback points).
            rgb = rgb + _STAND_IN_COLOR * (weights * ~active).sum(dim=-1, keepdim=True)
        return FieldOutput(sdf=sdf, rgb=rgb, weights=weights, bone_sdf=bone_sdf, region_mask=active)

    def _weights(
        self,
        local: torch.Tensor,
        bone_sdf: torch.Tensor,
        active: torch.Tensor,
        fallback: torch.Tensor,
        cull: bool,
        mlp_options: dict,
    ) -> torch.Tensor:
        """Skinning weights [B, N, 16] of the per-bone compositions."""
        config = self.config
        dtype = bone_sdf.dtype
        if config.composition == "nasa":
            return one_hot_weights(nasa_selection(bone_sdf, active, fallback), NUM_JOINTS, dtype)
        batch, num = active.shape[:2]
        lisa = config.composition == "lisa"
        mlp = self.skinning_mlp
        if not cull:
            inputs = [local.reshape(batch, num, 3 * NUM_JOINTS)]
            if lisa:
                inputs.append(bone_sdf / config.coordinate_scale)
            bias = mlp.first_bias.expand(batch, 1, -1)
            logits = mlp.forward_dense(torch.cat(inputs, dim=-1)[..., None, :], bias)[..., 0, :]
            return masked_softmax(logits, active, fallback)
        count = active.sum(dim=-1)
        first_active = active.to(torch.uint8).argmax(dim=-1)
        single = torch.where(count > 0, first_active, fallback)
        weights = one_hot_weights(single, NUM_JOINTS, dtype).reshape(-1, NUM_JOINTS)
        rows = (count.reshape(-1) >= 2).nonzero()[:, 0]
        if rows.numel() == 0:
            return weights.reshape(batch, num, NUM_JOINTS)
        inputs = [local.reshape(-1, 3 * NUM_JOINTS)[rows]]
        if lisa:
            inputs.append(bone_sdf.reshape(-1, NUM_JOINTS)[rows] / config.coordinate_scale)
        logits = mlp.forward_grouped(
            torch.cat(inputs, dim=-1), [rows.numel()], mlp.first_bias, **mlp_options
        )
        blended = masked_softmax(
            logits, active.reshape(-1, NUM_JOINTS)[rows], fallback.reshape(-1)[rows]
        )
        return weights.index_put((rows,), blended).reshape(batch, num, NUM_JOINTS)

    def _evaluate_single(
        self,
        state: FrameState,
        points: torch.Tensor,
        active: torch.Tensor,
        stand_in: torch.Tensor,
        with_color: bool,
        cull: bool,
        precision: str,
    ) -> FieldOutput:
        """The VolSDF baseline: one MLP on the hand-frame point, inside the union of regions."""
        config = self.config
        scale = config.coordinate_scale
        batch, num = points.shape[:2]
        local = points @ state.hand_to_local.transpose(-1, -2) + state.hand_offset[:, None]
        inside = active.any(dim=-1)
        outside_sdf = stand_in.amin(dim=-1)  # the nearest region's stand-in
        rgb = None
        if cull:
            _, rows, sizes = self._group_rows(inside[..., None])
            encoded = positional_encoding(local.reshape(-1, 3)[rows], config.pe_frequencies)
            options = {"low_precision": precision == "bfloat16"}
            sdf_rows = self.sdf_mlp.forward_grouped(
                encoded, sizes, self._first_bias(state.sdf_bias), **options
            )[:, 0]
            options = {"low_precision": precision != "float32"}
            sdf = outside_sdf.reshape(-1).index_put((rows,), sdf_rows * scale).reshape(batch, num)
            if with_color:
                color_rows = torch.sigmoid(
                    self.color_mlp.forward_grouped(
                        encoded, sizes, self._first_bias(state.color_bias), **options
                    )
                )
                rgb = torch.full_like(points, _STAND_IN_COLOR).reshape(-1, 3)
                rgb = rgb.index_put((rows,), color_rows).reshape(batch, num, 3)
        else:
            encoded = positional_encoding(local, config.pe_frequencies)[:, :, None]
            sdf_all = self.sdf_mlp.forward_dense(encoded, state.sdf_bias)[..., 0, 0]
            sdf = torch.where(inside, sdf_all * scale, outside_sdf)
            if with_color:
                color_all = torch.sigmoid(
                    self.color_mlp.forward_dense(encoded, state.color_bias)[..., 0, :]
                )
                rgb = torch.where(inside[..., None], color_all, _STAND_IN_COLOR)
        return FieldOutput(sdf=sdf, rgb=rgb, weights=None, bone_sdf=None, region_mask=active)


def build_model(
    config: FieldConfig | dict | None = None, *, init_rest_joints: torch.Tensor | None = None
) -> LisaModel:
    """Build a :class:`LisaModel` from a config or its :meth:`FieldConfig.to_dict` dict."""
    if isinstance(config, dict):
        config = FieldConfig.from_dict(config)
    return LisaModel(config, init_rest_joints=init_rest_joints)
