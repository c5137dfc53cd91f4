"""Batched per-bone MLPs: ``G`` MLPs of one architecture with stacked weights ``[G, in, out]``.

The first layer's weight is split into a point part and a conditioning part. The conditioning
(pose, latents) is the same for every point of a frame, so its product with the weight is
computed once per frame (:meth:`StackedMLP.condition`) and becomes a per-frame, per-bone bias
``[B, G, hidden]``; the per-point work only multiplies the encoded point. This is exactly the
MLP on ``concat(point, conditioning)`` (tests check it).

Two evaluation modes share the weights:

* :meth:`StackedMLP.forward_dense`: every point through every group, one bmm over the stacked
  weights a layer (in row chunks).
* :meth:`StackedMLP.forward_grouped`: rows already grouped by bone (culled (point, bone) pairs
  sorted by bone); each group runs through all layers in row chunks that stay in cache.
  Without gradients and with :func:`lisa_hand.fields.fused.set_fused_inference` on, each float32
  chunk runs through a compiled chain instead (bias and activation fused, a polynomial Softplus
  within 1e-8 of ``F.softplus``; :mod:`lisa_hand.fields.fused`); with gradients it is eager.
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F
from torch import nn

from .fused import fused_chain, fused_inference_enabled

__all__ = ["StackedMLP", "ACTIVATIONS", "geometric_init_", "soft_min_init_"]

ACTIVATIONS = ("softplus", "relu")

# Rows per chunk in forward_grouped. A [4096, 128] float32 activation is 2 MiB, so a chunk's
# layer input and output stay in the L2/L3 caches across the layers of one group, which makes
# the chunked products a few times faster on a CPU than one product over all rows.
GROUP_CHUNK_ROWS = 4096

# Rows (all groups together) up to which forward_grouped runs a GPU query as one padded batched
# product a layer instead of its loop over the groups (and frames). A GPU's eager step is bound by
# kernel launches, and the loop launches 9 kernels per MLP call for each of 16 bones and each
# frame. Past about this many rows, padding every group to the largest (the palm's) costs more
# than the launches it saves (`python tools/padded_crossover.py --device cuda` finds the
# crossover).
GPU_PADDED_ROWS = 1 << 17


class StackedMLP(nn.Module):
    """``G`` independent MLPs ``[point | cond] -> hidden^depth -> out`` with stacked weights.

    Weights are ``[G, in, out]`` (``x @ W``), biases ``[G, out]``. Hidden activations are Softplus
    (``beta``; smooth second derivatives for the Eikonal loss) or ReLU; the output is linear.
    """

    def __init__(
        self,
        num_groups: int,
        point_dim: int,
        cond_dim: int,
        hidden: int,
        depth: int,
        out_dim: int,
        *,
        activation: str = "softplus",
        beta: float = 100.0,
    ) -> None:
        """
        num_groups: number of independent MLPs G (16 bones, or 1).
        point_dim: per-point input width (the encoded point).
        cond_dim: per-frame conditioning width (0 for none).
        hidden: hidden width; depth: number of hidden layers (>= 1); out_dim: output width.
        activation: 'softplus' or 'relu'; beta: Softplus sharpness.
        """
        super().__init__()
        if activation not in ACTIVATIONS:
            raise ValueError(f"activation must be one of {ACTIVATIONS}, got {activation!r}")
        if depth < 1:
            raise ValueError(f"depth must be >= 1, got {depth}")
        self.num_groups = num_groups
        self.point_dim = point_dim
        self.cond_dim = cond_dim
        self.hidden = hidden
        self.depth = depth
        self.out_dim = out_dim
        self.activation = activation
        self.beta = float(beta)
        groups = num_groups
        self.point_weight = nn.Parameter(torch.empty(groups, point_dim, hidden))
        if cond_dim > 0:
            self.cond_weight = nn.Parameter(torch.empty(groups, cond_dim, hidden))
        else:
            self.register_parameter("cond_weight", None)
        self.first_bias = nn.Parameter(torch.empty(groups, hidden))
        self.hidden_weights = nn.ParameterList(
            [nn.Parameter(torch.empty(groups, hidden, hidden)) for _ in range(depth - 1)]
        )
        self.hidden_biases = nn.ParameterList(
            [nn.Parameter(torch.empty(groups, hidden)) for _ in range(depth - 1)]
        )
        self.out_weight = nn.Parameter(torch.empty(groups, hidden, out_dim))
        self.out_bias = nn.Parameter(torch.empty(groups, out_dim))
        self.reset_parameters()

    def extra_repr(self) -> str:
        return (
            f"groups={self.num_groups}, point={self.point_dim}, cond={self.cond_dim}, "
            f"hidden={self.hidden}, depth={self.depth}, out={self.out_dim}, "
            f"activation={self.activation}"
            + (f"(beta={self.beta:g})" if self.activation == "softplus" else "")
        )

    @torch.no_grad()
    def reset_parameters(self) -> None:
        """``nn.Linear``'s default: weights and biases uniform in ``+-1/sqrt(fan_in)``."""
        first_fan_in = self.point_dim + self.cond_dim
        first = [self.point_weight, self.first_bias]
        if self.cond_weight is not None:
            first.append(self.cond_weight)
        for tensor in first:
            bound = 1.0 / math.sqrt(first_fan_in)
            tensor.uniform_(-bound, bound)
        bound = 1.0 / math.sqrt(self.hidden)
        for tensor in [*self.hidden_weights, *self.hidden_biases, self.out_weight, self.out_bias]:
            tensor.uniform_(-bound, bound)

    def layers(self) -> list[tuple[torch.Tensor, torch.Tensor]]:
        """The (weight [G, in, out], bias [G, out]) pairs after the first layer, output last."""
        pairs = list(zip(self.hidden_weights, self.hidden_biases, strict=True))
        return pairs + [(self.out_weight, self.out_bias)]

    def act(self, values: torch.Tensor) -> torch.Tensor:
        """The hidden activation."""
        if self.activation == "relu":
            return torch.relu(values)
        return F.softplus(values, beta=self.beta)

    def condition(self, cond: torch.Tensor | None, batch_size: int) -> torch.Tensor:
        """Per-frame first-layer bias: ``b_0 + cond @ W_cond``, computed once per frame.

        cond: [B, G, cond_dim] (or None when cond_dim is 0) -> [B, G, hidden]
        """
        bias = self.first_bias.expand(batch_size, -1, -1)
        if self.cond_weight is None:
            return bias
        if cond is None or cond.shape != (batch_size, self.num_groups, self.cond_dim):
            shape = None if cond is None else tuple(cond.shape)
            raise ValueError(
                f"cond must have shape [{batch_size}, {self.num_groups}, {self.cond_dim}], "
                f"got {shape}"
            )
        return bias + torch.einsum("bgc,gch->bgh", cond, self.cond_weight)

    def forward_dense(
        self, points: torch.Tensor, first_bias: torch.Tensor, *, chunk_rows: int = GROUP_CHUNK_ROWS
    ) -> torch.Tensor:
        """Every point of a frame through every group (a batched product per layer).

        points: [B, N, G, point_dim]; first_bias: [B, G, hidden] (from :meth:`condition`).
        chunk_rows: rows (points x groups) per chunk; each chunk runs through all layers.
        -> [B, N, G, out_dim]
        """
        batch, num, groups, _ = points.shape
        layers = self.layers()
        step = max(1, chunk_rows // groups)
        outputs = []
        for frame in range(batch):
            bias = first_bias[frame][:, None]  # [G, 1, H]
            for lo in range(0, num, step):
                # Group-major rows: each layer is one bmm over [G, rows, in].
                hidden = points[frame, lo : lo + step].transpose(0, 1)
                hidden = self.act(torch.baddbmm(bias, hidden, self.point_weight))
                for index, (weight, layer_bias) in enumerate(layers):
                    hidden = torch.baddbmm(layer_bias[:, None], hidden, weight)
                    if index < len(layers) - 1:
                        hidden = self.act(hidden)
                outputs.append(hidden.transpose(0, 1))
        return torch.cat(outputs, dim=0).reshape(batch, num, groups, self.out_dim)

    def _fused(
        self,
        rows: torch.Tensor,
        group: int,
        bias: torch.Tensor,
        layers: list[tuple[torch.Tensor, torch.Tensor]],
        low_precision: bool,
    ) -> torch.Tensor | None:
        """Group ``group``'s MLP on ``rows`` through the compiled fused chain
        (:func:`lisa_hand.fields.fused.fused_chain`), or None where it does not apply (turned
        off, gradients recorded, ``low_precision``, not float32, too few rows, compilation
        failed).

        rows: [R, point_dim]; bias: [hidden] or [R, hidden] (first layer); layers: from
        :meth:`layers`. -> [R, out_dim]
        """
        if low_precision or not fused_inference_enabled():
            return None
        group_layers = [(weight[group], layer_bias[group]) for weight, layer_bias in layers]
        return fused_chain(
            rows, self.point_weight[group], bias, group_layers, self.activation, self.beta
        )

    def forward_grouped(
        self,
        points: torch.Tensor,
        group_sizes: list[int],
        first_bias: torch.Tensor,
        *,
        bias_per_row: bool = False,
        low_precision: bool = False,
        chunk_rows: int | None = None,
        padded: bool | None = None,
    ) -> torch.Tensor:
        """Rows grouped by MLP: rows ``[o_g, o_g + group_sizes[g])`` go through MLP ``g``.

        points: [Q, point_dim], rows sorted by group.
        group_sizes: G ints summing to Q; or, with a per-frame ``first_bias`` [B, G, hidden],
            G lists of B ints: the rows of each group sorted by frame (``group_sizes[g][b]`` rows
            of group g in frame b), each frame's rows taking that frame's bias.
        first_bias: [G, hidden] (one bias per group: a single frame); [B, G, hidden] (from
            :meth:`condition`: several frames, no per-row gather); or [Q, hidden] with
            ``bias_per_row`` (gathered for each row's frame).
        low_precision: run the hidden layers' products in bfloat16 (inference only; the
            first layer and the output stay in the input dtype).
        chunk_rows: rows per chunk of the loop (None: :data:`GROUP_CHUNK_ROWS` on a CPU, none
            on a GPU). padded: every group at once (:meth:`_forward_padded`; None: on a GPU up
            to :data:`GPU_PADDED_ROWS` rows, else the loop). The same function either way.
        -> [Q, out_dim]

        On a CPU, a short Python loop over the groups, each group in row chunks through all
        layers: one padded bmm over the stacked weights pads every bone to the largest bone's
        count (the palm's), which multiplies the work, and ``torch.nn.functional.grouped_mm``
        is slower and its backward fails on expanded gradients (``python -m benchmarks
        field`` compares them). The loop also supports double backward (Eikonal loss). On a GPU
        (launch-bound) the padded bmm wins up to :data:`GPU_PADDED_ROWS` rows."""
        per_frame, sizes = self._check_grouped(points, group_sizes, first_bias, bias_per_row)
        on_cpu = points.device.type == "cpu"
        if padded is None:
            padded = not on_cpu and 0 < points.shape[0] <= GPU_PADDED_ROWS
        if padded:
            return self._forward_padded(points, sizes, group_sizes, first_bias, per_frame,
                                        bias_per_row, low_precision)
        if chunk_rows is None:
            chunk_rows = GROUP_CHUNK_ROWS if on_cpu else 1 << 62
        layers = self.layers()
        if low_precision:
            layers = [(w.to(torch.bfloat16), b.to(torch.bfloat16)) for w, b in layers[:-1]] + [
                layers[-1]
            ]
        # The chunks as one split (not slices: the backward of Q slices of a [Q, D] tensor fills
        # a [Q, D] zero gradient each, quadratic in the number of chunks; a split's is one cat).
        # Per-group weights by one unbind each (not by indexing: the backward of every
        # ``weight[group]`` fills a zero gradient of the whole [G, in, out] stack).
        point_weights = self.point_weight.unbind(0)
        group_layers = [(weight.unbind(0), layer_bias.unbind(0)) for weight, layer_bias in layers]
        segments = _chunk_segments(group_sizes, first_bias, per_frame, bias_per_row, chunk_rows)
        lengths = [length for _, length, _ in segments]
        point_chunks = torch.split(points, lengths)
        bias_chunks = torch.split(first_bias, lengths) if bias_per_row else None
        outputs = []
        for index_chunk, (group, _, group_bias) in enumerate(segments):
            bias = bias_chunks[index_chunk] if bias_per_row else group_bias
            fused = self._fused(point_chunks[index_chunk], group, bias, layers, low_precision)
            if fused is not None:
                outputs.append(fused)
                continue
            hidden = self.act(torch.addmm(bias, point_chunks[index_chunk],
                                          point_weights[group]))
            if low_precision:
                hidden = hidden.to(torch.bfloat16)
            for index, (weight, layer_bias) in enumerate(group_layers):
                last = index == len(group_layers) - 1
                if last and low_precision:
                    hidden = hidden.to(points.dtype)
                hidden = torch.addmm(layer_bias[group], hidden, weight[group])
                if not last:
                    hidden = self.act(hidden)
            outputs.append(hidden)
        if not outputs:
            return points.new_zeros(0, self.out_dim)
        return torch.cat(outputs, dim=0)

    def _check_grouped(self, points: torch.Tensor, group_sizes: list, first_bias: torch.Tensor,
                       bias_per_row: bool) -> tuple[bool, list[int]]:
        """:meth:`forward_grouped`'s arguments checked. -> (per-frame biases, rows of each
        group)"""
        per_frame = first_bias.dim() == 3 and not bias_per_row
        sizes = [sum(size) for size in group_sizes] if per_frame else group_sizes
        if len(group_sizes) != self.num_groups or sum(sizes) != points.shape[0]:
            raise ValueError(
                f"group_sizes must be {self.num_groups} "
                f"{'lists of ints' if per_frame else 'ints'} summing to {points.shape[0]}, "
                f"got {group_sizes}"
            )
        if per_frame:
            expected = (len(group_sizes[0]) if group_sizes else 0, self.num_groups, self.hidden)
        else:
            expected = (points.shape[0] if bias_per_row else self.num_groups, self.hidden)
        if first_bias.shape != expected or (per_frame and any(len(size) != expected[0]
                                                              for size in group_sizes)):
            raise ValueError(
                f"first_bias must have shape {list(expected)}, got {list(first_bias.shape)}"
            )
        return per_frame, sizes

    def _forward_padded(
        self,
        points: torch.Tensor,
        sizes: list[int],
        group_sizes: list,
        first_bias: torch.Tensor,
        per_frame: bool,
        bias_per_row: bool,
        low_precision: bool,
    ) -> torch.Tensor:
        """:meth:`forward_grouped` as one batched product a layer: the rows of every group
        copied into ``[G, M, in]`` (``M``: the largest group's rows; zeros elsewhere), run
        through the stacked weights, and the real rows read back. A few launches a layer in
        place of the loop's G (x B) each, which is what a GPU's eager step pays for.
        Differentiable twice (index_copy / index_select / baddbmm).

        points: [Q, point_dim]; sizes: G ints (rows of each group); the other arguments as in
        :meth:`forward_grouped`. -> [Q, out_dim]
        """
        groups, rows = self.num_groups, points.shape[0]
        if rows == 0:
            return points.new_zeros(0, self.out_dim)
        where, largest = _padded_rows(sizes, points.device)

        def pad(values: torch.Tensor) -> torch.Tensor:  # [Q, C] -> [G, M, C]
            out = values.new_zeros(groups * largest, values.shape[1])
            return out.index_copy(0, where, values).view(groups, largest, values.shape[1])

        if per_frame:  # each row's bias: its frame's, for its group
            frames = first_bias.shape[0]
            counts = torch.tensor([count for group in group_sizes for count in group],
                                  device=points.device)
            segment = torch.repeat_interleave(torch.arange(groups * frames, device=points.device),
                                              counts, output_size=rows)
            frame = segment % frames
            group = torch.div(segment, frames, rounding_mode="floor")
            bias = pad(first_bias[frame, group])
        elif bias_per_row:
            bias = pad(first_bias)
        else:
            bias = first_bias[:, None]
        hidden = self.act(torch.baddbmm(bias, pad(points), self.point_weight))
        layers = self.layers()
        for index, (weight, layer_bias) in enumerate(layers):
            last = index == len(layers) - 1
            if low_precision and not last:
                hidden = torch.baddbmm(layer_bias[:, None].to(torch.bfloat16),
                                       hidden.to(torch.bfloat16), weight.to(torch.bfloat16))
            else:
                hidden = torch.baddbmm(layer_bias[:, None], hidden.to(points.dtype), weight)
            if not last:
                hidden = self.act(hidden)
        return hidden.reshape(groups * largest, self.out_dim).index_select(0, where)


def _padded_rows(sizes: list[int], device: torch.device) -> tuple[torch.Tensor, int]:
    """Where each row of a group-sorted ``[Q, D]`` goes in a ``[G * M, D]`` padding (``M``: the
    largest group's rows). -> (row index [Q] int64, M)"""
    counts = torch.tensor(sizes, device=device)
    largest = max(sizes)
    starts = torch.cumsum(counts, 0) - counts
    group = torch.repeat_interleave(torch.arange(len(sizes), device=device), counts,
                                    output_size=sum(sizes))
    slot = torch.arange(sum(sizes), device=device) - starts[group]
    return group * largest + slot, largest


def _chunk_segments(group_sizes: list, first_bias: torch.Tensor, per_frame: bool,
                    bias_per_row: bool, chunk_rows: int) -> list[tuple]:
    """The row chunks of :meth:`StackedMLP.forward_grouped` in row order: (group, rows, first
    layer bias [hidden] or None with ``bias_per_row``); with ``per_frame`` the (group, frame)
    segments, each with its frame's bias. Biases by one unbind (see the caller)."""
    if per_frame:
        frame_biases = [bias.unbind(0) for bias in first_bias.unbind(0)]
        return [(group, min(chunk_rows, size - lo), frame_biases[frame][group])
                for group, frame_sizes in enumerate(group_sizes)
                for frame, size in enumerate(frame_sizes)
                for lo in range(0, size, chunk_rows)]
    group_biases = None if bias_per_row else first_bias.unbind(0)
    return [(group, min(chunk_rows, size - lo), None if bias_per_row else group_biases[group])
            for group, size in enumerate(group_sizes)
            for lo in range(0, size, chunk_rows)]


@torch.no_grad()
def geometric_init_(
    mlp: StackedMLP,
    radii: torch.Tensor,
    *,
    raw_dim: int = 3,
    axes: torch.Tensor | None = None,
    half_lengths: torch.Tensor | None = None,
    cond_std: float = 1e-3,
) -> None:
    """IGR/SAL geometric initialisation: MLP ``g`` starts as ``f_g(x) ~ |D_g x| - r_g``.

    Gropp et al. (IGR, ICML 2020) and Atzmon & Lipman (SAL, CVPR 2020): hidden weights
    ``N(0, 2/hidden)``, zero biases, output weights ``N(sqrt(pi/hidden), 1e-4)`` and output bias
    ``-r`` make a ReLU/Softplus MLP approximate the SDF of a sphere of radius ``r``. As in IDR and
    VolSDF, only the raw coordinates (the first ``raw_dim`` point inputs; the sinusoids start at
    zero weight) enter the first layer. With ``axes`` and ``half_lengths`` the sphere becomes a
    spheroid stretched along the bone, ``D = I - (1 - r / a) u u^T`` with ``a = half_length + r``
    (a capsule-like blob around the bone). The output is then calibrated to a unit slope
    between the surfaces ``|D x| = r`` and ``3 r`` and to zero on average over ``|D x| = r``.
    Conditioning weights start small (``cond_std``), so the initial shape barely depends on pose
    and latents.

    radii: [G] in network units; axes: [G, 3] unit vectors; half_lengths: [G] network units.
    """
    hidden = mlp.hidden
    groups = mlp.num_groups
    dtype = mlp.point_weight.dtype
    device = mlp.point_weight.device
    radii = radii.to(dtype=dtype, device=device)
    std = math.sqrt(2.0) / math.sqrt(hidden)
    first = torch.zeros_like(mlp.point_weight)
    raw = torch.randn(groups, raw_dim, hidden, dtype=dtype, device=device) * std
    eye = torch.eye(raw_dim, dtype=dtype, device=device)
    unsquash = eye.expand(groups, raw_dim, raw_dim)
    if axes is not None and half_lengths is not None:
        axes = axes.to(dtype=dtype, device=device)
        stretch = radii / (half_lengths.to(dtype=dtype, device=device) + radii)  # r / a
        outer = axes[:, :, None] * axes[:, None, :]
        squash = eye - (1.0 - stretch)[:, None, None] * outer
        unsquash = eye + (1.0 / stretch - 1.0)[:, None, None] * outer  # D^-1
        raw = squash.transpose(-1, -2) @ raw  # x @ (D^T G) = (D x) @ G
    first[:, :raw_dim] = raw
    mlp.point_weight.copy_(first)
    if mlp.cond_weight is not None:
        mlp.cond_weight.normal_(0.0, cond_std)
    mlp.first_bias.zero_()
    for weight, bias in zip(mlp.hidden_weights, mlp.hidden_biases, strict=True):
        weight.normal_(0.0, std)
        bias.zero_()
    mlp.out_weight.normal_(math.sqrt(math.pi) / math.sqrt(hidden), 1e-4)
    mlp.out_bias.zero_()
    # Calibrate: ReLU's cone |D x| is only approximated (Softplus(0) = log(2) / beta, finite
    # width, a rounded tip), which at radii of ~0.2 units moves the surface by a good fraction
    # of r. Rescale the output to a unit slope between the surfaces |D x| = r and 3 r, and
    # shift it to be 0 on average over |D x| = r.
    num_dirs = 64
    dirs = torch.randn(num_dirs, raw_dim, dtype=dtype, device=device)
    dirs = dirs / dirs.norm(dim=-1, keepdim=True)
    surface = radii[:, None, None] * (dirs @ unsquash.transpose(-1, -2))  # [G, D, raw]
    probe = torch.zeros(1, 2 * num_dirs, groups, mlp.point_dim, dtype=dtype, device=device)
    probe[0, :num_dirs, :, :raw_dim] = surface.transpose(0, 1)
    probe[0, num_dirs:, :, :raw_dim] = 3.0 * surface.transpose(0, 1)
    zero_bias = torch.zeros(1, groups, hidden, dtype=dtype, device=device)
    values = mlp.forward_dense(probe, zero_bias)[0, :, :, 0]  # [2 D, G]
    rise = (values[num_dirs:] - values[:num_dirs]).mean(dim=0)  # [G]
    mlp.out_weight.mul_((2.0 * radii / rise)[:, None, None])
    on_surface = mlp.forward_dense(probe[:, :num_dirs], zero_bias)[0].mean(dim=0)  # [G, out]
    mlp.out_bias.copy_(-on_surface)


@torch.no_grad()
def soft_min_init_(
    mlp: StackedMLP, value_offset: int, num_values: int, sharpness: float, value_max: float
) -> bool:
    """Initialise a one-group MLP so that its logits are ``sharpness * (value_max - v_j)``.

    ``v`` are the inputs ``[value_offset, value_offset + num_values)`` (per-bone SDFs in network
    units), so a softmax over the logits is a soft minimum of the per-bone SDFs: a fresh LISA
    model blends its bone blobs into their union (a blobby hand) instead of their average.
    ``num_values`` hidden units per layer carry ``v`` through identity weights (Softplus is
    linear well above zero, which the bias ``sharpness * value_max`` ensures for
    ``v < value_max``); the other units keep a small random init.
    Returns False (and changes nothing) when the hidden width is below ``num_values``.
    """
    if mlp.num_groups != 1 or mlp.hidden < num_values or mlp.out_dim != num_values:
        return False
    span = slice(0, num_values)
    eye = torch.eye(num_values, dtype=mlp.point_weight.dtype, device=mlp.point_weight.device)
    mlp.point_weight[0, :, span] = 0.0
    mlp.point_weight[0, value_offset : value_offset + num_values, span] = -sharpness * eye
    mlp.first_bias[0, span] = sharpness * value_max
    for weight, bias in zip(mlp.hidden_weights, mlp.hidden_biases, strict=True):
        weight[0, span, :] = 0.0
        weight[0, :, span] = 0.0
        weight[0, span, span] = eye
        bias[0, span] = 0.0
    mlp.out_weight.mul_(0.01)
    mlp.out_weight[0, span, :] = eye
    mlp.out_bias.zero_()
    return True
